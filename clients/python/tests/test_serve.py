"""d3il_client.serve: a reference-style agent served with `python -m d3il_client.serve
--agent module:Name --checkpoint ...`, submitted as an endpoint and evaluated by the server."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import Server, policy_server

from d3il_client import Client

AGENT = '''
import collections
import numpy as np


class PathAgent:
    """Shaped like the D3IL agents: its own window deque, reset() and predict(obs)."""

    def __init__(self, checkpoint):
        with open(checkpoint) as f:
            self.step = float(f.read())
        self.window = collections.deque(maxlen=5)

    def reset(self):
        self.window.clear()

    def predict(self, obs):
        assert obs.shape == (4,), obs.shape
        self.window.append(obs)
        # avoiding_path's steering: desired x towards 0.57 / 0.50 / 0.575 by desired y.
        x, y = obs[0], obs[1]
        tx = 0.57 if y < -0.04 else (0.50 if y < 0.16 else 0.575)
        return np.array([[np.clip(tx - x, -self.step, self.step), self.step]], np.float32)
'''


def test_a_served_agent_is_evaluated_by_the_server(server: Server, tmp_path: Path) -> None:
    (tmp_path / "my_agents.py").write_text(AGENT)
    (tmp_path / "ckpt.txt").write_text("0.008")
    client = Client(server.base, server.token)
    with policy_server(
        "d3il_client.serve",
        "--agent",
        "my_agents:PathAgent",
        "--checkpoint",
        "ckpt.txt",
        "--port",
        "0",
        cwd=tmp_path,
    ) as url:
        sub = client.submit(endpoint=url, method="pytest-agent", task="avoiding", training_seed=0, protocol="quick")
        done = client.wait(sub, progress=False, timeout=900)
    assert done.policy.kind == "remote" and done.policy.endpoint_url == url
    assert done.result is not None
    assert done.result.metrics.success_rate.value == 1.0, "the agent steers through like avoiding_path"
    assert [r.steps for r in done.result.rollouts] == [80] * 8


def test_serve_says_what_is_wrong(tmp_path: Path) -> None:
    (tmp_path / "not_an_agent.py").write_text("def make(checkpoint=None):\n    return 42\n")
    for args, words in [
        (["--agent", "no_such_module:Agent"], "cannot import no_such_module"),
        (["--agent", "not_an_agent"], "is not MODULE:NAME"),
        (["--agent", "not_an_agent:make"], "has no reset() and predict(obs)"),
        (["--checkpoint", "x.pth"], "--checkpoint goes with --agent"),
        (["--agent", "not_an_agent:make", "--history", "3"], "history = horizon = execute = 1"),
        (["--task", "aligning"], "--task goes with --agent"),
        (["--agent", "not_an_agent:make", "--task", "juggling"], "invalid choice: 'juggling'"),
    ]:
        out = subprocess.run(
            [sys.executable, "-m", "d3il_client.serve", *args], capture_output=True, text=True, cwd=tmp_path, timeout=60
        )
        assert out.returncode != 0 and words in out.stderr, (args, out.stderr)
