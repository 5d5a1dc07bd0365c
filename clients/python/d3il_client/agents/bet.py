"""BeT: ``BeT_Agent`` of agents/bet_agent.py in the D3IL reference.

Its ``predict(state)``, step by step:

1. ``state`` [obs_dim] -> float32 [1, obs_dim]; ``scaler.scale_input`` (with the 1e-12);
2. appended to ``obs_context``, a deque of ``maxlen = window_size`` that ``reset()``
   empties: the window grows 1, 2, …, k at episode start;
3. the deque stacked on dim 0, [T, 1, obs_dim], through ``self.model``
   (``BeT_Policy``: ``obs_encoder`` (Identity), then the latent generator's
   ``generate_latents``, which reads it as (seq, batch, embed) and runs its minGPT on
   [1, T, obs_dim]); the GPT's output per position is V bin logits followed by V × act
   offsets (``"N T (V A) -> (N T) V A"``);
4. ``probs = softmax(logits)`` (no temperature) and ``torch.multinomial(probs.view(-1,
   V), num_samples=1)``: one bin drawn for EVERY position of the window (T draws), each
   with that bin's offset;
5. only the last position is kept: ``action_ae.decode_actions`` gives
   ``bin_centers[bin] + offset`` (the k-means centres fitted on the scaled training
   actions, ``KMeansDiscretizer.bin_centers``);
6. ``clamp_(self.min_action, self.max_action)``: the scaled data bounds
   (``scaler.y_bounds``, float64, not × 1.1); ``scaler.inverse_scale_output``;
   returns [1, act_dim] (``sample=False``, as the simulations call it).

One action per call (H = E = 1). The module does the same for a batch of windows
[B, T, obs] with the agent's own policy network and bins: it runs the minGPT of the
latent generator on the scaled window, takes the last position, and picks the bin by
inverse CDF of ``u = Φ(noise[:, 0])`` over ``softmax(logits)`` (the same distribution as
``torch.multinomial``). ``noise`` is [B, 1]. The check hands ``predict``'s
``torch.multinomial`` call the bins the same inverse CDF gives from the same ``u`` on
the probabilities predict itself computed (every row gets ``u``; only the last row is
used).

Tracing: the minGPT takes ``B, T, C = x.size()`` and ``t = idx.size()[1]`` in Python,
slices ``pos_emb[:, :t]`` and ``mask[:, :, :T, :T]`` and reshapes with them; the
TorchScript tracer records these as shape operations of the input, so the graph traced
at window k is correct at every window (tested at 1..k in onnxruntime). The sampling
(``einops.rearrange`` with Python ints, ``torch.arange(offsets.shape[0])``, the index
by ``sampled.flatten()``) is not traced: the module does it itself with a gather.
"""

from __future__ import annotations

from typing import Any, List, Optional

import torch

from .base import Draw, Family, Settings, inverse_cdf_index, multinomial_draw, uniform_from_noise
from .gpt_bc import is_visual, window_of
from .scaling import ClampedScaledGraph, ScalerArithmetic, unwrap


def latent_generator(agent: Any) -> Any:
    """The policy's latent generator (``BeT_Policy.model``, the BeT ``MinGPT``)."""
    return unwrap(agent.model).model


class BetGraph(ClampedScaledGraph):
    """[B, T, obs] raw observations, [B, 1] noise -> [B, 1, act] raw actions, as BeT_Agent.predict."""

    def __init__(self, agent: Any) -> None:
        super().__init__(agent)
        policy = unwrap(agent.model)
        gen = policy.model
        if not getattr(gen, "predict_offsets", False):
            raise ValueError(
                "this BeT's latent generator has predict_offsets=False; the reference predict() then fails "
                "(it unpacks offsets), so there is no predict to export"
            )
        self.encoder = policy.obs_encoder
        self.gpt = gen.model
        self.vocab = int(gen.vocab_size)
        self.act_dim = int(gen.action_dim)
        self.register_buffer("centers", torch.as_tensor(agent.action_ae.bin_centers).detach().cpu().clone())

    def forward(
        self, obs: torch.Tensor, prev_actions: Optional[torch.Tensor] = None, noise: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """Raw actions [B, 1, act] for raw windows [B, T, obs] (module docstring)."""
        assert noise is not None
        x = self.encoder(self.scaler.scale_input(obs))
        out, _ = self.gpt(x, None)  # [B, T, V (1 + A)]
        last = out[:, -1, :]
        logits = last[:, : self.vocab]
        offsets = last[:, self.vocab :].reshape(-1, self.vocab, self.act_dim)  # [B, V, A]
        probs = torch.softmax(logits, dim=-1)
        idx = inverse_cdf_index(probs, uniform_from_noise(noise[:, 0]))  # [B]
        center = self.centers.index_select(0, idx).unsqueeze(1)  # [B, 1, A]
        # [B, 1, A] without a squeeze: the exporter writes squeeze(1) of a dynamic shape as an If
        offset = torch.gather(offsets, 1, idx.reshape(-1, 1, 1).expand(-1, 1, self.act_dim))
        return self.clamp_unscale(center + offset)


class BetFamily(Family):
    """BeT (module docstring)."""

    name = "bet"
    classes = ("BeT_Agent",)

    def accepts(self, agent: Any) -> bool:
        """State agents only: the vision variants share the class name."""
        return not is_visual(agent)

    def settings(self, agent: Any) -> Settings:
        """The window k from the deque, H = E = 1."""
        sc = ScalerArithmetic(agent.scaler)
        gen = latent_generator(agent)
        return Settings(
            family=self.name,
            obs_dim=sc.obs_dim,
            act_dim=sc.act_dim,
            history=window_of(agent),
            window="grow",
            horizon=1,
            execute=1,
            prev_actions=False,
            noise_shape=(1,),
            sampler=(
                f"GPT over the growing window; bin of the last position ~ softmax of {int(gen.vocab_size)} logits "
                "(inverse CDF of Φ(noise[:, 0]), torch.multinomial in predict), k-means centre + the bin's offset, "
                "clamped to the data bounds"
            ),
        )

    def graph(self, agent: Any) -> torch.nn.Module:
        """The batched module of predict, on the agent's own networks."""
        return BetGraph(agent)

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """One torch.multinomial call of ``window`` rows, each given u = Φ(noise[0])."""
        u = uniform_from_noise(noise.reshape(1)[:1])
        return [multinomial_draw(u.expand(window).clone())]


FAMILY = BetFamily()
