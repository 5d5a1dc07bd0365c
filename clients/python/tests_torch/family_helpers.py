"""Shared by the tests of the BC, VAE-State, VAE-ACT and BeT-MLP families: which
registered family recognises an agent, and the ONNX export of a family's module
compared with onnxruntime on the check's cases.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Dict, List, Sequence

import torch

from d3il_client.agents import _MODULES, FAMILY_NAMES, recognise
from d3il_client.agents.base import Family, Settings
from d3il_client.agents.check import Case


def matching_families(agent: Any) -> List[str]:
    """Names of the families that recognise ``agent``: ``recognise`` when every
    family module exists, else the families of the modules written so far.
    """
    try:
        return [recognise(agent).name]
    except ModuleNotFoundError:
        pass
    found = []
    for name in FAMILY_NAMES:
        try:
            mod = importlib.import_module(f"d3il_client.agents.{_MODULES[name]}")
        except ModuleNotFoundError:
            continue
        fams = getattr(mod, "FAMILIES", None) or [mod.FAMILY]
        found += [f.name for f in fams if f.name == name and f.matches(agent)]
    return found


class _Positional(torch.nn.Module):
    def __init__(self, module: torch.nn.Module, s: Settings) -> None:
        super().__init__()
        self.module, self.s = module, s

    def forward(self, obs, *rest):
        it = iter(rest)
        prev = next(it) if self.s.prev_actions else None
        noise = next(it) if self.s.noise_shape is not None else None
        return self.module(obs, prev, noise)


def _inputs(s: Settings, c: Case) -> Dict[str, torch.Tensor]:
    out = {"obs": c.obs}
    if s.prev_actions:
        assert c.prev_actions is not None
        out["prev_actions"] = c.prev_actions
    if s.noise_shape is not None:
        assert c.noise is not None
        out["noise"] = c.noise
    return out


def export_and_compare(family: Family, agent: Any, cases: Sequence[Case], path: Path) -> float:
    """Export ``family.graph(agent)`` (opset 18, TorchScript exporter, batch — and a
    growing window — symbolic) from the case with the largest window, run every case
    in onnxruntime and return the largest difference from the module's actions.
    """
    import onnxruntime as ort

    s = family.settings(agent)
    module = _Positional(family.graph(agent).eval(), s).eval()
    example = max(cases, key=lambda c: c.window)
    names = list(_inputs(s, example))
    axes: Dict[str, Dict[int, str]] = {n: {0: "B"} for n in names}
    if s.window == "grow" and s.history > 1:
        axes["obs"] = {0: "B", 1: "T"}
        if s.prev_actions:
            axes["prev_actions"] = {0: "B", 1: "P"}
    axes["actions"] = {0: "B"}
    with torch.no_grad():
        torch.onnx.export(
            module,
            tuple(_inputs(s, example).values()),
            str(path),
            input_names=names,
            output_names=["actions"],
            dynamic_axes=axes,
            opset_version=18,
            dynamo=False,
        )
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    worst = 0.0
    for c in cases:
        (got,) = sess.run(["actions"], {n: t.numpy() for n, t in _inputs(s, c).items()})
        got_t = torch.as_tensor(got)
        assert got_t.shape == c.actions.shape, (got_t.shape, c.actions.shape)
        assert torch.isfinite(got_t).all()
        worst = max(worst, float((got_t - c.actions).abs().max()))
    return worst
