"""Like the reference BeT (agents/bet_agent.py ``BeT_Agent`` with ``BeT_Policy``,
agents/models/bet/latent_generators/mingpt.py ``MinGPT`` and
agents/models/bet/action_ae/discretizers/k_means.py ``KMeansDiscretizer``): a GPT over
the window gives, per position, logits over k-means bins and an offset per bin; a bin
is sampled per position with ``torch.multinomial`` from the softmax and the last
position's bin centre plus its offset is the action.

The quirks kept: ``obs_context`` starts EMPTY at ``reset()`` (window 1..k); each
observation is [1, obs] and the deque is stacked on dim 0, [T, 1, obs], which
``generate_latents`` reads as (seq, batch, embed) and rearranges to [1, T, obs];
``torch.multinomial(probs.view(-1, V), num_samples=1)`` samples a bin for EVERY
position of the window (T draws) though only the last is used; the action is clamped
in place to the float64 scaled data bounds, then inverse-scaled, [1, act].
"""

from __future__ import annotations

from collections import deque
from typing import Any, Optional

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from .mingpt import GPT, GPTConfig
from .scaler import Scaler, aligning_like_data


class eval_mode:  # noqa: N801 (agents/models/bet/utils.py)
    def __init__(self, *models: nn.Module, no_grad: bool = False) -> None:
        self.models, self.no_grad = models, no_grad
        self.ctx = torch.no_grad()

    def __enter__(self) -> None:
        self.prev = [m.training for m in self.models]
        for m in self.models:
            m.train(False)
        if self.no_grad:
            self.ctx.__enter__()

    def __exit__(self, *args: Any) -> bool:
        if self.no_grad:
            self.ctx.__exit__(*args)
        for m, state in zip(self.models, self.prev, strict=True):
            m.train(state)
        return False


class MinGPT(nn.Module):
    """The latent generator: a GPT whose head gives V logits and V × act offsets."""

    def __init__(
        self, input_dim: int, n_layer: int, n_head: int, n_embd: int, block_size: int, vocab_size: int, action_dim: int
    ) -> None:
        super().__init__()
        self.vocab_size = vocab_size
        self.action_dim = action_dim
        self.predict_offsets = True
        config = GPTConfig(
            input_size=input_dim,
            vocab_size=vocab_size * (1 + action_dim),
            block_size=block_size,
            n_layer=n_layer,
            n_head=n_head,
            n_embd=n_embd,
        )
        self.model = GPT(config)

    def generate_latents(self, seq_obses: torch.Tensor, seq_masks: torch.Tensor):
        seq, batch, embed = seq_obses.size()
        obs_rep = seq_obses.permute(1, 0, 2)  # seq batch embed -> batch seq embed
        output, _ = self.model(obs_rep, None)
        logits = output[:, :, : self.vocab_size]
        offsets = output[:, :, self.vocab_size :]
        n, t = offsets.shape[0], offsets.shape[1]
        offsets = offsets.reshape(n * t, self.vocab_size, self.action_dim)
        probs = F.softmax(logits, dim=-1)
        batch, seq, choices = probs.shape
        sampled = torch.multinomial(probs.view(-1, choices), num_samples=1)
        sampled = sampled.reshape(batch, seq, 1)
        sampled_offsets = offsets[torch.arange(offsets.shape[0]), sampled.flatten()].view(batch, seq, self.action_dim)
        return (sampled, sampled_offsets)


class BeT_Policy(nn.Module):  # noqa: N801 (the reference's name)
    def __init__(self, model: MinGPT, visual_input: bool = False) -> None:
        super().__init__()
        self.visual_input = visual_input
        self.obs_encoder = nn.Identity()
        self.model = model

    def forward(self, inputs: torch.Tensor):
        obs = self.obs_encoder(inputs)
        return self.model.generate_latents(obs, torch.ones_like(obs).mean(dim=-1))


class KMeansDiscretizer(nn.Module):
    def __init__(self, action_dim: int, num_bins: int, device: str = "cpu", predict_offsets: bool = True) -> None:
        super().__init__()
        self.n_bins = num_bins
        self.action_dim = action_dim
        self.device = device
        self.predict_offsets = predict_offsets

    def fit_discretizer(self, actions: torch.Tensor, seed: int = 0) -> None:
        """A few Lloyd iterations from random data points (the reference runs 50)."""
        g = torch.Generator().manual_seed(seed)
        x = actions.reshape(-1, self.action_dim)
        c = x[torch.randperm(x.shape[0], generator=g)[: self.n_bins]].clone()
        for _ in range(10):
            a = ((x[:, None, :] - c[None, :, :]) ** 2).sum(-1).argmin(1)
            for k in range(self.n_bins):
                if (a == k).any():
                    c[k] = x[a == k].mean(0)
        self.bin_centers = c

    def decode_actions(self, latent_action_batch, input_rep_batch=None) -> torch.Tensor:
        offsets = None
        if type(latent_action_batch) is tuple:
            latent_action_batch, offsets = latent_action_batch
        centers = self.bin_centers[latent_action_batch]
        reconstructed = centers.view(latent_action_batch.shape[:-1] + (self.action_dim,))
        if offsets is not None:
            reconstructed += offsets
        return reconstructed


class BeT_Agent:  # noqa: N801 (the reference's name)
    def __init__(
        self, model: BeT_Policy, action_ae: KMeansDiscretizer, scaler: Scaler, window_size: int, device: str = "cpu"
    ) -> None:
        self.model = model
        self.action_ae = action_ae
        self.scaler = scaler
        self.device = device
        self.min_action = torch.from_numpy(self.scaler.y_bounds[0, :]).to(self.device)
        self.max_action = torch.from_numpy(self.scaler.y_bounds[1, :]).to(self.device)
        self.window_size = window_size
        self.obs_context: deque = deque(maxlen=self.window_size)

    def reset(self) -> None:
        self.obs_context.clear()

    def predict(self, state, sample: bool = False, if_vision: bool = False):
        with eval_mode(self.action_ae, self.model, no_grad=True):
            obs = torch.from_numpy(state).float().to(self.device).unsqueeze(0)
            obs = self.scaler.scale_input(obs)
            self.obs_context.append(obs)
            obs_seq = torch.stack(tuple(self.obs_context), dim=0)  # [T, 1, obs]
            latents = self.model(obs_seq)
            if type(latents) is tuple:
                latents, offsets = latents
            action_latents = (latents[:, -1:, :], offsets[:, -1:, :])
            actions = self.action_ae.decode_actions(latent_action_batch=action_latents)
            actions = actions.clamp_(self.min_action, self.max_action)
            actions = self.scaler.inverse_scale_output(actions)
            actions = actions.cpu().numpy()
            if sample:
                return actions[np.random.randint(len(actions))]
            return actions.reshape(actions.shape[0], actions.shape[2])


def make_agent(checkpoint: Optional[Any] = None, window_size: int = 3, seed: int = 5) -> BeT_Agent:
    """An Aligning-shaped BeT (obs 20, act 3, window 3 as the reference's Aligning
    script, 16 bins) with random weights and bins fitted on the scaled actions, or
    the network's state dict in ``checkpoint``.
    """
    torch.manual_seed(seed)
    x, y = aligning_like_data(20, 3)
    scaler = Scaler(x, y)
    gpt = MinGPT(input_dim=20, n_layer=2, n_head=4, n_embd=32, block_size=window_size, vocab_size=16, action_dim=3)
    action_ae = KMeansDiscretizer(action_dim=3, num_bins=16)
    action_ae.fit_discretizer(scaler.scale_output(torch.from_numpy(y)))
    agent = BeT_Agent(BeT_Policy(gpt), action_ae, scaler, window_size=window_size)
    if checkpoint is not None:
        agent.model.load_state_dict(torch.load(checkpoint, map_location="cpu"))
    return agent
