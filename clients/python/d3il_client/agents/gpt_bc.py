"""BC-GPT: ``Gpt_Agent`` of agents/gpt_bc_agent.py in the D3IL reference.

Its ``predict(state)``, step by step:

1. ``state`` [obs_dim] -> float32 [1, obs_dim]; ``scaler.scale_input`` (with the 1e-12);
2. appended to ``obs_context``, a deque of ``maxlen = window_size`` that ``reset()``
   empties: the window grows 1, 2, …, k at episode start;
3. the deque stacked on dim 1, [1, T, obs_dim], through ``self.model`` (``GptPolicy``:
   ``obs_encoder`` (Identity) then ``MinGPT``, a minGPT whose head gives ``action_dim``
   numbers per position): [1, T, act_dim], one regressed action per position;
4. ``actions.clamp_(self.min_action, self.max_action)``: the scaled data bounds
   (``scaler.y_bounds``, float64, not × 1.1);
5. ``scaler.inverse_scale_output``; returns the LAST position's action, [1, act_dim].

No randomness; one action per call (H = E = 1). The module does the same for a batch
of windows [B, T, obs] with the agent's own ``model``.

Tracing: the reference GPT takes ``B, T, C = x.size()`` and ``t = idx.size()[1]`` in
Python, slices ``pos_emb[:, :t]`` and its causal ``mask[:, :, :T, :T]`` with them and
reshapes with ``view(B, T, n_head, C // n_head)``. The TorchScript tracer records
these sizes as shape operations of the input (nothing is converted to a Python number
with ``int()``), so the graph traced at window k stays correct at every window 1..k;
the tests check the exported file at every window in onnxruntime.
"""

from __future__ import annotations

from typing import Any, List, Optional

import torch

from .base import Draw, Family, Settings
from .scaling import ClampedScaledGraph, ScalerArithmetic, unwrap


def window_of(agent: Any) -> int:
    """k: the ``maxlen`` of the agent's observation deque (``window_size``)."""
    ctx = getattr(agent, "obs_context", None)
    k = getattr(ctx, "maxlen", None) or getattr(agent, "window_size", None)
    if not k:
        raise ValueError(f"{type(agent).__name__} has neither obs_context.maxlen nor window_size")
    return int(k)


def is_visual(agent: Any) -> bool:
    """Whether the agent's policy takes images (the vision variants share class names)."""
    return bool(getattr(unwrap(agent.model), "visual_input", False))


class GptBcGraph(ClampedScaledGraph):
    """[B, T, obs] raw observations (T = 1..k) -> [B, 1, act] raw actions, as Gpt_Agent.predict."""

    def __init__(self, agent: Any) -> None:
        super().__init__(agent)
        self.model = unwrap(agent.model)

    def forward(
        self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor] = None, noise: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """Raw actions [B, 1, act] for raw windows [B, T, obs] (module docstring)."""
        actions = self.model(self.scaler.scale_input(obs))  # [B, T, act]
        return self.clamp_unscale(actions[:, -1:, :])


class GptBcFamily(Family):
    """BC-GPT (module docstring)."""

    name = "bc_gpt"
    classes = ("Gpt_Agent",)

    def accepts(self, agent: Any) -> bool:
        """State agents only: the vision variants share the class name."""
        return not is_visual(agent)

    def settings(self, agent: Any) -> Settings:
        """The window k from the deque, H = E = 1."""
        sc = ScalerArithmetic(agent.scaler)
        return Settings(
            family=self.name,
            obs_dim=sc.obs_dim,
            act_dim=sc.act_dim,
            history=window_of(agent),
            window="grow",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=None,
            sampler="deterministic GPT over the growing window; last position's action clamped to the data bounds",
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """The batched module of predict, on the agent's own networks."""
        return GptBcGraph(agent)

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """None: deterministic."""
        return []


FAMILY = GptBcFamily()
