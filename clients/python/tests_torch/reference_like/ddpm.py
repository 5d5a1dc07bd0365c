"""Like the reference ``agents/ddpm_agent.py`` ``DiffusionAgent`` with the
``gc_diffusion.Diffusion`` sampler: DDPM-MLP (``DiffusionMLPNetwork``,
``make_mlp_agent``) and DDPM-GPT (``DiffusionTransformerNetwork``, ``make_gpt_agent``).

Kept from the reference: the class and attribute names, the deque emptied by
``reset()`` (windows grow 1..k), the 2-D state when ``window_size == 1``, the EMA
weights copied in for ``predict`` and restored after, the schedules (cosine, linear,
vp) and every tensor the sampler derives from them, ``torch.randn`` then one
``torch.randn_like`` per step (t = 0 too, masked), x0 clamped to the scaled action
bounds (float64) and the sample clamped again, the transformer's Python
``int(x.size()[1] / 2)`` and its window branch, and its ``unsqueeze(0)`` of a 2-D
state. Small networks, random weights, few steps.
"""

from __future__ import annotations

import collections
import math
from typing import Any, Optional

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from .scaler import Scaler, aligning_like_data

OBS_DIM, ACT_DIM = 20, 3


# ---- schedules and helpers (agents/models/diffusion/utils.py) ----------------------


def cosine_beta_schedule(timesteps: int, s: float = 0.008) -> torch.Tensor:
    steps = timesteps + 1
    grid = np.linspace(0, steps, steps)
    ac = np.cos(((grid / steps) + s) / (1 + s) * np.pi * 0.5) ** 2
    ac = ac / ac[0]
    return torch.tensor(np.clip(1 - ac[1:] / ac[:-1], 0, 0.999), dtype=torch.float32)


def linear_beta_schedule(timesteps: int, beta_start: float = 1e-4, beta_end: float = 2e-2) -> torch.Tensor:
    return torch.tensor(np.linspace(beta_start, beta_end, timesteps), dtype=torch.float32)


def vp_beta_schedule(timesteps: int) -> torch.Tensor:
    t = np.arange(1, timesteps + 1)
    b_max, b_min = 10.0, 0.1
    alpha = np.exp(-b_min / timesteps - 0.5 * (b_max - b_min) * (2 * t - 1) / timesteps**2)
    return torch.tensor(1 - alpha, dtype=torch.float32)


def extract(a: torch.Tensor, t: torch.Tensor, x_shape: Any) -> torch.Tensor:
    b = t.shape[0]
    return a.gather(-1, t).reshape(b, *((1,) * (len(x_shape) - 1)))


class SinusoidalPosEmb(nn.Module):
    def __init__(self, dim: int) -> None:
        super().__init__()
        self.dim = dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        half = self.dim // 2
        scale = math.log(10000) / (half - 1)
        freqs = torch.exp(torch.arange(half, device=x.device) * -scale)
        e = x[:, None] * freqs[None, :]
        return torch.cat((e.sin(), e.cos()), dim=-1)


class ExponentialMovingAverage:
    """The reference EMA helper: shadow copies of the trainable parameters."""

    def __init__(self, parameters: Any, decay: float, device: str = "cpu") -> None:
        self.decay = decay
        self.num_updates = 0
        self.shadow_params = [p.clone().detach() for p in parameters if p.requires_grad]
        self.collected_params: list = []

    def update(self, parameters: Any) -> None:
        self.num_updates += 1
        decay = min(self.decay, (1 + self.num_updates) / (10 + self.num_updates))
        with torch.no_grad():
            for s, p in zip(self.shadow_params, [p for p in parameters if p.requires_grad], strict=False):
                s.sub_((1.0 - decay) * (s - p))

    def copy_to(self, parameters: Any) -> None:
        for s, p in zip(self.shadow_params, [p for p in parameters if p.requires_grad], strict=False):
            p.data.copy_(s.data)

    def store(self, parameters: Any) -> None:
        self.collected_params = [p.clone() for p in parameters]

    def restore(self, parameters: Any) -> None:
        for c, p in zip(self.collected_params, parameters, strict=False):
            p.data.copy_(c.data)


# ---- the sampler (agents/models/diffusion/gc_diffusion.py) ---------------------------


class Diffusion(nn.Module):
    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        model: nn.Module,
        beta_schedule: str,
        n_timesteps: int,
        clip_denoised: bool = True,
        predict_epsilon: bool = True,
        device: str = "cpu",
        diffusion_x: bool = False,
        diffusion_x_M: int = 10,
    ) -> None:
        super().__init__()
        self.device = device
        self.state_dim, self.action_dim = state_dim, action_dim
        self.betas = {"linear": linear_beta_schedule, "cosine": cosine_beta_schedule, "vp": vp_beta_schedule}[
            beta_schedule
        ](n_timesteps)
        self.model = model
        self.n_timesteps = n_timesteps
        self.clip_denoised = clip_denoised
        self.predict_epsilon = predict_epsilon
        self.alphas = 1.0 - self.betas
        self.alphas_cumprod = torch.cumprod(self.alphas, dim=0)
        self.alphas_cumprod_prev = torch.cat([torch.ones(1), self.alphas_cumprod[:-1]])
        self.sqrt_alphas_cumprod = torch.sqrt(self.alphas_cumprod)
        self.sqrt_one_minus_alphas_cumprod = torch.sqrt(1.0 - self.alphas_cumprod)
        self.sqrt_recip_alphas_cumprod = torch.sqrt(1.0 / self.alphas_cumprod)
        self.sqrt_recipm1_alphas_cumprod = torch.sqrt(1.0 / self.alphas_cumprod - 1)
        self.posterior_variance = self.betas * (1.0 - self.alphas_cumprod_prev) / (1.0 - self.alphas_cumprod)
        self.posterior_log_variance_clipped = torch.log(torch.clamp(self.posterior_variance, min=1e-20))
        self.posterior_mean_coef1 = self.betas * torch.sqrt(self.alphas_cumprod_prev) / (1.0 - self.alphas_cumprod)
        self.posterior_mean_coef2 = (
            (1.0 - self.alphas_cumprod_prev) * torch.sqrt(self.alphas) / (1.0 - self.alphas_cumprod)
        )
        self.diffusion_x = diffusion_x
        self.diffusion_x_M = diffusion_x_M

    def get_params(self) -> Any:
        return self.model.get_params()

    def predict_start_from_noise(self, x_t: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        if self.predict_epsilon:
            return (
                extract(self.sqrt_recip_alphas_cumprod, t, x_t.shape) * x_t
                - extract(self.sqrt_recipm1_alphas_cumprod, t, x_t.shape) * noise
            )
        return noise

    def q_posterior(self, x_start: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor):
        mean = (
            extract(self.posterior_mean_coef1, t, x_t.shape) * x_start
            + extract(self.posterior_mean_coef2, t, x_t.shape) * x_t
        )
        return mean, extract(self.posterior_log_variance_clipped, t, x_t.shape)

    def p_sample(self, x: torch.Tensor, t: torch.Tensor, s: torch.Tensor, g: Optional[torch.Tensor]) -> torch.Tensor:
        b = x.shape[0]
        x_recon = self.predict_start_from_noise(x, t=t, noise=self.model(x, t, s, g))
        if self.clip_denoised:
            x_recon.clamp_(self.min_action, self.max_action)
        model_mean, model_log_variance = self.q_posterior(x_recon, x, t)
        noise = torch.randn_like(x)
        nonzero_mask = (1 - (t == 0).float()).reshape(b, *((1,) * (len(x.shape) - 1)))
        return model_mean + nonzero_mask * (0.5 * model_log_variance).exp() * noise

    def p_sample_loop(self, state: torch.Tensor, goal: Optional[torch.Tensor], shape: Any) -> torch.Tensor:
        batch_size = shape[0]
        x = torch.randn(shape, device=self.device)
        for i in reversed(range(0, self.n_timesteps)):
            timesteps = torch.full((batch_size,), i, device=self.device, dtype=torch.long)
            x = self.p_sample(x, timesteps, state, goal)
        if self.diffusion_x:
            timesteps = torch.full((batch_size,), 0, device=self.device, dtype=torch.long)
            for _ in range(self.diffusion_x_M):
                x = self.p_sample(x, timesteps, state, goal)
        return x

    def sample_shape(self, state: torch.Tensor) -> tuple:
        if len(state.shape) == 3:
            return (state.shape[0], state.shape[1], self.action_dim)
        return (state.shape[0], self.action_dim)

    def sample(self, state: torch.Tensor, goal: Optional[torch.Tensor]) -> torch.Tensor:
        action = self.p_sample_loop(state, goal, self.sample_shape(state))
        return action.clamp_(self.min_action, self.max_action)

    def forward(self, state: torch.Tensor, goal: Optional[torch.Tensor]) -> torch.Tensor:
        return self.sample(state, goal)


# ---- the denoisers (agents/models/diffusion/diffusion_models.py, common/mlp.py) ------


class TwoLayerPreActivationResNetLinear(nn.Module):
    def __init__(self, hidden_dim: int) -> None:
        super().__init__()
        self.l1 = nn.Linear(hidden_dim, hidden_dim)
        self.l2 = nn.Linear(hidden_dim, hidden_dim)
        self.dropout = nn.Dropout(0.0)
        self.act = nn.Mish()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.l1(self.dropout(self.act(x)))
        h = self.l2(self.dropout(self.act(h)))
        return h + x


class ResidualMLPNetwork(nn.Module):
    def __init__(self, input_dim: int, hidden_dim: int, num_hidden_layers: int, output_dim: int) -> None:
        super().__init__()
        self.network_type = "mlp"
        self.layers = nn.ModuleList([nn.Linear(input_dim, hidden_dim)])
        self.layers.extend([TwoLayerPreActivationResNetLinear(hidden_dim) for _ in range(1, num_hidden_layers, 2)])
        self.layers.append(nn.Linear(hidden_dim, output_dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.layers:
            x = layer(x.to(torch.float32))
        return x


class DiffusionMLPNetwork(nn.Module):
    def __init__(self, action_dim: int, obs_dim: int, t_dim: int, hidden_dim: int = 32, num_hidden_layers: int = 2):
        super().__init__()
        self.network_type = "mlp"
        self.goal_conditioned = False
        self.temp_layers = nn.Sequential(
            SinusoidalPosEmb(t_dim), nn.Linear(t_dim, t_dim * 2), nn.Mish(), nn.Linear(t_dim * 2, t_dim)
        )
        self.layers = ResidualMLPNetwork(obs_dim + action_dim + t_dim, hidden_dim, num_hidden_layers, action_dim)

    def forward(self, x: torch.Tensor, t: torch.Tensor, state: torch.Tensor, goal: Optional[torch.Tensor]):
        t = self.temp_layers(t)
        if len(state.shape) == 3:
            t = t[:, None, :]
            x = torch.cat([x, t, state], dim=2)
        else:
            x = torch.cat([x, t, state], dim=1)
        return self.layers(x)

    def get_params(self) -> Any:
        return self.parameters()


class CausalSelfAttention(nn.Module):
    def __init__(self, n_embd: int, n_heads: int, block_size: int) -> None:
        super().__init__()
        self.key = nn.Linear(n_embd, n_embd)
        self.query = nn.Linear(n_embd, n_embd)
        self.value = nn.Linear(n_embd, n_embd)
        self.attn_drop = nn.Dropout(0.2)
        self.resid_drop = nn.Dropout(0.1)
        self.proj = nn.Linear(n_embd, n_embd)
        self.register_buffer("mask", torch.tril(torch.ones(block_size, block_size)).view(1, 1, block_size, block_size))
        self.n_head = n_heads

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, T, C = x.size()
        k = self.key(x).view(B, T, self.n_head, C // self.n_head).transpose(1, 2)
        q = self.query(x).view(B, T, self.n_head, C // self.n_head).transpose(1, 2)
        v = self.value(x).view(B, T, self.n_head, C // self.n_head).transpose(1, 2)
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(k.size(-1)))
        att = att.masked_fill(self.mask[:, :, :T, :T] == 0, float("-inf"))
        att = self.attn_drop(F.softmax(att, dim=-1))
        y = (att @ v).transpose(1, 2).contiguous().view(B, T, C)
        return self.resid_drop(self.proj(y))


class Block(nn.Module):
    def __init__(self, n_embd: int, n_heads: int, block_size: int) -> None:
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


class DiffusionTransformerNetwork(nn.Module):
    """Tokens [t, s_1, a_1, …, s_w, a_w], causal; with the reference's Python
    ``int(x.size()[1] / 2)`` and its branch on the window (tracing traps).
    """

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        embed_dim: int = 24,
        n_layers: int = 2,
        n_heads: int = 4,
        obs_seq_len: int = 5,
        goal_seq_len: int = 10,
        goal_conditioned: bool = False,
        linear_output: bool = True,
        device: str = "cpu",
    ) -> None:
        super().__init__()
        self.device = device
        self.goal_conditioned = goal_conditioned
        if not goal_conditioned:
            goal_seq_len = 0
        block_size = goal_seq_len + 2 * obs_seq_len + 1
        seq_size = goal_seq_len + obs_seq_len + 1
        self.tok_emb = nn.Linear(state_dim, embed_dim)
        self.pos_emb = nn.Parameter(torch.zeros(1, seq_size, embed_dim))
        self.drop = nn.Dropout(0.0)
        self.action_dim, self.obs_dim, self.embed_dim = action_dim, state_dim, embed_dim
        self.blocks = nn.Sequential(*[Block(embed_dim, n_heads, block_size) for _ in range(n_layers)])
        self.ln_f = nn.LayerNorm(embed_dim)
        self.block_size, self.goal_seq_len, self.obs_seq_len = block_size, goal_seq_len, obs_seq_len
        self.time_emb = nn.Sequential(
            SinusoidalPosEmb(embed_dim),
            nn.Linear(embed_dim, embed_dim * 2),
            nn.Mish(),
            nn.Linear(embed_dim * 2, embed_dim),
        )
        self.action_emb = nn.Linear(action_dim, embed_dim)
        if linear_output:
            self.action_pred = nn.Linear(embed_dim, action_dim)
        else:
            self.action_pred = nn.Sequential(nn.Linear(embed_dim, 100), nn.GELU(), nn.Linear(100, action_dim))

    def forward(self, actions: torch.Tensor, time: torch.Tensor, states: torch.Tensor, goals: Optional[torch.Tensor]):
        if len(states.size()) != 3:
            states = states.unsqueeze(0)
        if len(actions.size()) != 3:
            actions = actions.unsqueeze(0)
        b, t, dim = states.size()
        assert t <= self.block_size, "Cannot forward, model block size is exhausted."
        emb_t = self.time_emb(time.reshape(-1, 1))
        second_half_idx = 1
        state_embed = self.tok_emb(states)
        action_embed = self.action_emb(actions)
        position_embeddings = self.pos_emb[:, :t, :]
        state_x = self.drop(state_embed + position_embeddings[:, self.goal_seq_len :, :])
        action_x = self.drop(action_embed + position_embeddings[:, self.goal_seq_len :, :])
        sa_seq = torch.stack([state_x, action_x], dim=1).permute(0, 2, 1, 3).reshape(b, 2 * t, self.embed_dim)
        x = self.ln_f(self.blocks(torch.cat([emb_t, sa_seq], dim=1)))
        x = x[:, second_half_idx:, :]
        if x.size()[1] < 2 * self.obs_seq_len:
            x_len = int(x.size()[1] / 2)
            x = x.reshape(b, x_len, 2, self.embed_dim).permute(0, 2, 1, 3)
        else:
            x = x.reshape(b, self.obs_seq_len, 2, self.embed_dim).permute(0, 2, 1, 3)
        return self.action_pred(x[:, 1])

    def get_params(self) -> Any:
        return self.parameters()


# ---- the agent (agents/ddpm_agent.py) ---------------------------------------------


class DiffusionAgent:
    def __init__(
        self,
        model: Diffusion,
        scaler: Scaler,
        window_size: int,
        use_ema: bool = True,
        decay: float = 0.995,
        device: str = "cpu",
        goal_window_size: int = 1,
        pred_last_action_only: bool = False,
        diffusion_kde: bool = False,
        diffusion_kde_samples: int = 100,
        goal_conditioned: bool = False,
    ) -> None:
        self.model = model.to(device)
        self.scaler = scaler
        self.device = device
        self.model.min_action = torch.from_numpy(self.scaler.y_bounds[0, :]).to(self.device)
        self.model.max_action = torch.from_numpy(self.scaler.y_bounds[1, :]).to(self.device)
        self.steps = 0
        self.ema_helper = ExponentialMovingAverage(self.model.get_params(), decay, self.device)
        self.use_ema = use_ema
        self.decay = decay
        self.goal_window_size = goal_window_size
        self.window_size = window_size
        self.pred_last_action_only = pred_last_action_only
        self.goal_condition = goal_conditioned
        self.obs_context: collections.deque = collections.deque(maxlen=self.window_size)
        self.goal_context: collections.deque = collections.deque(maxlen=self.goal_window_size)
        if not self.pred_last_action_only:
            self.action_context: collections.deque = collections.deque(maxlen=self.window_size - 1)
            self.que_actions = True
        else:
            self.que_actions = False
        self.diffusion_kde = diffusion_kde
        self.diffusion_kde_samples = diffusion_kde_samples

    def reset(self) -> None:
        self.obs_context.clear()

    @torch.no_grad()
    def predict(self, state: np.ndarray, goal: Optional[torch.Tensor] = None, extra_args: Any = None) -> np.ndarray:
        state = torch.from_numpy(state).float().to(self.device).unsqueeze(0)
        state = self.scaler.scale_input(state)
        if self.window_size > 1:
            self.obs_context.append(state)
            input_state = torch.stack(tuple(self.obs_context), dim=1)
        else:
            input_state = state
        if self.use_ema:
            self.ema_helper.store(self.model.parameters())
            self.ema_helper.copy_to(self.model.parameters())
        self.model.eval()
        if self.diffusion_kde:
            raise NotImplementedError("the mimic has no KDE path")
        model_pred = self.model(input_state, goal)
        if model_pred.size()[1] > 1 and len(model_pred.size()) == 3:
            model_pred = model_pred[:, -1, :]
        if self.use_ema:
            self.ema_helper.restore(self.model.parameters())
        model_pred = self.scaler.inverse_scale_output(model_pred)
        if len(model_pred.size()) == 3:
            model_pred = model_pred[0]
        return model_pred.cpu().numpy()

    def load_pretrained_model(self, weights_path: str, sv_name: Optional[str] = None, **kwargs: Any) -> None:
        import os

        path = os.path.join(weights_path, sv_name) if sv_name else weights_path
        self.model.load_state_dict(torch.load(path))
        self.ema_helper = ExponentialMovingAverage(self.model.get_params(), self.decay, self.device)


def _trained(agent: DiffusionAgent, seed: int) -> DiffusionAgent:
    """Live weights and EMA shadow apart, as after training: predict must use the shadow."""
    gen = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for p in agent.model.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen))
        agent.ema_helper.update(agent.model.parameters())
        for p in agent.model.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen))
    return agent


def _scaler() -> Scaler:
    x, y = aligning_like_data(OBS_DIM, ACT_DIM)
    return Scaler(x, y, True, "cpu")


def make_mlp_agent(
    checkpoint: Optional[str] = None,
    n_timesteps: int = 8,
    beta_schedule: str = "cosine",
    t_dim: int = 8,
    diffusion_x: bool = False,
    seed: int = 0,
) -> DiffusionAgent:
    """DDPM-MLP as scripts/aligning/ddpm_benchmark.sh (window 1, t_dim 8), smaller."""
    torch.manual_seed(seed)
    net = DiffusionMLPNetwork(ACT_DIM, OBS_DIM, t_dim)
    model = Diffusion(OBS_DIM, ACT_DIM, net, beta_schedule, n_timesteps, diffusion_x=diffusion_x, diffusion_x_M=3)
    agent = _trained(DiffusionAgent(model, _scaler(), window_size=1), seed)
    if checkpoint:
        agent.load_pretrained_model(checkpoint)
    return agent


def make_gpt_agent(
    checkpoint: Optional[str] = None,
    window_size: int = 5,
    n_timesteps: int = 8,
    beta_schedule: str = "cosine",
    seed: int = 0,
) -> DiffusionAgent:
    """DDPM-GPT ("ddpm_transformer") as scripts/avoiding/ddpm_transformer_benchmark.sh
    (window 5; Aligning runs it with window 1), smaller.
    """
    torch.manual_seed(seed)
    net = DiffusionTransformerNetwork(OBS_DIM, ACT_DIM, obs_seq_len=window_size)
    with torch.no_grad():
        net.pos_emb.normal_(0.0, 0.5)
    model = Diffusion(OBS_DIM, ACT_DIM, net, beta_schedule, n_timesteps)
    agent = _trained(DiffusionAgent(model, _scaler(), window_size=window_size), seed)
    if checkpoint:
        agent.load_pretrained_model(checkpoint)
    return agent
