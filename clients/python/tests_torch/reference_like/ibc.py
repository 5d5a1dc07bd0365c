"""Like the reference IBC (agents/ibc_agent.py ``IBCAgent`` with agents/models/ibc/ebms.py
``EBMMLP`` and agents/models/ibc/samplers/langevin_mcmc.py ``LangevinMCMCSampler``): an
energy MLP over [scaled state; scaled action], sampled at inference by Langevin MCMC.

The quirks kept:

* the initial samples come from NUMPY, ``np.random.uniform(bounds[0], bounds[1],
  size=(batch * samples, act))`` in float64, then cast to float32;
* each Langevin step clamps with the float64 bounds tensors, so from the first step on
  the samples are float64 (the network casts its input to float32 at every layer);
  the step noise is ``torch.randn_like(action) * noise_scale``;
* the step size starts at ``sampler_stepsize_init_infer`` and then follows the
  polynomial schedule built from ``sampler_stepsize_init`` (a different number); the
  second loop runs ``inference_iterations`` more steps at the constant
  ``second_inference_stepsize_init``;
* the final sample is drawn from ``softmax(-energy)`` with
  ``torch.distributions.Categorical`` (``torch.multinomial`` inside), not the argmin;
* ``predict`` does not clamp; it inverse-scales and returns [1, act] (float64).
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from .mlp import ResidualMLPNetwork
from .scaler import Scaler, aligning_like_data


class PolynomialSchedule:
    def __init__(self, init: float, final: float, power: float, num_steps: int) -> None:
        self._init, self._final, self._power, self._num_steps = init, final, power, num_steps

    def get_rate(self, index: int) -> float:
        frac = 1 - float(index) / float(self._num_steps - 1)
        return (self._init - self._final) * frac**self._power + self._final


class EBMMLP(nn.Module):
    def __init__(self, mlp: nn.Module, device: str = "cpu") -> None:
        super().__init__()
        self.mlp = mlp
        self.device = device

    def forward(self, state: torch.Tensor, action: torch.Tensor, goal: Optional[torch.Tensor] = None) -> torch.Tensor:
        if action.dim() == 3 and state.dim() == 2:
            state = state.unsqueeze(1).expand(-1, action.size(1), -1)
        fused = torch.cat([state, action], dim=-1)
        B, N, D = fused.size()
        return self.mlp(fused.reshape(B * N, D)).view(B, N)

    def get_params(self):
        return self.mlp.parameters()


class LangevinMCMCSampler:
    def __init__(
        self,
        noise_scale_infer: float = 0.5,
        inference_samples: int = 64,
        inference_iterations: int = 10,
        sampler_stepsize_init: float = 0.0493,
        sampler_stepsize_init_infer: float = 0.5,
        second_inference_stepsize_init: float = 1e-5,
        sampler_stepsize_final: float = 1e-5,
        sampler_stepsize_power: float = 2.0,
        second_inference_iteration: bool = True,
        delta_action_clip: float = 0.1,
        device: str = "cpu",
    ) -> None:
        self.noise_scale_infer = noise_scale_infer
        self.inference_samples = inference_samples
        self.inference_iterations = inference_iterations
        self.sampler_stepsize_init = sampler_stepsize_init
        self.sampler_stepsize_init_infer = sampler_stepsize_init_infer
        self.second_inference_stepsize_init = second_inference_stepsize_init
        self.second_infer = second_inference_iteration
        self.delta_action_clip = delta_action_clip
        self._gradient_scale = 0.5
        self._use_polynomial_rate = True
        self.device = device
        self.bounds: Any = None
        self.infer_schedule = PolynomialSchedule(
            sampler_stepsize_init, sampler_stepsize_final, sampler_stepsize_power, inference_iterations
        )

    def get_bounds(self, scaler: Scaler) -> None:
        self.bounds = scaler.y_bounds

    def _update(self, ebm: nn.Module, state: torch.Tensor, action: torch.Tensor, step_size: float, scale: float):
        bounds = torch.as_tensor(self.bounds)  # float64
        clip = self.delta_action_clip * 0.5 * (bounds[1, :] - bounds[0, :])
        action = action.detach()
        action.requires_grad = True
        e = ebm(state, action, None)
        (grad,) = torch.autograd.grad(outputs=e, inputs=action, grad_outputs=torch.ones(e.size()))
        noise = torch.randn_like(action) * scale
        dynamics = step_size * self._gradient_scale * grad + step_size * noise
        dynamics = dynamics.clamp(min=-clip, max=clip)
        action = action - dynamics
        return action.clamp(min=bounds[0, :], max=bounds[1, :])

    def infer(self, state: torch.Tensor, ebm: nn.Module, goal: Any) -> torch.Tensor:
        batch_size = state.size(0)
        act_dim = self.bounds.shape[1]
        samples = np.random.uniform(
            self.bounds[0, :], self.bounds[1, :], size=(batch_size * self.inference_samples, act_dim)
        )
        x = torch.as_tensor(samples, dtype=torch.float32).reshape(batch_size, self.inference_samples, act_dim)
        step_size = self.sampler_stepsize_init_infer
        for idx in range(self.inference_iterations):
            x = self._update(ebm, state, x, step_size, self.noise_scale_infer).detach()
            step_size = self.infer_schedule.get_rate(idx + 1)
        if self.second_infer:
            step_size = self.second_inference_stepsize_init
            for _ in range(self.inference_iterations):
                x = self._update(ebm, state, x, step_size, self.noise_scale_infer).detach()
        energies = ebm(state, x, goal)
        probs = F.softmax(-1.0 * energies, dim=-1)
        best = torch.distributions.Categorical(probs).sample()
        return x[torch.arange(x.size(0)), best, :]


class ExponentialMovingAverage:
    """The EMA helper's interface (agents/models/ibc/ema_helper/ema.py): shadow copies
    of the parameters that require grad, swapped in by ``store``/``copy_to`` and out by
    ``restore``.
    """

    def __init__(self, parameters, decay: float = 0.999, device: str = "cpu") -> None:
        self.decay = decay
        self.shadow_params = [p.clone().detach() for p in parameters if p.requires_grad]
        self.collected_params: list = []

    def copy_to(self, parameters) -> None:
        for s, p in zip(self.shadow_params, [p for p in parameters if p.requires_grad], strict=True):
            p.data.copy_(s.data)

    def store(self, parameters) -> None:
        self.collected_params = [p.clone() for p in parameters]

    def restore(self, parameters) -> None:
        for c, p in zip(self.collected_params, parameters, strict=True):
            p.data.copy_(c.data)


class IBCAgent:
    def __init__(
        self, model: EBMMLP, sampler: LangevinMCMCSampler, scaler: Scaler, device: str = "cpu", use_ema: bool = False
    ) -> None:
        self.model = model
        self.sampler = sampler
        self.scaler = scaler
        self.device = device
        self.ema_helper = ExponentialMovingAverage(self.model.get_params(), 0.999, device)
        self.use_ema = use_ema
        self.goal_conditioning = False
        self.sampler.get_bounds(scaler)

    def reset(self) -> None:
        pass

    def predict(self, state, goal: Optional[torch.Tensor] = None):
        self.model.eval()
        state = torch.from_numpy(state).float().to(self.device).unsqueeze(0)
        state = self.scaler.scale_input(state)
        if self.use_ema:
            self.ema_helper.store(self.model.parameters())
            self.ema_helper.copy_to(self.model.parameters())
        out = self.sampler.infer(state, self.model, None)
        if self.use_ema:
            self.ema_helper.restore(self.model.parameters())
        out = self.scaler.inverse_scale_output(out)
        return out.detach().cpu().numpy()


def make_agent(
    checkpoint: Optional[Any] = None, samples: int = 16, iterations: int = 3, hidden: int = 16, seed: int = 7
) -> IBCAgent:
    """An Aligning-shaped IBC (obs 20, act 3) with random weights (or the EBM's state
    dict in ``checkpoint``) and a Langevin sampler with the reference's step sizes,
    noise and clip, but fewer samples and iterations than its 64 and 10 + 10.
    """
    torch.manual_seed(seed)
    x, y = aligning_like_data(20, 3)
    ebm = EBMMLP(ResidualMLPNetwork(23, hidden_dim=hidden, num_hidden_layers=4, output_dim=1))
    sampler = LangevinMCMCSampler(inference_samples=samples, inference_iterations=iterations)
    agent = IBCAgent(ebm, sampler, Scaler(x, y))
    if checkpoint is not None:
        agent.model.load_state_dict(torch.load(checkpoint, map_location="cpu"))
    return agent
