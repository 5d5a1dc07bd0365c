#!/usr/bin/env python3
"""Build the agent fixtures in assets/fixtures/agents/ the way researchers make them.

Usage:  pip install "./clients/python[export,serve]" ; python3 scripts/make_agent_fixtures.py [outdir]

Each fixture is OUR OWN small PyTorch module with the structure of one D3IL method
family (the reference agents' classes are not copied; sizes are tiny so the files
stay small). The whole `predict` path (window, sampling loop) is one graph whose
randomness comes from the `noise` input (docs/export.md), exported with
`torch.onnx.export`. Weights are random (fixed seeds), scaled so actions stay a few
millimetres per step: the fixtures test that every method family loads, runs and
matches onnxruntime, not that it solves the task.

For every fixture the script writes
  NAME.onnx      the model
  NAME.json      its manifest (docs/submission.md)
  NAME.ort.json  inputs and onnxruntime's outputs on them (batch 4 and, for window
                 `grow` models, every window length 1..k), so the Rust tests compare
                 tract with onnxruntime without needing onnxruntime or torch.

The recipes (Φ(noise) for uniforms, inverse-CDF categorical sampling, IBC's
hand-written gradient, DDPM timesteps, BESO's action context) live in
d3il_client.export (clients/python) and are documented in docs/export.md.
"""

import json
import math
import os
import sys

import numpy as np
import torch
from torch import nn

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "clients", "python"))
from d3il_client import export as rx  # noqa: E402

OBS = 20  # Aligning policy observation (docs/submission.md)
ACT = 3
ACT_SCALE = 0.005  # metres per step: keeps random policies near the box
OPSET = 18  # Mish is an opset-18 operator


def mlp(sizes, act=nn.ReLU, last_act=False):
    layers = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2 or last_act:
            layers.append(act())
    return nn.Sequential(*layers)


class SelfAttention(nn.Module):
    """One pre-norm transformer block (GPT style), optional causal mask."""

    def __init__(self, d, heads=2, causal=False, max_len=16):
        super().__init__()
        self.d, self.h, self.causal = d, heads, causal
        self.ln1 = nn.LayerNorm(d)
        self.qkv = nn.Linear(d, 3 * d)
        self.proj = nn.Linear(d, d)
        self.ln2 = nn.LayerNorm(d)
        self.ff = nn.Sequential(nn.Linear(d, 2 * d), nn.GELU(), nn.Linear(2 * d, d))
        self.register_buffer("mask", torch.tril(torch.ones(max_len, max_len)))

    def forward(self, x):
        b, t, d = x.shape
        q, k, v = self.qkv(self.ln1(x)).split(d, dim=-1)
        hd = d // self.h
        q = q.reshape(b, t, self.h, hd).transpose(1, 2)
        k = k.reshape(b, t, self.h, hd).transpose(1, 2)
        v = v.reshape(b, t, self.h, hd).transpose(1, 2)
        att = (q @ k.transpose(-2, -1)) / math.sqrt(hd)
        if self.causal:
            att = att.masked_fill(self.mask[:t, :t] == 0, float("-inf"))
        y = (att.softmax(-1) @ v).transpose(1, 2).reshape(b, t, d)
        x = x + self.proj(y)
        return x + self.ff(self.ln2(x))


# ---------------------------------------------------------------- BC (MLP) ----
class BcMlp(nn.Module):
    """BC-MLP: k = 1, H = 1, normalisation baked in."""

    def __init__(self):
        super().__init__()
        self.register_buffer("obs_mean", torch.randn(OBS) * 0.1)
        self.register_buffer("obs_std", torch.rand(OBS) + 0.5)
        self.net = mlp([OBS, 64, 64, ACT])

    def forward(self, obs):
        x = (obs[:, -1] - self.obs_mean) / self.obs_std
        return torch.tanh(self.net(x)) * ACT_SCALE


# ------------------------------------------------------ VAE-ACT (decoder) ----
class VaeAct(nn.Module):
    """VAE decoder with an action chunk: z ~ N(0, I) from `noise`, H = E = 3."""

    H, Z = 3, 8

    def __init__(self):
        super().__init__()
        self.dec = mlp([OBS + self.Z, 64, 64, self.H * ACT])

    def forward(self, obs, noise):
        x = torch.cat([obs[:, -1], noise], dim=1)
        return (torch.tanh(self.dec(x)) * ACT_SCALE).reshape(obs.shape[0], self.H, ACT)


# -------------------------------------------------------------- BeT (GPT) ----
class Bet(nn.Module):
    """BeT: causal transformer over a growing window (k = 5), action bins + offsets,
    bin drawn by inverse CDF of Φ(noise)."""

    K, BINS, D = 5, 8, 32

    def __init__(self):
        super().__init__()
        self.inp = nn.Linear(OBS, self.D)
        self.pos = nn.Parameter(torch.randn(1, self.K, self.D) * 0.1)
        self.block = SelfAttention(self.D, causal=True, max_len=self.K)
        self.logits = nn.Linear(self.D, self.BINS)
        self.offsets = nn.Linear(self.D, self.BINS * ACT)
        self.register_buffer("centers", torch.randn(self.BINS, ACT) * ACT_SCALE)

    def forward(self, obs, noise):
        t = obs.shape[1]
        x = self.block(self.inp(obs) + self.pos[:, :t])
        last = x[:, -1]
        probs = self.logits(last).softmax(-1)
        onehot = rx.categorical_inverse_cdf(probs, rx.uniform_from_noise(noise[:, 0]))
        offs = self.offsets(last).reshape(-1, self.BINS, ACT) * (0.2 * ACT_SCALE)
        return onehot @ self.centers + (onehot.unsqueeze(-1) * offs).sum(1)


# --------------------------------------------------------------------- IBC ----
class Ibc(nn.Module):
    """IBC: energy MLP, uniform initial samples, Langevin steps with the
    hand-written gradient, the lowest-energy sample is the action."""

    S, STEPS, HID = 64, 12, 64

    def __init__(self):
        super().__init__()
        self.energy = rx.EnergyMlp(OBS, ACT, self.HID)
        self.lo, self.hi = -1.0, 1.0

    def forward(self, obs, noise):
        # noise: [B, STEPS + 1, S, ACT]; the first slice gives the initial samples.
        o = obs[:, -1]
        a = self.lo + (self.hi - self.lo) * rx.uniform_from_noise(noise[:, 0])
        a = rx.langevin(self.energy, o, a, noise[:, 1:], self.STEPS, lr=0.05, scale=0.1,
                        lo=self.lo, hi=self.hi)
        e = self.energy(o, a)  # [B, S]
        best = rx.onehot_argmin(e)
        return (best.unsqueeze(-1) * a).sum(1) * ACT_SCALE


# ---------------------------------------------------------------- DDPM-MLP ----
class DdpmMlpDenoiser(nn.Module):
    def __init__(self, x_dim, cond_dim):
        super().__init__()
        self.temb = rx.SinusoidalEmbedding(8)
        self.net = mlp([x_dim + 8 + cond_dim, 64, 64, x_dim], act=nn.Mish)

    def forward(self, x, t, cond):
        return self.net(torch.cat([x, self.temb(t), cond], dim=1))


class DdpmMlp(nn.Module):
    """DDPM with an MLP denoiser, k = 1, H = 1, timesteps as torch.full((B,), t)."""

    N = 16

    def __init__(self):
        super().__init__()
        self.den = DdpmMlpDenoiser(ACT, OBS)
        self.sched = rx.DdpmSchedule(self.N)

    def forward(self, obs, noise):
        o = obs[:, -1]
        x = self.sched.sample(lambda x, t: self.den(x, t, o), noise)
        return x.clamp(-1, 1) * ACT_SCALE


# -------------------------------------------------------- DDPM-Transformer ----
class TransformerDenoiser(nn.Module):
    """Tokens: [time, obs_1..obs_T, act_1..act_H] -> denoised action tokens."""

    def __init__(self, d, n_obs, n_act):
        super().__init__()
        self.temb = rx.SinusoidalEmbedding(d)
        self.obs_in = nn.Linear(OBS, d)
        self.act_in = nn.Linear(ACT, d)
        self.pos = nn.Parameter(torch.randn(1, 1 + n_obs + n_act, d) * 0.1)
        self.block = SelfAttention(d, max_len=1 + n_obs + n_act)
        self.out = nn.Linear(d, ACT)

    def forward(self, x, t, obs):
        h = x.shape[1]
        tok = torch.cat([self.temb(t).unsqueeze(1), self.obs_in(obs), self.act_in(x)], dim=1)
        tok = tok + self.pos[:, : tok.shape[1]]
        return self.out(self.block(tok)[:, -h:])


class DdpmTransformer(nn.Module):
    """DDPM-Transformer: k = 5 (padded window), H = 4, E = 1."""

    N, K, H = 16, 5, 4

    def __init__(self):
        super().__init__()
        self.den = TransformerDenoiser(32, self.K, self.H)
        self.sched = rx.DdpmSchedule(self.N)

    def forward(self, obs, noise):
        x = self.sched.sample(lambda x, t: self.den(x, t, obs), noise)
        return x.clamp(-1, 1) * ACT_SCALE


class DdpmAct(nn.Module):
    """DDPM-ACT: k = 1, H = E = 10, transformer over the chunk."""

    N, H = 16, 10

    def __init__(self):
        super().__init__()
        self.den = TransformerDenoiser(32, 1, self.H)
        self.sched = rx.DdpmSchedule(self.N)

    def forward(self, obs, noise):
        x = self.sched.sample(lambda x, t: self.den(x, t, obs), noise)
        return x.clamp(-1, 1) * ACT_SCALE


# -------------------------------------------------------------------- BESO ----
class BesoDenoiser(nn.Module):
    """GPT-style score transformer over [sigma, obs_1..obs_T, act_1..act_T]."""

    def __init__(self, d, k):
        super().__init__()
        self.semb = rx.SinusoidalEmbedding(d)
        self.obs_in = nn.Linear(OBS, d)
        self.act_in = nn.Linear(ACT, d)
        self.pos = nn.Parameter(torch.randn(1, 1 + 2 * k, d) * 0.1)
        self.block = SelfAttention(d, causal=True, max_len=1 + 2 * k)
        self.out = nn.Linear(d, ACT)

    def forward(self, x, sigma, obs):
        t = x.shape[1]
        tok = torch.cat(
            [self.semb(sigma.log() / 4).unsqueeze(1), self.obs_in(obs), self.act_in(x)], dim=1
        )
        tok = tok + self.pos[:, : tok.shape[1]]
        return self.out(self.block(tok)[:, -t:])


class Beso(nn.Module):
    """BESO: growing window k = 5, the agent's own previous actions as action
    context (`prev_actions`, [B, T-1, 3]), Karras sigmas, DDIM-style sampler."""

    K, STEPS = 5, 4

    def __init__(self):
        super().__init__()
        self.den = BesoDenoiser(32, self.K)
        self.sampler = rx.KarrasSampler(self.STEPS, sigma_min=0.001, sigma_max=1.0, sigma_data=0.5)

    def forward(self, obs, prev_actions, noise):
        # The model works in normalised action space; prev_actions are the
        # executed (de-normalised) actions, so scale them back.
        ctx = prev_actions / ACT_SCALE
        x = self.sampler.sample(lambda x, s: self.den(x, s, obs), ctx, noise)
        return x[:, -1].clamp(-1, 1) * ACT_SCALE


# -------------------------------------------------------------- the list ----
FIXTURES = [
    # name, module, manifest extras, noise shape (non-batch), inputs, window
    ("bc_mlp", BcMlp, dict(history=1, horizon=1, execute=1), None, "pad"),
    ("vae_act", VaeAct, dict(history=1, horizon=3, execute=3), [VaeAct.Z], "pad"),
    ("bet", Bet, dict(history=5, horizon=1, execute=1), [1], "grow"),
    ("ibc", Ibc, dict(history=1, horizon=1, execute=1), [Ibc.STEPS + 1, Ibc.S, ACT], "pad"),
    ("ddpm_mlp", DdpmMlp, dict(history=1, horizon=1, execute=1), [DdpmMlp.N, ACT], "pad"),
    (
        "ddpm_transformer",
        DdpmTransformer,
        dict(history=5, horizon=4, execute=1),
        [DdpmTransformer.N, DdpmTransformer.H, ACT],
        "pad",
    ),
    ("ddpm_act", DdpmAct, dict(history=1, horizon=10, execute=10), [DdpmAct.N, DdpmAct.H, ACT], "pad"),
    ("beso", Beso, dict(history=5, horizon=1, execute=1), [1, ACT], "grow"),
]


def export(name, module, man, noise_dims, window, outdir):
    torch.manual_seed(sum(map(ord, name)))
    m = module().eval()
    k = man["history"]
    names = ["obs"]
    dyn = {"obs": {0: "B"}}
    if window == "grow":
        dyn["obs"][1] = "T"
    prev = name == "beso"
    if prev:
        names.append("prev_actions")
        dyn["prev_actions"] = {0: "B", 1: "P"}
    if noise_dims is not None:
        names.append("noise")
        dyn["noise"] = {0: "B"}
    dyn["actions"] = {0: "B"}

    def example(b, t):
        g = torch.Generator().manual_seed(1000 * b + t)
        x = [torch.randn(b, t, OBS, generator=g)]
        if prev:
            x.append(torch.randn(b, t - 1, ACT, generator=g) * ACT_SCALE)
        if noise_dims is not None:
            x.append(torch.randn(b, *noise_dims, generator=g))
        return x

    # Export at a window of k (or 3 for grow) so no dimension is specialised to 1.
    ex = example(2, 3 if window == "grow" else k)
    path = os.path.join(outdir, f"{name}.onnx")
    with torch.no_grad():
        torch.onnx.export(
            m, tuple(ex), path, input_names=names, output_names=["actions"],
            dynamic_axes=dyn, opset_version=OPSET, dynamo=False,
        )
    manifest = {"task": "aligning", "obs_type": "state", **man, "window": window}
    with open(os.path.join(outdir, f"{name}.json"), "w") as f:
        json.dump(manifest, f, indent=2)
        f.write("\n")

    import onnxruntime as ort

    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    cases = []
    for t in (range(1, k + 1) if window == "grow" else [k]):
        ins = example(4, t)
        feed = {n: v.numpy() for n, v in zip(names, ins)}
        (out,) = sess.run(None, feed)
        with torch.no_grad():
            ref = m(*ins).numpy()
        assert np.allclose(out, ref, atol=1e-5), (name, t, np.abs(out - ref).max())
        cases.append(
            {
                "window": t,
                "inputs": {n: {"shape": list(v.shape), "data": v.reshape(-1).tolist()} for n, v in feed.items()},
                "actions": {"shape": list(out.shape), "data": out.reshape(-1).tolist()},
            }
        )
    with open(os.path.join(outdir, f"{name}.ort.json"), "w") as f:
        json.dump({"onnxruntime": ort.__version__, "torch": torch.__version__, "cases": cases}, f)
    size = os.path.getsize(path)
    print(f"{name:18s} {size / 1024:8.1f} KiB  window {window}  cases {len(cases)}")


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    outdir = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "assets", "fixtures", "agents")
    os.makedirs(outdir, exist_ok=True)
    only = set(sys.argv[2:])
    for name, module, man, noise, window in FIXTURES:
        if only and name not in only:
            continue
        export(name, module, man, noise, window, outdir)


if __name__ == "__main__":
    main()
