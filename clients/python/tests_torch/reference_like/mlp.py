"""A small residual MLP shaped like the reference's ``ResidualMLPNetwork``
(agents/models/common/mlp.py): an input layer, pre-activation residual blocks of two
layers each, an output layer; float32 input cast as the reference does. Written here
for the tests (random weights), not the reference's code.
"""

from __future__ import annotations

import torch
from torch import nn


class ResidualBlock(nn.Module):
    """x + l2(act(l1(act(x)))): two pre-activated layers with a skip connection."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.l1 = nn.Linear(width, width)
        self.l2 = nn.Linear(width, width)
        self.act = nn.Mish()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.l2(self.act(self.l1(self.act(x))))


class ResidualMLPNetwork(nn.Module):
    def __init__(self, input_dim: int, hidden_dim: int = 16, num_hidden_layers: int = 2, output_dim: int = 1) -> None:
        super().__init__()
        if num_hidden_layers % 2:
            raise ValueError("num_hidden_layers must be even (two layers per residual block)")
        blocks = [ResidualBlock(hidden_dim) for _ in range(num_hidden_layers // 2)]
        self.layers = nn.ModuleList([nn.Linear(input_dim, hidden_dim), *blocks, nn.Linear(hidden_dim, output_dim)])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.layers:
            x = layer(x.to(torch.float32))
        return x

    def get_params(self):
        return self.parameters()
