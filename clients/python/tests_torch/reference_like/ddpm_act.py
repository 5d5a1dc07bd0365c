"""Like the reference ``agents/ddpm_encdec_agent.py`` ``DiffusionAgent`` (DDPM-ACT):
a ``DiffusionEncDec`` (``agents/models/diffusion/diffusion_models.py``) with the
ACT encoder and decoder (``agents/models/act/act_vae.py``), sampled by the
``diffusion_policy.Diffusion`` (a chunk of the model's ``action_seq_len``).

Kept from the reference: the names, ``obs_context`` appended on every step and
emptied by ``reset()``, ``action_counter`` (a chunk sampled when it reaches
``action_seq_size``), the EMA weights copied in for sampling, the position slices
(states from 0, actions from w − 1), the encoder's causal mask, bias-free layer
norms, and the DDPM loop of ``reference_like.ddpm``. ``make_agent`` is DDPM-ACT as the
reference's other tasks run it (window 8: obs_seq_len 5, chunks of 4), smaller;
``make_agent(obs_seq_len=1, action_seq_size=10, action_seq_len=10, window_size=10)``
is its Aligning setting.
"""

from __future__ import annotations

import collections
import math
from typing import Any, Optional

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from .ddpm import ACT_DIM, OBS_DIM, ExponentialMovingAverage, SinusoidalPosEmb, _scaler, _trained
from .ddpm import Diffusion as _GcDiffusion
from .scaler import Scaler


class Diffusion(_GcDiffusion):
    """diffusion_policy.Diffusion: a 3-D state samples the model's action_seq_len."""

    def sample_shape(self, state: torch.Tensor) -> tuple:
        if len(state.shape) == 3:
            return (state.shape[0], self.model.action_seq_len, self.action_dim)
        return (state.shape[0], self.action_dim)


class LayerNorm(nn.Module):
    def __init__(self, ndim: int, bias: bool) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.ones(ndim))
        self.bias = nn.Parameter(torch.zeros(ndim)) if bias else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.layer_norm(x, self.weight.shape, self.weight, self.bias, 1e-5)


def _heads(x: torch.Tensor, lin: nn.Linear, n_head: int) -> torch.Tensor:
    B, T, _ = x.size()
    C = lin.out_features
    return lin(x).view(B, T, n_head, C // n_head).transpose(1, 2)


class SelfAttention(nn.Module):
    def __init__(self, n_embd: int, n_heads: int, block_size: int) -> None:
        super().__init__()
        self.key, self.query, self.value = (nn.Linear(n_embd, n_embd) for _ in range(3))
        self.attn_drop, self.resid_drop = nn.Dropout(0.1), nn.Dropout(0.1)
        self.proj = nn.Linear(n_embd, n_embd)
        self.register_buffer("mask", torch.tril(torch.ones(block_size, block_size)).view(1, 1, block_size, block_size))
        self.n_head = n_heads

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, T, C = x.size()
        k, q, v = (_heads(x, m, self.n_head) for m in (self.key, self.query, self.value))
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(k.size(-1)))
        att = att.masked_fill(self.mask[:, :, :T, :T] == 0, float("-inf"))
        y = self.attn_drop(F.softmax(att, dim=-1)) @ v
        return self.resid_drop(self.proj(y.transpose(1, 2).contiguous().view(B, T, C)))


class CausalSelfCrossAttention(nn.Module):
    def __init__(self, n_embd: int, cross_embed: int, n_heads: int, block_size: int) -> None:
        super().__init__()
        self.key, self.query, self.value = (nn.Linear(n_embd, n_embd) for _ in range(3))
        self.cross_key = nn.Linear(cross_embed, n_embd)
        self.cross_query = nn.Linear(n_embd, n_embd)
        self.cross_value = nn.Linear(cross_embed, n_embd)
        self.attn_drop, self.resid_drop = nn.Dropout(0.1), nn.Dropout(0.1)
        self.proj = nn.Linear(n_embd, n_embd)
        self.register_buffer("mask", torch.tril(torch.ones(block_size, block_size)).view(1, 1, block_size, block_size))
        self.n_head = n_heads

    def forward(self, x: torch.Tensor, cross_input: Optional[torch.Tensor] = None) -> torch.Tensor:
        B, T, C = x.size()
        k, q, v = (_heads(x, m, self.n_head) for m in (self.key, self.query, self.value))
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(k.size(-1)))
        att = att.masked_fill(self.mask[:, :, :T, :T] == 0, float("-inf"))
        y = self.attn_drop(F.softmax(att, dim=-1)) @ v
        if cross_input is not None:
            kc = _heads(cross_input, self.cross_key, self.n_head)
            vc = _heads(cross_input, self.cross_value, self.n_head)
            qc = _heads(x, self.cross_query, self.n_head)
            att_c = (qc @ kc.transpose(-2, -1)) * (1.0 / math.sqrt(kc.size(-1)))
            y = y + self.attn_drop(F.softmax(att_c, dim=-1)) @ vc
        return self.resid_drop(self.proj(y.transpose(1, 2).contiguous().view(B, T, C)))


def _mlp(n_embd: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_embd, 4 * n_embd), nn.GELU(), nn.Linear(4 * n_embd, n_embd), nn.Dropout(0.1))


class EncoderBlock(nn.Module):
    def __init__(self, n_embd: int, n_heads: int, block_size: int) -> None:
        super().__init__()
        self.ln1, self.ln2 = LayerNorm(n_embd, bias=False), LayerNorm(n_embd, bias=False)
        self.attn = SelfAttention(n_embd, n_heads, block_size)
        self.mlp = _mlp(n_embd)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln1(x))
        return x + self.mlp(self.ln2(x))


class DecoderBlock(nn.Module):
    def __init__(self, n_embd: int, cross_embd: int, n_heads: int, block_size: int) -> None:
        super().__init__()
        self.ln1, self.ln2 = LayerNorm(n_embd, bias=False), LayerNorm(n_embd, bias=False)
        self.attn = CausalSelfCrossAttention(n_embd, cross_embd, n_heads, block_size)
        self.mlp = _mlp(n_embd)

    def forward(self, x: torch.Tensor, cond: Optional[torch.Tensor] = None) -> torch.Tensor:
        x = x + self.attn(self.ln1(x), cross_input=cond)
        return x + self.mlp(self.ln2(x))


class TransformerEncoder(nn.Module):
    def __init__(self, embed_dim: int, n_heads: int, n_layers: int, block_size: int, bias: bool = False) -> None:
        super().__init__()
        self.blocks = nn.Sequential(*[EncoderBlock(embed_dim, n_heads, block_size) for _ in range(n_layers)])
        self.ln = LayerNorm(embed_dim, bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.blocks:
            x = layer(x)
        return self.ln(x)


class TransformerDecoder(nn.Module):
    def __init__(self, embed_dim: int, n_heads: int, n_layers: int, block_size: int, bias: bool = False) -> None:
        super().__init__()
        self.blocks = nn.Sequential(*[DecoderBlock(embed_dim, embed_dim, n_heads, block_size) for _ in range(n_layers)])
        self.ln = LayerNorm(embed_dim, bias)

    def forward(self, x: torch.Tensor, cond: Optional[torch.Tensor] = None) -> torch.Tensor:
        for layer in self.blocks:
            x = layer(x, cond=cond)
        return self.ln(x)


class DiffusionEncDec(nn.Module):
    def __init__(
        self,
        encoder: nn.Module,
        decoder: nn.Module,
        state_dim: int,
        action_dim: int,
        embed_dim: int,
        goal_seq_len: int,
        obs_seq_len: int,
        action_seq_len: int,
        goal_conditioned: bool = False,
        linear_output: bool = True,
        device: str = "cpu",
    ) -> None:
        super().__init__()
        self.encoder, self.decoder = encoder, decoder
        self.device = device
        self.goal_conditioned = goal_conditioned
        if not goal_conditioned:
            goal_seq_len = 0
        self.block_size = goal_seq_len + action_seq_len + obs_seq_len + 1
        seq_size = goal_seq_len + obs_seq_len - 1 + action_seq_len
        self.tok_emb = nn.Linear(state_dim, embed_dim)
        self.pos_emb = nn.Parameter(torch.zeros(1, seq_size, embed_dim))
        self.drop = nn.Dropout(0.0)
        self.action_dim, self.obs_dim, self.embed_dim = action_dim, state_dim, embed_dim
        self.goal_seq_len, self.obs_seq_len, self.action_seq_len = goal_seq_len, obs_seq_len, action_seq_len
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
        state_embed = self.tok_emb(states)
        action_embed = self.action_emb(actions)
        g = self.goal_seq_len
        position_embeddings = self.pos_emb[:, : (t + g + self.action_seq_len - 1), :]
        state_x = self.drop(state_embed + position_embeddings[:, g : (g + t), :])
        action_x = self.drop(action_embed + position_embeddings[:, (g + t - 1) :, :])
        encoder_output = self.encoder(torch.cat([emb_t, state_x], dim=1))
        return self.action_pred(self.decoder(action_x, encoder_output))

    def get_params(self) -> Any:
        return self.parameters()


class DiffusionAgent:
    def __init__(
        self,
        model: Diffusion,
        scaler: Scaler,
        window_size: int,
        obs_seq_len: int,
        action_seq_size: int,
        use_ema: bool = True,
        decay: float = 0.995,
        device: str = "cpu",
        goal_window_size: int = 1,
        pred_last_action_only: bool = False,
        diffusion_kde: bool = False,
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
        if not self.pred_last_action_only:
            self.action_context: collections.deque = collections.deque(maxlen=self.window_size - 1)
            self.que_actions = True
        else:
            self.que_actions = False
        self.diffusion_kde = diffusion_kde
        self.obs_seq_len = obs_seq_len
        self.action_seq_size = action_seq_size
        self.action_counter = self.action_seq_size
        self.obs_context: collections.deque = collections.deque(maxlen=self.obs_seq_len)
        self.goal_context: collections.deque = collections.deque(maxlen=self.goal_window_size)

    def reset(self) -> None:
        self.obs_context.clear()
        self.action_counter = self.action_seq_size

    @torch.no_grad()
    def predict(self, state: np.ndarray, goal: Optional[torch.Tensor] = None, extra_args: Any = None) -> np.ndarray:
        obs = torch.from_numpy(state).float().to(self.device).unsqueeze(0)
        obs = self.scaler.scale_input(obs)
        self.obs_context.append(obs)
        input_state = torch.stack(tuple(self.obs_context), dim=1)
        if self.action_counter == self.action_seq_size:
            self.action_counter = 0
            if self.use_ema:
                self.ema_helper.store(self.model.parameters())
                self.ema_helper.copy_to(self.model.parameters())
            self.model.eval()
            model_pred = self.model(input_state, goal)
            if self.use_ema:
                self.ema_helper.restore(self.model.parameters())
            self.curr_action_seq = self.scaler.inverse_scale_output(model_pred)
        next_action = self.curr_action_seq[:, self.action_counter, :]
        self.action_counter += 1
        return next_action.detach().cpu().numpy()

    def load_pretrained_model(self, weights_path: str, sv_name: Optional[str] = None, **kwargs: Any) -> None:
        import os

        path = os.path.join(weights_path, sv_name) if sv_name else weights_path
        self.model.load_state_dict(torch.load(path))
        self.ema_helper = ExponentialMovingAverage(self.model.get_params(), self.decay, self.device)


def make_agent(
    checkpoint: Optional[str] = None,
    obs_seq_len: int = 5,
    action_seq_size: int = 4,
    action_seq_len: int = 4,
    window_size: int = 8,
    n_timesteps: int = 8,
    beta_schedule: str = "cosine",
    seed: int = 0,
) -> DiffusionAgent:
    """DDPM-ACT as scripts/<task>/ddpm_encdec_benchmark.sh run it, smaller networks."""
    torch.manual_seed(seed)
    embed = 16
    net = DiffusionEncDec(
        TransformerEncoder(embed, 2, 1, block_size=window_size + 1),
        TransformerDecoder(embed, 2, 2, block_size=window_size + 1),
        OBS_DIM,
        ACT_DIM,
        embed_dim=embed,
        goal_seq_len=10,
        obs_seq_len=obs_seq_len,
        action_seq_len=action_seq_len,
    )
    with torch.no_grad():
        net.pos_emb.normal_(0.0, 0.5)
    model = Diffusion(OBS_DIM, ACT_DIM, net, beta_schedule, n_timesteps)
    agent = DiffusionAgent(
        model, _scaler(), window_size=window_size, obs_seq_len=obs_seq_len, action_seq_size=action_seq_size
    )
    agent = _trained(agent, seed)  # type: ignore[arg-type]
    if checkpoint:
        agent.load_pretrained_model(checkpoint)
    return agent
