"""Issue 52: the policy server bounds what one connection may keep. Over a
real websocket on 127.0.0.1: a connection may keep at most `max_live_rollouts`
rollouts live (a `reset` or an `infer` past it is an `error` reply that names
the limit), what a policy keeps per rollout is freed when its episode ends (at
the next `reset`, for the rollouts it no longer names, and when the connection
closes), and the library's servers bind 127.0.0.1 unless told otherwise."""

from __future__ import annotations

import asyncio
import inspect
import queue
import threading
import time
from typing import Any, Dict, List

import numpy as np
import websockets

from d3il_client.serve import agent as agent_mod
from d3il_client.serve import policy as policy_mod


class Still:
    """A per-rollout agent (the adapter keeps one per live rollout)."""

    def reset(self) -> None:
        pass

    def predict(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(2, np.float32)


def _arr(a: np.ndarray) -> Dict[str, Any]:
    return policy_mod.pack_array(a.astype(np.float32))


async def _session(port: int, adapter: agent_mod.AgentAdapter) -> List[str]:
    replies: List[str] = []
    async with websockets.connect(f"ws://127.0.0.1:{port}") as ws:
        hello = await ws.recv()
        assert isinstance(hello, bytes)

        async def ask(msg: Dict[str, Any]) -> Dict[str, Any]:
            await ws.send(policy_mod.packb(msg))
            frame = await ws.recv()
            assert isinstance(frame, bytes)
            r = policy_mod.unpackb(frame)
            replies.append(r["type"] if r["type"] != "error" else "error: " + r["message"])
            return r

        await ask({"type": "spec", "task": "avoiding", "obs_dim": 4, "act_dim": 2, "seed": 0})
        # An episode batch of 3 rollouts, one step.
        await ask({"type": "reset", "rollout_ids": [0, 1, 2]})
        obs = np.zeros((3, 1, 4), np.float32)
        await ask({"type": "infer", "id": 1, "rollout_ids": [0, 1, 2], "steps": [0, 0, 0], "obs": _arr(obs)})
        assert len(adapter.agents) == 3
        # The next batch names 2 others: the 3 ended episodes are freed.
        await ask({"type": "reset", "rollout_ids": [3, 4]})
        assert sorted(adapter.agents) == [3, 4], adapter.agents
        # Past the cap (4): refused, naming it; an infer naming new ids too.
        await ask({"type": "reset", "rollout_ids": [10, 11, 12, 13, 14]})
        obs5 = np.zeros((3, 1, 4), np.float32)
        await ask({"type": "infer", "id": 2, "rollout_ids": [3, 4, 20], "steps": [0, 0, 0], "obs": _arr(obs5)})
        await ask({"type": "infer", "id": 3, "rollout_ids": [5, 6, 7], "steps": [0, 0, 0], "obs": _arr(obs5)})
    return replies


def test_a_connection_keeps_a_bounded_number_of_rollouts_and_frees_ended_ones() -> None:
    adapter = agent_mod.AgentAdapter(lambda: Still())
    server = policy_mod.PolicyServer(
        adapter, history=1, horizon=1, execute=1, reset=adapter.reset, forget=adapter.forget, max_live_rollouts=4
    )

    # The server runs on its own thread and loop, as `serve()` would.
    bound: queue.Queue[int] = queue.Queue()
    threading.Thread(target=lambda: asyncio.run(server.run("127.0.0.1", 0, bound.put)), daemon=True).start()
    port = bound.get(timeout=30)

    async def main() -> List[str]:
        return await _session(port, adapter)

    replies = asyncio.run(main())
    assert replies[:5] == ["ready", "ok", "actions", "ok", replies[4]], replies
    cap = "5 live rollouts on this connection; this endpoint keeps at most 4 (max_live_rollouts)"
    assert cap in replies[4], replies
    assert replies[5] == "actions", replies  # 3, 4 and 20: three live
    assert replies[6].startswith("error: ") and "6 live rollouts" in replies[6], replies
    # The connection closed: everything it kept is freed.
    deadline = time.monotonic() + 30
    while adapter.agents and time.monotonic() < deadline:
        time.sleep(0.05)
    assert adapter.agents == {}, adapter.agents


def test_library_servers_bind_loopback_by_default() -> None:
    for fn in (policy_mod.serve, agent_mod.serve_agent):
        assert inspect.signature(fn).parameters["host"].default == "127.0.0.1", fn
