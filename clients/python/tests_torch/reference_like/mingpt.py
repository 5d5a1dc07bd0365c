"""A small GPT shaped like the one BeT and BC-GPT use in the D3IL reference
(agents/models/bet/libraries/mingpt/model.py, after Karpathy's minGPT), written here
for the tests with random weights: a linear token embedding of the observations, a
learned positional embedding sliced to the window (``pos_emb[:, :t]``), pre-norm blocks
of causal self-attention (a ``mask`` buffer of the block size sliced to the window) and
a GELU MLP, a final LayerNorm and a bias-free head. Like the reference it takes the
window length and batch from ``x.size()`` in Python, the shape arithmetic tracing
records from the example input.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F


class GPTConfig:
    def __init__(self, vocab_size: int, block_size: int, **kwargs) -> None:
        self.vocab_size = vocab_size
        self.block_size = block_size
        self.input_size = 10
        self.n_embd = 32
        self.n_layer = 2
        self.n_head = 4
        self.embd_pdrop = self.resid_pdrop = self.attn_pdrop = 0.1
        self.discrete_input = False
        for k, v in kwargs.items():
            setattr(self, k, v)


class CausalSelfAttention(nn.Module):
    def __init__(self, config: GPTConfig) -> None:
        super().__init__()
        self.key = nn.Linear(config.n_embd, config.n_embd)
        self.query = nn.Linear(config.n_embd, config.n_embd)
        self.value = nn.Linear(config.n_embd, config.n_embd)
        self.attn_drop = nn.Dropout(config.attn_pdrop)
        self.resid_drop = nn.Dropout(config.resid_pdrop)
        self.proj = nn.Linear(config.n_embd, config.n_embd)
        causal = torch.tril(torch.ones(config.block_size, config.block_size))
        self.register_buffer("mask", causal.view(1, 1, config.block_size, config.block_size))
        self.n_head = config.n_head

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, T, C = x.size()
        hs = C // self.n_head
        k = self.key(x).view(B, T, self.n_head, hs).transpose(1, 2)
        q = self.query(x).view(B, T, self.n_head, hs).transpose(1, 2)
        v = self.value(x).view(B, T, self.n_head, hs).transpose(1, 2)
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(k.size(-1)))
        att = att.masked_fill(self.mask[:, :, :T, :T] == 0, float("-inf"))
        att = self.attn_drop(F.softmax(att, dim=-1))
        y = (att @ v).transpose(1, 2).contiguous().view(B, T, C)
        return self.resid_drop(self.proj(y))


class Block(nn.Module):
    def __init__(self, config: GPTConfig) -> None:
        super().__init__()
        self.ln1 = nn.LayerNorm(config.n_embd)
        self.ln2 = nn.LayerNorm(config.n_embd)
        self.attn = CausalSelfAttention(config)
        self.mlp = nn.Sequential(
            nn.Linear(config.n_embd, 4 * config.n_embd),
            nn.GELU(),
            nn.Linear(4 * config.n_embd, config.n_embd),
            nn.Dropout(config.resid_pdrop),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln1(x))
        return x + self.mlp(self.ln2(x))


class GPT(nn.Module):
    def __init__(self, config: GPTConfig) -> None:
        super().__init__()
        self.tok_emb = nn.Linear(config.input_size, config.n_embd)
        self.pos_emb = nn.Parameter(0.02 * torch.randn(1, config.block_size, config.n_embd))
        self.drop = nn.Dropout(config.embd_pdrop)
        self.blocks = nn.Sequential(*[Block(config) for _ in range(config.n_layer)])
        self.ln_f = nn.LayerNorm(config.n_embd)
        self.head = nn.Linear(config.n_embd, config.vocab_size, bias=False)
        self.block_size = config.block_size

    def forward(self, idx: torch.Tensor, targets=None):
        b, t, _ = idx.size()
        assert t <= self.block_size, "Cannot forward, model block size is exhausted."
        x = self.drop(self.tok_emb(idx) + self.pos_emb[:, :t, :])
        logits = self.head(self.ln_f(self.blocks(x)))
        return logits, None
