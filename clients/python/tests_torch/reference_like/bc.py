"""BC (MLP) like agents/bc_agent.py of the reference: ``BC_Agent`` with a ``BC_Policy``
(Identity observation encoder + residual MLP), ``min_action``/``max_action`` from the
scaler's ``y_bounds`` (float64), and its ``predict``: current observation only,
[1, 1, obs_dim], the scaled output clamped in place to the data bounds *before* the
inverse scaling, ``[0]`` of the numpy result.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
import torch
from torch import nn

from .mlp import ResidualMLPNetwork
from .scaler import Scaler, aligning_like_data

OBS_DIM, ACT_DIM = 20, 3


class BC_Policy(nn.Module):  # noqa: N801 (the reference's name)
    def __init__(self, model: nn.Module, obs_encoder: Optional[nn.Module] = None, visual_input: bool = False) -> None:
        super().__init__()
        self.visual_input = visual_input
        self.obs_encoder = obs_encoder if obs_encoder is not None else nn.Identity()
        self.model = model

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return self.model(self.obs_encoder(inputs))

    def get_params(self):
        return self.parameters()


class BC_Agent:  # noqa: N801
    def __init__(self, model: nn.Module, scaler: Any, device: str = "cpu") -> None:
        self.model = model
        self.scaler = scaler
        self.device = device
        self.min_action = torch.from_numpy(self.scaler.y_bounds[0, :]).to(self.device)
        self.max_action = torch.from_numpy(self.scaler.y_bounds[1, :]).to(self.device)
        self.eval_model_name = "eval_best_bc.pth"
        self.last_model_name = "last_bc.pth"

    @torch.no_grad()
    def predict(self, state: np.ndarray, goal: Optional[torch.Tensor] = None, if_vision: bool = False) -> np.ndarray:
        self.model.eval()
        x = torch.from_numpy(state).float().to(self.device).unsqueeze(0).unsqueeze(0)
        x = self.scaler.scale_input(x)
        out = self.model(x)
        out = out.clamp_(self.min_action, self.max_action)
        return self.scaler.inverse_scale_output(out).detach().cpu().numpy()[0]

    def reset(self) -> None:
        pass


def make_policy(obs_dim: int = OBS_DIM, act_dim: int = ACT_DIM) -> BC_Policy:
    return BC_Policy(ResidualMLPNetwork(obs_dim, 16, 2, act_dim))


def make_agent(checkpoint: Optional[str] = None) -> BC_Agent:
    """A BC agent on Aligning-like data (obs 20, act 3, 4 constant observation dims);
    random weights, or the state dict in ``checkpoint``.
    """
    torch.manual_seed(0)
    model = make_policy()
    if checkpoint is not None:
        model.load_state_dict(torch.load(checkpoint, weights_only=True))
    x, y = aligning_like_data(OBS_DIM, ACT_DIM)
    return BC_Agent(model, Scaler(x, y, True, "cpu"))
