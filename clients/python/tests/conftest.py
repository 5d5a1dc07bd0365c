"""A real `d3il serve` on 127.0.0.1 for the client's tests.

The server is the repository's binary (``$D3IL_BIN``, set by tests/python_client.rs
to the one cargo just built; else target/debug/d3il) on a fresh SQLite file in a
temporary directory, with one sandboxed worker, a token from ``d3il token create``
and remote endpoints on loopback allowed (the served-agent test submits one).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from d3il_client import Client, Submission

REPO = Path(__file__).resolve().parents[3]
FIXTURES = REPO / "assets" / "fixtures"


def d3il_bin() -> Path:
    exe = Path(os.environ.get("D3IL_BIN") or REPO / "target" / "debug" / "d3il")
    if not exe.exists():
        pytest.fail(f"no d3il binary at {exe}: build it (cargo build --bin d3il) or set D3IL_BIN")
    return exe


def fresh_python() -> Path:
    """The Python of the virtualenv that has only `pip install ./clients/python` (./dev makes it)."""
    exe = Path(os.environ.get("D3IL_FRESH_PYTHON") or REPO / "target" / "python-client" / "fresh" / "bin" / "python")
    if not exe.exists():
        pytest.fail(f"no fresh virtualenv at {exe}: run ./dev test, which makes it")
    return exe


@contextlib.contextmanager
def policy_server(module: str, *args: str, cwd: Path | None = None) -> Iterator[str]:
    """`python -m MODULE ARGS --port 0`-style policy server of this package on 127.0.0.1; yields its ws:// URL."""
    proc = subprocess.Popen(
        [sys.executable, "-m", module, *args],
        stdout=subprocess.PIPE,
        stderr=sys.stderr,
        text=True,
        cwd=cwd,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("listening on "), f"{module} printed {line!r}"
        port = int(line.strip().rsplit(":", 1)[1])
        yield f"ws://127.0.0.1:{port}/"
    finally:
        proc.terminate()
        proc.wait(timeout=20)


@dataclass
class Server:
    base: str
    token: str
    db: Path
    log: list[str]


NO_QUOTA = ["--quota-per-day", "0", "--quota-total", "0", "--quota-concurrent", "0", "--max-queued-races", "0"]


@contextlib.contextmanager
def run_server(tmp: Path, *extra: str) -> Iterator[Server]:
    """`d3il serve` on a fresh database in `tmp` with one worker and EXTRA flags."""
    exe = d3il_bin()
    db = tmp / "lb.sqlite"
    token = subprocess.run(
        [exe, "token", "create", "--name", "pytest", "--db", db], check=True, capture_output=True, text=True
    ).stdout.strip()
    assert token.startswith("d3il_"), token
    proc = subprocess.Popen(
        [
            exe,
            "serve",
            "--db",
            db,
            "--bind",
            "127.0.0.1:0",
            "--workers",
            "1",
            "--no-verify",
            "--fidelity",
            "off",
            # The client's tests read their own submissions' boards: no zoo
            # (docs/zoo.md) unless the test names one.
            *([] if "--zoo" in extra else ["--zoo", "none"]),
            # No submission quota unless the test sets one: the session submits many.
            *([] if any(str(e).startswith("--quota") for e in extra) else NO_QUOTA),
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=sys.stderr,
        text=True,
        cwd=tmp,
    )
    assert proc.stdout is not None
    base = None
    for line in proc.stdout:
        if line.startswith("listening on "):
            base = line[len("listening on ") :].strip()
            break
    if base is None:
        proc.wait()
        pytest.fail(f"d3il serve exited ({proc.returncode}) before listening")
    log: list[str] = []
    out = proc.stdout
    threading.Thread(target=lambda: log.extend(out), daemon=True).start()
    try:
        yield Server(base, token, db, log)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    with run_server(tmp_path_factory.mktemp("d3il-serve"), "--allow-private-endpoints") as s:
        yield s


@pytest.fixture
def client(server: Server) -> Client:
    return Client(server.base, server.token)


@dataclass
class Pair:
    """Two completed quick-protocol Avoiding submissions: a path follower and a noisy policy."""

    path: Submission
    noise: Submission


@pytest.fixture(scope="session")
def evaluated(server: Server) -> Pair:
    c = Client(server.base, server.token)
    a = c.submit(
        onnx=FIXTURES / "avoiding_path.onnx",
        method="pytest-path",
        task="avoiding",
        training_seed=0,
        protocol="quick",
        backbone="MLP",
    )
    b = c.submit(
        onnx=FIXTURES / "avoiding_noise.onnx",
        manifest=FIXTURES / "avoiding_noise.json",
        method="pytest-noise",
        task="avoiding",
        training_seed=0,
        protocol="quick",
    )
    return Pair(c.wait(a, timeout=900, progress=False), c.wait(b, timeout=900, progress=False))
