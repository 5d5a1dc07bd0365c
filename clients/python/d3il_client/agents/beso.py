"""BESO (agents/beso_agent.py ``BesoAgent`` of the D3IL reference code).

What the reference ``predict(obs)`` does for one rollout, and this module for a batch:

1. scale the observation (``(x - mean) / (std + 1e-12)``) and push it into
   ``obs_context`` (empty at ``reset()``: windows 1..``window_size``);
2. ``x = randn((1, 1, act)) * sigma_max`` appended to ``action_context``, the
   previous ``window_size - 1`` CLAMPED SCALED actions (here: ``prev_actions``, the
   raw executed actions, scaled back: the round trip costs about 1e-7);
3. the sampler ``sampler_type`` over ``get_noise_schedule(num_sampling_steps,
   noise_scheduler)`` (the reference's constructor sets ``noise_scheduler =
   'linear'``; the schedule is taken from the agent's own method) with the
   ``GCDenoiser`` preconditioning (c_skip, c_out, c_in of ``sigma_data``) around
   ``DiffusionGPT``. ``euler_ancestral`` (the configs' sampler) adds fresh
   ``randn_like`` noise to the WHOLE sequence, context rows included, after every
   step whose ``sigma_down > 0`` (all but the last);
4. the last row, clamped to ``model.min_action``/``max_action`` and inverse-scaled.

The EMA weights are the ones ``predict`` runs with (``ema_helper.copy_to``) when
``use_ema``. ``DiffusionGPT.forward`` computes ``int(x.size()[1] / 2)`` in Python,
which tracing freezes to the example window; the module re-expresses that forward
(same submodules and weights, ``reshape(B, -1, 2, E)``) so that the ONNX graph
keeps the window symbolic. Its sigma embeddings and the sampler's coefficients are
constants computed once, with the reference's own float32 expressions.

``noise`` is ``[B, 1 + S, k, act]``: ``noise[:, 0, 0]`` the initial draw,
``noise[:, 1 + j, :T]`` the j-th ``randn_like`` of the ancestral steps (prefix
slices only: tract cannot unify ``Sym(T)`` with a suffix slice). Deterministic
samplers (``euler``, ``heun``, ``ddim``) have S = 0; ``euler`` and ``heun`` still
draw a ``randn_like`` every step that they never use (``s_churn`` is 0), which
``draws`` hands them as zeros.
"""

from __future__ import annotations

import copy
from typing import Any, List, Optional, Tuple

import torch
from torch import nn

from .base import Draw, Family, Settings
from .scaling import ScalerArithmetic, as_float32_bound

#: Samplers of ``BesoAgent.sample_loop`` this module reproduces.
SAMPLERS = ("euler_ancestral", "euler", "heun", "ddim")


class UnsupportedBeso(ValueError):
    """A BESO agent configured in a way the module does not reproduce."""


class _Scaling(ScalerArithmetic):
    """The shared Scaler arithmetic plus ``scale_output`` for the action context:
    ``(y - y_mean) / (y_std + 1e-12 * ones)`` in float32, as the reference scales
    actions (its context rows are already scaled; ours arrive raw).
    """

    def scale_output(self, y: torch.Tensor) -> torch.Tensor:
        """Raw actions -> the model's action space."""
        if not self.scale_data:
            return y
        dt = torch.promote_types(y.dtype, self.y_mean.dtype)
        return ((y.to(dt) - self.y_mean) / self.y_den).to(torch.float32)


class _Denoiser(nn.Module):
    """``GCDenoiser(DiffusionGPT)`` at one sigma, for a batch and a symbolic window.

    ``DiffusionGPT.forward`` is re-expressed on the same submodules (tok_emb,
    pos_emb, action_emb, blocks, ln_f, action_pred): its ``int(x.size()[1] / 2)``
    becomes ``reshape(B, -1, 2, E)``. Another inner model is called as it is.
    """

    def __init__(self, wrapper: nn.Module) -> None:
        super().__init__()
        self.inner = wrapper.inner_model
        self.sigma_data = float(wrapper.sigma_data)
        self.gpt = type(self.inner).__name__ == "DiffusionGPT"
        if self.gpt and getattr(self.inner, "goal_conditioned", False):
            raise UnsupportedBeso(
                "a goal-conditioned DiffusionGPT: the reference predict() passes no goal for the state tasks; "
                "serve this agent instead (python -m d3il_client.serve --agent ...)"
            )

    def scalings(self, sigma: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """GCDenoiser.get_scalings, same expressions (float32 ``sigma`` of shape [1])."""
        sd = self.sigma_data
        c_skip = sd**2 / (sigma**2 + sd**2)
        c_out = sigma * sd / (sigma**2 + sd**2) ** 0.5
        c_in = 1 / (sigma**2 + sd**2) ** 0.5
        return c_skip, c_out, c_in

    def sigma_embedding(self, sigma: torch.Tensor) -> torch.Tensor:
        """The sigma token [1, 1, E] (``sigma_emb(log(sigma) / 4)``)."""
        with torch.no_grad():
            return self.inner.sigma_emb((sigma.log() / 4).reshape(1, 1).to(torch.float32)).reshape(1, 1, -1)

    def inner_gpt(self, states: torch.Tensor, actions: torch.Tensor, emb_t: torch.Tensor) -> torch.Tensor:
        m = self.inner
        b, t = states.shape[0], states.shape[1]
        pos = m.pos_emb[:, :t, :]
        state_x = m.drop(m.tok_emb(states) + pos)
        action_x = m.drop(m.action_emb(actions) + pos)
        e = state_x.shape[-1]
        sa = torch.stack([state_x, action_x], dim=1).permute(0, 2, 1, 3).reshape(b, -1, e)
        x = torch.cat([emb_t.expand(b, 1, e), sa], dim=1)
        x = m.ln_f(m.blocks(x))[:, 1:, :]
        x = x.reshape(b, -1, 2, e)[:, :, 1, :]
        return m.action_pred(x)

    def forward(
        self,
        states: torch.Tensor,
        x: torch.Tensor,
        sigma: torch.Tensor,
        emb_t: torch.Tensor,
        c_skip: torch.Tensor,
        c_out: torch.Tensor,
        c_in: torch.Tensor,
    ) -> torch.Tensor:
        """D(x; sigma) = F(c_in x) c_out + x c_skip, as GCDenoiser.forward."""
        if self.gpt:
            f = self.inner_gpt(states, x * c_in, emb_t)
        else:
            f = self.inner(states, x * c_in, None, sigma.expand(x.shape[0]))
        return f * c_out + x * c_skip


class BesoGraph(nn.Module):
    """``forward(obs [B, T, obs], prev_actions [B, T-1, act] or None, noise
    [B, 1 + S, k, act]) -> [B, 1, act]`` (module conventions in ``base``).
    """

    def __init__(self, agent: Any, settings: Settings) -> None:
        super().__init__()
        self.sampler = str(agent.sampler_type)
        if self.sampler not in SAMPLERS:
            raise UnsupportedBeso(
                f"BESO sampler_type {self.sampler!r} is not reproduced here (supported: {', '.join(SAMPLERS)}); "
                "serve this agent instead (python -m d3il_client.serve --agent ...)"
            )
        model = copy.deepcopy(agent.model).cpu().eval()
        ema = getattr(agent, "ema_helper", None)
        if getattr(agent, "use_ema", False) and ema is not None:
            # predict() runs with the EMA weights (ema_helper.copy_to).
            live = [p for p in model.parameters() if p.requires_grad]
            with torch.no_grad():
                for s, p in zip(ema.shadow_params, live, strict=False):  # as copy_to pairs them
                    p.copy_(s.detach().cpu())
        for p in model.parameters():
            p.requires_grad_(False)
        self.den = _Denoiser(model)
        self.scale = _Scaling(agent.scaler)
        self.register_buffer("min_action", as_float32_bound(agent.model.min_action).reshape(-1))
        self.register_buffer("max_action", as_float32_bound(agent.model.max_action).reshape(-1))
        self.sigma_max = agent.sigma_max
        self.act_dim = settings.act_dim
        self.takes_prev = settings.prev_actions
        sigmas = sigma_schedule(agent)
        self.n = len(sigmas) - 1
        # Per model call: sigma [1], its token, c_skip, c_out, c_in.
        self.calls: List[Tuple[torch.Tensor, ...]] = []
        # Per step: what the sampler does with the model calls' results.
        self.plan: List[dict] = []

        def call(sig: torch.Tensor) -> int:
            sig = sig.reshape(1)
            self.calls.append((sig, self.den.sigma_embedding(sig), *self.den.scalings(sig)))
            return len(self.calls) - 1

        draws = 0
        for i in range(self.n):
            s, s_next = sigmas[i], sigmas[i + 1]
            if self.sampler == "euler_ancestral":
                down, up = ancestral_step(s, s_next)
                step = {"call": call(s), "sigma": s, "dt": down - s, "up": up, "noise": None}
                if down > 0:
                    step["noise"] = 1 + draws
                    draws += 1
            elif self.sampler in ("euler", "heun"):
                hat = s * (0.0 + 1)  # gamma is 0: s_churn is 0 in predict's sample_loop
                step = {"call": call(hat), "sigma": hat, "dt": s_next - hat, "second": None}
                if self.sampler == "heun" and not bool(s_next == 0):
                    step["second"] = call(s_next)
                    step["sigma2"] = s_next
            else:  # ddim
                t, t_next = s.log().neg(), s_next.log().neg()
                h = t_next - t
                step = {"call": call(s), "a": t_next.neg().exp() / t.neg().exp(), "b": (-h).expm1()}
            self.plan.append(step)
        self.draws = draws
        # As buffers, so that .to() and the ONNX export see constants.
        for j, c in enumerate(self.calls):
            for name, v in zip(("sig", "emb", "skip", "out", "cin"), c, strict=True):
                self.register_buffer(f"c{j}_{name}", v.detach().clone())

    def _model(self, j: int, states: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        g = lambda n: getattr(self, f"c{j}_{n}")  # noqa: E731
        return self.den(states, x, g("sig"), g("emb"), g("skip"), g("out"), g("cin"))

    def forward(self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor], noise: torch.Tensor) -> torch.Tensor:
        """Raw actions [B, 1, act] of one predict() per row."""
        states = self.scale.scale_input(obs)
        t = obs.shape[1]
        x = noise[:, 0, :1, :] * self.sigma_max
        if self.takes_prev and prev_actions is not None:
            x = torch.cat([self.scale.scale_output(prev_actions), x], dim=1)
        for step in self.plan:
            if self.sampler == "euler_ancestral":
                sig = step["sigma"]
                denoised = self._model(step["call"], states, x)
                x = x + (x - denoised) / sig * step["dt"]
                if step["noise"] is not None:
                    x = x + noise[:, step["noise"], :t, :] * step["up"]
            elif self.sampler in ("euler", "heun"):
                sig = step["sigma"]
                d = (x - self._model(step["call"], states, x)) / sig
                if step["second"] is None:
                    x = x + d * step["dt"]
                else:
                    x2 = x + d * step["dt"]
                    d2 = (x2 - self._model(step["second"], states, x2)) / step["sigma2"]
                    x = x + (d + d2) / 2 * step["dt"]
            else:
                x = step["a"] * x - step["b"] * self._model(step["call"], states, x)
        last = x[:, -1:, :]
        last = torch.minimum(torch.maximum(last, self.min_action), self.max_action)  # clamp_(min, max)
        return self.scale.inverse_scale_output(last)


def ancestral_step(
    sigma_from: torch.Tensor, sigma_to: torch.Tensor, eta: float = 1.0
) -> Tuple[torch.Tensor, torch.Tensor]:
    """k-diffusion's ancestral step sizes, with the reference's float32 expressions."""
    sigma_up = min(sigma_to, eta * (sigma_to**2 * (sigma_from**2 - sigma_to**2) / sigma_from**2) ** 0.5)
    sigma_down = (sigma_to**2 - sigma_up**2) ** 0.5
    return sigma_down, sigma_up


def sigma_schedule(agent: Any) -> torch.Tensor:
    """The sigmas ``predict`` samples over: the agent's own ``get_noise_schedule``
    with its ``num_sampling_steps`` and ``noise_scheduler``.
    """
    kind = getattr(agent, "noise_scheduler", "linear")
    sig = agent.get_noise_schedule(int(agent.num_sampling_steps), kind)
    return torch.as_tensor(sig).detach().cpu().to(torch.float32)


class BesoFamily(Family):
    """BESO: ``BesoAgent`` with ``GCDenoiser(DiffusionGPT)`` (module docstring)."""

    name = "beso"
    classes = ("BesoAgent",)

    def settings(self, agent: Any) -> Settings:
        """Window, sampler and noise layout from the agent's attributes."""
        act_dim = int(agent.scaler.y_bounds.shape[1])
        obs_dim = int(torch.as_tensor(agent.scaler.x_mean).reshape(-1).shape[0])
        k = int(agent.window_size)
        sampler = str(agent.sampler_type)
        if sampler not in SAMPLERS:
            raise UnsupportedBeso(
                f"BESO sampler_type {sampler!r} is not reproduced here (supported: {', '.join(SAMPLERS)}); "
                "serve this agent instead (python -m d3il_client.serve --agent ...)"
            )
        sigmas = sigma_schedule(agent)
        draws = 0
        if sampler == "euler_ancestral":
            draws = sum(bool(ancestral_step(sigmas[i], sigmas[i + 1])[0] > 0) for i in range(len(sigmas) - 1))
        kind = getattr(agent, "noise_scheduler", "linear")
        return Settings(
            family=self.name,
            obs_dim=obs_dim,
            act_dim=act_dim,
            history=k,
            window="grow",
            horizon=1,
            execute=1,
            prev_actions=k > 1,
            noise_shape=(1 + draws, k, act_dim),
            sampler=(
                f"{sampler}, {int(agent.num_sampling_steps)} steps, {kind} sigmas "
                f"{float(agent.sigma_max):g}..{float(agent.sigma_min):g}, sigma_data {float(agent.model.sigma_data):g}"
            ),
        )

    def graph(self, agent: Any) -> nn.Module:
        """The batched module of the agent's predict (:class:`BesoGraph`)."""
        return BesoGraph(agent, self.settings(agent)).eval()

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """The initial randn, then the sampler's randn_like calls (zeros when unused)."""
        s = self.settings(agent)
        sampler = str(agent.sampler_type)
        act = s.act_dim
        out = [Draw("randn", noise[0, :1, :].reshape(1, 1, act).clone())]
        n = len(sigma_schedule(agent)) - 1
        if sampler == "euler_ancestral":
            assert s.noise_shape is not None
            for j in range(s.noise_shape[0] - 1):
                out.append(Draw("randn_like", noise[1 + j, :window, :].reshape(1, window, act).clone()))
        elif sampler in ("euler", "heun"):
            out += [Draw("randn_like", torch.zeros((1, window, act))) for _ in range(n)]
        return out


FAMILY = BesoFamily()
