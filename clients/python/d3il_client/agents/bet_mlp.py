"""BeT-MLP: ``BetMLP_Agent`` of agents/bet_mlp_agent.py in the D3IL reference (its
``BeTPolicy`` and the ``KMeansDiscretizer`` of agents/models/bet/action_ae).

Its ``predict(state)``, step by step:

1. ``state`` [obs_dim] -> float32 [1, 1, obs_dim]; ``scaler.scale_input``;
   ``obs_encoding_net`` (Identity in the configs);
2. ``model.generate_latents``: the MLP gives [1, 1, V · (1 + act_dim)]: V bin logits,
   then V offsets of act_dim each; ``softmax``; ONE ``torch.multinomial(probs, 1)``
   picks the bin; the chosen bin's offset;
3. ``action_ae.decode_actions``: ``bin_centers[bin] + offset``;
4. ``clamp_(min_action, max_action)`` (the scaled data bounds), ``inverse_scale_output``;
   returns [1, act_dim].

``predict`` never uses its ``obs_context`` deque: one observation, one action per
call, whatever ``window_size`` says. The module picks the bin by inverse CDF of
u = Φ(noise[:, 0]) on the same probabilities (``base.inverse_cdf_index``); the check
hands ``torch.multinomial`` the bin that u gives on predict's own probabilities.
"""

from __future__ import annotations

from typing import Any, List, Optional

import torch

from .base import Draw, Family, Settings, inverse_cdf_index, multinomial_draw, uniform_from_noise
from .scaling import ClampedScaledGraph, ScalerArithmetic, unwrap


class BetMlpGraph(ClampedScaledGraph):
    """[B, 1, obs] raw observations, [B, 1] noise -> [B, 1, act] raw actions."""

    def __init__(self, agent: Any) -> None:
        super().__init__(agent)
        policy = unwrap(agent.model)
        if not getattr(policy, "predict_offsets", False):
            raise ValueError(
                "BeTPolicy.predict_offsets is false: the reference BetMLP_Agent.predict() then fails "
                "(it reads offsets that generate_latents did not return); nothing to export"
            )
        self.mlp = policy.model
        self.obs_encoding_net = agent.obs_encoding_net
        self.vocab_size = int(policy.vocab_size)
        self.act_dim = int(policy.act_dim)
        self.register_buffer("bin_centers", torch.as_tensor(agent.action_ae.bin_centers).detach().cpu().clone())

    def forward(
        self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor] = None, noise: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """BetMLP_Agent.predict on each row, the bin sampled from Φ(noise[:, 0])."""
        assert noise is not None
        v, a = self.vocab_size, self.act_dim
        enc = self.obs_encoding_net(self.scaler.scale_input(obs[:, -1:, :]))  # [B, 1, obs]
        out = self.mlp(enc)  # [B, 1, V (1 + A)]
        probs = torch.softmax(out[:, 0, :v], dim=-1)  # [B, V]
        offsets = out[:, 0, v:].reshape(-1, v, a)  # [B, V, A]
        idx = inverse_cdf_index(probs, uniform_from_noise(noise[:, 0]))  # [B]
        onehot = (torch.arange(v).unsqueeze(0) == idx.unsqueeze(-1)).to(offsets.dtype).unsqueeze(-1)  # [B, V, 1]
        action = (onehot * self.bin_centers.to(offsets.dtype)).sum(1) + (onehot * offsets).sum(1)  # [B, A]
        return self.clamp_unscale(action.unsqueeze(1))


class BetMlpFamily(Family):
    """BetMLP_Agent: one k-means bin sampled per call plus its predicted offset."""

    name = "bet_mlp"
    classes = ("BetMLP_Agent",)

    def settings(self, agent: Any) -> Settings:
        """One observation, one action, one uniform (the bin) per call."""
        sc = ScalerArithmetic(agent.scaler)
        v = int(unwrap(agent.model).vocab_size)
        return Settings(
            family=self.name,
            obs_dim=sc.obs_dim,
            act_dim=sc.act_dim,
            history=1,
            window="pad",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=(1,),
            sampler=f"bin ~ softmax over {v} k-means bins (inverse CDF of Phi(noise)) plus its offset; "
            "scaled output clamped to the data bounds",
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """:class:`BetMlpGraph` on the agent's own MLP, bin centres and scaler."""
        return BetMlpGraph(agent)

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """``torch.multinomial(probs, 1)`` in ``BeTPolicy.generate_latents``."""
        return [multinomial_draw(uniform_from_noise(noise.reshape(1)))]


FAMILY = BetMlpFamily()
