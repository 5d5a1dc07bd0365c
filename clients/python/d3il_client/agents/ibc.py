"""IBC: ``IBCAgent`` of agents/ibc_agent.py in the D3IL reference, with the
``LangevinMCMCSampler`` of agents/models/ibc/samplers/langevin_mcmc.py that every
benchmark configuration uses (configs/agents/ibc_agent.yaml).

Its ``predict(state)``, step by step:

1. ``state`` [obs_dim] -> float32 [1, obs_dim]; ``scaler.scale_input`` (with the 1e-12);
   only the current state (no deque; ``reset()`` does nothing); with ``use_ema`` the
   EBM's parameters are swapped for the EMA's during the call;
2. ``sampler.infer``: S = ``inference_samples`` initial actions from NUMPY,
   ``np.random.uniform(bounds[0], bounds[1], size=(S, act))`` with ``bounds =
   scaler.y_bounds`` (the scaled data bounds), cast to float32, [1, S, act];
3. ``inference_iterations`` Langevin steps, each: ``grad = dE/da`` (autograd of the
   EBM ``model(state, a)``, ``EBMMLP``: [state; a] through its MLP, one energy per
   sample), ``noise = torch.randn_like(a) * noise_scale_infer``, ``dyn = step * 0.5 *
   grad + step * noise`` clamped to ± ``delta_action_clip * 0.5 * (bounds[1] −
   bounds[0])``, ``a = clamp(a − dyn, bounds[0], bounds[1])``; the step size starts at
   ``sampler_stepsize_init_infer`` and then follows ``infer_schedule.get_rate(i + 1)``
   (the polynomial schedule built from ``sampler_stepsize_init``);
4. with ``second_inference_iteration``, ``inference_iterations`` more steps at the
   constant ``second_inference_stepsize_init``;
5. the final action is DRAWN from ``softmax(−E)`` over the S samples with
   ``torch.distributions.Categorical(probs).sample()`` (not the argmin);
6. ``scaler.inverse_scale_output``, no clamp; returns [1, act_dim].

The module does the same for a batch [B, 1, obs] with the agent's own EBM layers and
sampler settings: ``noise`` is [B, I + 2, S, act] with I the number of Langevin steps
(``inference_iterations``, twice that with the second loop): slot 0 gives the initial
samples ``bounds[0] + (bounds[1] − bounds[0]) · Φ(noise[:, 0])``, slot 1 + i the
standard-normal noise of step i, and ``noise[:, I + 1, 0, 0]`` the uniform Φ(·) of the
final draw, taken by inverse CDF over ``softmax(−E)``. The check hands predict's
``np.random.uniform`` call the module's initial samples, each ``randn_like`` the step's
slot and ``torch.multinomial`` (inside ``Categorical.sample``) the same inverse CDF on
the probabilities predict computed.

Tracing: neither PyTorch exporter records ``torch.autograd.grad``, so the module
computes dE/da itself, by a reverse pass over the EBM's own layers (``EnergyGradient``:
the reference's ``ResidualMLPNetwork`` — linear input layer, pre-activation residual
blocks, linear output — or ``MLPNetwork``, with Mish, ReLU, Sigmoid, Tanh, SiLU, GELU
or PReLU activations); it is checked against autograd. After the first step the
reference's samples are float64 (clamped with the float64 bounds); the module stays in
float32, within 1e-5 of predict.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Callable, List, Optional, Tuple

import torch
from torch import nn

from .base import Draw, Family, Settings, inverse_cdf_index, multinomial_draw, uniform_from_noise
from .scaling import ScalerArithmetic, unwrap


def _softplus(x: torch.Tensor) -> torch.Tensor:
    """log(1 + eˣ) without overflow, in operators every ONNX runtime has."""
    return torch.relu(x) + torch.log(1.0 + torch.exp(-x.abs()))


def activation_derivative(act: nn.Module) -> Callable[[torch.Tensor], torch.Tensor]:
    """D act(x) / dx as a function of x, for the activations the reference's MLPs use."""
    if isinstance(act, nn.Mish):

        def mish(x: torch.Tensor) -> torch.Tensor:
            t = torch.tanh(_softplus(x))
            return t + x * torch.sigmoid(x) * (1.0 - t * t)

        return mish
    if isinstance(act, nn.ReLU):
        return lambda x: (x > 0).to(x.dtype)
    if isinstance(act, nn.Sigmoid):

        def sigmoid(x: torch.Tensor) -> torch.Tensor:
            s = torch.sigmoid(x)
            return s * (1.0 - s)

        return sigmoid
    if isinstance(act, nn.Tanh):

        def tanh(x: torch.Tensor) -> torch.Tensor:
            t = torch.tanh(x)
            return 1.0 - t * t

        return tanh
    if isinstance(act, nn.SiLU):

        def silu(x: torch.Tensor) -> torch.Tensor:
            s = torch.sigmoid(x)
            return s * (1.0 + x * (1.0 - s))

        return silu
    if isinstance(act, nn.GELU) and act.approximate == "none":

        def gelu(x: torch.Tensor) -> torch.Tensor:
            cdf = 0.5 * (1.0 + torch.erf(x / math.sqrt(2.0)))
            return cdf + x * torch.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)

        return gelu
    if isinstance(act, nn.PReLU):
        return lambda x: torch.where(x > 0, torch.ones_like(x), act.weight.to(x.dtype).expand_as(x))
    if isinstance(act, (nn.Identity, nn.Dropout)):
        return torch.ones_like
    raise ValueError(
        f"IBC export: the EBM uses the activation {type(act).__name__}, whose derivative the exporter does not "
        "know (it writes dE/da out by hand: Mish, ReLU, Sigmoid, Tanh, SiLU, GELU, PReLU); serve the agent instead"
    )


class EnergyGradient(nn.Module):
    """Energies E [N] of fused inputs [N, in] and dE/dinput [N, in], from the EBM's
    own MLP layers: the forward pass keeps the pre-activations, the reverse pass
    multiplies back through the transposed weights and activation derivatives
    (what ``torch.autograd.grad(E, a, ones)`` computes, as traceable operators).
    """

    def __init__(self, mlp: nn.Module) -> None:
        super().__init__()
        layers = list(getattr(mlp, "layers", []))
        if len(layers) < 2 or not isinstance(layers[0], nn.Linear) or not isinstance(layers[-1], nn.Linear):
            raise ValueError(
                f"IBC export: the EBM's MLP ({type(mlp).__name__}) is not the reference's ResidualMLPNetwork or "
                "MLPNetwork (a `layers` list from a Linear to a Linear); serve the agent instead"
            )
        if layers[-1].out_features != 1:
            raise ValueError("IBC export: the EBM's last layer must give one energy per sample")
        self.first, self.last = layers[0], layers[-1]
        self.middle = nn.ModuleList(layers[1:-1])
        if all(isinstance(m, nn.Linear) for m in self.middle):
            self.kind = "mlp"  # MLPNetwork: act after every layer but the last
            self.act = mlp.act
            self.d_act = activation_derivative(mlp.act)
        else:
            self.kind = "residual"
            self.d_blocks: List[Tuple[Callable[[torch.Tensor], torch.Tensor]]] = []
            for b in self.middle:
                if not all(hasattr(b, n) for n in ("l1", "l2", "act")) or getattr(b, "use_norm", False):
                    raise ValueError(
                        f"IBC export: the EBM block {type(b).__name__} is not a pre-activation residual block "
                        "without normalisation (l1, l2, act); serve the agent instead"
                    )
                self.d_blocks.append((activation_derivative(b.act),))

    def forward(self, x: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        """(E [N], dE/dx [N, in]) for x [N, in] float32."""
        if self.kind == "mlp":
            pre = []
            h = x
            for layer in [self.first, *self.middle]:
                p = layer(h)
                pre.append(p)
                h = self.act(p)
            e = self.last(h)
            g = torch.ones_like(e) @ self.last.weight
            for layer, p in zip(reversed([self.first, *self.middle]), reversed(pre), strict=True):
                g = (g * self.d_act(p)) @ layer.weight
            return e.squeeze(-1), g
        h = self.first(x)
        cache = []
        for b in self.middle:
            p1 = b.l1(b.act(h))
            cache.append((h, p1))
            h = b.l2(b.act(p1)) + h
        e = self.last(h)
        g = torch.ones_like(e) @ self.last.weight
        for b, (d,), (a1, p1) in zip(reversed(self.middle), reversed(self.d_blocks), reversed(cache), strict=True):
            g = g + (((g @ b.l2.weight) * d(p1)) @ b.l1.weight) * d(a1)
        return e.squeeze(-1), g @ self.first.weight


def _ebm(agent: Any) -> nn.Module:
    """The EBM predict() runs: the agent's, or a copy holding the EMA's parameters."""
    ebm = unwrap(agent.model)
    if getattr(agent, "use_ema", False):
        ebm = copy.deepcopy(ebm)
        agent.ema_helper.copy_to(ebm.parameters())
    return ebm


def step_sizes(sampler: Any) -> List[float]:
    """The step size of every Langevin step of ``sampler.infer``, in order."""
    n = int(sampler.inference_iterations)
    sizes = [float(sampler.sampler_stepsize_init_infer)]
    sizes += [float(sampler.infer_schedule.get_rate(i + 1)) for i in range(n - 1)]
    if sampler.second_infer:
        sizes += [float(sampler.second_inference_stepsize_init)] * n
    return sizes


def sample_bounds(sampler: Any) -> Tuple[torch.Tensor, torch.Tensor]:
    """The sampler's bounds (``scaler.y_bounds``, float64) as float32 rows."""
    bounds = torch.as_tensor(sampler.bounds, dtype=torch.float64)
    return bounds[0].to(torch.float32), bounds[1].to(torch.float32)


def initial_samples(lo: torch.Tensor, width: torch.Tensor, noise0: torch.Tensor) -> torch.Tensor:
    """Initial samples uniform in the bounds, ``lo + width · Φ(noise0)`` (noise0 [..., S, act])."""
    return lo + width * uniform_from_noise(noise0)


class IbcGraph(nn.Module):
    """[B, 1, obs] raw observations, [B, I + 2, S, act] noise -> [B, 1, act] raw actions, as IBCAgent.predict."""

    def __init__(self, agent: Any) -> None:
        super().__init__()
        sampler = agent.sampler
        ebm = _ebm(agent)
        self.energy = EnergyGradient(ebm.mlp)
        self.scaler = ScalerArithmetic(agent.scaler)
        self.obs_dim = self.scaler.obs_dim
        bounds = torch.as_tensor(sampler.bounds, dtype=torch.float64)
        clip = sampler.delta_action_clip * 0.5 * (bounds[1] - bounds[0])
        lo, hi = sample_bounds(sampler)
        self.register_buffer("lo", lo)
        self.register_buffer("hi", hi)
        self.register_buffer("width", hi - lo)
        self.register_buffer("clip", clip.to(torch.float32))
        self.samples = int(sampler.inference_samples)
        self.steps = step_sizes(sampler)
        self.noise_scale = float(sampler.noise_scale_infer)
        self.gradient_scale = float(sampler._gradient_scale)

    def _fused(self, state: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """[state; a] rows [B·S, obs + act] (EBMMLP's concatenation)."""
        s = state.unsqueeze(1).expand(-1, self.samples, -1)
        return torch.cat([s, a], dim=-1).reshape(-1, self.obs_dim + a.shape[-1])

    def forward(
        self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor] = None, noise: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """Raw actions [B, 1, act] (module docstring)."""
        assert noise is not None
        state = self.scaler.scale_input(obs[:, -1, :])  # [B, obs]
        a = initial_samples(self.lo, self.width, noise[:, 0])
        act = a.shape[-1]
        for i, step in enumerate(self.steps):
            _, g = self.energy(self._fused(state, a))
            grad = g[:, self.obs_dim :].reshape(-1, self.samples, act)
            n = noise[:, 1 + i] * self.noise_scale
            dyn = (step * self.gradient_scale) * grad + step * n
            dyn = torch.clamp(dyn, -self.clip, self.clip)
            a = torch.clamp(a - dyn, self.lo, self.hi)
        e, _ = self.energy(self._fused(state, a))
        probs = torch.softmax(-1.0 * e.reshape(-1, self.samples), dim=-1)  # [B, S]
        idx = inverse_cdf_index(probs, uniform_from_noise(noise[:, len(self.steps) + 1, 0, 0]))  # [B]
        best = torch.gather(a, 1, idx.reshape(-1, 1, 1).expand(-1, 1, act))  # [B, 1, act]
        return self.scaler.inverse_scale_output(best)


class IbcFamily(Family):
    """IBC with Langevin MCMC inference (module docstring)."""

    name = "ibc"
    classes = ("IBCAgent",)

    def accepts(self, agent: Any) -> bool:
        """Only the Langevin sampler of the reference configurations is exported; an
        IBC agent with another sampler is left to serving.
        """
        return type(getattr(agent, "sampler", None)).__name__ == "LangevinMCMCSampler"

    def settings(self, agent: Any) -> Settings:
        """Current state only (k = 1), one action per call, the sampler's sizes."""
        sc = ScalerArithmetic(agent.scaler)
        sampler = agent.sampler
        steps = step_sizes(sampler)
        return Settings(
            family=self.name,
            obs_dim=sc.obs_dim,
            act_dim=sc.act_dim,
            history=1,
            window="pad",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=(len(steps) + 2, int(sampler.inference_samples), sc.act_dim),
            sampler=(
                f"Langevin MCMC: {int(sampler.inference_samples)} samples uniform in the data bounds, "
                f"{len(steps)} steps (noise scale {sampler.noise_scale_infer}), final sample ~ softmax(-E)"
            ),
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """The batched module of predict with the hand-written energy gradient."""
        return IbcGraph(agent)

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """np.random.uniform (the module's initial samples), one randn_like per step,
        the Categorical's torch.multinomial.
        """
        n_steps = len(step_sizes(agent.sampler))
        lo, hi = sample_bounds(agent.sampler)
        start = initial_samples(lo, hi - lo, noise[0])  # [S, act]
        out = [Draw("numpy.random.uniform", start)]
        out += [Draw("randn_like", noise[1 + i].unsqueeze(0).clone()) for i in range(n_steps)]
        out.append(multinomial_draw(uniform_from_noise(noise[n_steps + 1, 0, 0].reshape(1))))
        return out


FAMILY = IbcFamily()
