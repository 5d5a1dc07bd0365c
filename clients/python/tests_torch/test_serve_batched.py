"""The batched agent server (d3il_client.serve.BatchedAgentAdapter): its actions for
several rollouts, started at different steps so that one request mixes window
lengths, equal each rollout's own predict() fed the same draws (the family's draws
from the noise row the server drew for that rollout and step), with one model call
per window length present in a request.
"""

from __future__ import annotations

import copy
import io
from typing import Any, Dict, List

import numpy as np
import pytest
import torch
from reference_like import act as ref_act
from reference_like import bc as ref_bc
from reference_like import beso as ref_beso
from reference_like import bet as ref_bet

from d3il_client.agents.base import Tape
from d3il_client.serve.agent import AgentAdapter, BatchedAgentAdapter, make_adapter, noise_for, startup_projection
from d3il_client.serve.policy import Request

torch.set_num_threads(1)

AGENTS = {
    "beso": lambda: ref_beso.make_agent(embed_dim=16, n_layers=2, n_heads=2, num_sampling_steps=4),
    "bc": ref_bc.make_agent,  # deterministic
    "act": ref_act.make_agent,  # a chunk of H executed E at a time, uniform latent
    "bet": ref_bet.make_agent,  # growing window, a categorical draw
}

# Rollouts and the request at which each starts: 0 and 1 at once, 2 two requests
# later, 3 five later (windows of different lengths in one request, and a rollout
# ending: 1 stops after request 7).
STARTS = {0: 0, 1: 0, 2: 2, 3: 5}
ENDS = {1: 7}
REQUESTS = 11


def run_served(agent: Any, seed: int = 7) -> tuple[Dict[int, List[np.ndarray]], Dict[int, np.ndarray], List[int]]:
    """Requests as the evaluator makes them; the actions per rollout, its
    observations and the model calls per request.
    """
    adapter = BatchedAgentAdapter(agent)
    s = adapter.settings
    rng = np.random.default_rng(3)
    obs = {rid: (0.5 + 0.1 * rng.standard_normal((REQUESTS, s.obs_dim))).astype(np.float32) for rid in STARTS}
    acts: Dict[int, List[np.ndarray]] = {rid: [] for rid in STARTS}
    calls = []
    spec = {"task": "aligning", "obs_dim": s.obs_dim, "act_dim": s.act_dim, "seed": seed}
    for q in range(REQUESTS):
        starting = [rid for rid, st in STARTS.items() if st == q]
        if starting:
            adapter.reset(np.array(starting, np.uint64))
        live = [rid for rid, st in STARTS.items() if st <= q and q <= ENDS.get(rid, REQUESTS)]
        steps = [q - STARTS[rid] for rid in live]
        batch = np.stack([obs[rid][st] for rid, st in zip(live, steps, strict=True)])[:, None, :]
        req = Request(np.array(live, np.uint64), np.array(steps, np.uint64), spec)
        before = adapter.calls
        out = adapter(batch, req)
        calls.append(adapter.calls - before)
        for i, rid in enumerate(live):
            acts[rid].append(out[i])
    return acts, obs, calls


def own_predict(agent: Any, family: Any, rid: int, obs: np.ndarray, n: int, seed: int = 7) -> List[np.ndarray]:
    """Rollout ``rid``'s own agent through ``n`` steps, fed at every model call the
    draws the family makes from the noise the server drew for (rid, step).
    """
    s = family.settings(agent)
    a = copy.deepcopy(agent)
    a.reset()
    out = []
    for t in range(n):
        if t % s.execute == 0 and s.noise_shape is not None:
            w = min(t + 1, s.history) if s.window == "grow" else s.history
            tape = Tape(family.draws(a, noise_for(s.noise_shape, seed, rid, t), w))
        else:
            tape = Tape([])
        with tape.active():
            got = a.predict(obs[t])
        out.append(np.asarray(got, np.float32).reshape(-1)[: s.act_dim])
    return out


@pytest.mark.parametrize("name", sorted(AGENTS))
def test_batched_server_equals_each_rollouts_own_predict(name: str) -> None:
    agent = AGENTS[name]()
    served, obs, calls = run_served(agent)
    adapter = BatchedAgentAdapter(agent)
    s = adapter.settings
    for rid, got in served.items():
        want = own_predict(agent, adapter.family, rid, obs[rid], len(got))
        np.testing.assert_allclose(np.stack(got), np.stack(want), atol=1e-5, rtol=0, err_msg=f"rollout {rid}")
    # One call per window length among the rollouts needing a chunk.
    for q, n in enumerate(calls):
        live = [rid for rid, st in STARTS.items() if st <= q and q <= ENDS.get(rid, REQUESTS)]
        lengths = set()
        for rid in live:
            t = q - STARTS[rid]
            if t % s.execute == 0:
                lengths.add(min(t + 1, s.history) if s.window == "grow" else s.history)
        assert n == len(lengths), f"request {q}: {n} model calls for window lengths {sorted(lengths)}"


def test_the_same_evaluation_gives_the_same_actions_whatever_the_batching() -> None:
    agent = AGENTS["beso"]()
    a, _, _ = run_served(agent)
    b, _, _ = run_served(agent)
    for rid in a:
        np.testing.assert_array_equal(np.stack(a[rid]), np.stack(b[rid]))
    c, _, _ = run_served(agent, seed=8)
    assert not np.array_equal(np.stack(a[0]), np.stack(c[0])), "the spec's seed drives the noise"


def test_make_adapter_batches_known_agents_and_serves_others_per_rollout() -> None:
    log = io.StringIO()
    assert isinstance(make_adapter(AGENTS["bc"](), log=log), BatchedAgentAdapter)
    assert "recognised as bc" in log.getvalue()

    class Other:
        def reset(self) -> None:
            pass

        def predict(self, obs: np.ndarray) -> np.ndarray:
            return np.zeros(3, np.float32)

    log = io.StringIO()
    assert isinstance(make_adapter(Other(), log=log), AgentAdapter)
    assert "per rollout" in log.getvalue()
    beso = AGENTS["beso"]()
    beso.sampler_type = "lms"
    log = io.StringIO()
    assert isinstance(make_adapter(beso, log=log), AgentAdapter)
    assert "'lms' is not reproduced" in log.getvalue()


def test_startup_projection_prints_the_task_and_warns_when_over() -> None:
    log = io.StringIO()
    p = startup_projection(make_adapter(AGENTS["bc"](), log=log), "aligning", max_live=96, log=log)
    assert p is not None and p.calls == 5 * 400 and p.fits
    assert "aligning paper protocol: 60 x 8 = 480 rollouts" in log.getvalue()
    assert "WARNING" not in log.getvalue()

    class Slow:
        scaler = ref_bc.make_agent().scaler

        def reset(self) -> None:
            pass

        def predict(self, obs: np.ndarray) -> np.ndarray:
            import time

            time.sleep(0.02)
            return np.zeros(3, np.float32)

    log = io.StringIO()
    p = startup_projection(make_adapter(Slow(), log=io.StringIO()), "aligning", max_live=96, log=log)
    assert p is not None and not p.fits  # 96 x 20 ms x 2000 requests
    assert "will NOT finish" in log.getvalue()
