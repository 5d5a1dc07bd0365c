"""Like the reference BC-GPT (agents/gpt_bc_agent.py ``Gpt_Agent`` with ``GptPolicy`` and
agents/models/transformer/gpt_policy.py ``MinGPT``): a GPT over the window of scaled
observations that regresses one action per position.

The quirks kept: ``obs_context`` is a deque of ``window_size`` that starts EMPTY at
``reset()`` (the window grows 1..k); each observation is unsqueezed to [1, obs] and the
deque stacked on dim 1 ([1, T, obs]); the outputs of every position are clamped in
place to the float64 scaled data bounds (``min_action``/``max_action``), inverse-scaled,
and the LAST position's action returned as [1, act].
"""

from __future__ import annotations

from collections import deque
from typing import Any, Optional

import torch
from torch import nn

from .mingpt import GPT, GPTConfig
from .scaler import Scaler, aligning_like_data


class MinGPT(nn.Module):
    """A GPT whose head gives ``action_dim`` numbers per position."""

    def __init__(self, input_dim: int, n_layer: int, n_head: int, n_embd: int, block_size: int, action_dim: int):
        super().__init__()
        config = GPTConfig(
            input_size=input_dim,
            vocab_size=action_dim,
            block_size=block_size,
            n_layer=n_layer,
            n_head=n_head,
            n_embd=n_embd,
        )
        self.model = GPT(config)

    def get_params(self):
        return self.model.parameters()

    def forward(self, obs_rep: torch.Tensor) -> torch.Tensor:
        output, _ = self.model(obs_rep)
        return output


class GptPolicy(nn.Module):
    def __init__(self, model: nn.Module, visual_input: bool = False) -> None:
        super().__init__()
        self.visual_input = visual_input
        self.obs_encoder = nn.Identity()
        self.model = model

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return self.model(self.obs_encoder(inputs))

    def get_params(self):
        return self.parameters()


class Gpt_Agent:  # noqa: N801 (the reference's name)
    def __init__(self, model: GptPolicy, scaler: Scaler, window_size: int, device: str = "cpu") -> None:
        self.model = model
        self.scaler = scaler
        self.device = device
        self.min_action = torch.from_numpy(self.scaler.y_bounds[0, :]).to(self.device)
        self.max_action = torch.from_numpy(self.scaler.y_bounds[1, :]).to(self.device)
        self.window_size = window_size
        self.obs_context: deque = deque(maxlen=self.window_size)

    def reset(self) -> None:
        self.obs_context.clear()

    def predict(self, state, sample: bool = False):
        self.model.eval()
        obs = torch.from_numpy(state).float().to(self.device).unsqueeze(0)
        obs = self.scaler.scale_input(obs)
        self.obs_context.append(obs)
        enc_obs_seq = torch.stack(tuple(self.obs_context), dim=1)
        actions = self.model(enc_obs_seq)
        actions = actions.clamp_(self.min_action, self.max_action)
        actions = self.scaler.inverse_scale_output(actions)
        actions = actions.detach().cpu().numpy()
        return actions[:, -1]


def make_agent(checkpoint: Optional[Any] = None, window_size: int = 3, seed: int = 3) -> Gpt_Agent:
    """An Aligning-shaped BC-GPT (obs 20, act 3, window 3 as the reference's Aligning
    script) with random weights, or the state dict in ``checkpoint``.
    """
    torch.manual_seed(seed)
    x, y = aligning_like_data(20, 3)
    gpt = MinGPT(input_dim=20, n_layer=2, n_head=4, n_embd=32, block_size=window_size, action_dim=3)
    agent = Gpt_Agent(GptPolicy(gpt), Scaler(x, y), window_size=window_size)
    if checkpoint is not None:
        agent.model.load_state_dict(torch.load(checkpoint, map_location="cpu"))
    return agent
