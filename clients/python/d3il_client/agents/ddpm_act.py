"""DDPM-ACT: the reference ``agents/ddpm_encdec_agent.py`` ``DiffusionAgent`` (the
"ddpm_encdec" agent: a ``DiffusionEncDec`` transformer denoising a chunk of actions).

Its ``predict`` for one observation:

1. scales it and appends it to ``obs_context`` (a deque of ``obs_seq_len``, emptied
   by ``reset()``: windows grow 1..k) on EVERY step;
2. when ``action_counter == action_seq_size`` (at reset and after each chunk), sets
   the counter to 0 and samples a chunk ``[1, action_seq_len, act]`` with the EMA
   weights: ``agents/models/diffusion/diffusion_policy.py`` ``Diffusion`` (the same
   DDPM loop as DDPM-MLP/GPT, ``d3il_client.agents.ddpm``; its sample shape is the
   model's ``action_seq_len``), clamped to the scaled bounds, inverse-scaled;
3. returns ``chunk[:, action_counter]`` and counts up.

So k = ``obs_seq_len`` (grow), H = the model's ``action_seq_len``, E = the agent's
``action_seq_size``; noise ``[n, H, act]`` (row 0 the initial chunk, row j the
noise of step t = n − j).

The denoiser: tokens [emb(t), s_1 … s_w] (positions 0..w−1) into the encoder (causal
self-attention), the chunk's action tokens (positions w−1 … w+H−2) through the decoder
(causal self-attention plus cross-attention on the encoder output). The reference
slices the action positions from ``w − 1`` on; the module gathers positions
``arange(H) + w − 1`` instead, so the chunk's length stays H for tract whatever the
window (a slice from a symbolic start leaves tract a length it cannot reduce to H).
``einops.rearrange`` of the timesteps becomes ``[:, None]``.
"""

from __future__ import annotations

from typing import Any, List, Optional

import torch

from .base import Draw, Family, Settings
from .ddpm import AGENT_CLASSES, DdpmSampler, check_supported, class_names, denoiser, full_steps, predict_diffusion
from .scaling import ScalerArithmetic


class DdpmActGraph(torch.nn.Module):
    """DDPM-ACT's model call for a batch: window [B, w] (1..k) -> chunk [B, H, act]."""

    def __init__(self, agent: Any) -> None:
        super().__init__()
        d = predict_diffusion(agent)
        self.net = d.model
        self.sampler = DdpmSampler(d)
        self.scaling = ScalerArithmetic(agent.scaler)
        self.horizon = int(self.net.action_seq_len)

    def denoise(self, actions: torch.Tensor, t: int, states: torch.Tensor) -> torch.Tensor:
        """``DiffusionEncDec.forward`` (not goal-conditioned, eval mode), window symbolic."""
        net = self.net
        w = states.shape[1]
        g = int(net.goal_seq_len)
        emb_t = net.time_emb(full_steps(states, t)[:, None])  # [B, 1, E]
        state_x = net.drop(net.tok_emb(states) + net.pos_emb[:, g : g + w, :])
        idx = torch.arange(self.horizon, device=states.device) + (w - 1 + g)
        action_x = net.drop(net.action_emb(actions) + torch.index_select(net.pos_emb, 1, idx))
        memory = net.encoder(torch.cat([emb_t, state_x], dim=1))
        return net.action_pred(net.decoder(action_x, memory))

    def forward(self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor], noise: torch.Tensor) -> torch.Tensor:
        """[B, w, obs] raw observations, noise [B, n, H, act] -> [B, H, act] raw actions."""
        s = self.scaling.scale_input(obs)  # [B, w, obs]
        x = self.sampler.run(noise[:, 0], lambda x, t: self.denoise(x, t, s), lambda j: noise[:, j])
        return self.scaling.inverse_scale_output(x)  # [B, H, act]


class DdpmAct(Family):
    """DDPM-ACT: the encoder-decoder ``DiffusionAgent`` (chunks of actions)."""

    name = "ddpm_act"
    classes = AGENT_CLASSES

    def accepts(self, agent: Any) -> bool:
        """Whether the agent is the encoder-decoder DiffusionAgent."""
        net = denoiser(agent)
        return net is not None and hasattr(agent, "action_seq_size") and "DiffusionEncDec" in class_names(net)

    def settings(self, agent: Any) -> Settings:
        """The window k = obs_seq_len, H = the model's action_seq_len, E = action_seq_size."""
        check_supported(agent, self.name)
        net = denoiser(agent)
        k, horizon, execute = int(agent.obs_seq_len), int(net.action_seq_len), int(agent.action_seq_size)
        if execute > horizon:
            raise ValueError(
                f"ddpm_act: the agent executes action_seq_size={execute} actions of a chunk of the model's "
                f"action_seq_len={horizon}: its own predict() indexes past the chunk"
            )
        positions = int(net.pos_emb.shape[1])
        if int(net.goal_seq_len) + k - 1 + horizon > positions:
            raise ValueError(
                f"ddpm_act: obs_seq_len={k} with a chunk of {horizon} needs {k - 1 + horizon} positions, "
                f"the model has {positions} (its obs_seq_len differs from the agent's): predict() fails"
            )
        sampler = DdpmSampler(agent.model)
        act = int(agent.model.action_dim)
        return Settings(
            family=self.name,
            obs_dim=int(agent.scaler.x_mean.shape[-1]),
            act_dim=act,
            history=k,
            window="grow",
            horizon=horizon,
            execute=execute,
            prev_actions=False,
            noise_shape=(sampler.n, horizon, act),
            sampler=sampler.describe(),
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """The batched module of one chunk sampling (module docstring)."""
        self.settings(agent)
        return DdpmActGraph(agent).eval()

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """The torch.randn and randn_like draws of predict() from one noise row."""
        sampler = DdpmSampler(agent.model)
        horizon, act = int(denoiser(agent).action_seq_len), int(agent.model.action_dim)
        return sampler.draws(noise, [(1, horizon, act)] * (1 + sampler.n + sampler.extra))


FAMILY = DdpmAct()
