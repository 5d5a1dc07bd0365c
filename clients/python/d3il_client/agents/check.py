"""Checks that a family's batched module computes what the agent's own ``predict`` does.

``against_predict(agent)`` runs ``batch`` copies of the agent through ``steps``
environment steps, exactly as the evaluator will query the exported graph: a model
call every ``execute`` steps on the window the evaluator sends (1..k at episode start
for ``grow``), the previous actions, fresh noise per call. Each copy's own
``predict(obs)`` runs with torch's random functions handing out the draws the
family makes from that copy's noise row (:class:`d3il_client.agents.base.Tape`),
and every action it returns must equal the module's within ``atol``.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any, List, Optional, Tuple

import numpy as np
import torch

from .base import Family, Settings, Tape


class CheckFailed(AssertionError):
    """The module and the agent's predict() disagree; the message says where."""


@dataclasses.dataclass
class Case:
    """One model call as the evaluator makes it: inputs and the module's output."""

    window: int
    obs: torch.Tensor  # [B, w, obs_dim]
    prev_actions: Optional[torch.Tensor]  # [B, w-1, act_dim]
    noise: Optional[torch.Tensor]  # [B, *noise_shape]
    actions: torch.Tensor  # [B, H, act_dim], the module's output
    predict_diff: float = 0.0  # largest |module − predict()| over this call's executed actions


def observations(agent: Any, batch: int, steps: int, gen: torch.Generator) -> torch.Tensor:
    """Plausible raw observations [batch, steps, obs_dim]: the agent's scaler mean
    plus its std times N(0, 1) (a dimension with std 0 stays at its mean).
    """
    sc = agent.scaler
    mean = torch.as_tensor(sc.x_mean, dtype=torch.float32).reshape(-1)
    std = torch.as_tensor(sc.x_std, dtype=torch.float32).reshape(-1)
    z = torch.randn((batch, steps, mean.shape[0]), generator=gen)
    return mean + std * z


def module_inputs(
    s: Settings, obs_hist: torch.Tensor, act_hist: torch.Tensor, t: int, noise: Optional[torch.Tensor]
) -> Tuple[int, torch.Tensor, Optional[torch.Tensor], Optional[torch.Tensor]]:
    """The window, previous actions and noise the evaluator sends at step t
    (``obs_hist`` [B, t+1, obs], ``act_hist`` [B, t, act]).
    """
    k = s.history
    if s.window == "grow" or t + 1 >= k:
        w = min(t + 1, k)
        obs = obs_hist[:, t + 1 - w : t + 1]
    else:  # pad: the first observation repeated in front
        w = k
        first = obs_hist[:, :1].expand(-1, k - (t + 1), -1)
        obs = torch.cat([first, obs_hist[:, : t + 1]], dim=1)
    prev = act_hist[:, t - (w - 1) : t] if s.prev_actions else None
    return w, obs, prev, noise


def run_module(
    module: torch.nn.Module, obs: torch.Tensor, prev: Optional[torch.Tensor], noise: Optional[torch.Tensor]
) -> torch.Tensor:
    """The module's actions [B, H, act] for one call."""
    with torch.no_grad():
        return module(obs, prev, noise)


def against_predict(
    agent: Any,
    family: Family,
    batch: int = 3,
    steps: Optional[int] = None,
    seed: int = 0,
    atol: float = 1e-5,
    module: Optional[torch.nn.Module] = None,
) -> List[Case]:
    """Compare ``family.graph(agent)`` with ``agent.predict`` (module docstring).

    Returns the module calls made (for checking other runtimes on the same inputs);
    raises :class:`CheckFailed` naming the step, rollout and difference.
    """
    s = family.settings(agent)
    g = module if module is not None else family.graph(agent).eval()
    steps = steps if steps is not None else s.history + 2 * s.execute + 1
    gen = torch.Generator().manual_seed(seed)
    obs_hist = observations(agent, batch, steps, gen)
    act_hist = torch.zeros((batch, steps, s.act_dim))
    agents = [copy.deepcopy(agent) for _ in range(batch)]
    for a in agents:
        a.reset()
    cases: List[Case] = []
    chunk: Optional[torch.Tensor] = None
    tapes: List[Tape] = []
    for t in range(steps):
        j = t % s.execute
        if j == 0:
            noise = torch.randn((batch, *s.noise_shape), generator=gen) if s.noise_shape is not None else None
            w, obs, prev, noise = module_inputs(s, obs_hist, act_hist, t, noise)
            chunk = run_module(g, obs, prev, noise)
            if tuple(chunk.shape) != (batch, s.horizon, s.act_dim):
                raise CheckFailed(f"the module returned {tuple(chunk.shape)}, expected {(batch, s.horizon, s.act_dim)}")
            cases.append(Case(w, obs, prev, noise, chunk))
            tapes = [Tape(family.draws(agents[b], noise[b], w) if noise is not None else []) for b in range(batch)]
        else:
            tapes = [Tape([]) for _ in range(batch)]
        assert chunk is not None
        for b in range(batch):
            with tapes[b].active():
                got = agents[b].predict(obs_hist[b, t].numpy().astype(np.float32))
            got_t = torch.as_tensor(np.asarray(got, dtype=np.float32)).reshape(-1)
            if got_t.numel() < s.act_dim:
                raise CheckFailed(f"step {t}, rollout {b}: predict() returned {got_t.numel()} numbers")
            got_t = got_t[: s.act_dim]
            want = chunk[b, j]
            if not torch.isfinite(want).all():
                raise CheckFailed(f"step {t}, rollout {b}: the module's action is not finite: {want.tolist()}")
            diff = (got_t - want).abs().max().item()
            if not diff <= atol:
                raise CheckFailed(
                    f"step {t} (window {cases[-1].window}), rollout {b}: the module gives {want.tolist()}, "
                    f"predict() gives {got_t.tolist()} (max difference {diff:.3g} > {atol:g})"
                )
            cases[-1].predict_diff = max(cases[-1].predict_diff, diff)
            act_hist[b, t] = got_t
    return cases
