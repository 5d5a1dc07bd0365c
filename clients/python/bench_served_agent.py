"""Bench: a served BESO-sized reference agent against the Aligning paper protocol.

    $D3IL_TORCH_PYTHON clients/python/bench_served_agent.py [--smoke] [--max-live 96]

(``d3il bench served-agent`` runs it.) The agent is the reference's Aligning BESO in
size and settings (tests_torch/reference_like/beso.py with random weights: window 5,
16 sampling steps, sigma 0.01..3, euler_ancestral over 'linear' sigmas, a
DiffusionGPT of 4 layers, width 72, 4 heads). It is served as ``python -m
d3il_client.serve --agent`` serves it (batched, one model call per request group,
torch threads chosen at startup), on 127.0.0.1 over the remote protocol; a client
sends the evaluator's requests (spec, reset, infer of ``--max-live`` rollouts, the
windows growing 1..5 first) and times the requests at the full window. The
per-rollout fallback (one ``predict()`` per rollout and step, as unknown agents are
served) is timed on a few rollouts and scaled to the batch.

Prints the per-request cost of both, the projected inference time of the Aligning
paper protocol for both against the default wall limit, and on the LAST line the
batched server's ratio projected/limit (``ratio 0.25``: a quarter of the limit).
"""

from __future__ import annotations

import argparse
import asyncio
import io
import sys
import threading
import time
from pathlib import Path
from typing import Any, List

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE / "tests_torch")]

from d3il_client import tasks  # noqa: E402
from d3il_client.serve.agent import (  # noqa: E402
    AgentAdapter,
    BatchedAgentAdapter,
    choose_threads,
    make_adapter,
    time_predict,
)
from d3il_client.serve.policy import PolicyServer, Request, pack_array, packb, unpack_array, unpackb  # noqa: E402

TASK = "aligning"
OBS_DIM, ACT_DIM = 20, 3


def serve_in_thread(server: PolicyServer) -> int:
    """Run ``server`` on 127.0.0.1 in a daemon thread; its port."""
    ready: List[int] = []
    started = threading.Event()

    def on_ready(port: int) -> None:
        ready.append(port)
        started.set()

    def run() -> None:
        asyncio.run(server.run("127.0.0.1", 0, on_ready))

    threading.Thread(target=run, daemon=True).start()
    if not started.wait(60):
        raise SystemExit("the server did not start")
    return ready[0]


def time_requests(port: int, batch: int, window: int, timed: int) -> List[float]:
    """The evaluator's conversation: spec, reset, ``window - 1`` requests while the
    windows grow, then ``timed`` requests at the full window; their seconds.
    """
    from websockets.sync.client import connect

    rng = np.random.default_rng(0)
    with connect(f"ws://127.0.0.1:{port}/", max_size=64 << 20) as ws:
        hello = unpackb(ws.recv())
        assert hello["type"] == "hello", hello
        spec = {"type": "spec", "protocol": 1, "task": TASK, "obs_type": "state", "obs_dim": OBS_DIM}
        ws.send(packb({**spec, "act_dim": ACT_DIM, "max_steps": 400, "n_behaviours": 0, "seed": 0}))
        assert unpackb(ws.recv())["type"] == "ready"
        ids = list(range(batch))
        ws.send(packb({"type": "reset", "rollout_ids": ids}))
        assert unpackb(ws.recv())["type"] == "ok"
        times = []
        for step in range(window - 1 + timed):
            obs = (0.5 + 0.1 * rng.standard_normal((batch, 1, OBS_DIM))).astype(np.float32)
            msg = {"type": "infer", "id": step, "rollout_ids": ids, "steps": [step] * batch, "obs": pack_array(obs)}
            t = time.perf_counter()
            ws.send(packb(msg))
            reply = unpackb(ws.recv())
            dt = time.perf_counter() - t
            if reply["type"] != "actions":
                raise SystemExit(f"the server answered {reply}")
            acts = unpack_array(reply["actions"])
            assert acts.shape == (batch, 1, ACT_DIM) and np.isfinite(acts).all(), acts.shape
            if step >= window - 1:
                times.append(dt)
    return times


def time_per_rollout_request(agent: Any, rollouts: int, window: int) -> float:
    """Seconds of one per-rollout request of ``rollouts`` rollouts at the full window
    (the ``AgentAdapter`` called directly, after the windows have grown).
    """
    adapter = AgentAdapter(agent)
    adapter.reset(np.arange(rollouts, dtype=np.uint64))
    spec = {"act_dim": ACT_DIM, "obs_dim": OBS_DIM, "seed": 0}
    rng = np.random.default_rng(1)
    dt = 0.0
    for step in range(window):
        obs = (0.5 + 0.1 * rng.standard_normal((rollouts, 1, OBS_DIM))).astype(np.float32)
        req = Request(np.arange(rollouts, dtype=np.uint64), np.full(rollouts, step, np.uint64), spec)
        t = time.perf_counter()
        adapter(obs, req)
        dt = time.perf_counter() - t
    return dt


def main() -> None:
    """Run the bench; the ratio on the last line."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--smoke", action="store_true", help="a few seconds: fewer requests and rollouts timed")
    ap.add_argument("--max-live", type=int, default=tasks.MAX_LIVE, help="rollouts per request (the evaluator's)")
    a = ap.parse_args()
    import torch
    from reference_like.beso import make_agent

    agent = make_agent()
    batch = a.max_live
    adapter = make_adapter(agent, log=io.StringIO())  # its own lines would repeat ours
    assert isinstance(adapter, BatchedAgentAdapter), "the BESO mimic must be recognised"
    s = adapter.settings
    protocol = tasks.paper_protocol(TASK)
    print(
        f"{TASK}, served BESO of the reference's size ({s.sampler}; window {s.history}, "
        f"DiffusionGPT 4 x 72, 4 heads), batch {batch}; paper protocol {protocol.episodes} rollouts x "
        f"{protocol.max_steps} steps; default wall limit {tasks.WALL_SECONDS} s; "
        f"{torch.get_num_threads()} torch threads"
    )
    if a.smoke:
        torch.set_num_threads(1)  # no thread comparison: seconds, not minutes
    else:
        choose_threads(adapter, batch, sys.stdout)
    server = PolicyServer(adapter, history=1, horizon=1, execute=1, reset=adapter.reset, log=sys.stderr)
    port = serve_in_thread(server)
    timed = 2 if a.smoke else 8
    before = adapter.calls
    times = time_requests(port, batch, s.history, timed)
    calls_per_request = (adapter.calls - before) / (s.history - 1 + timed)
    req_s = float(np.median(times))
    batched = tasks.project(TASK, req_s, execute=s.execute, max_live=batch)
    print(
        f"batched server: {1000 * req_s:.1f} ms per request of {batch} rollouts at window {s.history} "
        f"(median of {len(times)}, over the websocket; {calls_per_request:.1f} model calls per request)"
    )
    print(f"  {batched.line()}")

    rollouts = 2 if a.smoke else 8
    per_req = time_per_rollout_request(agent, rollouts, s.history) * batch / rollouts
    per_predict = time_predict(AgentAdapter(agent), OBS_DIM, steps=4 if a.smoke else 12)
    fallback = tasks.project(TASK, per_req, execute=1, max_live=batch)
    print(
        f"per-rollout predict() (the fallback for unknown agents): {1000 * per_predict:.1f} ms per predict, "
        f"{per_req:.2f} s per request of {batch} rollouts (measured on {rollouts}, scaled)"
        + (f", over the {tasks.REMOTE_DEADLINE_S:.0f} s request deadline" if per_req > tasks.REMOTE_DEADLINE_S else "")
    )
    print(f"  {fallback.line()}")
    print(f"batched / per-rollout time per request: {req_s / per_req:.3f} (x{per_req / req_s:.1f} faster)")
    print(
        f"{TASK} paper protocol served batched: {batched.seconds:.0f} s projected of {batched.limit_s:.0f} s: "
        f"{'fits' if batched.fits else 'DOES NOT FIT'}; ratio {batched.ratio:.3f}"
    )


if __name__ == "__main__":
    main()
