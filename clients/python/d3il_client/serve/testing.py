"""A deliberately misbehaving variant of the reference server, for testing clients
of the remote protocol (the evaluator's: policy/tests/policies/remote.rs, tests/worker/worker_remote.rs).

    python -m d3il_client.serve.testing --mode MODE [--horizon H]

Serves the `avoiding` demo policy on 127.0.0.1 (free port, printed as
`listening on 127.0.0.1:PORT`), except that on the first `infer` (or at the
stage named by the mode) it:

  ok            behaves (with a reset log, for checking reset calls)
  hang          never answers
  slow-drip     sends the reply one byte per 50 ms (past any short deadline)
  nan           returns NaN actions
  wrong-shape   returns actions with the wrong act_dim
  oversized     returns a 2 MiB reply
  garbage       returns bytes that are not msgpack
  text          returns a text frame
  disconnect    closes the connection
  error         returns an `error` message
  bad-version   announces protocol version 99 in the hello
  bad-hello     sends a hello without `history`
  wrong-id      answers with a different request id
  noisy         returns actions drawn from a RNG seeded with the spec's seed
                and the rollout ids/steps (determinism check)
  inf-later     behaves, except that rollout 3 gets an infinite action from
                step 5 on
  drop-later    behaves for 10 infers, then drops the TCP connection without
                a close handshake (a crash or network loss mid-episode)
"""

from __future__ import annotations

import argparse
import asyncio
from typing import Any, AsyncIterator, Dict, List

import numpy as np

from .policy import PolicyServer, Request, avoiding_policy, packb


class MisbehavingServer(PolicyServer):
    """The reference server with the misbehaviour `mode` (the list above)."""

    def __init__(self, mode: str, **kw: Any) -> None:
        super().__init__(self.policy, reset=self.on_reset, **kw)
        self.mode = mode
        self.resets: List[List[int]] = []
        self.infers = 0

    def on_reset(self, ids: np.ndarray) -> None:
        self.resets.append(ids.tolist())

    def policy(self, obs: np.ndarray, req: Request) -> np.ndarray:
        if self.mode == "nan":
            return np.full((obs.shape[0], self.horizon, req.spec["act_dim"]), np.nan, np.float32)
        if self.mode == "wrong-shape":
            return np.zeros((obs.shape[0], self.horizon, req.spec["act_dim"] + 1), np.float32)
        if self.mode == "oversized":
            return np.zeros((obs.shape[0], 1 << 19), np.float32)  # 2 MiB per row
        if self.mode == "noisy":
            out = np.empty((obs.shape[0], self.horizon, req.spec["act_dim"]), np.float32)
            for i, (r, s) in enumerate(zip(req.rollout_ids, req.steps, strict=True)):
                rng = np.random.default_rng([int(req.spec["seed"]), int(r), int(s)])
                out[i] = rng.standard_normal(out[i].shape)
            return out
        a = avoiding_policy(obs, req)
        if self.mode == "inf-later":
            for i, (r, s) in enumerate(zip(req.rollout_ids, req.steps, strict=True)):
                if int(r) == 3 and int(s) >= 5:
                    a[i, 1] = np.inf
        # A chunk of H copies of the action.
        return np.repeat(a[:, None, :], self.horizon, axis=1)

    def hello(self) -> Dict[str, Any]:
        h = super().hello()
        if self.mode == "bad-version":
            h["protocol"] = 99
        if self.mode == "bad-hello":
            del h["history"]
        return h

    async def handle(self, msg: Dict[Any, Any], state: Dict[str, Any]) -> Dict[str, Any]:
        if msg.get("type") == "infer" and msg.get("obs") is not None and self.mode == "ok":
            # Let the test see that resets arrived: answer an infer for rollout id
            # 999 with an error listing them.
            if 999 in list(msg["rollout_ids"]):
                raise ValueError(f"resets seen: {self.resets}")
        return await super().handle(msg, state)

    async def reply(self, ws: Any, request_type: Any, reply: Dict[str, Any]) -> None:
        if request_type == "infer":
            m = self.mode
            self.infers += 1
            if m == "drop-later" and self.infers > 10:
                ws.transport.abort()
                return
            if m == "hang":
                await asyncio.sleep(3600)
            if m == "slow-drip":
                # A valid reply, dribbled out one byte per WebSocket fragment.
                data = packb(reply)

                async def frags() -> AsyncIterator[bytes]:
                    for i in range(len(data)):
                        await asyncio.sleep(0.05)
                        yield data[i : i + 1]

                await ws.send(frags())
                return
            if m == "garbage":
                await ws.send(b"\xc1\xc1\xc1 not msgpack")
                return
            if m == "text":
                await ws.send("hello there")
                return
            if m == "disconnect":
                await ws.close()
                return
            if m == "error":
                reply = {"type": "error", "message": "model exploded"}
            if m == "wrong-id":
                reply = dict(reply, id=12345)
        await super().reply(ws, request_type, reply)


def main() -> None:
    """Serve the misbehaving server on 127.0.0.1, a free port (printed)."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--mode", default="ok")
    ap.add_argument("--history", type=int, default=1)
    ap.add_argument("--horizon", type=int, default=1)
    ap.add_argument("--execute", type=int, default=1)
    a = ap.parse_args()
    server = MisbehavingServer(a.mode, history=a.history, horizon=a.horizon, execute=a.execute)

    def ready(port: int) -> None:
        print(f"listening on 127.0.0.1:{port}", flush=True)

    try:
        asyncio.run(server.run("127.0.0.1", 0, ready))
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
