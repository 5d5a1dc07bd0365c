"""DDPM-MLP and DDPM-GPT: the reference ``agents/ddpm_agent.py`` ``DiffusionAgent``.

Both are the same agent class; the denoiser (``agent.model.model``) tells them apart:
``DiffusionMLPNetwork`` (DDPM-MLP) or ``DiffusionTransformerNetwork`` (DDPM-GPT,
"ddpm_transformer" in the reference scripts). The agent's ``predict`` for one
observation:

1. scales it with the agent's ``Scaler`` (``(x - mean) / (std + 1e-12)``, in the
   scaler's dtype, then float32);
2. with ``window_size > 1`` appends it to ``obs_context`` (a deque emptied by
   ``reset()``: windows grow 1..k) and stacks the window ``[1, w, obs]``; with
   ``window_size == 1`` it keeps the 2-D ``[1, obs]`` state;
3. copies the EMA weights into the network when ``use_ema`` (restored afterwards):
   the actions come from ``ema_helper.shadow_params``, not from the live parameters;
4. runs ``Diffusion.p_sample_loop`` (``agents/models/diffusion/gc_diffusion.py``):
   ``x = torch.randn(shape)`` (``[1, w, act]`` for a window, ``[1, act]`` for a 2-D
   state), then for t = n−1 … 0: ε = net(x, t, s); x0 = √(1/ᾱ_t)·x − √(1/ᾱ_t − 1)·ε,
   clamped to the scaled action bounds (``clip_denoised``); μ = c1_t·x0 + c2_t·x;
   ``torch.randn_like(x)`` is drawn at EVERY step, the last one (t = 0) multiplied by
   0; x = μ + exp(½·log σ²_t)·z with the log posterior variance clipped at 1e-20;
   ``diffusion_x`` adds M steps at t = 0 (no noise either). The result is clamped to
   the bounds again;
5. keeps the last window position, inverse-scales it and returns ``[1, act]``.

The module does the same for a batch: noise ``[B, n, K, act]`` (K = k for DDPM-GPT,
1 for DDPM-MLP), row 0 the initial sample, row j the noise of step t = n − j; the
t = 0 draws do not move the result, ``draws`` hands predict zeros for them.

Tracing traps handled here without touching the user's model:

* ``DiffusionTransformerNetwork.forward`` takes ``int(x.size()[1] / 2)`` in Python
  and branches on the window in Python: a trace freezes both at the example window
  (tract then refuses the graph: "Reshape volume mismatch"). The module runs the
  transformer's own submodules (embeddings, ``blocks``, ``ln_f``, ``action_pred``)
  with the same arithmetic and a symbolic ``reshape(B, -1, 2, E)``.
* The reference denoisers batch wrongly: with a 2-D state the transformer unsqueezes
  the batch into the sequence axis (``states.unsqueeze(0)``). The module gives every
  rollout its own ``[1, w]`` sequence, as ``predict`` does for one rollout.
* With ``window_size == 1`` DDPM-GPT's sample changes rank after the first step
  (``[1, act]`` plus the network's ``[1, 1, act]``): ``draws`` gives the first two
  draws as ``[1, act]`` and the rest as ``[1, 1, act]``, as predict asks for them.
"""

from __future__ import annotations

import copy
from typing import Any, List, Optional, Tuple

import torch

from .base import Draw, Family, Settings
from .scaling import ScalerArithmetic, as_float32_bound

AGENT_CLASSES = ("DiffusionAgent",)


def class_names(obj: Any) -> set:
    """Names of ``obj``'s class and its bases."""
    return {c.__name__ for c in type(obj).__mro__}


def denoiser(agent: Any) -> Any:
    """The denoising network of a reference diffusion agent (``agent.model.model``),
    or None when the agent is not built that way (vision agents wrap one more level).
    """
    diffusion = getattr(agent, "model", None)
    if diffusion is None or not hasattr(diffusion, "p_sample_loop"):
        return None
    return getattr(diffusion, "model", None)


def predict_diffusion(agent: Any) -> Any:
    """A CPU copy of ``agent.model`` (the ``Diffusion``) with the weights ``predict``
    uses: the EMA shadow parameters when ``use_ema`` (predict copies them in with
    ``ema_helper.copy_to`` before sampling).
    """
    d = copy.deepcopy(agent.model)
    if getattr(agent, "use_ema", False):
        agent.ema_helper.copy_to(d.parameters())
    return d.to("cpu").eval()


class DdpmSampler(torch.nn.Module):
    """The reverse DDPM sampler of the reference ``Diffusion`` (p_sample_loop, sample)
    with its schedule, bounds and flags; ``denoise(x, t, B)`` is supplied by the family.
    """

    def __init__(self, diffusion: Any) -> None:
        super().__init__()
        self.n = int(diffusion.n_timesteps)
        self.predict_epsilon = bool(diffusion.predict_epsilon)
        self.clip_denoised = bool(diffusion.clip_denoised)
        self.extra = int(getattr(diffusion, "diffusion_x_M", 0)) if getattr(diffusion, "diffusion_x", False) else 0

        def f32(name: str) -> torch.Tensor:
            return torch.as_tensor(getattr(diffusion, name)).detach().to("cpu", torch.float32).clone()

        self.register_buffer("recip", f32("sqrt_recip_alphas_cumprod"))
        self.register_buffer("recipm1", f32("sqrt_recipm1_alphas_cumprod"))
        self.register_buffer("coef1", f32("posterior_mean_coef1"))
        self.register_buffer("coef2", f32("posterior_mean_coef2"))
        # predict: nonzero_mask * (0.5 * log_variance).exp() * z, the mask 1.0 for t > 0
        self.register_buffer("sigma", (0.5 * f32("posterior_log_variance_clipped")).exp())
        # float64 in the reference (the scaler's y_bounds): see as_float32_bound
        self.register_buffer("lo", as_float32_bound(diffusion.min_action))
        self.register_buffer("hi", as_float32_bound(diffusion.max_action))

    def clamp(self, x: torch.Tensor) -> torch.Tensor:
        """``clamp_(min_action, max_action)``."""
        return torch.minimum(torch.maximum(x, self.lo), self.hi)

    def step(self, x: torch.Tensor, eps: torch.Tensor, t: int, z: Optional[torch.Tensor]) -> torch.Tensor:
        """One ``p_sample`` at timestep t with the network output ``eps``; ``z`` the
        noise (None at t = 0, where predict multiplies its draw by 0).
        """
        x0 = self.recip[t] * x - self.recipm1[t] * eps if self.predict_epsilon else eps
        if self.clip_denoised:
            x0 = self.clamp(x0)
        mean = self.coef1[t] * x0 + self.coef2[t] * x
        if t == 0 or z is None:
            return mean
        return mean + self.sigma[t] * z

    def run(self, x: torch.Tensor, denoise: Any, noise_row: Any) -> torch.Tensor:
        """The whole loop from x_T = ``x``: ``denoise(x, t)`` the network, ``noise_row(j)``
        the noise of loop step j (1-based, t = n − j); clamped at the end as ``sample``.
        """
        for j, t in enumerate(reversed(range(self.n)), start=1):
            x = self.step(x, denoise(x, t), t, noise_row(j) if t > 0 else None)
        for _ in range(self.extra):
            x = self.step(x, denoise(x, 0), 0, None)
        return self.clamp(x)

    def describe(self) -> str:
        """The sampler as ``Settings.sampler`` says it."""
        return (
            f"DDPM, {self.n} steps (the agent's schedule), x0 clipped to the data bounds, "
            "posterior variance log-clipped, no noise at t = 0"
            + (f", {self.extra} extra steps at t = 0 (diffusion_x)" if self.extra else "")
        )

    def draws(self, noise: torch.Tensor, shapes: List[tuple]) -> List[Draw]:
        """predict()'s draws from one noise row ``[n, K, act]``: ``torch.randn`` of
        shapes[0], then one ``randn_like`` per step (shapes[j]); the t = 0 draws zero.
        """
        out: List[Draw] = []
        for j, shape in enumerate(shapes):
            w = shape[-2] if len(shape) == 3 else 1
            if j < self.n:
                value = noise[j, :w].reshape(shape).clone()
            else:
                value = torch.zeros(shape)
            out.append(Draw("randn" if j == 0 else "randn_like", value))
        return out


def full_steps(batch: torch.Tensor, t: int) -> torch.Tensor:
    """The timesteps ``torch.full((B,), t)`` of the reference loop, B from ``batch``."""
    return torch.full((batch.shape[0],), t, dtype=torch.long, device=batch.device)


def check_supported(agent: Any, family: str) -> None:
    """Refuse what the reference predict does that no export can (said precisely)."""
    if getattr(agent, "diffusion_kde", False):
        raise ValueError(
            f"{family}: this agent has diffusion_kde=True: its predict() picks a sample by a scikit-learn "
            "kernel density fit, which no ONNX graph computes; serve the agent instead (docs/remote-protocol.md)"
        )
    if getattr(agent, "goal_condition", False) or getattr(denoiser(agent), "goal_conditioned", False):
        raise ValueError(
            f"{family}: goal-conditioned agents are not supported (the D3IL state tasks run without goals; "
            "predict() is called without one)"
        )


class DdpmMlpGraph(torch.nn.Module):
    """DDPM-MLP's predict for a batch: window 1, the 2-D state path."""

    def __init__(self, agent: Any) -> None:
        super().__init__()
        d = predict_diffusion(agent)
        self.net = d.model
        self.sampler = DdpmSampler(d)
        self.scaling = ScalerArithmetic(agent.scaler)

    def forward(self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor], noise: torch.Tensor) -> torch.Tensor:
        """[B, 1, obs] raw observations, noise [B, n, 1, act] -> [B, 1, act] raw actions."""
        s = self.scaling.scale_input(obs[:, 0])  # [B, obs]
        x = self.sampler.run(
            noise[:, 0, 0],
            lambda x, t: self.net(x, full_steps(s, t), s, None),
            lambda j: noise[:, j, 0],
        )
        return self.scaling.inverse_scale_output(x).unsqueeze(1)  # [B, 1, act]


class DdpmGptGraph(torch.nn.Module):
    """DDPM-GPT's predict for a batch: the window [B, w] (1..k), the whole window's
    actions denoised together, the last position returned.
    """

    def __init__(self, agent: Any) -> None:
        super().__init__()
        d = predict_diffusion(agent)
        self.net = d.model
        self.sampler = DdpmSampler(d)
        self.scaling = ScalerArithmetic(agent.scaler)

    def denoise(self, actions: torch.Tensor, t: int, states: torch.Tensor) -> torch.Tensor:
        """``DiffusionTransformerNetwork.forward`` (not goal-conditioned, eval mode) with
        the window symbolic: [emb_t, s_1, a_1, …, s_w, a_w] through the blocks, the
        action tokens of the output into ``action_pred``.
        """
        net = self.net
        b = states.shape[0]
        w = states.shape[1]
        emb_t = net.time_emb(full_steps(states, t)[:, None])  # [B, 1, E]
        pos = net.pos_emb[:, :w, :]
        state_x = net.drop(net.tok_emb(states) + pos)
        action_x = net.drop(net.action_emb(actions) + pos)
        sa = torch.stack([state_x, action_x], dim=2).reshape(b, -1, net.embed_dim)  # s_1, a_1, s_2, …
        x = net.ln_f(net.blocks(torch.cat([emb_t, sa], dim=1)))
        x = x[:, 1:, :].reshape(b, -1, 2, net.embed_dim)
        return net.action_pred(x[:, :, 1])  # [B, w, act]

    def forward(self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor], noise: torch.Tensor) -> torch.Tensor:
        """[B, w, obs] raw observations, noise [B, n, k, act] -> [B, 1, act] raw actions."""
        s = self.scaling.scale_input(obs)  # [B, w, obs]
        w = obs.shape[1]
        x = self.sampler.run(
            noise[:, 0, :w],
            lambda x, t: self.denoise(x, t, s),
            lambda j: noise[:, j, :w],
        )
        return self.scaling.inverse_scale_output(x[:, -1:, :])  # [B, 1, act]


class DdpmMlp(Family):
    """DDPM-MLP: ``DiffusionAgent`` with a ``DiffusionMLPNetwork`` (window 1)."""

    name = "ddpm_mlp"
    classes = AGENT_CLASSES

    def accepts(self, agent: Any) -> bool:
        """Whether the agent's denoiser is this family's network."""
        net = denoiser(agent)
        return net is not None and not hasattr(agent, "action_seq_size") and "DiffusionMLPNetwork" in class_names(net)

    def settings(self, agent: Any) -> Settings:
        """The window k, H = E = 1 and the noise layout, from the agent object."""
        check_supported(agent, self.name)
        if int(agent.window_size) != 1:
            raise ValueError(
                f"ddpm_mlp: window_size={agent.window_size}: the reference DiffusionMLPNetwork concatenates one "
                "time embedding with the whole window, so the agent's own predict() fails from the second "
                "step on; DDPM-MLP runs with window_size=1 (scripts/*/ddpm_benchmark.sh)"
            )
        sampler = DdpmSampler(agent.model)
        return Settings(
            family=self.name,
            obs_dim=int(agent.scaler.x_mean.shape[-1]),
            act_dim=int(agent.model.action_dim),
            history=1,
            window="grow",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=(sampler.n, 1, int(agent.model.action_dim)),
            sampler=sampler.describe(),
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """The batched module of the agent's predict (module docstring)."""
        self.settings(agent)
        return DdpmMlpGraph(agent).eval()

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """The torch.randn and randn_like draws of predict() from one noise row."""
        sampler = DdpmSampler(agent.model)
        act = int(agent.model.action_dim)
        return sampler.draws(noise, [(1, act)] * (1 + sampler.n + sampler.extra))


class DdpmGpt(Family):
    """DDPM-GPT: ``DiffusionAgent`` with a ``DiffusionTransformerNetwork``."""

    name = "ddpm_gpt"
    classes = AGENT_CLASSES

    def accepts(self, agent: Any) -> bool:
        """Whether the agent's denoiser is this family's network."""
        net = denoiser(agent)
        return (
            net is not None
            and not hasattr(agent, "action_seq_size")
            and "DiffusionTransformerNetwork" in class_names(net)
        )

    def settings(self, agent: Any) -> Settings:
        """The window k, H = E = 1 and the noise layout, from the agent object."""
        check_supported(agent, self.name)
        k = int(agent.window_size)
        net = denoiser(agent)
        if k > int(net.obs_seq_len):
            raise ValueError(
                f"ddpm_gpt: window_size={k} is longer than the transformer's obs_seq_len={net.obs_seq_len}: "
                "its position embedding has no room for the window, predict() fails"
            )
        sampler = DdpmSampler(agent.model)
        act = int(agent.model.action_dim)
        return Settings(
            family=self.name,
            obs_dim=int(agent.scaler.x_mean.shape[-1]),
            act_dim=act,
            history=k,
            window="grow",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=(sampler.n, k, act),
            sampler=sampler.describe(),
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """The batched module of the agent's predict (module docstring)."""
        self.settings(agent)
        return DdpmGptGraph(agent).eval()

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """The torch.randn and randn_like draws of predict() from one noise row."""
        sampler = DdpmSampler(agent.model)
        act = int(agent.model.action_dim)
        count = 1 + sampler.n + sampler.extra
        if int(agent.window_size) > 1:
            shapes: List[Tuple[int, ...]] = [(1, window, act)] * count
        else:
            # 2-D state: x starts [1, act]; the first step's output broadcasts with the
            # network's [1, 1, act] and stays 3-D.
            shapes = [(1, act), (1, act)] + [(1, 1, act)] * (count - 2)
        return sampler.draws(noise, shapes)


FAMILIES = [DdpmMlp(), DdpmGpt()]
