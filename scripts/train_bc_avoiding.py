"""Train a deterministic BC-MLP for Avoiding from recorded rollouts (a probe
policy for the robustness track, docs/robustness.md): the paper's BC baseline
in kind (MLP, mean-squared error on the action), trained on rollouts that
`d3il eval --json` recorded, e.g. of the scripted expert:

    d3il eval --task avoiding --policy scripted:avoiding:all-paths --json demos.json
    python scripts/train_bc_avoiding.py demos.json avoid_bc.onnx

The observation is rebuilt from each rollout's trace as the evaluator builds
it (docs/original-d3il.md §10.2.3): the previous command (the reset's
measured TCP, then the sum of the actions) and the measured TCP at the start
of the previous step. Standardisation is part of the exported graph, so the
manifest has none. Needs torch and onnx (the torch virtualenv of the tests).
"""

import base64
import json
import sys
import zlib

import numpy as np
import torch


def unpack_f32(text):
    return np.frombuffer(zlib.decompress(base64.b64decode(text), -15), dtype="<f4")


def pairs(doc):
    obs, act = [], []
    for r in doc["rollouts"]:
        if not r["success"] or r.get("trace") is None:
            continue
        t = r["trace"]
        a = unpack_f32(t["actions"]).reshape(-1, t["act_dim"]).astype(np.float64)
        tcp = unpack_f32(t["tcp"]).reshape(-1, 3)[:, :2].astype(np.float64)
        cmd = tcp[0].copy()
        for k in range(len(a)):
            m = tcp[max(k - 1, 0)]
            obs.append([cmd[0], cmd[1], m[0], m[1]])
            act.append(a[k])
            cmd = cmd + a[k]
    return np.asarray(obs, np.float32), np.asarray(act, np.float32)


class Policy(torch.nn.Module):
    def __init__(self, o_mean, o_std, a_mean, a_std):
        super().__init__()
        self.register_buffer("o_mean", torch.tensor(o_mean))
        self.register_buffer("o_std", torch.tensor(o_std))
        self.register_buffer("a_mean", torch.tensor(a_mean))
        self.register_buffer("a_std", torch.tensor(a_std))
        self.net = torch.nn.Sequential(
            torch.nn.Linear(4, 256),
            torch.nn.ReLU(),
            torch.nn.Linear(256, 256),
            torch.nn.ReLU(),
            torch.nn.Linear(256, 2),
        )

    def standardised(self, x):
        return self.net((x - self.o_mean) / self.o_std)

    def forward(self, obs):  # obs [B, 1, 4] -> actions [B, 2]
        return self.standardised(obs[:, -1]) * self.a_std + self.a_mean


def main(demos, out, epochs=60, seed=0):
    torch.manual_seed(seed)
    obs, act = pairs(json.load(open(demos)))
    print(f"{len(obs)} (observation, action) pairs")
    p = Policy(obs.mean(0), obs.std(0) + 1e-6, act.mean(0), act.std(0) + 1e-6)
    x = torch.tensor(obs)
    y = (torch.tensor(act) - p.a_mean) / p.a_std
    opt = torch.optim.Adam(p.net.parameters(), lr=1e-3)
    for epoch in range(epochs):
        perm = torch.randperm(len(x))
        total = 0.0
        for i in range(0, len(x), 256):
            b = perm[i : i + 256]
            loss = torch.nn.functional.mse_loss(p.standardised(x[b]), y[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(b)
        if epoch % 10 == 9:
            print(f"epoch {epoch + 1}: mse {total / len(x):.4f}")
    p.eval()
    torch.onnx.export(
        p,
        (torch.zeros(1, 1, 4),),
        out,
        input_names=["obs"],
        output_names=["actions"],
        dynamic_axes={"obs": {0: "B"}, "actions": {0: "B"}},
        opset_version=17,
        dynamo=False,
    )
    manifest = {"task": "avoiding", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}
    with open(out[: -len(".onnx")] + ".json", "w") as f:
        json.dump(manifest, f, indent=2)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
