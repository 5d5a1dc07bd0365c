"""VAE-ACT like agents/act_agent.py of the reference: ``ActAgent`` with an ``ActVAE``
(state and latent tokens through a causal transformer encoder; one query token per
chunk action through a decoder with causal self-attention and cross-attention on the
encoder output). At test time the latent comes from ``torch.rand([bs, 1,
latent_dim])`` (uniform, as the reference); ``predict`` calls the model when
``action_counter == action_seq_size`` (``reset()`` sets it so), keeps the chunk in
``curr_action_seq`` and returns ``curr_action_seq[:, action_counter]``. The
reference asserts ``window_size == action_seq_size + obs_size - 1``; so does this.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Optional

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from .scaler import Scaler, aligning_like_data

OBS_DIM, ACT_DIM, LATENT_DIM, CHUNK = 20, 3, 4, 3


class Attention(nn.Module):
    """Multi-head attention; causal over the queries' own sequence when ``causal``."""

    def __init__(self, dim: int, heads: int, block_size: int, causal: bool) -> None:
        super().__init__()
        self.q, self.k, self.v, self.out = (nn.Linear(dim, dim) for _ in range(4))
        self.heads, self.causal = heads, causal
        self.register_buffer("mask", torch.tril(torch.ones(block_size, block_size)).view(1, 1, block_size, block_size))

    def forward(self, x: torch.Tensor, ctx: Optional[torch.Tensor] = None) -> torch.Tensor:
        B, T, C = x.size()
        src = x if ctx is None else ctx
        S = src.size(1)
        h = self.heads
        q = self.q(x).view(B, T, h, C // h).transpose(1, 2)
        k = self.k(src).view(B, S, h, C // h).transpose(1, 2)
        v = self.v(src).view(B, S, h, C // h).transpose(1, 2)
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(k.size(-1)))
        if self.causal:
            att = att.masked_fill(self.mask[:, :, :T, :T] == 0, float("-inf"))
        y = F.softmax(att, dim=-1) @ v
        return self.out(y.transpose(1, 2).contiguous().view(B, T, C))


class Block(nn.Module):
    def __init__(self, dim: int, heads: int, block_size: int, cross: bool) -> None:
        super().__init__()
        self.ln1, self.ln2 = nn.LayerNorm(dim), nn.LayerNorm(dim)
        self.attn = Attention(dim, heads, block_size, causal=True)
        self.cross = Attention(dim, heads, block_size, causal=False) if cross else None
        self.mlp = nn.Sequential(nn.Linear(dim, 2 * dim), nn.GELU(), nn.Linear(2 * dim, dim), nn.Dropout(0.1))

    def forward(self, x: torch.Tensor, cond: Optional[torch.Tensor] = None) -> torch.Tensor:
        y = self.ln1(x)
        a = self.attn(y)
        if self.cross is not None and cond is not None:
            a = a + self.cross(y, cond)
        x = x + a
        return x + self.mlp(self.ln2(x))


class TransformerEncoder(nn.Module):
    def __init__(self, embed_dim: int, n_heads: int, n_layers: int, block_size: int) -> None:
        super().__init__()
        self.blocks = nn.Sequential(*[Block(embed_dim, n_heads, block_size, cross=False) for _ in range(n_layers)])
        self.ln = nn.LayerNorm(embed_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for b in self.blocks:
            x = b(x)
        return self.ln(x)


class TransformerDecoder(nn.Module):
    def __init__(self, embed_dim: int, n_heads: int, n_layers: int, block_size: int) -> None:
        super().__init__()
        self.blocks = nn.Sequential(*[Block(embed_dim, n_heads, block_size, cross=True) for _ in range(n_layers)])
        self.ln = nn.LayerNorm(embed_dim)

    def forward(self, x: torch.Tensor, cond: Optional[torch.Tensor] = None) -> torch.Tensor:
        for b in self.blocks:
            x = b(x, cond=cond)
        return self.ln(x)


class ActVAE(nn.Module):
    def __init__(
        self, state_dim: int, action_dim: int, hidden_dim: int = 16, act_seq_size: int = CHUNK, latent_dim: int = 4
    ) -> None:
        super().__init__()
        self.encoder = TransformerEncoder(hidden_dim, 2, 1, act_seq_size)
        self.decoder = TransformerDecoder(hidden_dim, 2, 2, act_seq_size)
        self.action_encoder = TransformerEncoder(hidden_dim, 2, 1, act_seq_size + 1)
        self.state_encoder = nn.Linear(state_dim, hidden_dim, bias=False)
        self.action_embed = nn.Linear(action_dim, hidden_dim, bias=False)
        self.latent_out_proj = nn.Linear(latent_dim, hidden_dim, bias=False)
        self.action_head = nn.Linear(hidden_dim, action_dim)
        self.latent_proj = nn.Linear(hidden_dim, 2 * latent_dim)
        self.query_embed = nn.Embedding(act_seq_size, hidden_dim)
        self.cls_embed = nn.Embedding(1, hidden_dim)
        self.latent_dim = latent_dim
        self.pos_emb = nn.Parameter(0.1 * torch.randn(1, act_seq_size, hidden_dim))
        self.act_pos_emb = nn.Parameter(torch.zeros(1, act_seq_size + 1, hidden_dim))

    def forward(self, state: torch.Tensor, goal: Optional[torch.Tensor] = None, action: Optional[torch.Tensor] = None):
        state = state[:, :1, :]
        bs = state.shape[0]
        if action is not None:
            seq = torch.cat([self.cls_embed.weight.unsqueeze(0).repeat(bs, 1, 1), self.action_embed(action)], 1)
            info = self.latent_proj(self.action_encoder(seq + self.act_pos_emb)[:, :1])
            mu, logvar = info[..., : self.latent_dim], info[..., self.latent_dim :]
            sample = mu + (0.5 * logvar).exp() * torch.randn_like(mu)
        else:
            mu = logvar = None
            sample = torch.rand([bs, 1, self.latent_dim], dtype=torch.float32).to(state.device)
        tokens = torch.cat([self.state_encoder(state), self.latent_out_proj(sample)], dim=1)
        tokens = tokens + self.pos_emb[:, : tokens.shape[1]]
        memory = self.encoder(tokens)
        queries = self.query_embed.weight.unsqueeze(0).repeat(bs, 1, 1)
        return self.action_head(self.decoder(queries, memory)), [mu, logvar]

    def get_params(self):
        return self.parameters()


class ActAgent:
    def __init__(
        self,
        model: ActVAE,
        scaler: Any,
        window_size: int = CHUNK,
        obs_size: int = 1,
        action_seq_size: int = CHUNK,
        device: str = "cpu",
    ) -> None:
        self.model = model
        self.scaler = scaler
        self.device = device
        self.min_action = torch.from_numpy(self.scaler.y_bounds[0, :]).to(self.device)
        self.max_action = torch.from_numpy(self.scaler.y_bounds[1, :]).to(self.device)
        self.gc = False
        self.window_size = window_size
        self.goal_window_size = 1
        self.action_seq_size = action_seq_size
        self.obs_size = obs_size
        self.obs_context: deque = deque(maxlen=self.obs_size)
        self.action_context: deque = deque(maxlen=self.action_seq_size)
        self.pred_counter = 0
        self.action_counter = self.action_seq_size
        assert self.window_size == self.action_seq_size + self.obs_size - 1, "window_size does not match"

    def reset(self) -> None:
        self.action_counter = self.action_seq_size

    @torch.no_grad()
    def predict(self, state: np.ndarray, goal: Optional[torch.Tensor] = None, if_vision: bool = False) -> np.ndarray:
        x = torch.from_numpy(state).float().to(self.device).unsqueeze(0).unsqueeze(0)
        x = self.scaler.scale_input(x)
        if self.action_counter == self.action_seq_size:
            self.action_counter = 0
            self.model.eval()
            a_hat, _ = self.model(x, goal)
            a_hat = a_hat.clamp_(self.min_action, self.max_action)
            self.curr_action_seq = self.scaler.inverse_scale_output(a_hat)
        nxt = self.curr_action_seq[:, self.action_counter, :]
        self.action_counter += 1
        return nxt.detach().cpu().numpy()


def make_agent(checkpoint: Optional[str] = None, action_seq_size: int = CHUNK) -> ActAgent:
    """An ACT agent on Aligning-like data (chunk 3 executed whole, latent 4); random
    weights (scaled up so the chunk's actions differ) or ``checkpoint``.
    """
    torch.manual_seed(2)
    model = ActVAE(OBS_DIM, ACT_DIM)
    with torch.no_grad():
        model.action_head.weight.mul_(3.0)
        model.latent_out_proj.weight.mul_(3.0)
    if checkpoint is not None:
        model.load_state_dict(torch.load(checkpoint, weights_only=True))
    x, y = aligning_like_data(OBS_DIM, ACT_DIM)
    return ActAgent(model, Scaler(x, y, True, "cpu"), window_size=action_seq_size, action_seq_size=action_seq_size)
