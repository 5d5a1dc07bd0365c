"""The must-show of issue 33: in a virtualenv with only `pip install ./clients/python`,
submit an ONNX fixture to a running `d3il serve`, wait, read the per-rollout
DataFrame and compare two submissions."""

from __future__ import annotations

import json
import os
import subprocess

from conftest import FIXTURES, REPO, Server, fresh_python

SCRIPT = r"""
import json, sys
import d3il_client
from d3il_client import Client

server, token, fixtures = sys.argv[1:4]
client = Client(server, token)
a = client.submit(onnx=f"{fixtures}/avoiding_path.onnx", method="fresh-path", task="avoiding",
                  training_seed=0, protocol="quick")
b = client.submit(onnx=f"{fixtures}/aligning_mlp.onnx", method="fresh-aligning", task="aligning",
                  training_seed=0, protocol="quick")
c = client.submit(onnx=f"{fixtures}/avoiding_noise.onnx", method="fresh-noise", task="avoiding",
                  training_seed=0, protocol="quick")
done = [client.wait(s, timeout=900) for s in (a, b, c)]
frame = client.rollouts_frame(a)
cmp = client.compare(a, c)
try:
    client.compare(a, b)
    refused = None
except d3il_client.BadRequest as e:
    refused = e.message
print(json.dumps({
    "module": d3il_client.__file__,
    "statuses": [s.status for s in done],
    "columns": list(frame.columns),
    "rows": len(frame),
    "successes": int(frame.success.sum()),
    "numbers": frame.number.tolist(),
    "endings": sorted(set(frame.ending)),
    "success_a": cmp.success_rate.a,
    "difference": cmp.success_rate.difference.value,
    "n_contexts": cmp.n_contexts,
    "refused": refused,
}))
"""


def test_a_fresh_virtualenv_submits_waits_reads_rollouts_and_compares(server: Server) -> None:
    python = fresh_python()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    out = subprocess.run(
        [python, "-I", "-c", SCRIPT, server.base, server.token, str(FIXTURES)],
        capture_output=True,
        text=True,
        env=env,
        cwd="/",
        timeout=1200,
    )
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    # The installed copy ran, not the source tree.
    assert str(REPO / "clients") not in got["module"], got["module"]
    assert got["statuses"] == ["completed"] * 3
    assert got["columns"][:4] == ["number", "context", "rollout", "success"]
    assert got["rows"] == 8, "Avoiding's quick protocol: 1 initial state x 8 rollouts"
    assert got["numbers"] == list(range(8))
    assert got["successes"] == 8, "the path fixture reaches the finish line every time"
    assert got["endings"] == ["task_success"]
    assert got["success_a"] == 1.0
    assert got["n_contexts"] == 1
    assert -1.0 <= got["difference"] <= 1.0
    assert "task" in got["refused"], got["refused"]
    # The progress bars went to stderr.
    assert "submission" in out.stderr and "completed" in out.stderr


def test_the_fresh_virtualenv_holds_the_client_and_its_dependencies_only() -> None:
    out = subprocess.run(
        [fresh_python(), "-m", "pip", "list", "--format", "json"], capture_output=True, text=True, check=True
    )
    names = {p["name"].lower() for p in json.loads(out.stdout)}
    assert "d3il-client" in names
    for extra in ("pytest", "jsonschema", "onnxruntime", "websockets", "msgpack", "torch", "ruff", "mypy"):
        assert extra not in names, f"{extra} is in the fresh virtualenv: {sorted(names)}"
