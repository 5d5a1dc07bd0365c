"""A BESO agent with the reference's interface and quirks (agents/beso_agent.py,
agents/models/beso/... in ALRhub/d3il), written here for the tests.

What it keeps of the reference, because the family must reproduce it:

* ``BesoAgent.predict(obs)``: the observation deque starts empty at ``reset()`` and
  grows 1..``window_size``; the action context holds the previous CLAMPED SCALED
  actions (``window_size - 1`` at most); ``x = randn((1, 1, act)) * sigma_max`` is
  appended to them; the sampler named by ``sampler_type`` runs on the whole sequence
  over ``get_noise_schedule(num_sampling_steps, self.noise_scheduler)`` (``'linear'``
  as the reference's constructor sets it); the last row is clamped to
  ``model.min_action``/``max_action`` (float64, from the scaler's bounds) and
  inverse-scaled;
* the EMA weights are swapped in for ``predict`` when ``use_ema``;
* ``GCDenoiser`` (Karras preconditioning with ``sigma_data``) around ``DiffusionGPT``
  whose ``forward`` takes ``int(x.size()[1] / 2)`` in Python (frozen by tracing);
* the samplers as the reference writes them: ``euler_ancestral`` draws
  ``randn_like`` over the whole sequence after every step but the last; ``euler``
  and ``heun`` draw a ``randn_like`` every step and never use it (``s_churn`` 0).
"""

from __future__ import annotations

import collections
import math
from typing import Any, List, Optional

import numpy as np
import torch
from torch import nn

from .scaler import Scaler, aligning_like_data

# -- the network ---------------------------------------------------------------------


class CausalSelfAttention(nn.Module):
    def __init__(self, n_embd: int, n_heads: int, block_size: int, attn_pdrop: float = 0.2, resid_pdrop: float = 0.1):
        super().__init__()
        self.key = nn.Linear(n_embd, n_embd)
        self.query = nn.Linear(n_embd, n_embd)
        self.value = nn.Linear(n_embd, n_embd)
        self.proj = nn.Linear(n_embd, n_embd)
        self.attn_drop = nn.Dropout(attn_pdrop)
        self.resid_drop = nn.Dropout(resid_pdrop)
        self.register_buffer("mask", torch.tril(torch.ones(block_size, block_size)).view(1, 1, block_size, block_size))
        self.n_head = n_heads

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, t, c = x.size()
        hs = c // self.n_head
        k = self.key(x).view(b, t, self.n_head, hs).transpose(1, 2)
        q = self.query(x).view(b, t, self.n_head, hs).transpose(1, 2)
        v = self.value(x).view(b, t, self.n_head, hs).transpose(1, 2)
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(k.size(-1)))
        att = att.masked_fill(self.mask[:, :, :t, :t] == 0, float("-inf")).softmax(dim=-1)
        y = (self.attn_drop(att) @ v).transpose(1, 2).contiguous().view(b, t, c)
        return self.resid_drop(self.proj(y))


class Block(nn.Module):
    def __init__(self, n_embd: int, n_heads: int, block_size: int):
        super().__init__()
        self.ln1 = nn.LayerNorm(n_embd)
        self.ln2 = nn.LayerNorm(n_embd)
        self.attn = CausalSelfAttention(n_embd, n_heads, block_size)
        self.mlp = nn.Sequential(
            nn.Linear(n_embd, 4 * n_embd), nn.GELU(), nn.Linear(4 * n_embd, n_embd), nn.Dropout(0.1)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln1(x))
        return x + self.mlp(self.ln2(x))


class DiffusionGPT(nn.Module):
    """Tokens [sigma, s_1, a_1, …, s_t, a_t]; the action tokens predict the actions."""

    def __init__(self, state_dim: int, action_dim: int, embed_dim: int, n_layers: int, n_heads: int, obs_seq_len: int):
        super().__init__()
        self.goal_conditioned = False
        self.goal_seq_len = 0
        self.obs_seq_len = obs_seq_len
        self.block_size = 2 * obs_seq_len + 1
        self.embed_dim = embed_dim
        self.action_dim = action_dim
        self.obs_dim = state_dim
        self.tok_emb = nn.Linear(state_dim, embed_dim)
        self.pos_emb = nn.Parameter(torch.randn(1, obs_seq_len + 1, embed_dim) * 0.02)
        self.drop = nn.Dropout(0.0)
        self.blocks = nn.Sequential(*[Block(embed_dim, n_heads, self.block_size) for _ in range(n_layers)])
        self.ln_f = nn.LayerNorm(embed_dim)
        self.sigma_emb = nn.Linear(1, embed_dim)
        self.action_emb = nn.Linear(action_dim, embed_dim)
        self.action_pred = nn.Linear(embed_dim, action_dim)

    def forward(self, states, actions, goals, sigma, uncond=False, keep_last_actions=False):
        b, t, _ = states.size()
        emb_t = self.sigma_emb((sigma.log() / 4).reshape(-1, 1).to(torch.float32)).reshape(b, 1, self.embed_dim)
        pos = self.pos_emb[:, :t, :]
        state_x = self.drop(self.tok_emb(states) + pos)
        action_x = self.drop(self.action_emb(actions) + pos)
        sa = torch.stack([state_x, action_x], dim=1).permute(0, 2, 1, 3).reshape(b, 2 * t, self.embed_dim)
        x = self.ln_f(self.blocks(torch.cat([emb_t, sa], dim=1)))[:, 1:, :]
        # The reference's shape arithmetic: a Python int of a size (frozen by tracing).
        if x.size()[1] < 2 * self.obs_seq_len:
            half = int(x.size()[1] / 2)
            x = x.reshape(b, half, 2, self.embed_dim).permute(0, 2, 1, 3)
        else:
            x = x.reshape(b, self.obs_seq_len, 2, self.embed_dim).permute(0, 2, 1, 3)
        return self.action_pred(x[:, 1])


class GCDenoiser(nn.Module):
    """Karras et al. preconditioning: D(x) = c_skip x + c_out F(c_in x, sigma)."""

    def __init__(self, inner_model: nn.Module, sigma_data: float = 0.5):
        super().__init__()
        self.inner_model = inner_model
        self.sigma_data = sigma_data

    def get_scalings(self, sigma):
        sd2 = self.sigma_data**2
        c_skip = sd2 / (sigma**2 + sd2)
        c_out = sigma * self.sigma_data / (sigma**2 + sd2) ** 0.5
        c_in = 1 / (sigma**2 + sd2) ** 0.5
        return c_skip, c_out, c_in

    def forward(self, state, action, goal, sigma, **kwargs):
        c_skip, c_out, c_in = [c[:, None, None] for c in self.get_scalings(sigma)]
        return self.inner_model(state, action * c_in, goal, sigma, **kwargs) * c_out + action * c_skip

    def get_params(self):
        return self.inner_model.parameters()


# -- schedules and samplers (k-diffusion style) ---------------------------------------


def sigmas_linear(n, sigma_min, sigma_max):
    s = torch.linspace(sigma_max, sigma_min, n)
    return torch.cat([s, s.new_zeros([1])])


def sigmas_exponential(n, sigma_min, sigma_max):
    s = torch.linspace(math.log(sigma_max), math.log(sigma_min), n).exp()
    return torch.cat([s, s.new_zeros([1])])


def sigmas_karras(n, sigma_min, sigma_max, rho):
    ramp = torch.linspace(0, 1, n)
    lo, hi = sigma_min ** (1 / rho), sigma_max ** (1 / rho)
    s = (hi + ramp * (lo - hi)) ** rho
    return torch.cat([s, s.new_zeros([1])])


def ancestral_step(sigma_from, sigma_to, eta=1.0):
    sigma_up = min(sigma_to, eta * (sigma_to**2 * (sigma_from**2 - sigma_to**2) / sigma_from**2) ** 0.5)
    sigma_down = (sigma_to**2 - sigma_up**2) ** 0.5
    return sigma_down, sigma_up


def to_d(x, sigma, denoised):
    return (x - denoised) / sigma[:, None, None]


@torch.no_grad()
def sample_euler_ancestral(model, state, x, goal, sigmas):
    ones = x.new_ones([x.shape[0]])
    for i in range(len(sigmas) - 1):
        denoised = model(state, x, goal, sigmas[i] * ones)
        down, up = ancestral_step(sigmas[i], sigmas[i + 1])
        x = x + to_d(x, sigmas[i] * ones, denoised) * (down - sigmas[i])
        if down > 0:
            x = x + torch.randn_like(x) * up
    return x


@torch.no_grad()
def sample_euler(model, state, x, goal, sigmas):
    ones = x.new_ones([x.shape[0]])
    for i in range(len(sigmas) - 1):
        _unused = torch.randn_like(x)  # drawn every step; s_churn is 0 in predict
        hat = sigmas[i] * (0.0 + 1)
        denoised = model(state, x, goal, hat * ones)
        x = x + to_d(x, hat * ones, denoised) * (sigmas[i + 1] - hat)
    return x


@torch.no_grad()
def sample_heun(model, state, x, goal, sigmas):
    ones = x.new_ones([x.shape[0]])
    for i in range(len(sigmas) - 1):
        _unused = torch.randn_like(x)
        hat = sigmas[i] * (0.0 + 1)
        denoised = model(state, x, goal, hat * ones)
        d = to_d(x, hat * ones, denoised)
        dt = sigmas[i + 1] - hat
        if sigmas[i + 1] == 0:
            x = x + d * dt
        else:
            x2 = x + d * dt
            d2 = to_d(x2, sigmas[i + 1] * ones, model(state, x2, goal, sigmas[i + 1] * ones))
            x = x + (d + d2) / 2 * dt
    return x


@torch.no_grad()
def sample_ddim(model, state, x, goal, sigmas):
    ones = x.new_ones([x.shape[0]])
    for i in range(len(sigmas) - 1):
        denoised = model(state, x, goal, sigmas[i] * ones)
        t, t_next = sigmas[i].log().neg(), sigmas[i + 1].log().neg()
        x = (t_next.neg().exp() / t.neg().exp()) * x - (-(t_next - t)).expm1() * denoised
    return x


SAMPLERS = {"euler_ancestral": sample_euler_ancestral, "euler": sample_euler, "heun": sample_heun, "ddim": sample_ddim}


# -- EMA and the agent ----------------------------------------------------------------


class Ema:
    """Shadow copies of the trainable parameters, swapped in for predict."""

    def __init__(self, params) -> None:
        self.shadow_params = [p.clone().detach() for p in params if p.requires_grad]
        self.collected_params: List[torch.Tensor] = []

    def store(self, params) -> None:
        self.collected_params = [p.clone() for p in params]

    def copy_to(self, params) -> None:
        for s, p in zip(self.shadow_params, [p for p in params if p.requires_grad], strict=False):
            p.data.copy_(s.data)

    def restore(self, params) -> None:
        for c, p in zip(self.collected_params, params, strict=False):
            p.data.copy_(c.data)


class BesoAgent:
    def __init__(
        self,
        model: GCDenoiser,
        scaler: Scaler,
        window_size: int = 5,
        num_sampling_steps: int = 16,
        sampler_type: str = "euler_ancestral",
        sigma_min: float = 0.01,
        sigma_max: float = 3.0,
        rho: float = 5.0,
        use_ema: bool = True,
        device: str = "cpu",
    ) -> None:
        self.model = model
        self.scaler = scaler
        self.device = device
        self.model.min_action = torch.from_numpy(scaler.y_bounds[0, :])
        self.model.max_action = torch.from_numpy(scaler.y_bounds[1, :])
        self.window_size = window_size
        self.goal_window_size = 1
        self.num_sampling_steps = num_sampling_steps
        self.sampler_type = sampler_type
        self.sigma_min, self.sigma_max, self.rho = sigma_min, sigma_max, rho
        self.sigma_data = model.sigma_data
        self.use_ema = use_ema
        self.ema_helper = Ema(model.get_params())
        self.obs_context: collections.deque = collections.deque(maxlen=window_size)
        self.action_context: collections.deque = collections.deque(maxlen=window_size - 1)
        self.noise_scheduler = "linear"  # as the reference's constructor sets it

    def reset(self) -> None:
        self.obs_context.clear()
        self.action_context.clear()

    def get_noise_schedule(self, n: int, kind: str) -> torch.Tensor:
        if kind == "linear":
            return sigmas_linear(n, self.sigma_min, self.sigma_max)
        if kind == "exponential":
            return sigmas_exponential(n, self.sigma_min, self.sigma_max)
        if kind == "karras":
            return sigmas_karras(n, self.sigma_min, self.sigma_max, self.rho)
        raise ValueError("Unknown noise schedule type")

    @torch.no_grad()
    def predict(
        self, state: np.ndarray, goal: Optional[Any] = None, noise_scheduler: Optional[str] = None
    ) -> np.ndarray:
        scheduler = self.noise_scheduler if noise_scheduler is None else noise_scheduler
        s = self.scaler.scale_input(torch.from_numpy(state).float().unsqueeze(0))
        self.obs_context.append(s)
        input_state = torch.stack(tuple(self.obs_context), dim=1)
        if self.use_ema:
            self.ema_helper.store(self.model.parameters())
            self.ema_helper.copy_to(self.model.parameters())
        self.model.eval()
        sigmas = self.get_noise_schedule(self.num_sampling_steps, scheduler)
        x = torch.randn((len(input_state), 1, self.scaler.y_bounds.shape[1])) * self.sigma_max
        if len(self.action_context) > 0:
            x = torch.cat([torch.cat(tuple(self.action_context), dim=1), x], dim=1)
        if self.sampler_type not in SAMPLERS:
            raise ValueError("desired sampler type not found!")
        x_0 = SAMPLERS[self.sampler_type](self.model, input_state, x, goal, sigmas)
        if x_0.size()[1] > 1 and len(x_0.size()) == 3:
            x_0 = x_0[:, -1, :]
        x_0 = x_0.clamp_(self.model.min_action, self.model.max_action)
        if self.use_ema:
            self.ema_helper.restore(self.model.parameters())
        pred = self.scaler.inverse_scale_output(x_0)
        if len(pred.shape) == 2:
            x_0 = x_0.reshape(x_0.shape[0], 1, -1)
        self.action_context.append(x_0)
        if len(pred.size()) == 3:
            pred = pred[0]
        return pred.cpu().numpy()


def make_agent(
    checkpoint: Optional[str] = None,
    obs_dim: int = 20,
    act_dim: int = 3,
    window_size: int = 5,
    embed_dim: int = 72,
    n_layers: int = 4,
    n_heads: int = 4,
    num_sampling_steps: int = 16,
    sampler_type: str = "euler_ancestral",
    sigma_min: float = 0.01,
    sigma_max: float = 3.0,
    seed: int = 0,
) -> BesoAgent:
    """The reference's Aligning BESO by default (obs 20, act 3, window 5, 4 layers of
    width 72 with 4 heads, 16 steps, sigma 0.01..3, euler_ancestral, 'linear'
    schedule), random weights; the EMA shadow differs from the live weights so that
    a module using the wrong set fails the check. ``checkpoint``: a state dict.
    """
    torch.manual_seed(seed)
    inner = DiffusionGPT(obs_dim, act_dim, embed_dim, n_layers, n_heads, window_size)
    model = GCDenoiser(inner, sigma_data=0.5)
    if checkpoint is not None:
        model.load_state_dict(torch.load(checkpoint, weights_only=True))
    x, y = aligning_like_data(obs_dim, act_dim, seed=seed)
    agent = BesoAgent(model, Scaler(x, y), window_size, num_sampling_steps, sampler_type, sigma_min, sigma_max)
    with torch.no_grad():
        for p in agent.ema_helper.shadow_params:
            p.add_(torch.randn(p.shape) * 0.01)
    return agent


def make_small_agent(checkpoint: Optional[str] = None) -> BesoAgent:
    """A narrower BESO (width 16, 2 layers, 4 sampling steps) for the end-to-end tests,
    where the Aligning-sized default would spend minutes in predict() step by step.
    """
    return make_agent(checkpoint, embed_dim=16, n_layers=2, n_heads=2, num_sampling_steps=4)
