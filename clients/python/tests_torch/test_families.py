"""Every D3IL method family, end to end with this build's ``d3il`` ($D3IL_BIN).

Per family: the reference-like agent (tests_torch/reference_like) is recognised,
exported with ``export_agent`` — which checks the graph against the agent's own
``predict()`` fed the same draws, onnxruntime and ``d3il infer`` (tract, the
evaluator's runtime) — and the file is evaluated by ``d3il eval --protocol quick``
on the quick protocol's first initial state (``--shard 1/3``); then the agent object
itself is served (``python -m d3il_client.serve --agent``) and
evaluated by ``d3il eval`` over the remote protocol with no flag (a local endpoint; the
quick protocol's first initial state), its first actions equal to the exported
graph's where the policy is deterministic. That served actions equal ``predict()``
fed the same draws, stochastic families included, is test_serve_batched.py's.
"""

from __future__ import annotations

import base64
import importlib
import json
import os
import pkgutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from typing import Any, Callable, Dict, List

import pytest
import reference_like

from d3il_client.agents import FAMILY_NAMES, recognise
from d3il_client.agents.export import export_agent

D3IL = os.environ.get("D3IL_BIN", "d3il")


def mimics() -> Dict[str, str]:
    """family -> "module:factory" of every reference-like agent factory; a module's
    ``make_small_agent`` (a narrower network for these end-to-end runs) is preferred
    to the ones named like the reference's sizes.
    """
    found: Dict[str, str] = {}
    for m in pkgutil.iter_modules(reference_like.__path__):
        mod = importlib.import_module(f"reference_like.{m.name}")
        names = sorted(n for n in dir(mod) if n.startswith("make_") and n.endswith("agent"))
        for name in sorted(names, key=lambda n: n != "make_small_agent"):
            f = getattr(mod, name)
            if callable(f):
                found.setdefault(recognise(f()).name, f"reference_like.{m.name}:{name}")
    return found


MIMICS = mimics()


def make(spec: str) -> Any:
    mod, _, name = spec.partition(":")
    factory: Callable[[], Any] = getattr(importlib.import_module(mod), name)
    return factory()


def test_every_family_has_a_reference_like_agent():
    assert sorted(MIMICS) == sorted(FAMILY_NAMES)


def unpack_f32(text: str) -> List[float]:
    raw = zlib.decompress(base64.b64decode(text), -15)
    return list(struct.unpack(f"<{len(raw) // 4}f", raw))


def first_actions(result: Dict[str, Any], act_dim: int) -> Dict[int, List[float]]:
    """initial-state index -> the first action the environment received."""
    out: Dict[int, List[float]] = {}
    for r in result["rollouts"]:
        trace = r.get("trace")
        if trace is None:
            continue
        out.setdefault(int(r["context_index"]), unpack_f32(trace["actions"])[:act_dim])
    return out


def evaluate(policy: str, out: Path, *extra: str) -> Dict[str, Any]:
    p = subprocess.run(
        [D3IL, "eval", "--task", "aligning", "--policy", policy, "--protocol", "quick", "--json", str(out), *extra],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert p.returncode == 0, f"d3il eval --policy {policy} failed:\n{p.stdout}\n{p.stderr}"
    doc: Dict[str, Any] = json.loads(out.read_text())
    return doc


@pytest.mark.parametrize("family", FAMILY_NAMES)
def test_export_check_evaluate_and_serve(family: str, tmp_path: Path):
    assert family in MIMICS, f"no reference-like agent of family {family}"
    agent = make(MIMICS[family])
    assert recognise(agent).name == family
    report = export_agent(agent, "aligning", tmp_path / "policy.onnx", require_d3il=True)
    s = report.settings
    assert report.max_diff_predict <= 1e-5 and report.max_diff_onnxruntime <= 1e-5
    assert report.max_diff_d3il is not None and report.max_diff_d3il <= 1e-5
    assert max(report.windows_checked) == s.history and min(report.windows_checked) == (
        1 if s.window == "grow" else s.history
    )
    manifest = json.loads(report.manifest.read_text())
    assert (manifest["history"], manifest["horizon"], manifest["execute"]) == (s.history, s.horizon, s.execute)

    # The exported file and the served agent are evaluated on the first of the
    # quick protocol's three initial states (a shard: CI time), the state whose
    # first actions are compared below; the other two are the same evaluation.
    exported = evaluate(str(report.onnx), tmp_path / "exported.json", "--shard", "1/3")
    assert exported["rollouts"], "the quick protocol ran no rollout"

    server = subprocess.Popen(
        [sys.executable, "-m", "d3il_client.serve", "--agent", MIMICS[family], "--port", "0"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert server.stdout is not None
        line = ""
        for line in server.stdout:
            if line.startswith("listening on"):
                break
        assert line.startswith("listening on"), f"the server did not start: {line!r}"
        port = int(line.rsplit(":", 1)[1])
        served = evaluate(f"ws://127.0.0.1:{port}", tmp_path / "served.json", "--shard", "1/3")
    finally:
        server.terminate()
        server.wait(timeout=30)
    assert served["rollouts"] and {r["context_index"] for r in served["rollouts"]} == {0}
    if s.noise_shape is None:
        a, b = first_actions(exported, s.act_dim), first_actions(served, s.act_dim)
        assert b and b.keys() <= a.keys()
        for ctx in b:
            assert max(abs(x - y) for x, y in zip(a[ctx], b[ctx], strict=True)) <= 1e-5, (ctx, a[ctx], b[ctx])


def test_the_export_command_of_the_docs(tmp_path: Path):
    """`d3il-client export --agent MODULE:NAME --task T --out F` as docs/export.md shows
    it: checks, writes the file and its manifest, prints the summary; an object of no
    known family is refused with the advice to serve it, and nothing is written.
    """
    out = tmp_path / "bc.onnx"
    cmd = [sys.executable, "-m", "d3il_client.cli", "export", "--agent", MIMICS["bc"], "--task", "aligning"]
    p = subprocess.run([*cmd, "--out", str(out), "--d3il", D3IL], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "d3il (tract) within" in p.stdout and out.exists() and out.with_suffix(".json").exists()
    (tmp_path / "my_agents.py").write_text(
        "class MyAgent:\n    def reset(self):\n        pass\n\n    def predict(self, obs):\n        return obs[:3]\n"
    )
    unknown = tmp_path / "unknown.onnx"
    q = subprocess.run(
        [*cmd[:4], "--agent", "my_agents:MyAgent", "--task", "aligning", "--out", str(unknown)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(str(Path(p).resolve()) for p in sys.path if p)},
    )
    assert q.returncode == 1 and "Serve it instead" in q.stderr and "nothing was written" in q.stderr, q.stderr
    assert not unknown.exists()
