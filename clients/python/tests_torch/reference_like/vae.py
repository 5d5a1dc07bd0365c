"""VAE-State like agents/cvae_agent.py of the reference: ``CVAEAgent`` with a
``VariationalAE`` (``VariationalEncoder`` + residual MLP decoder on [state, z]) whose
``predict`` draws ``torch.randn((batch, latent_dim))`` clamped to ±0.5; the agent's
``predict`` takes ONE unsqueeze ([1, obs_dim]), clamps the scaled output to the data
bounds, inverse-scales, returns [1, act_dim].
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
import torch
from torch import nn

from .mlp import ResidualMLPNetwork
from .scaler import Scaler, aligning_like_data

OBS_DIM, ACT_DIM, LATENT_DIM = 20, 3, 4


class VariationalEncoder(nn.Module):
    def __init__(self, input_dim: int, hidden_dim: int, latent_dim: int) -> None:
        super().__init__()
        self.enc = ResidualMLPNetwork(input_dim, hidden_dim, 2, hidden_dim)
        self.mean = nn.Linear(hidden_dim, latent_dim)
        self.log_std = nn.Linear(hidden_dim, latent_dim)

    def forward(self, x: torch.Tensor):
        h = self.enc(x)
        return self.mean(h), self.log_std(h)


class VariationalAE(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, hidden_dim: int = 16, latent_dim: int = LATENT_DIM) -> None:
        super().__init__()
        self.device = "cpu"
        self.encoder = VariationalEncoder(obs_dim + act_dim, hidden_dim, latent_dim)
        self.decoder = ResidualMLPNetwork(obs_dim + latent_dim, hidden_dim, 2, act_dim)
        self.latent_dim = latent_dim

    def forward(self, state: torch.Tensor, action: torch.Tensor):
        mean, std = self.encoder(torch.cat([state, action], dim=-1))
        z = mean + std * torch.randn_like(std)
        return self.decoder(torch.cat([state, z], dim=-1)), mean, std

    @torch.no_grad()
    def predict(self, state: torch.Tensor) -> torch.Tensor:
        z = torch.randn((state.shape[0], self.latent_dim)).to(self.device).clamp(-0.5, 0.5)
        if len(state.shape) == 3:
            z = z.unsqueeze(0)
        return self.decoder(torch.cat([state, z], dim=-1))

    def get_params(self):
        return self.parameters()


class CVAEAgent:
    def __init__(self, model: VariationalAE, scaler: Any, device: str = "cpu", kl_loss_factor: float = 1.0) -> None:
        self.model = model
        self.scaler = scaler
        self.device = device
        self.kl_loss_factor = kl_loss_factor
        self.min_action = torch.from_numpy(self.scaler.y_bounds[0, :]).to(self.device)
        self.max_action = torch.from_numpy(self.scaler.y_bounds[1, :]).to(self.device)

    @torch.no_grad()
    def predict(self, state: np.ndarray) -> np.ndarray:
        self.model.eval()
        x = torch.from_numpy(state).float().to(self.device).unsqueeze(0)
        x = self.scaler.scale_input(x)
        out = self.model.predict(x)
        out = out.clamp_(self.min_action, self.max_action)
        return self.scaler.inverse_scale_output(out).detach().cpu().numpy()

    def reset(self) -> None:
        pass


def make_agent(checkpoint: Optional[str] = None) -> CVAEAgent:
    """A CVAE agent on Aligning-like data (latent 4); random weights or ``checkpoint``."""
    torch.manual_seed(1)
    model = VariationalAE(OBS_DIM, ACT_DIM)
    if checkpoint is not None:
        model.load_state_dict(torch.load(checkpoint, weights_only=True))
    x, y = aligning_like_data(OBS_DIM, ACT_DIM)
    return CVAEAgent(model, Scaler(x, y, True, "cpu"))
