"""VAE-ACT: ``ActAgent`` of agents/act_agent.py in the D3IL reference, with ``ActVAE``
of agents/models/act/act_vae.py.

Its ``predict(state)``, step by step:

1. ``state`` [obs_dim] -> float32 [1, 1, obs_dim]; ``scaler.scale_input``;
2. only when ``self.action_counter == self.action_seq_size`` (so at the first call
   after ``reset()``, which sets the counter to ``action_seq_size``): counter := 0 and
   ``self.model(state, None)``, which samples the latent from its test-time prior
   ``torch.rand([1, 1, latent_dim])`` — UNIFORM on [0, 1), not Gaussian — projects it
   (``latent_out_proj``), encodes ``cat([state_encoder(state), latent], 1) +
   pos_emb[:, :2]`` with its transformer encoder, decodes the ``query_embed`` tokens
   (one per chunk action) with cross-attention on that, and maps them with
   ``action_head``: [1, H, act_dim]; ``clamp_(min_action, max_action)`` (the scaled
   data bounds) and ``inverse_scale_output``; kept as ``curr_action_seq``;
3. returns ``curr_action_seq[:, action_counter]`` and increments the counter.

So: one observation per model call (``obs_size`` 1; the model keeps ``state[:, :1]``),
a chunk of H = ``query_embed`` rows (the model's ``act_seq_size``), E =
``action_seq_size`` of them executed before the next call. The module takes the
uniform latent as Φ(noise) [B, latent_dim] and runs the agent's own submodules.
"""

from __future__ import annotations

from typing import Any, List, Optional

import torch

from .base import Draw, Family, Settings, uniform_from_noise
from .scaling import ClampedScaledGraph, ScalerArithmetic, unwrap
from .vae import latent_dim


class ActGraph(ClampedScaledGraph):
    """[B, 1, obs] raw observations, [B, latent] noise -> [B, H, act] raw actions."""

    def __init__(self, agent: Any) -> None:
        super().__init__(agent)
        self.model = unwrap(agent.model)
        self.horizon, self.width = (int(n) for n in self.model.query_embed.weight.shape)

    def forward(
        self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor] = None, noise: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """ActVAE.forward's sampling path (no action, no goal) on a batch."""
        assert noise is not None
        m = self.model
        state = self.scaler.scale_input(obs[:, -1:, :])  # [B, 1, obs]
        state_embed = m.state_encoder(state)
        latent = uniform_from_noise(noise).unsqueeze(1)  # [B, 1, latent], U(0, 1) as torch.rand
        encoder_input = torch.cat([state_embed, m.latent_out_proj(latent)], dim=1)
        encoder_input = encoder_input + m.pos_emb[:, :2]
        encoder_output = m.encoder(encoder_input)
        queries = m.query_embed.weight.unsqueeze(0).expand(obs.shape[0], self.horizon, self.width)
        out = m.action_head(m.decoder(queries, encoder_output))  # [B, H, act]
        return self.clamp_unscale(out)


class ActFamily(Family):
    """ActAgent: a chunk per call from a uniform latent, executed ``action_seq_size`` steps."""

    name = "vae_act"
    classes = ("ActAgent",)

    def settings(self, agent: Any) -> Settings:
        """H from the model's query tokens, E from the agent's ``action_seq_size``."""
        sc = ScalerArithmetic(agent.scaler)
        horizon = int(unwrap(agent.model).query_embed.weight.shape[0])
        execute = int(agent.action_seq_size)
        if not 1 <= execute <= horizon:
            raise ValueError(
                f"ActAgent.action_seq_size = {execute} but its model predicts chunks of {horizon} actions: "
                "its predict() would index past the chunk"
            )
        d = latent_dim(agent)
        return Settings(
            family=self.name,
            obs_dim=sc.obs_dim,
            act_dim=sc.act_dim,
            history=1,
            window="pad",
            horizon=horizon,
            execute=execute,
            prev_actions=False,
            noise_shape=(d,),
            sampler=f"latent ~ U(0, 1)^{d} (torch.rand, the reference's test-time prior) as Phi(noise); "
            "scaled chunk clamped to the data bounds",
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """:class:`ActGraph` on the agent's own ActVAE and scaler."""
        return ActGraph(agent)

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """``torch.rand([1, 1, latent_dim])`` in ``ActVAE.forward``, as Φ(noise)."""
        return [Draw("rand", uniform_from_noise(noise).reshape(1, 1, latent_dim(agent)))]


FAMILY = ActFamily()
