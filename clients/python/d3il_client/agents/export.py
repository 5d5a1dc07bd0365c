"""Export a reference agent object to one ONNX graph, checked before it is written.

``export_agent(agent, task="aligning", out="policy.onnx")`` (and ``d3il-client export
--agent MODULE:make_agent --checkpoint CKPT --task aligning --out policy.onnx``):

1. recognise the agent's family and read its settings from the object
   (window, chunk, executed actions, sampler);
2. build the family's batched module of the agent's own ``predict`` path and check it
   against ``predict`` itself, fed the same random draws, over windows 1..k and more
   (``check.against_predict``);
3. export it (``torch.onnx.export``, TorchScript exporter, opset 18, batch and — for
   growing windows — window symbolic) and check the file in onnxruntime and in the
   leaderboard's own runtime (``d3il infer``: the admission and the tract runtime the
   evaluator uses) on the same inputs;
4. only then write ``out`` and its manifest (``out`` with ``.json``) from what the
   agent actually does.

Every check compares actions within ``atol`` (1e-5 by default). A failed check writes
nothing and says which check failed, at which step and window.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Union

import torch

from . import check as checks
from . import recognise
from .base import Settings


class ExportFailed(RuntimeError):
    """A check failed before anything was written; the message says which."""


@dataclasses.dataclass
class ExportReport:
    """What ``export_agent`` did: the family, settings, files and the checks' differences."""

    family: str
    settings: Settings
    onnx: Path
    manifest: Path
    calls_checked: int
    windows_checked: List[int]
    max_diff_predict: float  # module vs the agent's own predict(), same draws
    max_diff_onnxruntime: float
    max_diff_d3il: Optional[float]  # None: no d3il binary was found (said in `notes`)
    bytes: int
    notes: List[str]

    def summary(self) -> str:
        """A few lines for the command line."""
        s = self.settings
        lines = [
            f"{self.family}: k = {s.history} ({s.window}), H = {s.horizon}, E = {s.execute}"
            + (f", {s.sampler}" if s.sampler else ""),
            f"checked {self.calls_checked} model calls (windows {', '.join(map(str, self.windows_checked))}):"
            f" predict() within {self.max_diff_predict:.2g}, onnxruntime within {self.max_diff_onnxruntime:.2g}"
            + (f", d3il (tract) within {self.max_diff_d3il:.2g}" if self.max_diff_d3il is not None else ""),
            f"wrote {self.onnx} ({self.bytes / 1e6:.1f} MB) and {self.manifest}",
        ]
        return "\n".join(lines + self.notes)


class _Graph(torch.nn.Module):
    """The family module with the ONNX inputs as positional arguments."""

    def __init__(self, module: torch.nn.Module, prev: bool, noise: bool) -> None:
        super().__init__()
        self.module, self.prev, self.noise = module, prev, noise

    def forward(self, obs, *rest):
        it = iter(rest)
        prev = next(it) if self.prev else None
        noise = next(it) if self.noise else None
        return self.module(obs, prev, noise)


def input_names(s: Settings) -> List[str]:
    """The ONNX inputs of an agent with settings ``s``, in order."""
    return ["obs"] + (["prev_actions"] if s.prev_actions else []) + (["noise"] if s.noise_shape is not None else [])


def case_inputs(s: Settings, case: checks.Case) -> List[torch.Tensor]:
    """One check case as the ONNX inputs, in ``input_names`` order."""
    out = [case.obs]
    if s.prev_actions:
        assert case.prev_actions is not None
        out.append(case.prev_actions)
    if s.noise_shape is not None:
        assert case.noise is not None
        out.append(case.noise)
    return out


def _export(module: torch.nn.Module, s: Settings, example: checks.Case, path: Path, opset: int) -> None:
    names = input_names(s)
    axes: Dict[str, Dict[int, str]] = {n: {0: "B"} for n in names}
    if s.window == "grow" and s.history > 1:
        axes["obs"] = {0: "B", 1: "T"}
        if s.prev_actions:
            axes["prev_actions"] = {0: "B", 1: "P"}
    axes["actions"] = {0: "B"}
    wrapper = _Graph(module, s.prev_actions, s.noise_shape is not None).eval()
    with torch.no_grad():
        torch.onnx.export(
            wrapper,
            tuple(case_inputs(s, example)),
            str(path),
            input_names=names,
            output_names=["actions"],
            dynamic_axes=axes,
            opset_version=opset,
            dynamo=False,
        )


def _max_diff(a: Any, b: torch.Tensor) -> float:
    t = torch.as_tensor(a, dtype=torch.float32).reshape(b.shape)
    if not torch.isfinite(t).all():
        return float("inf")
    return float((t - b).abs().max().item()) if b.numel() else 0.0


def check_onnxruntime(path: Path, s: Settings, cases: Sequence[checks.Case]) -> float:
    """Largest difference between onnxruntime's outputs and the module's on ``cases``."""
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    worst = 0.0
    for c in cases:
        feeds = {n: t.numpy() for n, t in zip(input_names(s), case_inputs(s, c), strict=True)}
        (got,) = sess.run(["actions"], feeds)
        worst = max(worst, _max_diff(got, c.actions))
    return worst


def find_d3il(d3il: Optional[str] = None) -> Optional[str]:
    """The ``d3il`` binary: the argument, ``$D3IL_BIN``, or ``d3il`` on the PATH."""
    if d3il:
        return d3il
    return os.environ.get("D3IL_BIN") or shutil.which("d3il")


def check_d3il(d3il: str, path: Path, manifest: Path, s: Settings, cases: Sequence[checks.Case]) -> float:
    """Largest difference between ``d3il infer`` (the evaluator's admission and tract
    runtime) and the module on ``cases``; :class:`ExportFailed` with the evaluator's
    message when it refuses the file.
    """
    doc = {
        "cases": [
            {
                "batch": int(c.obs.shape[0]),
                "window": int(c.window),
                "obs": c.obs.reshape(-1).tolist(),
                "prev_actions": c.prev_actions.reshape(-1).tolist() if c.prev_actions is not None else None,
                "noise": c.noise.reshape(-1).tolist() if c.noise is not None else None,
            }
            for c in cases
        ]
    }
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
        json.dump(doc, f)
        inputs = f.name
    try:
        p = subprocess.run(
            [d3il, "infer", "--policy", str(path), "--manifest", str(manifest), "--input", inputs],
            capture_output=True,
            text=True,
        )
    finally:
        os.unlink(inputs)
    if p.returncode != 0:
        raise ExportFailed(f"the leaderboard's runtime (d3il infer) refused the exported graph:\n{p.stderr.strip()}")
    out = json.loads(p.stdout)["cases"]
    return max((_max_diff(o["actions"], c.actions) for o, c in zip(out, cases, strict=True)), default=0.0)


def export_agent(
    agent: Any,
    task: str,
    out: Union[str, os.PathLike[str]] = "policy.onnx",
    *,
    atol: float = 1e-5,
    batch: int = 3,
    steps: Optional[int] = None,
    d3il: Optional[str] = None,
    require_d3il: bool = False,
    opset: int = 18,
) -> ExportReport:
    """Export ``agent`` (a D3IL reference agent object) for ``task`` to ``out`` and its
    manifest, after checking the graph against the agent's own ``predict``,
    onnxruntime and the leaderboard's runtime (module docstring). Raises
    :class:`d3il_client.agents.UnknownAgent` for an agent of no known family and
    :class:`ExportFailed` (or ``check.CheckFailed``) when a check fails; nothing is
    written then.
    """
    from ..manifest import TASKS, check_choice

    check_choice("task", task, TASKS)
    family = recognise(agent)
    s = family.settings(agent)
    module = family.graph(agent).eval()
    cases = checks.against_predict(agent, family, batch=batch, steps=steps, atol=atol, module=module)
    example = max(cases, key=lambda c: c.window)
    out = Path(out)
    manifest_path = out.with_suffix(".json")
    notes: List[str] = []
    with tempfile.TemporaryDirectory(dir=out.parent if out.parent.exists() else None) as tmp:
        onnx_tmp = Path(tmp) / out.name
        manifest_tmp = onnx_tmp.with_suffix(".json")
        _export(module, s, example, onnx_tmp, opset)
        manifest_tmp.write_text(json.dumps(s.manifest(task), indent=2) + "\n")
        ort_diff = check_onnxruntime(onnx_tmp, s, cases)
        if not ort_diff <= atol:
            raise ExportFailed(
                f"onnxruntime's outputs differ from the module's by {ort_diff:.3g} (> {atol:g}): "
                "the export changed the computation; report this with the agent's family"
            )
        d3il_diff: Optional[float] = None
        binary = find_d3il(d3il)
        if binary is None:
            msg = (
                "not checked in the leaderboard's runtime: no d3il binary (pass d3il=, set D3IL_BIN or put d3il "
                "on the PATH); the server's dry run checks the file when you submit it"
            )
            if require_d3il:
                raise ExportFailed(msg)
            notes.append("note: " + msg)
        else:
            d3il_diff = check_d3il(binary, onnx_tmp, manifest_tmp, s, cases)
            if not d3il_diff <= atol:
                raise ExportFailed(
                    f"the leaderboard's runtime (d3il infer) differs from the module by {d3il_diff:.3g} (> {atol:g})"
                )
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(onnx_tmp), out)
        shutil.move(str(manifest_tmp), manifest_path)
    return ExportReport(
        family=family.name,
        settings=s,
        onnx=out,
        manifest=manifest_path,
        calls_checked=len(cases),
        windows_checked=sorted({c.window for c in cases}),
        max_diff_predict=max(c.predict_diff for c in cases),
        max_diff_onnxruntime=ort_diff,
        max_diff_d3il=d3il_diff,
        bytes=out.stat().st_size,
        notes=notes,
    )
