"""The evaluator's numbers a policy's speed is judged by, once, in Python.

``PAPER_PROTOCOL`` is ``TaskId::paper_protocol`` (protocol/src/task.rs): initial
states (contexts) × rollouts per state and the step limit of every task's state
variant; ``MAX_LIVE`` the rollouts the evaluator simulates at once, i.e. the largest
batch of one query (``EvalOptions::default().max_live``, evaluator/src/eval.rs, and
``d3il eval --max-live``); ``WALL_SECONDS`` the default wall-clock limit of one
evaluation (``Limits::default().wall_seconds``, protocol/src/job.rs) and
``REMOTE_DEADLINE_S`` the deadline of one remote request (``remote_deadline_ms``).
``tests/test_tasks.py`` reads those Rust files and checks that these agree.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Dict

#: Rollouts simulated at once by default: the batch of one query.
MAX_LIVE = 96

#: Default wall-clock limit of one evaluation, in seconds.
WALL_SECONDS = 3600

#: Default deadline of one remote request, in seconds: a served policy must answer
#: every ``infer`` within it (``Limits::default().remote_deadline_ms``).
REMOTE_DEADLINE_S = 10.0


@dataclasses.dataclass(frozen=True)
class PaperProtocol:
    """A task's paper protocol: ``contexts`` × ``rollouts`` episodes of at most
    ``max_steps`` environment steps.
    """

    contexts: int
    rollouts: int
    max_steps: int

    @property
    def episodes(self) -> int:
        """Rollouts in all: contexts × rollouts per context."""
        return self.contexts * self.rollouts

    def groups(self, max_live: int = MAX_LIVE) -> int:
        """How many batches of live rollouts the episodes make (⌈episodes / max_live⌉)."""
        return math.ceil(self.episodes / max(1, max_live))

    def model_calls(self, execute: int = 1, max_live: int = MAX_LIVE) -> int:
        """Model calls of the whole protocol when every episode runs to ``max_steps``
        and a call yields ``execute`` executed actions: groups × ⌈max_steps / E⌉.
        """
        return self.groups(max_live) * math.ceil(self.max_steps / max(1, execute))


#: protocol/src/task.rs ``paper_protocol`` (state variants), by task slug.
PAPER_PROTOCOL: Dict[str, PaperProtocol] = {
    "avoiding": PaperProtocol(1, 480, 250),
    "aligning": PaperProtocol(60, 8, 400),
    "pushing": PaperProtocol(30, 16, 400),
    "sorting-2": PaperProtocol(60, 18, 500),
    "sorting-4": PaperProtocol(60, 18, 700),
    "sorting-6": PaperProtocol(60, 18, 1200),
    "stacking": PaperProtocol(60, 18, 1000),
    "inserting": PaperProtocol(60, 8, 2000),
}


def paper_protocol(task: str) -> PaperProtocol:
    """The paper protocol of ``task`` (a slug such as ``aligning`` or ``sorting-4``;
    ``sorting_4`` is accepted too).
    """
    slug = task.strip().lower().replace("_", "-")
    if slug not in PAPER_PROTOCOL:
        raise KeyError(f"unknown task {task!r}; expected one of: {', '.join(PAPER_PROTOCOL)}")
    return PAPER_PROTOCOL[slug]


@dataclasses.dataclass(frozen=True)
class Projection:
    """Projected inference time of a task's paper protocol from one call's cost."""

    task: str
    protocol: PaperProtocol
    calls: int
    seconds_per_call: float
    limit_s: float = WALL_SECONDS

    @property
    def seconds(self) -> float:
        """Inference seconds of the whole protocol (every episode to max_steps)."""
        return self.calls * self.seconds_per_call

    @property
    def ratio(self) -> float:
        """Projected seconds / the wall limit: above 1 it will not finish."""
        return self.seconds / self.limit_s

    @property
    def fits(self) -> bool:
        """Whether the projected inference alone fits inside the wall limit."""
        return self.ratio <= 1.0

    def line(self) -> str:
        """One line saying what the projection is and how it compares with the limit."""
        p = self.protocol
        return (
            f"{self.task} paper protocol: {p.contexts} x {p.rollouts} = {p.episodes} rollouts of up to "
            f"{p.max_steps} steps: {self.calls} model calls x {1000 * self.seconds_per_call:.1f} ms = "
            f"{self.seconds:.0f} s of inference against the {self.limit_s:.0f} s wall limit (ratio {self.ratio:.2f})"
        )


def project(
    task: str, seconds_per_call: float, execute: int = 1, max_live: int = MAX_LIVE, limit_s: float = WALL_SECONDS
) -> Projection:
    """The paper-protocol projection of ``task`` for a model call of
    ``seconds_per_call`` at batch ``max_live`` executing ``execute`` actions.
    """
    p = paper_protocol(task)
    return Projection(task, p, p.model_calls(execute, max_live), seconds_per_call, limit_s)
