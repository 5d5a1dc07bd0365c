"""Serve a D3IL reference agent unchanged (docs/export.md, docs/remote-protocol.md).

The reference agents keep their own state: `reset()` clears their observation and
action deques, `predict(obs)` takes ONE observation (the newest, a 1-D array), pushes
it into their deques, runs the model and returns one action. `serve_agent` puts such
an object behind the remote protocol with one agent state per rollout:

    from d3il_client.serve import serve_agent
    serve_agent(my_trained_agent, port=8765)     # deep-copied once per rollout
    # or: serve_agent(lambda: build_agent(cfg), port=8765)   # a factory

From the shell: `python -m d3il_client.serve --agent my_module:make_agent
--checkpoint ckpt.pth` (docs/remote-protocol.md).

The endpoint announces history = horizon = execute = 1: the evaluator sends the newest
observation of every live rollout, the adapter calls `predict` of that rollout's agent
(so windows grow from empty exactly as in the reference evaluation), and the agent's
own action chunking stays inside `predict`. The returned action is the task's
policy action (e.g. Aligning's Δ desired xyz, docs/submission.md).
"""

from __future__ import annotations

import copy
from typing import Any, Callable, Dict, Mapping, Optional

import numpy as np

from .policy import PolicyServer, Request, serve


class AgentAdapter:
    """A policy callable for `PolicyServer` made of one agent per rollout.

    `agent` is an object with `reset()` and `predict(obs)`, deep-copied for every
    rollout, or a zero-argument factory returning a fresh one.
    """

    def __init__(self, agent: Any, predict_kwargs: Optional[Mapping[str, Any]] = None) -> None:
        self._make: Callable[[], Any]
        if hasattr(agent, "predict"):
            self._make = lambda: copy.deepcopy(agent)
        elif callable(agent):
            self._make = agent
        else:
            raise TypeError("agent must have reset() and predict(obs), or be a factory returning one")
        self.predict_kwargs = dict(predict_kwargs or {})
        self.agents: Dict[int, Any] = {}

    def _fresh(self, rid: int) -> Any:
        a = self._make()
        a.reset()
        self.agents[rid] = a
        return a

    def reset(self, rollout_ids: np.ndarray) -> None:
        """New episodes: every named rollout gets a freshly reset agent state."""
        for rid in rollout_ids:
            self._fresh(int(rid))

    def __call__(self, obs: np.ndarray, req: Request) -> np.ndarray:
        """One `predict` of each asking rollout's agent with its newest observation."""
        act_dim = int(req.spec["act_dim"])
        out = np.zeros((obs.shape[0], act_dim), np.float32)
        for r, rid in enumerate(req.rollout_ids):
            key = int(rid)
            agent = self.agents.get(key) or self._fresh(key)
            a = np.asarray(agent.predict(np.array(obs[r, -1], np.float32), **self.predict_kwargs), np.float32)
            a = a.reshape(-1)
            if a.size < act_dim:
                raise ValueError(f"the agent returned {a.size} numbers; the task's action has {act_dim}")
            out[r] = a[:act_dim]
        return out


def agent_server(agent: Any, **kwargs: Any) -> PolicyServer:
    """A `PolicyServer` (history = horizon = execute = 1) serving `agent`."""
    adapter = AgentAdapter(agent, kwargs.pop("predict_kwargs", None))
    return PolicyServer(adapter, history=1, horizon=1, execute=1, reset=adapter.reset, **kwargs)


def serve_agent(
    agent: Any,
    host: str = "0.0.0.0",
    port: int = 8765,
    certfile: Optional[str] = None,
    keyfile: Optional[str] = None,
    predict_kwargs: Optional[Mapping[str, Any]] = None,
) -> None:
    """Blocking: serve `agent` until interrupted (prints the bound port)."""
    adapter = AgentAdapter(agent, predict_kwargs)
    serve(
        adapter,
        host=host,
        port=port,
        certfile=certfile,
        keyfile=keyfile,
        history=1,
        horizon=1,
        execute=1,
        reset=adapter.reset,
    )
