#!/usr/bin/env python3
"""Build assets/fixtures/frozen_window.onnx: a graph with the window trap of docs/export.md.

Usage:  /root/.cache/d3il/venvs/torch/bin/python scripts/make_frozen_window_fixture.py [outdir]

A tiny Aligning policy (obs [B, T, 20] -> actions [B, 3], manifest k = 5, window
`grow`) whose `forward` computes a Python int from a tensor size,
`int(obs.size()[1] / 1)`. The TorchScript tracer of `torch.onnx.export` freezes
that int to the example window (5), so the exported Reshape asks for
`[B, 5, 20]` whatever the window: onnxruntime accepts the file and runs it at the
example window, tract's analysis with a symbolic window refuses it. The Rust
test (policy/tests/policies/onnx_fixtures.rs) checks that the refusal names this cause
and its fix. Weights are random (fixed seed): the file tests admission only.
"""

import json
import os
import sys
import warnings

import torch
from torch import nn

OBS, ACT, K = 20, 3, 5


class FrozenWindow(nn.Module):
    def __init__(self):
        super().__init__()
        self.lin = nn.Linear(OBS, ACT)

    def forward(self, obs):
        # The trap: a Python int of a tensor size, frozen by tracing to K.
        steps = int(obs.size()[1] / 1)
        x = obs.reshape(obs.shape[0], steps, OBS).mean(dim=1)
        return 0.001 * torch.tanh(self.lin(x))


def main(out):
    torch.manual_seed(0)
    model = FrozenWindow().eval()
    path = os.path.join(out, "frozen_window.onnx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TracerWarning is the point
        torch.onnx.export(
            model,
            (torch.zeros(2, K, OBS),),
            path,
            input_names=["obs"],
            output_names=["actions"],
            dynamic_axes={"obs": {0: "B", 1: "T"}, "actions": {0: "B"}},
            opset_version=17,
            dynamo=False,
        )
    manifest = {"task": "aligning", "obs_type": "state", "history": K, "horizon": 1, "execute": 1, "window": "grow"}
    with open(os.path.join(out, "frozen_window.json"), "w") as f:
        json.dump(manifest, f, indent=2)
        f.write("\n")
    print(f"wrote {path} ({os.path.getsize(path)} bytes)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "assets", "fixtures"))
