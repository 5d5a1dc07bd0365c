"""BC (MLP): ``BC_Agent`` of agents/bc_agent.py in the D3IL reference.

Its ``predict(state)``, step by step:

1. ``state`` [obs_dim] -> float32 [1, 1, obs_dim]; ``scaler.scale_input`` (with the 1e-12);
2. ``out = self.model(state)``: ``BC_Policy`` = ``obs_encoder`` (Identity) then the MLP,
   [1, 1, act_dim];
3. ``out.clamp_(self.min_action, self.max_action)``: the scaled data bounds
   (``scaler.y_bounds``, not × 1.1), before the inverse scaling;
4. ``scaler.inverse_scale_output``; returns [1, act_dim].

Only the current observation is used (no deque, whatever ``window_size`` the agent
was trained with), one action per call, no randomness. The module does the same on
[B, 1, obs_dim] with the agent's own ``model``.
"""

from __future__ import annotations

from typing import Any, List, Optional

import torch

from .base import Draw, Family, Settings
from .scaling import ClampedScaledGraph, ScalerArithmetic, unwrap


class BcGraph(ClampedScaledGraph):
    """[B, 1, obs] raw observations -> [B, 1, act] raw actions, as BC_Agent.predict."""

    def __init__(self, agent: Any) -> None:
        super().__init__(agent)
        self.model = unwrap(agent.model)

    def forward(
        self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor] = None, noise: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """Raw observations [B, w, obs] (the last one is used) -> raw actions [B, 1, act]."""
        state = self.scaler.scale_input(obs[:, -1:, :])  # [B, 1, obs]
        out = self.model(state)  # [B, 1, act]
        return self.clamp_unscale(out)


class BcFamily(Family):
    """BC_Agent: deterministic, k = H = E = 1."""

    name = "bc"
    classes = ("BC_Agent",)

    def settings(self, agent: Any) -> Settings:
        """One observation and one action per call, whatever the agent's window_size."""
        sc = ScalerArithmetic(agent.scaler)
        return Settings(
            family=self.name,
            obs_dim=sc.obs_dim,
            act_dim=sc.act_dim,
            history=1,
            window="pad",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=None,
            sampler="deterministic MLP; scaled output clamped to the data bounds",
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """:class:`BcGraph` on the agent's own model and scaler."""
        return BcGraph(agent)

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """None: predict() draws nothing."""
        return []


FAMILY = BcFamily()
