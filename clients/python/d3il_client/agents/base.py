"""What every agent family provides (docs/export.md, "Exporting an agent object").

A *family* knows one kind of D3IL reference agent (``BC_Agent``, ``BesoAgent``, …):
how to recognise the object, the settings its ``predict`` path runs with (window,
chunk, sampler), and a torch module that computes, for a whole batch of rollouts at
once, exactly what the agent's own ``predict`` computes for one, with every random
draw taken from an explicit ``noise`` tensor. That one module is used three ways:

* exported to ONNX (``d3il_client.agents.export_agent``): the evaluator fills
  ``noise`` from its seeded stream, so an evaluation is reproducible bit for bit;
* run in torch on the stacked batch of a remote request (``d3il_client.serve``),
  with ``noise`` drawn from a seeded torch generator;
* checked against the agent's own ``predict`` (``d3il_client.agents.check``): the
  agent is run with torch's random functions patched to hand out, in call order,
  the draws ``Family.draws`` makes from the same noise row (:class:`Tape`).

Conventions of the batched module (``Family.graph(agent)``):

``forward(obs, prev_actions, noise)`` with

* ``obs``: float32 ``[B, w, obs_dim]``, the raw (unscaled) observations of the
  window, oldest first; w = k, or 1..k at episode start when ``window == "grow"``
  (the reference deques start empty at ``reset()``);
* ``prev_actions``: float32 ``[B, w − 1, act_dim]``, the raw actions the rollout
  executed before (what ``predict`` returned), or ``None`` when
  ``Settings.prev_actions`` is false;
* ``noise``: float32 ``[B, *Settings.noise_shape]`` of standard-normal samples, or
  ``None`` when ``Settings.noise_shape`` is ``None`` (deterministic families).
  Slice it with prefixes (``noise[:, i, :T]``), never ``noise[:, i, K - T:]``:
  tract cannot unify a symbolic window with a suffix slice.

and returns float32 ``[B, H, act_dim]`` raw actions (after the agent's clamps and
inverse scaling), H = ``Settings.horizon``. All shape arithmetic on the window must
stay symbolic under ``torch.onnx.export(dynamo=False)`` tracing (no Python ``int``
of a tensor size), the batch too.
"""

from __future__ import annotations

import contextlib
import dataclasses
from typing import Any, Callable, Iterator, List, Optional, Sequence, Tuple

import numpy as np
import torch

#: Family names, as the manifests and docs spell them.
FAMILY_NAMES = (
    "bc",  # BC (MLP): agents/bc_agent.py BC_Agent
    "vae_state",  # VAE-State / CVAE: agents/cvae_agent.py
    "vae_act",  # VAE-ACT: agents/act_agent.py
    "bet_mlp",  # BeT-MLP: agents/bet_mlp_agent.py
    "bet",  # BeT: agents/bet_agent.py
    "ibc",  # IBC: agents/ibc_agent.py
    "ddpm_mlp",  # DDPM-MLP: agents/ddpm_agent.py with an MLP
    "ddpm_gpt",  # DDPM-GPT (DDPM-Transformer): agents/ddpm_agent.py with a transformer
    "ddpm_act",  # DDPM-ACT (DDPM encoder-decoder): agents/ddpm_encdec_agent.py
    "beso",  # BESO: agents/beso_agent.py
    "bc_gpt",  # BC-GPT: agents/gpt_bc_agent.py
)


@dataclasses.dataclass(frozen=True)
class Settings:
    """How an agent's ``predict`` runs, read from the agent object itself."""

    family: str  # one of FAMILY_NAMES
    obs_dim: int
    act_dim: int
    history: int  # k: observations in the window
    window: str  # "grow" (deque empty at reset: 1..k) or "pad"
    horizon: int  # H: actions per model call
    execute: int  # E: actions executed from a chunk before the next call
    prev_actions: bool  # the module takes the previous actions (BESO's action context)
    noise_shape: Optional[Tuple[int, ...]]  # per-row shape of `noise`; None: deterministic
    sampler: str = ""  # human-readable sampler description for policy.json notes and logs

    def manifest(self, task: str) -> dict[str, Any]:
        """The policy.json of an export of this agent for ``task``."""
        return {
            "task": task,
            "obs_type": "state",
            "history": self.history,
            "horizon": self.horizon,
            "execute": self.execute,
            "window": self.window,
        }


class Family:
    """One D3IL method family. Subclasses set ``name`` and ``classes`` and implement
    ``settings``, ``graph`` and ``draws``.
    """

    #: One of FAMILY_NAMES.
    name: str = ""
    #: Class names of the reference agents this family recognises (the class or a base).
    classes: Tuple[str, ...] = ()

    def matches(self, agent: Any) -> bool:
        """Whether ``agent`` is one of this family's reference agents (by class name
        along its MRO, then ``accepts`` for families that share a class).
        """
        names = {c.__name__ for c in type(agent).__mro__}
        return bool(names & set(self.classes)) and self.accepts(agent)

    def accepts(self, agent: Any) -> bool:
        """Further test for families sharing a class (DDPM-MLP vs DDPM-GPT)."""
        return True

    def settings(self, agent: Any) -> Settings:
        """The settings the agent's own ``predict`` runs with, read from the object."""
        raise NotImplementedError

    def graph(self, agent: Any) -> torch.nn.Module:
        """The batched, traceable module of the agent's ``predict`` (module docstring)."""
        raise NotImplementedError

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        """The random draws the agent's own ``predict`` makes during one model call
        with a window of ``window`` observations, in call order, made from ONE row of
        the module's noise (``noise``: ``[*noise_shape]``), so that ``predict`` fed
        these draws computes what the module computes from that row.
        """
        raise NotImplementedError


@dataclasses.dataclass
class Draw:
    """One call of a torch random function and the value it must return.

    ``kind`` is the function's name: ``randn``, ``randn_like``, ``rand``,
    ``rand_like``, ``randint``, ``multinomial``, ``normal_`` or ``uniform_``
    (for ``Tensor.normal_`` / ``Tensor.uniform_``, filled in place), or
    ``numpy.random.uniform`` (IBC's initial samples; the call returns ``value`` as a
    float64 array, as numpy does).
    """

    kind: str
    value: torch.Tensor
    #: For a draw whose result depends on the call's arguments (``multinomial``: the bin
    #: depends on the probabilities predict() computes): called with the call's
    #: arguments, it returns what the call returns; ``value`` is then the noise the
    #: result is made from. None: the call returns ``value`` (every other kind).
    given: Optional[Callable[..., torch.Tensor]] = None


class TapeError(AssertionError):
    """The agent's predict drew differently from what its family says."""


class Tape:
    """Patches torch's random functions so that they return the given draws in order.

    Used by the check: ``with Tape(draws): agent.predict(obs)``. A call of another
    kind or shape than the next draw, a draw left over, or a call past the end raise
    :class:`TapeError` naming the call.
    """

    PATCHED = ("randn", "randn_like", "rand", "rand_like", "randint", "multinomial")

    def __init__(self, draws: Sequence[Draw]) -> None:
        self.draws = list(draws)
        self.pos = 0

    def _next(self, kind: str, shape: Optional[Sequence[int]]) -> torch.Tensor:
        if self.pos >= len(self.draws):
            raise TapeError(f"predict() called torch.{kind}{tuple(shape or ())} after all {len(self.draws)} draws")
        d = self.draws[self.pos]
        if d.kind != kind or (shape is not None and tuple(d.value.shape) != tuple(shape)):
            raise TapeError(
                f"draw {self.pos}: predict() called torch.{kind}{tuple(shape or ())}, "
                f"the family expected torch.{d.kind}{tuple(d.value.shape)}"
            )
        self.pos += 1
        return d.value.clone()

    @staticmethod
    def _shape(args: Tuple[Any, ...], kwargs: dict[str, Any]) -> Tuple[int, ...]:
        size = kwargs.get(
            "size", args[0] if len(args) == 1 and isinstance(args[0], (tuple, list, torch.Size)) else args
        )
        return tuple(int(s) for s in size)

    @contextlib.contextmanager
    def active(self) -> Iterator[Tape]:
        """Patch, run the body, unpatch; then check every draw was used."""
        saved = {n: getattr(torch, n) for n in self.PATCHED}
        saved_normal, saved_uniform = torch.Tensor.normal_, torch.Tensor.uniform_
        saved_np_uniform = np.random.uniform

        def like(kind: str) -> Callable[..., torch.Tensor]:
            return lambda t, *a, **k: self._next(kind, t.shape).to(t.dtype)

        def fresh(kind: str) -> Callable[..., torch.Tensor]:
            def f(*a: Any, **k: Any) -> torch.Tensor:
                dt = k.get("dtype")
                v = self._next(kind, self._shape(a, {x: y for x, y in k.items() if x == "size"}))
                return v if dt is None else v.to(dt)

            return f

        def randint(*a: Any, **k: Any) -> torch.Tensor:
            return self._next("randint", tuple(k.get("size", a[-1])))

        def multinomial(p: torch.Tensor, *a: Any, **k: Any) -> torch.Tensor:
            d = self.draws[self.pos] if self.pos < len(self.draws) else None
            v = self._next("multinomial", None)
            return d.given(p, *a, **k) if d is not None and d.given is not None else v

        def np_uniform(low: Any = 0.0, high: Any = 1.0, size: Any = None) -> Any:
            shape = () if size is None else (tuple(size) if isinstance(size, (tuple, list)) else (int(size),))
            return self._next("numpy.random.uniform", shape).numpy().astype(np.float64)

        def in_place(kind: str) -> Callable[..., torch.Tensor]:
            def f(t: torch.Tensor, *a: Any, **k: Any) -> torch.Tensor:
                with torch.no_grad():
                    t.copy_(self._next(kind, t.shape))
                return t

            return f

        try:
            torch.randn = fresh("randn")
            torch.rand = fresh("rand")
            torch.randn_like = like("randn_like")
            torch.rand_like = like("rand_like")
            torch.randint = randint
            torch.multinomial = multinomial
            torch.Tensor.normal_ = in_place("normal_")
            torch.Tensor.uniform_ = in_place("uniform_")
            np.random.uniform = np_uniform
            yield self
        finally:
            for n, f in saved.items():
                setattr(torch, n, f)
            torch.Tensor.normal_ = saved_normal
            torch.Tensor.uniform_ = saved_uniform
            np.random.uniform = saved_np_uniform
        if self.pos != len(self.draws):
            raise TapeError(f"predict() made {self.pos} draws, the family expected {len(self.draws)}")


def uniform_from_noise(n: torch.Tensor) -> torch.Tensor:
    """U(0, 1) samples from N(0, 1) samples: the standard normal CDF Φ(n)."""
    return 0.5 * (1.0 + torch.erf(n / 1.4142135623730951))


def inverse_cdf_index(probs: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """The bin a categorical distribution ``probs`` [..., n] gives for uniforms ``u``
    [...]: the first bin whose cumulative probability reaches u (the last bin when
    rounding leaves the total below u). Counting only the first n − 1 cumulative sums
    keeps the index below n without a clamp, so the same arithmetic exports.
    """
    cdf = probs.cumsum(-1)[..., :-1]
    return (cdf < u.unsqueeze(-1)).to(torch.int64).sum(-1)


def multinomial_draw(u: torch.Tensor) -> Draw:
    """The draw of ``torch.multinomial(probs, 1)`` (probs [rows, n]) made by inverse CDF
    from the uniforms ``u`` [rows]: returns [rows, 1] indices as torch does.
    """

    def given(p: torch.Tensor, *a: Any, **k: Any) -> torch.Tensor:
        n = k.get("num_samples", a[0] if a else 1)
        if n != 1:
            raise TapeError(f"predict() called torch.multinomial with num_samples={n}; the family draws one")
        return inverse_cdf_index(p, u.to(p.dtype).reshape(p.shape[:-1])).unsqueeze(-1)

    return Draw("multinomial", u, given=given)
