"""Our own reader of `d3il demos` output, written from the D3IL reference
code's dataset contract (ALRhub/d3il, environments/dataset/<task>_dataset.py
and configs/<task>_config.yaml; read, not copied):

* the train/eval lists are pickles of file names that `np.load(path,
  allow_pickle=True)` reads; Avoiding lists its episode directory instead;
* each episode is a pickled dict; the observation is the concatenation of
  robot/des_c_pos, robot/c_pos and the task's objects (Pushing and Sorting
  take xy and tan(yaw) of each box from pos and a wxyz quaternion), rows 0..T-1;
* the action is des_c_pos[t + 1] - des_c_pos[t], cast to float32;
* Stacking is joint space: its observation is robot/des_j_pos, robot/gripper_width
  (one-dimensional, expanded) and x, y, z, tan(yaw) of the red, green and blue
  boxes; its action des_j_pos[t + 1] - des_j_pos[t] and gripper_width[t + 1]; it
  also reads des_j_vel, des_c_pos, des_c_quat, c_pos, c_quat, j_pos and j_vel;
* an episode must fit the config's max_len_data.

Then the contract with our simulator: every episode's actions, rebuilt as the
reference rebuilds them, replayed open-loop by `d3il replay --task T` from the
episode's training state, give the observations the file holds and the
success the manifest records.

    python3 tests/demos_contract.py D3IL_BIN TASK DEMOS_DIR

Exits non-zero with a message on the first broken promise.
"""

import hashlib
import json
import os
import pickle
import subprocess
import sys

import numpy as np

# obs_dim and max_len_data of the reference's task configs.
CONFIG = {
    "avoiding": (4, 200),
    "aligning": (20, 512),
    "pushing": (10, 512),
    "sorting-2": (10, 600),
    "sorting-4": (16, 600),
    "sorting-6": (22, 1200),
    "stacking": (20, 1000),
}

# Width of the previous command at the start of the observation (and of the
# action): what the replay's environment observations are compared after.
COMMAND = {"aligning": 3, "stacking": 8}

STACKING_ROBOT = ("des_j_pos", "des_j_vel", "des_c_pos", "des_c_quat", "c_pos", "c_quat",
                  "j_pos", "j_vel", "gripper_width")


def tan_yaw(quat):
    w, x, y, z = quat[:, 0], quat[:, 1], quat[:, 2], quat[:, 3]
    return np.tan(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))[:, None]


def planar_box(ep, name):
    return [ep[name]["pos"][:, :2], tan_yaw(ep[name]["quat"])]


def observation(task, ep):
    robot = ep["robot"]
    if task == "avoiding":
        parts = [robot["des_c_pos"][:, :2], robot["c_pos"][:, :2]]
    elif task == "aligning":
        parts = [robot["des_c_pos"], robot["c_pos"]]
        for name in ("push-box", "target-box"):
            parts += [ep[name]["pos"], ep[name]["quat"]]
    elif task == "pushing":
        parts = [robot["des_c_pos"][:, :2], robot["c_pos"][:, :2]]
        parts += planar_box(ep, "red-box") + planar_box(ep, "green-box")
        for name in ("red-target", "green-target"):
            assert ep[name]["pos"].shape[1] >= 2, f"{name}/pos must have x and y"
    elif task == "stacking":
        for key in STACKING_ROBOT:
            assert len(robot[key]) == len(robot["des_j_pos"]), f"robot/{key} has another length"
        parts = [robot["des_j_pos"], robot["gripper_width"][:, None]]
        for name in ("red-box", "green-box", "blue-box"):
            parts += [ep[name]["pos"], tan_yaw(ep[name]["quat"])]
    else:
        k = int(task.split("-")[1]) // 2
        parts = [robot["des_c_pos"][:, :2], robot["c_pos"][:, :2]]
        for colour in ("red", "blue"):
            for i in range(1, k + 1):
                parts += planar_box(ep, f"{colour}-box{i}")
    return np.concatenate(parts, axis=-1)


def fail(msg):
    sys.exit(f"demos contract: {msg}")


def main(d3il, task, root):
    manifest = json.load(open(os.path.join(root, "manifest.json")))
    if manifest["task"] != task:
        fail(f"manifest task {manifest['task']} != {task}")
    for rel, digest in manifest["files"].items():
        with open(os.path.join(root, rel), "rb") as f:
            if hashlib.sha256(f.read()).hexdigest() != digest:
                fail(f"{rel}: sha256 differs from the manifest")
    lay = manifest["reference_layout"]
    ep_dir = os.path.join(root, lay["episode_dir"])
    if lay["train_list"]:
        train = list(np.load(os.path.join(root, lay["train_list"]), allow_pickle=True))
        evals = list(np.load(os.path.join(root, lay["eval_list"]), allow_pickle=True))
        if not train or not evals:
            fail("empty train or eval list")
        names = train + evals
    else:
        names = sorted(os.listdir(ep_dir))
    listed = {e["file"]: e for e in manifest["episode_list"]}
    if sorted(names) != sorted(listed):
        fail("the file lists and the manifest name different episodes")
    obs_dim, max_len = CONFIG[task]
    behaviours = {}
    for name in names:
        with open(os.path.join(ep_dir, name), "rb") as f:
            ep = pickle.load(f)
        full = observation(task, ep)
        cmd = COMMAND.get(task, 2)
        obs = full[:-1].astype(np.float32)
        if task == "stacking":
            q, grip = ep["robot"]["des_j_pos"], ep["robot"]["gripper_width"][:, None]
            act = np.concatenate([q[1:] - q[:-1], grip[1:]], axis=-1).astype(np.float32)
        else:
            des = ep["robot"]["des_c_pos"]
            act = (des[1:] - des[:-1]).astype(np.float32)[:, :cmd]
        if obs.shape[1] != obs_dim:
            fail(f"{name}: observation width {obs.shape[1]}, the config says {obs_dim}")
        if len(act) > max_len:
            fail(f"{name}: {len(act)} steps do not fit max_len_data {max_len}")
        entry = listed[name]
        if len(act) != entry["steps"]:
            fail(f"{name}: {len(act)} actions, manifest says {entry['steps']}")
        episode = {"context": entry["context"], "actions": act.tolist()}
        out = subprocess.run(
            [d3il, "replay", "--task", task, "--input", "/dev/stdin"],
            input=json.dumps(episode).encode(),
            capture_output=True,
            check=False,
        )
        if out.returncode != 0:
            fail(f"{name}: d3il replay failed: {out.stderr.decode()[-2000:]}")
        rep = json.loads(out.stdout)
        if not rep["success"]:
            fail(f"{name}: the replayed actions do not succeed (the expert's episode did)")
        env_obs = np.asarray(rep["observations"], dtype=np.float32)[: len(obs)]
        # Where tan(yaw) is large (a box turned near 90 degrees) compare the
        # angles: a quaternion holds the yaw, and tan near the pole keeps only
        # about 1e-16 / (pi/2 - yaw) of relative precision (none at 1e15).
        want = obs[:, cmd:]
        rel = np.abs(env_obs - want) / np.maximum(1.0, np.abs(want))
        angle = np.abs(np.arctan(env_obs.astype(np.float64)) - np.arctan(want.astype(np.float64)))
        err = np.where(np.abs(want) > 1e4, angle, rel).max()
        if err > 1e-5:
            fail(f"{name}: the file's observations differ from the replay's by {err}")
        behaviours[entry["behaviour"]] = behaviours.get(entry["behaviour"], 0) + 1
    if behaviours != manifest["behaviours"]["histogram"]:
        fail(f"histogram {behaviours} != manifest {manifest['behaviours']['histogram']}")
    print(json.dumps({"task": task, "episodes": len(names), "behaviours": len(behaviours)}))


if __name__ == "__main__":
    main(*sys.argv[1:])
