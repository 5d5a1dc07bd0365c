"""The reference Scaler's arithmetic (agents/utils/scaler.py in ALRhub/d3il) as module
buffers, for the families' batched modules.

The reference computes ``(x - x_mean) / (x_std + 1e-12 * torch.ones(...))`` with the
ones in torch's default dtype (float32) and the statistics in the dtype of the
training data (float32 for the D3IL datasets), and the inverse
``y * (y_std + 1e-12 * torch.ones(...)) + y_mean``. The denominators are computed
here once with that same expression, so a dimension with std 0 (Aligning's constant
observation dimensions) divides by the same 1e-12 as ``predict`` and stays finite.
Nothing here reads the training data: only the scaler object's arrays.
"""

from __future__ import annotations

from typing import Any

import torch


def _tensor(v: Any) -> torch.Tensor:
    return torch.as_tensor(v).detach().cpu().clone()


def eps_denominator(std: torch.Tensor) -> torch.Tensor:
    """``std + 1e-12 * torch.ones(std.shape)``, as the reference Scaler writes it."""
    return std + 1e-12 * torch.ones(std.shape)


class ScalerArithmetic(torch.nn.Module):
    """``scale_input``, ``inverse_scale_output`` and the clamps of an agent's
    predict(), on batches, from the agent's scaler object.
    """

    def __init__(self, scaler: Any) -> None:
        super().__init__()
        self.scale_data = bool(scaler.scale_data)
        x_mean, x_std = _tensor(scaler.x_mean), _tensor(scaler.x_std)
        y_mean, y_std = _tensor(scaler.y_mean), _tensor(scaler.y_std)
        self.register_buffer("x_mean", x_mean)
        self.register_buffer("x_den", eps_denominator(x_std))
        self.register_buffer("y_mean", y_mean)
        self.register_buffer("y_den", eps_denominator(y_std))
        # clip_action: the scaled data bounds × 1.1, computed in the bounds' dtype
        bounds = _tensor(getattr(scaler, "y_bounds_tensor", getattr(scaler, "y_bounds", torch.zeros(2, 0))))
        self.register_buffer("clip_lo", as_float32_bound(bounds[0] * 1.1))
        self.register_buffer("clip_hi", as_float32_bound(bounds[1] * 1.1))

    @property
    def obs_dim(self) -> int:
        """Observation dimensions of the scaler's statistics."""
        return int(self.x_mean.shape[-1])

    @property
    def act_dim(self) -> int:
        """Action dimensions of the scaler's statistics."""
        return int(self.y_mean.shape[-1])

    def scale_input(self, x: torch.Tensor) -> torch.Tensor:
        """Raw float32 observations -> the float32 inputs predict() gives the network."""
        if not self.scale_data:
            return x
        return ((_promote(x, self.x_mean) - self.x_mean) / self.x_den).to(torch.float32)

    def inverse_scale_output(self, y: torch.Tensor) -> torch.Tensor:
        """Network actions -> raw actions (float32; the reference returns the dtype of
        its statistics, float32 for the D3IL datasets).
        """
        if not self.scale_data:
            return y
        return (_promote(y, self.y_mean) * self.y_den + self.y_mean).to(torch.float32)

    def clip_action(self, y: torch.Tensor) -> torch.Tensor:
        """``Scaler.clip_action``: clamp to the scaled data bounds × 1.1."""
        return torch.clamp(y, self.clip_lo, self.clip_hi)


def as_float32_bound(b: Any) -> torch.Tensor:
    """A clamp bound for float32 tensors. Clamping float32 values to float64 bounds
    (``out.clamp_(min_action, max_action)`` with the float64 ``y_bounds``) gives
    exactly what clamping to the bounds rounded to nearest float32 gives: no float32
    lies strictly between a bound and its nearest float32.
    """
    return _tensor(b).to(torch.float32)


def _promote(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    dt = torch.promote_types(x.dtype, like.dtype)
    return x if x.dtype == dt else x.to(dt)


def clamp_bounds(agent: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """An agent's ``min_action`` / ``max_action`` (what BC, VAE, ACT and BeT-MLP
    predict() clamp the scaled actions to) as float32 bounds.
    """
    return as_float32_bound(agent.min_action), as_float32_bound(agent.max_action)


class ClampedScaledGraph(torch.nn.Module):
    """Base of the graphs whose agent's predict() clamps the scaled actions to its
    ``min_action`` / ``max_action`` and then inverse-scales them (BC, VAE-State,
    VAE-ACT, BeT-MLP, BeT, BC-GPT): the scaler and the bounds, held once.
    """

    def __init__(self, agent: Any) -> None:
        super().__init__()
        self.scaler = ScalerArithmetic(agent.scaler)
        lo, hi = clamp_bounds(agent)
        self.register_buffer("lo", lo)
        self.register_buffer("hi", hi)

    def clamp_unscale(self, scaled: torch.Tensor) -> torch.Tensor:
        """Raw actions from scaled ones, clamped first as predict() does."""
        return self.scaler.inverse_scale_output(torch.clamp(scaled, self.lo, self.hi))


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    """The network inside ``nn.DataParallel`` (BC_Agent wraps its model when several
    GPUs are visible); the same object otherwise.
    """
    return model.module if isinstance(model, torch.nn.DataParallel) else model
