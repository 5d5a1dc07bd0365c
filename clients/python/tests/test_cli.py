"""The d3il-client command against a real server: the flags and output of `d3il submit`."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

from conftest import FIXTURES, Pair, Server

EXE = Path(sys.executable).parent / "d3il-client"


def run(server: Server, *args: str, token: bool = True) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, D3IL_SERVER=server.base)
    env.pop("D3IL_TOKEN", None)
    if token:
        env["D3IL_TOKEN"] = server.token
    return subprocess.run([EXE, *args], capture_output=True, text=True, env=env, timeout=900)


def test_submit_wait_prints_what_d3il_submit_prints(server: Server) -> None:
    out = run(
        server,
        "submit",
        "--method",
        "cli-path",
        "--task",
        "avoiding",
        "--training-seed",
        "0",
        "--protocol",
        "quick",
        "--onnx",
        str(FIXTURES / "avoiding_path.onnx"),
        "--backbone",
        "MLP",
        "--wait",
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("submission ") and f" accepted: {server.base}/submissions/" in lines[0]
    assert lines[1] == "task avoiding, state observations (1 x 8 rollouts, quick protocol, seed 0)"
    assert lines[2].split() == ["metric", "value", "95%", "CI"]
    # 8 of 8 rollouts on Avoiding's one initial state: Clopper-Pearson, [0.025^(1/8), 1] = [0.631, 1].
    assert lines[3].split()[:4] == ["success", "rate", "1.000", "0.631"]
    assert "behaviours of the 8 successful rollouts:" in out.stdout
    # Progress lines on standard error, as `d3il submit --wait` prints them (no terminal here).
    assert "completed 8/8" in out.stderr and " 0/0" not in out.stderr


def test_submit_without_wait_and_json(server: Server) -> None:
    out = run(
        server,
        "submit",
        "--method",
        "cli-json",
        "--task",
        "avoiding",
        "--training-seed",
        "0",
        "--protocol",
        "quick",
        "--onnx",
        str(FIXTURES / "avoiding_path.onnx"),
        "--wait",
        "--json",
    )
    assert out.returncode == 0, out.stderr
    import json

    doc = json.loads(out.stdout[out.stdout.index("{") :])
    assert doc["status"] == "completed" and doc["result"]["metrics"]["success_rate"]["value"] == 1.0


def test_status_results_compare_leaderboard(server: Server, evaluated: Pair, tmp_path: Path) -> None:
    a, b = str(evaluated.path.id), str(evaluated.noise.id)
    status = run(server, "status", a, token=False)
    assert status.returncode == 0, status.stderr
    assert "completed 8/8" in status.stdout and "pytest-path" in status.stdout
    rollouts = tmp_path / "rollouts.csv"
    results = run(server, "results", a, "--rollouts-csv", str(rollouts), token=False)
    assert results.returncode == 0, results.stderr
    assert results.stdout.startswith("task avoiding, state observations")
    rows = list(csv.DictReader(rollouts.open()))
    assert len(rows) == 8 and rows[0]["number"] == "0" and rows[0]["success"] == "True"
    compare = run(server, "compare", a, b, token=False)
    assert compare.returncode == 0, compare.stderr
    assert compare.stdout.startswith("paired comparison A − B: task avoiding, quick protocol")
    assert compare.stdout.splitlines()[3].startswith("success rate ")
    board = run(server, "leaderboard", "avoiding", token=False)
    assert board.returncode == 0 and "pytest-path" in board.stdout and "BC-MLP" in board.stdout
    saved = tmp_path / "board.csv"
    assert run(server, "leaderboard", "avoiding", "--csv", str(saved), token=False).returncode == 0
    assert saved.read_text().startswith("task,obs_type,method,")


def test_errors_exit_1_with_the_servers_message(server: Server, evaluated: Pair) -> None:
    missing = run(server, "compare", str(evaluated.path.id), "999999")
    assert missing.returncode == 1 and "submission 999999 not found" in missing.stderr
    dup = run(
        server,
        "submit",
        "--method",
        "pytest-path",
        "--task",
        "avoiding",
        "--training-seed",
        "0",
        "--protocol",
        "quick",
        "--onnx",
        str(FIXTURES / "avoiding_path.onnx"),
    )
    assert dup.returncode == 1 and "already submitted" in dup.stderr and "training_seed" in dup.stderr
    no_token = run(
        server,
        "submit",
        "--method",
        "x",
        "--task",
        "avoiding",
        "--training-seed",
        "0",
        "--onnx",
        str(FIXTURES / "avoiding_path.onnx"),
        token=False,
    )
    assert no_token.returncode == 1 and "D3IL_TOKEN" in no_token.stderr
    bad = run(
        server,
        "submit",
        "--method",
        "x",
        "--task",
        "avoid",
        "--training-seed",
        "0",
        "--onnx",
        str(FIXTURES / "avoiding_path.onnx"),
    )
    assert bad.returncode == 1 and "task `avoid` is not one of" in bad.stderr
