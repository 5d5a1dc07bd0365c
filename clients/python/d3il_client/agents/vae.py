"""VAE-State (CVAE): ``CVAEAgent`` of agents/cvae_agent.py in the D3IL reference, with
``VariationalAE`` of agents/models/vae/cvae.py.

Its ``predict(state)``, step by step:

1. ``state`` [obs_dim] -> float32 [1, obs_dim] (ONE unsqueeze: no window axis);
   ``scaler.scale_input`` (with the 1e-12);
2. ``self.model.predict(state)``: ``z = torch.randn((1, latent_dim)).clamp(-0.5, 0.5)``
   — a standard-normal latent from the prior, clamped to ±0.5 — then
   ``decoder(cat([state, z], -1))``, [1, act_dim];
3. ``out.clamp_(self.min_action, self.max_action)`` (the scaled data bounds) and
   ``scaler.inverse_scale_output``; returns [1, act_dim].

One observation, one action per call. The module takes the latent from
``noise`` [B, latent_dim] (clamped as predict clamps its draw) and runs the agent's
own decoder on [B, obs_dim + latent_dim].
"""

from __future__ import annotations

from typing import Any, List, Optional

import torch

from .base import Draw, Family, Settings
from .scaling import ClampedScaledGraph, ScalerArithmetic, unwrap


class VaeStateGraph(ClampedScaledGraph):
    """[B, 1, obs] raw observations, [B, latent] noise -> [B, 1, act] raw actions."""

    def __init__(self, agent: Any) -> None:
        super().__init__(agent)
        self.decoder = unwrap(agent.model).decoder

    def forward(
        self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor] = None, noise: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """As CVAEAgent.predict on each row, the latent drawn from ``noise``."""
        assert noise is not None
        state = self.scaler.scale_input(obs[:, -1, :])  # [B, obs]
        z = noise.clamp(-0.5, 0.5)
        out = self.decoder(torch.cat([state, z], dim=-1))  # [B, act]
        return self.clamp_unscale(out).unsqueeze(1)


def latent_dim(agent: Any) -> int:
    """The prior's latent size, as ``VariationalAE.predict`` (VAE-State) and
    ``ActVAE`` (VAE-ACT) read it.
    """
    return int(unwrap(agent.model).latent_dim)


class VaeStateFamily(Family):
    """CVAEAgent: one Gaussian latent per call, k = H = E = 1."""

    name = "vae_state"
    classes = ("CVAEAgent",)

    def settings(self, agent: Any) -> Settings:
        """One observation, one action, a latent of the model's ``latent_dim`` per call."""
        sc = ScalerArithmetic(agent.scaler)
        d = latent_dim(agent)
        return Settings(
            family=self.name,
            obs_dim=sc.obs_dim,
            act_dim=sc.act_dim,
            history=1,
            window="pad",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=(d,),
            sampler=f"z ~ N(0, I_{d}) clamped to [-0.5, 0.5], decoded; scaled output clamped to the data bounds",
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """:class:`VaeStateGraph` on the agent's own decoder and scaler."""
        return VaeStateGraph(agent)

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """``torch.randn((1, latent_dim))`` in ``VariationalAE.predict``."""
        return [Draw("randn", noise.reshape(1, latent_dim(agent)))]


FAMILY = VaeStateFamily()
