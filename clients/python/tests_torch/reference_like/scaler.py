"""The reference Scaler's arithmetic (agents/utils/scaler.py in ALRhub/d3il): mean and
std per dimension from the training data, ``(x - mean) / (std + 1e-12)`` in float32,
bounds of the scaled actions in ``y_bounds`` (float64 numpy, row 0 min, row 1 max).
"""

from __future__ import annotations

import numpy as np
import torch


class Scaler:
    def __init__(self, x_data: np.ndarray, y_data: np.ndarray, scale_data: bool = True, device: str = "cpu") -> None:
        self.scale_data = scale_data
        self.device = device
        x_data = np.asarray(x_data, np.float32).reshape(-1, np.shape(x_data)[-1])
        y_data = np.asarray(y_data, np.float32).reshape(-1, np.shape(y_data)[-1])
        self.x_mean = torch.from_numpy(x_data.mean(0))
        self.x_std = torch.from_numpy(x_data.std(0))
        self.y_mean = torch.from_numpy(y_data.mean(0))
        self.y_std = torch.from_numpy(y_data.std(0))
        self.x_max = torch.from_numpy(x_data.max(0))
        self.x_min = torch.from_numpy(x_data.min(0))
        self.y_min = torch.from_numpy(y_data.min(0))
        self.y_max = torch.from_numpy(y_data.max(0))
        eps_y = 1e-12 * np.ones(y_data.shape[-1])
        eps_x = 1e-12 * np.ones(x_data.shape[-1])
        self.y_bounds = np.zeros((2, y_data.shape[-1]))
        self.x_bounds = np.zeros((2, x_data.shape[-1]))
        if scale_data:
            self.y_bounds[0] = (y_data.min(0) - y_data.mean(0)) / (y_data.std(0) + eps_y)
            self.y_bounds[1] = (y_data.max(0) - y_data.mean(0)) / (y_data.std(0) + eps_y)
            self.x_bounds[0] = (x_data.min(0) - x_data.mean(0)) / (x_data.std(0) + eps_x)
            self.x_bounds[1] = (x_data.max(0) - x_data.mean(0)) / (x_data.std(0) + eps_x)
        else:
            self.y_bounds[0], self.y_bounds[1] = y_data.min(0), y_data.max(0)
            self.x_bounds[0], self.x_bounds[1] = x_data.min(0), x_data.max(0)
        self.y_bounds_tensor = torch.from_numpy(self.y_bounds)
        self.x_bounds_tensor = torch.from_numpy(self.x_bounds)
        self.tensor_y_bounds = self.y_bounds_tensor

    @torch.no_grad()
    def scale_input(self, x: torch.Tensor) -> torch.Tensor:
        if self.scale_data:
            return ((x - self.x_mean) / (self.x_std + 1e-12 * torch.ones(self.x_std.shape))).to(torch.float32)
        return x

    @torch.no_grad()
    def scale_output(self, y: torch.Tensor) -> torch.Tensor:
        if self.scale_data:
            return ((y - self.y_mean) / (self.y_std + 1e-12 * torch.ones(self.y_std.shape))).to(torch.float32)
        return y

    @torch.no_grad()
    def inverse_scale_input(self, x: torch.Tensor) -> torch.Tensor:
        if self.scale_data:
            return (x * (self.x_std + 1e-12 * torch.ones(self.x_std.shape)) + self.x_mean).to(torch.float32)
        return x

    @torch.no_grad()
    def inverse_scale_output(self, y: torch.Tensor) -> torch.Tensor:
        if self.scale_data:
            return y * (self.y_std + 1e-12 * torch.ones(self.y_std.shape)) + self.y_mean
        return y

    def clip_action(self, y: torch.Tensor) -> torch.Tensor:
        return y.clamp(self.tensor_y_bounds[0, :] * 1.1, self.tensor_y_bounds[1, :] * 1.1).to(torch.float32)


def aligning_like_data(obs_dim: int, act_dim: int, n: int = 512, seed: int = 0, constant_obs_dims: int = 4):
    """Synthetic training data shaped like a D3IL task's: the last
    ``constant_obs_dims`` observation dimensions constant (std 0), as Aligning's
    target pose is in every demonstration, so only the scaler's 1e-12 keeps them finite.
    """
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, obs_dim)).astype(np.float32) * 0.1 + 0.5
    y = rng.normal(size=(n, act_dim)).astype(np.float32) * 0.01
    if constant_obs_dims:
        x[:, -constant_obs_dims:] = 0.25
    return x, y
