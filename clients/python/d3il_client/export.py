"""Export recipes for D3IL agents (docs/export.md).

Building blocks that keep a whole `predict` path exportable as ONE ONNX graph whose
randomness all comes from the evaluator's `noise` input (standard normal samples):

* uniform samples: ``uniform_from_noise(n) = Φ(n)``;
* categorical samples (BeT bins, IBC's final choice): inverse CDF of a uniform;
* IBC's Langevin steps: neither PyTorch exporter handles autograd, so the energy
  MLP carries its gradient written out by hand (``EnergyMlp.grad``);
* DDPM: ``torch.full((B,), t)`` timesteps, one slice of `noise` per step;
* BESO: Karras sigmas, a DDIM-style sampler and the action context (the agent's
  own previous actions, the evaluator's ``prev_actions`` input).

Requires torch only to build and export (the ``export`` extra:
``pip install 'd3il-client[export]'``); nothing here is needed at evaluation.
``scripts/make_agent_fixtures.py`` builds the agent fixtures with these blocks.
"""

import math

import torch
from torch import nn

SQRT2 = math.sqrt(2.0)


def uniform_from_noise(n):
    """U(0, 1) samples from N(0, 1) samples: the standard normal CDF Φ(n)."""
    return 0.5 * (1.0 + torch.erf(n / SQRT2))


def categorical_inverse_cdf(probs, u):
    """One-hot sample of a categorical distribution `probs` [B, n] from uniforms
    `u` [B]: the first bin whose cumulative probability reaches u.
    """
    n = probs.shape[-1]
    cdf = probs.cumsum(-1)
    idx = (cdf < u.unsqueeze(-1)).to(torch.int64).sum(-1).clamp(max=n - 1)
    return (torch.arange(n).unsqueeze(0) == idx.unsqueeze(-1)).to(probs.dtype)


def onehot_argmin(e):
    """One-hot of the smallest entry along the last axis ([B, S] -> [B, S])."""
    s = e.shape[-1]
    return (torch.arange(s).unsqueeze(0) == e.argmin(-1, keepdim=True)).to(e.dtype)


class EnergyMlp(nn.Module):
    """IBC's energy E(o, a) = w3 · relu(W2 relu(W1 [o; a] + b1) + b2) + b3 with its
    gradient with respect to a written out by hand (the exporters trace no autograd).
    """

    def __init__(self, obs_dim, act_dim, hidden):
        super().__init__()
        self.obs_dim = obs_dim
        self.l1 = nn.Linear(obs_dim + act_dim, hidden)
        self.l2 = nn.Linear(hidden, hidden)
        self.l3 = nn.Linear(hidden, 1)

    def _pre(self, o, a):
        w1o = self.l1.weight[:, : self.obs_dim]
        w1a = self.l1.weight[:, self.obs_dim :]
        # o: [B, obs] broadcast over the S samples of a: [B, S, act]
        p1 = (o @ w1o.t()).unsqueeze(1) + a @ w1a.t() + self.l1.bias
        h1 = torch.relu(p1)
        p2 = self.l2(h1)
        return p1, h1, p2

    def forward(self, o, a):
        _, _, p2 = self._pre(o, a)
        return self.l3(torch.relu(p2)).squeeze(-1)

    def grad(self, o, a):
        """dE/da, [B, S, act]."""
        p1, _, p2 = self._pre(o, a)
        d2 = self.l3.weight[0] * (p2 > 0).to(a.dtype)  # dE/dp2
        d1 = (d2 @ self.l2.weight) * (p1 > 0).to(a.dtype)  # dE/dp1
        return d1 @ self.l1.weight[:, self.obs_dim :]


def langevin(energy, o, a, noise, steps, lr, scale, lo, hi):
    """`steps` Langevin steps a <- clip(a - lr ∇E + scale·noise_i); noise [B, steps, S, act]."""
    for i in range(steps):
        a = (a - lr * energy.grad(o, a) + scale * noise[:, i]).clamp(lo, hi)
    return a


class SinusoidalEmbedding(nn.Module):
    """Timestep / noise-level embedding [B] -> [B, d]."""

    def __init__(self, d):
        super().__init__()
        half = d // 2
        self.register_buffer("freqs", torch.exp(-math.log(10000.0) * torch.arange(half) / half))

    def forward(self, t):
        args = t.unsqueeze(-1) * self.freqs.unsqueeze(0)
        return torch.cat([args.sin(), args.cos()], dim=-1)


class DdpmSchedule(nn.Module):
    """Linear-beta DDPM ancestral sampler over N steps. `noise` [B, N, *x] holds x_T
    in slice 0 and the noise of step t in slice N - t.
    """

    def __init__(self, n, beta_1=1e-4, beta_n=0.02):
        super().__init__()
        self.n = n
        betas = torch.linspace(beta_1, beta_n, n)
        alphas = 1.0 - betas
        abar = torch.cumprod(alphas, 0)
        abar_prev = torch.cat([torch.ones(1), abar[:-1]])
        self.betas = betas.tolist()
        self.alphas = alphas.tolist()
        self.abar = abar.tolist()
        self.sigmas = (betas * (1 - abar_prev) / (1 - abar)).sqrt().tolist()

    def sample(self, denoiser, noise):
        x = noise[:, 0]
        b = x.shape[0]
        for i, t in enumerate(reversed(range(self.n))):
            # As the reference agents do: a [B] tensor of the current timestep.
            tt = torch.full((b,), float(t))
            eps = denoiser(x, tt)
            x = (x - self.betas[t] / math.sqrt(1.0 - self.abar[t]) * eps) / math.sqrt(self.alphas[t])
            if t > 0:
                x = x + self.sigmas[t] * noise[:, i + 1]
        return x


class KarrasSampler(nn.Module):
    """BESO's sampling: Karras et al. noise levels, preconditioned denoiser, DDIM-style
    deterministic steps. The action context (previous actions, [B, T-1, act]) is
    prepended to the noisy current action, as BESO's `predict` does.
    """

    def __init__(self, steps, sigma_min, sigma_max, sigma_data, rho=7.0):
        super().__init__()
        ramp = torch.linspace(0, 1, steps)
        lo, hi = sigma_min ** (1 / rho), sigma_max ** (1 / rho)
        self.sigmas = ((hi + ramp * (lo - hi)) ** rho).tolist() + [0.0]
        self.sigma_data = sigma_data

    def denoise(self, model, x, sigma):
        sd = self.sigma_data
        c_skip = sd**2 / (sigma**2 + sd**2)
        c_out = sigma * sd / math.sqrt(sigma**2 + sd**2)
        c_in = 1.0 / math.sqrt(sigma**2 + sd**2)
        s = torch.full((x.shape[0],), sigma)
        return c_skip * x + c_out * model(c_in * x, s)

    def sample(self, model, context, noise):
        x = torch.cat([context, noise * self.sigmas[0]], dim=1)
        for s, s_next in zip(self.sigmas[:-1], self.sigmas[1:], strict=True):
            d = self.denoise(model, x, s)
            x = d + (s_next / s) * (x - d)
        return x
