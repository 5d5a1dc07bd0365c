"""Write a tiny SYNTHETIC demonstration set in the layout the D3IL reference's dataset
classes read (environments/dataset/*_dataset.py in ALRhub/d3il), plus manifest.json.

Only for testing the zoo driver (scripts/zoo/train_cell.py) where `d3il demos` has not
recorded real demonstrations: the trajectories are smooth random walks, not task
solutions, and a policy trained on them means nothing. The manifest says so
("synthetic": true) and the provenance record copies that.

    python scripts/zoo/synth_demos.py --task aligning --episodes 8 --steps 60 --out /tmp/demos/aligning

Layout per task (relative to the checkout's environments/dataset/data/<dir>/):
  aligning   all_data/state/<name>.pkl, train_files.pkl, eval_files.pkl
  pushing    all_data/<name>.pkl,       train_files.pkl, eval_files.pkl
  avoiding   data/<name>.pkl            (the reference reads every file of the folder)
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
from pathlib import Path

import numpy as np


def _walk(rng, steps, dim, scale=0.01, start=None):
    start = rng.normal(0.0, 0.1, dim) if start is None else np.asarray(start, float)
    steps_ = rng.normal(0.0, scale, (steps, dim)).cumsum(axis=0)
    return (start + steps_).astype(np.float64)


def _quat(rng, steps):
    q = _walk(rng, steps, 4, 0.01, start=[1.0, 0.0, 0.0, 0.0])
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def episode(task: str, rng, steps: int) -> dict:
    des = _walk(rng, steps, 3)
    robot = {"des_c_pos": des, "c_pos": des + rng.normal(0.0, 1e-3, des.shape)}
    if task == "avoiding":
        return {"robot": robot}
    if task == "aligning":
        return {
            "robot": robot,
            "push-box": {"pos": _walk(rng, steps, 3, 0.005), "quat": _quat(rng, steps)},
            # the target pose is constant in every real Aligning demonstration (std 0)
            "target-box": {"pos": np.tile([0.5, 0.0, 0.0], (steps, 1)), "quat": np.tile([1.0, 0, 0, 0], (steps, 1))},
        }
    if task == "pushing":
        out = {"robot": robot}
        for box in ("red-box", "green-box"):
            out[box] = {"pos": _walk(rng, steps, 3, 0.005), "quat": _quat(rng, steps)}
        for target in ("red-target", "green-target"):
            out[target] = {"pos": np.tile(rng.normal(0.0, 0.2, 3), (steps, 1))}
        return out
    raise SystemExit(f"synth_demos: task {task!r} not supported (aligning, avoiding, pushing)")


def write(task: str, episodes: int, steps: int, out: Path, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    out.mkdir(parents=True, exist_ok=True)
    sub = {"aligning": "all_data/state", "pushing": "all_data", "avoiding": "data"}[task]
    (out / sub).mkdir(parents=True, exist_ok=True)
    names = []
    for i in range(episodes):
        name = f"env_{i:03d}_00.pkl"
        with open(out / sub / name, "wb") as f:
            pickle.dump(episode(task, rng, steps + int(rng.integers(0, 10))), f)
        names.append(name)
    if task != "avoiding":
        n_eval = max(1, episodes // 8)
        with open(out / "eval_files.pkl", "wb") as f:
            pickle.dump(names[:n_eval], f)
        with open(out / "train_files.pkl", "wb") as f:
            pickle.dump(names[n_eval:], f)
    files = {}
    for p in sorted(out.rglob("*")):
        if p.is_file() and p.name != "manifest.json":
            files[str(p.relative_to(out))] = hashlib.sha256(p.read_bytes()).hexdigest()
    manifest = {
        "version": "synthetic-1",
        "synthetic": True,
        "task": task,
        "episodes": episodes,
        "seed": seed,
        "files": files,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", required=True, choices=["aligning", "avoiding", "pushing"])
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, type=Path)
    a = ap.parse_args(argv)
    print(write(a.task, a.episodes, a.steps, a.out, a.seed))


if __name__ == "__main__":
    main()
