"""BeT-MLP like agents/bet_mlp_agent.py of the reference: ``BetMLP_Agent`` with a
``BeTPolicy`` (residual MLP -> V bin logits and V offsets) and a ``KMeansDiscretizer``
holding ``bin_centers``; ``predict`` scales [1, 1, obs_dim], samples ONE bin with
``torch.multinomial(probs, num_samples=1)``, adds the bin's centre and offset, clamps
to the data bounds, inverse-scales and returns [1, act_dim]. Its ``obs_context``
deque is cleared by ``reset()`` and never used by ``predict``, as in the reference.
"""

from __future__ import annotations

from collections import deque
from typing import Any, Optional

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from .mlp import ResidualMLPNetwork
from .scaler import Scaler, aligning_like_data

OBS_DIM, ACT_DIM, VOCAB = 20, 3, 8


class BeTPolicy(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, vocab_size: int = VOCAB, predict_offsets: bool = True) -> None:
        super().__init__()
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.vocab_size = vocab_size
        self.predict_offsets = predict_offsets
        self.model = ResidualMLPNetwork(obs_dim, 16, 2, vocab_size * (1 + act_dim))

    def generate_latents(self, seq_obses: torch.Tensor):
        obs_rep = seq_obses.transpose(0, 1)  # "seq batch embed -> batch seq embed"
        output = self.model(obs_rep)
        logits = output[:, :, : self.vocab_size] if self.predict_offsets else output
        batch, seq, choices = logits.shape
        probs = F.softmax(logits, dim=-1)
        sampled = torch.multinomial(probs.view(-1, choices), num_samples=1).view(batch, seq, 1)
        if not self.predict_offsets:
            return sampled
        offsets = output[:, :, self.vocab_size :].reshape(batch * seq, self.vocab_size, self.act_dim)
        chosen = offsets[torch.arange(offsets.shape[0]), sampled.flatten()].view(batch, seq, self.act_dim)
        return sampled, chosen

    def get_params(self):
        return self.parameters()


class KMeansDiscretizer(nn.Module):
    def __init__(self, action_dim: int, num_bins: int = VOCAB, predict_offsets: bool = True) -> None:
        super().__init__()
        self.n_bins, self.action_dim, self.predict_offsets = num_bins, action_dim, predict_offsets
        self.bin_centers = torch.zeros(num_bins, action_dim)  # a plain attribute, as the reference's

    def decode_actions(self, latent_action_batch, input_rep_batch: Optional[torch.Tensor] = None) -> torch.Tensor:
        offsets = None
        if isinstance(latent_action_batch, tuple):
            latent_action_batch, offsets = latent_action_batch
        centers = self.bin_centers[latent_action_batch].view(latent_action_batch.shape[:-1] + (self.action_dim,))
        if offsets is not None:
            centers += offsets
        return centers


class BetMLP_Agent:  # noqa: N801
    def __init__(self, model: BeTPolicy, action_ae: KMeansDiscretizer, scaler: Any, window_size: int = 1) -> None:
        self.model = model
        self.action_ae = action_ae
        self.obs_encoding_net = nn.Identity()
        self.scaler = scaler
        self.device = "cpu"
        self.min_action = torch.from_numpy(self.scaler.y_bounds[0, :]).to(self.device)
        self.max_action = torch.from_numpy(self.scaler.y_bounds[1, :]).to(self.device)
        self.window_size = window_size
        self.obs_context: deque = deque(maxlen=self.window_size)

    @torch.no_grad()
    def predict(self, state: np.ndarray, sample: bool = False) -> np.ndarray:
        self.model.eval()
        obs = torch.from_numpy(state).float().to(self.device).unsqueeze(0).unsqueeze(0)
        obs = self.scaler.scale_input(obs)
        enc = self.obs_encoding_net(obs)
        latents, offsets = self.model.generate_latents(enc)
        actions = self.action_ae.decode_actions((latents[:, -1:, :], offsets[:, -1:, :]), enc)
        actions = actions.clamp_(self.min_action, self.max_action)
        actions = self.scaler.inverse_scale_output(actions).cpu().numpy()
        if sample:
            return actions[np.random.randint(len(actions))]
        return actions.reshape(actions.shape[0], actions.shape[-1])

    def reset(self) -> None:
        self.obs_context.clear()


def make_agent(checkpoint: Optional[str] = None) -> BetMLP_Agent:
    """A BeT-MLP agent on Aligning-like data (8 bins: k-means-like centres picked from
    the scaled actions); random weights or ``checkpoint``.
    """
    torch.manual_seed(3)
    model = BeTPolicy(OBS_DIM, ACT_DIM)
    with torch.no_grad():  # spread the logits so that several bins are likely
        model.model.layers[-1].weight.mul_(4.0)
    if checkpoint is not None:
        model.load_state_dict(torch.load(checkpoint, weights_only=True))
    x, y = aligning_like_data(OBS_DIM, ACT_DIM)
    scaler = Scaler(x, y, True, "cpu")
    ae = KMeansDiscretizer(ACT_DIM)
    ae.bin_centers = scaler.scale_output(torch.from_numpy(y[:: len(y) // VOCAB][:VOCAB]))
    return BetMLP_Agent(model, ae, scaler)
