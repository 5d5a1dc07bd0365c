"""Serve a D3IL reference agent unchanged (docs/export.md, docs/remote-protocol.md).

The reference agents keep their own state: `reset()` clears their observation and
action deques, `predict(obs)` takes ONE observation (the newest, a 1-D array), pushes
it into their deques, runs the model and returns one action. `serve_agent` puts such
an object behind the remote protocol:

    from d3il_client.serve import serve_agent
    serve_agent(my_trained_agent, port=8765)     # deep-copied once per rollout
    # or: serve_agent(lambda: build_agent(cfg), port=8765)   # a factory

From the shell: `python -m d3il_client.serve --agent my_module:make_agent
--checkpoint ckpt.pth --task aligning` (docs/remote-protocol.md).

The endpoint announces history = horizon = execute = 1: the evaluator sends the newest
observation of every live rollout and the server keeps, per rollout, what the agent
would keep (windows growing from empty exactly as in the reference evaluation). The
returned action is the task's policy action (e.g. Aligning's Δ desired xyz,
docs/submission.md). Two ways, chosen by `make_adapter`:

* **Batched** (`BatchedAgentAdapter`), for an agent of one of the D3IL families
  `d3il_client.agents.recognise` knows (needs torch): each rollout keeps its own
  observation window, the actions it executed and its queue of actions (a chunk of
  H from one model call, E of them executed), and the rollouts of a request that need
  a new chunk are stacked and run through the family's batched module
  (`family.graph(agent)`, the same module the ONNX export traces) in ONE call per
  window length: while windows grow at episode start (1..k) rollouts at different
  steps have different window lengths, and the module takes one length per call, so
  such a request makes one call per length present. Every random number comes from
  the module's `noise` input, drawn per rollout and step from a `torch.Generator`
  seeded with (the evaluator's spec seed, rollout id, step): the same evaluation gives
  the same actions whatever the batching.
* **Per rollout** (`AgentAdapter`), for any other object with `reset()` and
  `predict(obs)`: one deep copy per rollout and one `predict` per rollout and step
  (the agent's own chunking stays inside `predict`). Faithful for anything, but a
  request costs batch × predict: a BESO-sized agent takes seconds per request.
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import hashlib
import struct
import sys
import time
from typing import IO, Any, Callable, Deque, Dict, List, Mapping, Optional, Tuple, Union

import numpy as np

from .. import tasks
from .policy import PolicyServer, Request, serve


class AgentAdapter:
    """A policy callable for `PolicyServer` made of one agent per rollout.

    `agent` is an object with `reset()` and `predict(obs)`, deep-copied for every
    rollout, or a zero-argument factory returning a fresh one.
    """

    def __init__(self, agent: Any, predict_kwargs: Optional[Mapping[str, Any]] = None) -> None:
        self._make: Callable[[], Any]
        if hasattr(agent, "predict"):
            self._make = lambda: copy.deepcopy(agent)
        elif callable(agent):
            self._make = agent
        else:
            raise TypeError("agent must have reset() and predict(obs), or be a factory returning one")
        self.predict_kwargs = dict(predict_kwargs or {})
        self.agents: Dict[int, Any] = {}

    def _fresh(self, rid: int) -> Any:
        a = self._make()
        a.reset()
        self.agents[rid] = a
        return a

    def reset(self, rollout_ids: np.ndarray) -> None:
        """New episodes: every named rollout gets a freshly reset agent state."""
        for rid in rollout_ids:
            self._fresh(int(rid))

    def forget(self, rollout_ids: np.ndarray) -> None:
        """Ended episodes: their agent copies are freed."""
        for rid in rollout_ids:
            self.agents.pop(int(rid), None)

    def __call__(self, obs: np.ndarray, req: Request) -> np.ndarray:
        """One `predict` of each asking rollout's agent with its newest observation."""
        act_dim = int(req.spec["act_dim"])
        out = np.zeros((obs.shape[0], act_dim), np.float32)
        for r, rid in enumerate(req.rollout_ids):
            key = int(rid)
            agent = self.agents.get(key) or self._fresh(key)
            a = np.asarray(agent.predict(np.array(obs[r, -1], np.float32), **self.predict_kwargs), np.float32)
            a = a.reshape(-1)
            if a.size < act_dim:
                raise ValueError(f"the agent returned {a.size} numbers; the task's action has {act_dim}")
            out[r] = a[:act_dim]
        return out


def noise_seed(seed: int, rollout_id: int, step: int) -> int:
    """The torch.Generator seed of one rollout's model call at ``step``: a hash of
    (spec seed, rollout id, step), so a row's draws do not depend on its company.
    """
    key = struct.pack("<QQQ", seed & (2**64 - 1), rollout_id & (2**64 - 1), step & (2**64 - 1))
    return int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little") & (2**63 - 1)


def noise_for(shape: Tuple[int, ...], seed: int, rollout_id: int, step: int) -> Any:
    """Standard normal noise ``[*shape]`` (torch float32) of one rollout's model call."""
    import torch

    g = torch.Generator().manual_seed(noise_seed(seed, rollout_id, step))
    return torch.randn(shape, generator=g)


@dataclasses.dataclass
class _Rollout:
    """What one rollout keeps between requests (the agent's deques, served)."""

    obs: Deque[np.ndarray]  # the window, oldest first (at most k)
    first: Optional[np.ndarray]  # the episode's first observation (windows padded with it)
    actions: Deque[np.ndarray]  # the last k - 1 executed actions
    queue: Deque[np.ndarray]  # actions of the current chunk still to execute
    steps: int = 0


class BatchedAgentAdapter:
    """A policy callable for `PolicyServer` running a recognised reference agent's
    batched module: one model call per window length among the rollouts of a request
    that need a new chunk (module docstring).

    `family` defaults to `d3il_client.agents.recognise(agent)`; `module` to
    `family.graph(agent)`. `calls` counts the model calls made.
    """

    def __init__(self, agent: Any, family: Any = None, module: Any = None) -> None:
        import torch

        from ..agents import recognise

        self.family = family if family is not None else recognise(agent)
        self.settings = self.family.settings(agent)
        self.module = (module if module is not None else self.family.graph(agent)).eval()
        self.agent_class = type(agent).__name__
        self.rollouts: Dict[int, _Rollout] = {}
        self.calls = 0
        self._torch = torch

    def describe(self) -> str:
        """One line: the agent, its family and the settings it is served with."""
        s = self.settings
        return (
            f"{self.agent_class} recognised as {s.family}: window k {s.history} ({s.window}), "
            f"chunk H {s.horizon}, executed E {s.execute}{', ' + s.sampler if s.sampler else ''}; "
            "batched: one model call per request group"
        )

    def _fresh(self, rid: int) -> _Rollout:
        k = self.settings.history
        r = _Rollout(collections.deque(maxlen=k), None, collections.deque(maxlen=max(k - 1, 0)), collections.deque())
        self.rollouts[rid] = r
        return r

    def reset(self, rollout_ids: np.ndarray) -> None:
        """New episodes: empty windows, action histories and queues."""
        for rid in rollout_ids:
            self._fresh(int(rid))

    def forget(self, rollout_ids: np.ndarray) -> None:
        """Ended episodes: their windows and queues are freed."""
        for rid in rollout_ids:
            self.rollouts.pop(int(rid), None)

    def window(self, r: _Rollout) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        """The window [w, obs_dim] and previous actions [w - 1, act_dim] the module
        gets for rollout state `r` (as d3il_client.agents.check builds them).
        """
        s = self.settings
        obs = list(r.obs)
        if s.window != "grow" and len(obs) < s.history:
            assert r.first is not None
            obs = [r.first] * (s.history - len(obs)) + obs
        w = len(obs)
        prev = None
        if s.prev_actions:
            acts = list(r.actions)[max(0, len(r.actions) - (w - 1)) :]
            if len(acts) < w - 1:  # a padded window: no actions before the episode
                acts = [np.zeros(s.act_dim, np.float32)] * (w - 1 - len(acts)) + acts
            prev = np.stack(acts) if acts else np.zeros((0, s.act_dim), np.float32)
        return np.stack(obs), prev

    def __call__(self, obs: np.ndarray, req: Request) -> np.ndarray:
        """One action per asking rollout: from its queue, refilled by batched calls."""
        s = self.settings
        torch = self._torch
        act_dim = int(req.spec.get("act_dim", s.act_dim))
        if act_dim != s.act_dim or obs.shape[-1] != s.obs_dim:
            raise ValueError(
                f"the agent has observations of {s.obs_dim} and actions of {s.act_dim} numbers; "
                f"the task sends {obs.shape[-1]} and wants {act_dim}: is this the agent of this task?"
            )
        seed = int(req.spec.get("seed", 0))
        states: List[_Rollout] = []
        need: Dict[int, List[int]] = {}
        for i, (rid, step) in enumerate(zip(req.rollout_ids, req.steps, strict=True)):
            r = self.rollouts.get(int(rid))
            if r is None or (int(step) == 0 and r.steps > 0):
                r = self._fresh(int(rid))
            o = np.array(obs[i, -1], np.float32)
            if r.first is None:
                r.first = o
            r.obs.append(o)
            r.steps += 1
            states.append(r)
            if not r.queue:
                w = len(r.obs) if s.window == "grow" else s.history
                need.setdefault(w, []).append(i)
        for rows in need.values():
            wins = [self.window(states[i]) for i in rows]
            o_t = torch.from_numpy(np.stack([w[0] for w in wins]))
            prevs = [w[1] for w in wins if w[1] is not None]
            p_t = torch.from_numpy(np.stack(prevs)) if s.prev_actions else None
            n_t = None
            if s.noise_shape is not None:
                n_t = torch.stack(
                    [noise_for(s.noise_shape, seed, int(req.rollout_ids[i]), int(req.steps[i])) for i in rows]
                )
            with torch.no_grad():
                chunk = self.module(o_t, p_t, n_t).numpy().astype(np.float32, copy=False)
            self.calls += 1
            for j, i in enumerate(rows):
                states[i].queue.extend(chunk[j, : s.execute])
        out = np.zeros((obs.shape[0], act_dim), np.float32)
        for i, r in enumerate(states):
            a = r.queue.popleft()
            r.actions.append(a)
            out[i] = a
        return out


Adapter = Union[AgentAdapter, BatchedAgentAdapter]


def make_adapter(
    agent: Any, predict_kwargs: Optional[Mapping[str, Any]] = None, log: Optional[IO[str]] = None
) -> Adapter:
    """`BatchedAgentAdapter` when `agent` (an object, or a factory, called once) is a
    reference agent of a known family, else the per-rollout `AgentAdapter`; says which
    on `log` (stderr by default), and why when it falls back.
    """
    log = log if log is not None else sys.stderr
    obj = agent if hasattr(agent, "predict") else None
    if obj is None and callable(agent):
        obj = agent()
    why = ""
    if predict_kwargs:
        why = "predict() keyword arguments were given"
    else:
        try:
            adapter = BatchedAgentAdapter(obj)
            print(adapter.describe(), file=log, flush=True)
            return adapter
        except ImportError as e:
            why = f"the agent families cannot be loaded ({e})"
        except Exception as e:  # UnknownAgent, or a family refusing this configuration
            known = type(e).__name__ != "UnknownAgent"
            why = str(e) if known else "not an agent of the D3IL families d3il_client.agents knows"
    print(f"serving {type(obj).__name__} per rollout (one predict() per rollout and step): {why}", file=log, flush=True)
    return AgentAdapter(agent, predict_kwargs)  # a factory stays one: a fresh agent per rollout


# ---- what one request costs, and what that makes of a paper protocol ---------------


def _dummy_obs(agent_or_settings_dim: int, batch: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (0.5 + 0.1 * rng.standard_normal((batch, agent_or_settings_dim))).astype(np.float32)


def time_batched_call(adapter: BatchedAgentAdapter, batch: int, min_s: float = 0.5, max_calls: int = 20) -> float:
    """Seconds of one model call of the adapter's module at `batch` rollouts and the
    full window (k observations, k - 1 previous actions), after a warm-up call: the
    median of at least two calls (or `min_s` of calls).
    """
    torch = adapter._torch
    s = adapter.settings
    obs = torch.from_numpy(np.stack([_dummy_obs(s.obs_dim, s.history, b) for b in range(batch)]))
    prev = torch.zeros((batch, s.history - 1, s.act_dim)) if s.prev_actions else None
    noise = torch.randn((batch, *s.noise_shape)) if s.noise_shape is not None else None
    times: List[float] = []
    with torch.no_grad():
        adapter.module(obs, prev, noise)
        start = time.perf_counter()
        while len(times) < 2 or (time.perf_counter() - start < min_s and len(times) < max_calls):
            t = time.perf_counter()
            adapter.module(obs, prev, noise)
            times.append(time.perf_counter() - t)
    return float(np.median(times))


def choose_threads(adapter: BatchedAgentAdapter, batch: int, log: IO[str]) -> float:
    """Time a call with torch's default threads and with one thread, keep the faster
    (on a loaded machine OpenMP's threads can make a call ten times slower) and
    return its seconds per call.
    """
    torch = adapter._torch
    default = torch.get_num_threads()
    best = (time_batched_call(adapter, batch), default)
    if default > 1:
        torch.set_num_threads(1)
        one = time_batched_call(adapter, batch)
        print(
            f"one call at batch {batch}: {1000 * best[0]:.1f} ms with {default} torch threads, "
            f"{1000 * one:.1f} ms with 1",
            file=log,
            flush=True,
        )
        best = min(best, (one, 1))
        torch.set_num_threads(best[1])
    return best[0]


def time_predict(adapter: AgentAdapter, obs_dim: int, steps: int = 12) -> float:
    """Mean seconds of one `predict` of a fresh agent over `steps` steps (the first,
    warm-up, not counted): the per-rollout path's cost per rollout and step.
    """
    a = adapter._make()
    a.reset()
    obs = _dummy_obs(obs_dim, steps + 1)
    a.predict(obs[0], **adapter.predict_kwargs)
    start = time.perf_counter()
    for o in obs[1:]:
        a.predict(o, **adapter.predict_kwargs)
    return (time.perf_counter() - start) / steps


def startup_projection(
    adapter: Adapter,
    task: Optional[str],
    max_live: int = tasks.MAX_LIVE,
    obs_dim: Optional[int] = None,
    log: IO[str] = sys.stderr,
) -> Optional[tasks.Projection]:
    """Measure what one request of `max_live` rollouts costs and print the projected
    inference time of `task`'s paper protocol (every task's when `task` is None)
    against the default wall limit, warning loudly when it will not fit or when one
    request would outlast the remote deadline. Returns `task`'s projection.
    """
    batch = max_live
    if isinstance(adapter, BatchedAgentAdapter):
        call_s = choose_threads(adapter, batch, log)
        execute = adapter.settings.execute
        print(
            f"one model call at batch {batch} (window {adapter.settings.history}): {1000 * call_s:.1f} ms "
            f"(torch, {adapter._torch.get_num_threads()} thread(s))",
            file=log,
            flush=True,
        )
        request_s = call_s
    else:
        dim = obs_dim if obs_dim is not None else _agent_obs_dim(adapter)
        if dim is None:
            print(
                "not measured: the agent has no scaler.x_mean to size a dummy observation by",
                file=log,
                flush=True,
            )
            return None
        per = time_predict(adapter, dim)
        call_s, execute = per * batch, 1
        request_s = call_s
        print(
            f"one predict(): {1000 * per:.1f} ms; a request of {batch} rollouts: {call_s:.2f} s (per rollout)",
            file=log,
            flush=True,
        )
    if request_s > tasks.REMOTE_DEADLINE_S:
        print(
            f"WARNING: one request of {batch} rollouts takes about {request_s:.1f} s, more than the evaluator's "
            f"{tasks.REMOTE_DEADLINE_S:.0f} s deadline per request: the evaluation will fail",
            file=log,
            flush=True,
        )
    chosen: Optional[tasks.Projection] = None
    for name in [task] if task else list(tasks.PAPER_PROTOCOL):
        p = tasks.project(name, call_s, execute=execute, max_live=max_live)
        print(p.line(), file=log, flush=True)
        if name == task:
            chosen = p
        if task and not p.fits:
            bar = "!" * 78
            print(
                f"{bar}\nWARNING: {name}'s paper protocol will NOT finish inside the default wall limit: "
                f"about {p.seconds:.0f} s of inference alone against {p.limit_s:.0f} s (x{p.ratio:.1f}). "
                "Fewer sampling steps, a smaller network or a faster machine, or export the agent to ONNX "
                f"(python -m d3il_client.agents.export, docs/export.md).\n{bar}",
                file=log,
                flush=True,
            )
    return chosen


def _agent_obs_dim(adapter: AgentAdapter) -> Optional[int]:
    try:
        a = adapter._make()
        return int(np.asarray(a.scaler.x_mean).reshape(-1).shape[0])
    except Exception:
        return None


def agent_server(agent: Any, **kwargs: Any) -> PolicyServer:
    """A `PolicyServer` (history = horizon = execute = 1) serving `agent`
    (batched when its family is known, `make_adapter`).
    """
    adapter = make_adapter(agent, kwargs.pop("predict_kwargs", None), log=kwargs.get("log", sys.stderr))
    return PolicyServer(adapter, history=1, horizon=1, execute=1, reset=adapter.reset, forget=adapter.forget, **kwargs)


def serve_agent(
    agent: Any,
    host: str = "127.0.0.1",
    port: int = 8765,
    certfile: Optional[str] = None,
    keyfile: Optional[str] = None,
    predict_kwargs: Optional[Mapping[str, Any]] = None,
    secret: Optional[str] = None,
) -> None:
    """Blocking: serve `agent` until interrupted (prints the bound port); batched
    when its family is known (`make_adapter`). With `secret`, only a client
    that sends it is served (docs/remote-protocol.md, "Shared secret").
    """
    adapter = make_adapter(agent, predict_kwargs)
    serve(
        adapter,
        host=host,
        port=port,
        certfile=certfile,
        keyfile=keyfile,
        history=1,
        horizon=1,
        execute=1,
        reset=adapter.reset,
        forget=adapter.forget,
        secret=secret,
    )
