"""Typed views of the server's JSON answers.

Each class mirrors one schema of the server's OpenAPI document
(``/api/v1/openapi.json``, named by its ``SCHEMA``); the field names are the
document's property names, so the tests can check that every field this client
reads is one the server publishes. Each object keeps the JSON it was built from
as ``raw``. Tables come as pandas DataFrames from the ``*_frame`` methods.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import typing
import warnings
from typing import TYPE_CHECKING, Any, ClassVar, Dict, List, Optional, Tuple, Type, TypeVar, Union

if TYPE_CHECKING:  # pandas is imported when a table is asked for, not with the package
    import pandas as pd

T = TypeVar("T")


def _convert(tp: Any, value: Any) -> Any:
    """``value`` (decoded JSON) as type ``tp`` (a model, Optional, Tuple, or a plain type)."""
    origin = typing.get_origin(tp)
    if origin is Union:
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _convert(options[0], value) if len(options) == 1 else value
    if origin in (tuple, Tuple):
        args = typing.get_args(tp)
        items = value or []
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v) for v in items)
        return tuple(_convert(a, v) for a, v in zip(args, items, strict=False))
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return from_json(tp, value)
    if tp is float and isinstance(value, int):
        return float(value)
    return value


@functools.cache
def _hints(cls: type) -> Dict[str, Any]:
    # Evaluated once per model: results documents hold hundreds of rollouts.
    return typing.get_type_hints(cls, vars(sys.modules[cls.__module__]))


def from_json(cls: Type[T], data: Any) -> T:
    """Build the model ``cls`` from the server's JSON object ``data``.

    Fields missing from ``data`` take their default (None for the optional
    ones); a required field that is missing raises ``ValueError`` naming it.
    """
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object for {cls.__name__}, got {type(data).__name__}")
    hints = _hints(typing.cast(type, cls))
    kwargs: Dict[str, Any] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name == "raw":
            continue
        if f.name in data:
            kwargs[f.name] = _convert(hints[f.name], data[f.name])
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ValueError(f"the server's {cls.__name__} has no `{f.name}`")
    obj = cls(**kwargs)
    object.__setattr__(obj, "raw", data)
    return obj


def _raw() -> Any:
    return dataclasses.field(default_factory=dict, repr=False, compare=False)


def _frame(rows: List[Dict[str, Any]], columns: List[str]) -> pd.DataFrame:
    import pandas as pd

    frame: pd.DataFrame = pd.DataFrame(rows, columns=columns)
    return frame


# ---- submissions -------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class LiveEstimate:
    """The success rate so far and its confidence sequence (issue 41).

    ``cs_low``..``cs_high`` covers the true success rate at every look,
    however often and whenever one looks, with probability at least
    ``1 - alpha`` (``valid_at_every_look``); one value per finished initial
    state. ``partial``: the evaluation was cancelled, this is all it has.
    """

    SCHEMA: ClassVar[str] = "LiveEstimate"
    states: int
    rollouts: int
    successes: int
    cs_low: float
    cs_high: float
    alpha: float
    valid_at_every_look: bool
    partial: bool
    success_rate: Optional[float] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Progress:
    """Rollouts done of the total (the total is 0 until the worker has said it).

    ``live``: the success rate so far with its confidence sequence.
    """

    SCHEMA: ClassVar[str] = "ProgressView"
    rollouts_done: int
    rollouts_total: int
    live: Optional[LiveEstimate] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Cancelled:
    """Who cancelled an evaluation (a token name), and when (Unix seconds)."""

    SCHEMA: ClassVar[str] = "CancelledView"
    at: int
    by: str
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class PolicyInfo:
    """What was submitted: ``kind`` ``onnx`` (with ``sha256`` and ``bytes``) or ``remote``."""

    SCHEMA: ClassVar[str] = "PolicyView"
    kind: str
    sha256: Optional[str] = None
    bytes: Optional[int] = None
    endpoint_url: Optional[str] = None
    #: True when each initial state is simulated once (a deterministic policy).
    simulated_once: Optional[bool] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class SubmissionError:
    """Why an evaluation failed: ``kind`` (``bad_model``, ``wall_clock``, ...) and a message."""

    SCHEMA: ClassVar[str] = "ErrorView"
    kind: str
    message: Optional[str] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A metric with its 95 % confidence interval, or why it has none (docs/intervals.md)."""

    SCHEMA: ClassVar[str] = "EstimateView"
    value: float
    #: Equal to ``value`` when ``no_interval`` is set: not an interval then (see :meth:`bounds`).
    ci_low: float
    ci_high: float
    #: The interval's method (``korn_graubard``, ``sign_flip_exact``, ...); None from servers before 0.5.0.
    method: Optional[str] = None
    #: Why there is no interval, e.g. ``{"reason": "too_few_states", "states": 3, "min": 5}``.
    no_interval: Optional[Dict[str, Any]] = None
    #: The method's name, or the reason there is no interval, in words.
    interval: Optional[str] = None
    raw: Dict[str, Any] = _raw()

    def bounds(self) -> Tuple[Optional[float], Optional[float]]:
        """``(ci_low, ci_high)``, or ``(None, None)`` when there is no interval."""
        if self.no_interval is not None:
            return (None, None)
        return (self.ci_low, self.ci_high)


@dataclasses.dataclass(frozen=True)
class StackingLevel:
    """Stacking-1, -2 or -3's metrics."""

    success_rate: Estimate
    behaviour_entropy: Estimate
    conditional_entropy: Estimate
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Metrics:
    """The three D3IL metrics (for Stacking: Stacking-3's) and the time per policy call."""

    SCHEMA: ClassVar[str] = "MetricsView"
    success_rate: Estimate
    behaviour_entropy: Estimate
    conditional_entropy: Estimate
    inference_ms: float
    #: Stacking: the success rates of Stacking-1/2/3.
    stacking: Optional[Tuple[float, ...]] = None
    #: Stacking: the metrics of Stacking-1/2/3.
    stacking_levels: Optional[Tuple[StackingLevel, ...]] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class ContextResult:
    """One initial state's success rate, conditional entropy and behaviour counts."""

    context_index: int
    success_rate: float
    conditional_entropy: float
    behaviours: Any = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Rollout:
    """One rollout as the results document has it."""

    SCHEMA: ClassVar[str] = "RolloutView"
    context_index: int
    rollout_index: int
    success: bool
    #: The behaviour code (the reference's encoding, per task).
    behaviour: Any
    steps: int
    #: ``task_success``, ``task_ended``, ``time_limit`` or ``sim_unstable``; None in old results.
    ending: Optional[str] = None
    #: ``{"reason", "message", "step"}`` when the simulation became unstable.
    failure: Optional[Dict[str, Any]] = None
    #: Avoiding: the end effector's path.
    path: Optional[List[Any]] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Results:
    """An evaluation's results (``GET /api/v1/submissions/{id}/results``)."""

    SCHEMA: ClassVar[str] = "ResultsView"
    submission_id: int
    metrics: Metrics
    #: Task version, MJCF and initial-state hashes, MuJoCo and evaluator versions, ...
    protocol_manifest: Dict[str, Any]
    per_context: Tuple[ContextResult, ...]
    rollouts: Tuple[Rollout, ...]
    created_at: int
    initial_states: str
    initial_states_label: str
    rollouts_ended_unstable: int
    mostly_unstable: bool
    #: The sandbox mechanisms the evaluation ran under.
    sandbox: Optional[List[Dict[str, Any]]] = None
    raw: Dict[str, Any] = _raw()

    def metrics_frame(self) -> pd.DataFrame:
        """One row per metric: ``metric``, ``value``, ``ci_low``, ``ci_high``."""
        m = self.metrics
        rows = [
            {"metric": name, "value": e.value, "ci_low": e.bounds()[0], "ci_high": e.bounds()[1]}
            for name, e in (
                ("success_rate", m.success_rate),
                ("conditional_entropy", m.conditional_entropy),
                ("behaviour_entropy", m.behaviour_entropy),
            )
        ]
        for i, level in enumerate(m.stacking_levels or ()):
            for name, e in (
                ("success_rate", level.success_rate),
                ("conditional_entropy", level.conditional_entropy),
                ("behaviour_entropy", level.behaviour_entropy),
            ):
                rows.append(
                    {
                        "metric": f"stacking-{i + 1} {name}",
                        "value": e.value,
                        "ci_low": e.bounds()[0],
                        "ci_high": e.bounds()[1],
                    }
                )
        rows.append({"metric": "inference_ms", "value": m.inference_ms, "ci_low": None, "ci_high": None})
        return _frame(rows, ["metric", "value", "ci_low", "ci_high"])

    def contexts_frame(self) -> pd.DataFrame:
        """One row per initial state: ``context``, ``success_rate``, ``conditional_entropy``, ``behaviours``."""
        rows = [
            {
                "context": c.context_index,
                "success_rate": c.success_rate,
                "conditional_entropy": c.conditional_entropy,
                "behaviours": c.behaviours,
            }
            for c in self.per_context
        ]
        return _frame(rows, ["context", "success_rate", "conditional_entropy", "behaviours"])

    def rollouts_frame(self) -> pd.DataFrame:
        """One row per rollout from this document: ``number`` (as ``d3il replay --rollout``
        names it), ``context``, ``rollout``, ``success``, ``behaviour``, ``steps``,
        ``ending``, ``failure_reason``. :meth:`Client.rollouts_frame
        <d3il_client.Client.rollouts_frame>` adds behaviour names and links.
        """
        per = int(self.protocol_manifest.get("rollouts_per_context") or 0)
        rows = [
            {
                "number": r.context_index * per + r.rollout_index,
                "context": r.context_index,
                "rollout": r.rollout_index,
                "success": r.success,
                "behaviour": r.behaviour,
                "steps": r.steps,
                "ending": r.ending,
                "failure_reason": (r.failure or {}).get("reason"),
            }
            for r in self.rollouts
        ]
        return _frame(
            rows, ["number", "context", "rollout", "success", "behaviour", "steps", "ending", "failure_reason"]
        )


@dataclasses.dataclass(frozen=True)
class Submission:
    """A submission and how its evaluation stands (``GET /api/v1/submissions/{id}``)."""

    SCHEMA: ClassVar[str] = "SubmissionView"
    id: int
    #: The submission's page, relative to the server's root.
    url: str
    #: ``queued``, ``running``, ``completed`` or ``failed``.
    status: str
    method: str
    task: str
    obs_type: str
    training_seed: int
    data_fraction: float
    protocol: str
    policy: PolicyInfo
    manifest: Dict[str, Any]
    attempts: int
    max_attempts: int
    progress: Progress
    created_at: int
    updated_at: int
    submitter: Optional[str] = None
    error: Optional[SubmissionError] = None
    #: Jobs ahead of this one while it is queued.
    queue_position: Optional[int] = None
    #: The server's estimate of the seconds left (from past runs of the same kind).
    eta_seconds: Optional[int] = None
    #: The results once completed.
    result: Optional[Results] = None
    #: Set when the evaluation was cancelled (``progress.live`` holds what ran).
    cancelled: Optional[Cancelled] = None
    raw: Dict[str, Any] = _raw()

    @property
    def done(self) -> bool:
        """True once the evaluation completed or failed."""
        return self.status in ("completed", "failed")


@dataclasses.dataclass(frozen=True)
class SubmissionSummary:
    """One line of ``GET /api/v1/submissions``."""

    SCHEMA: ClassVar[str] = "SubmissionSummary"
    id: int
    url: str
    status: str
    method: str
    task: str
    obs_type: str
    training_seed: int
    data_fraction: float
    protocol: str
    created_at: int
    submitter: Optional[str] = None
    raw: Dict[str, Any] = _raw()


# ---- rollouts ----------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RolloutLinks:
    """Where a rollout's page, record, video and pictures are (server-relative)."""

    SCHEMA: ClassVar[str] = "RolloutLinks"
    page: str
    record: str
    video: Optional[str] = None
    paths: Optional[str] = None
    steps: Optional[str] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class RolloutItem:
    """One rollout of ``GET /api/v1/submissions/{id}/rollouts``."""

    SCHEMA: ClassVar[str] = "RolloutItem"
    #: N = initial state × rollouts per state + index, as ``d3il replay --rollout N`` names it.
    number: int
    context: int
    rollout: int
    success: bool
    behaviour: Any
    #: The behaviour's name (``1-2-3``, ``RB``, ``0``).
    behaviour_label: str
    steps: int
    ending_text: str
    has_trace: bool
    links: RolloutLinks
    ending: Optional[str] = None
    failure: Optional[Dict[str, Any]] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class RolloutPage:
    """One page of ``GET /api/v1/submissions/{id}/rollouts``."""

    SCHEMA: ClassVar[str] = "RolloutList"
    submission_id: int
    task: str
    rollouts_per_context: int
    n_contexts: int
    #: Rollouts matching the filters.
    total: int
    #: Rollouts of the evaluation.
    all: int
    page: int
    per_page: int
    pages: int
    filters: Dict[str, Any]
    behaviours: Tuple[str, ...]
    outcomes: Tuple[Dict[str, Any], ...]
    items: Tuple[RolloutItem, ...]
    #: Why no rollout has a trace (results stored before traces were recorded).
    traces_note: Optional[str] = None
    raw: Dict[str, Any] = _raw()


def rollout_items_frame(items: List[RolloutItem]) -> pd.DataFrame:
    """The per-rollout DataFrame of :meth:`Client.rollouts_frame <d3il_client.Client.rollouts_frame>`."""
    columns = [
        "number",
        "context",
        "rollout",
        "success",
        "behaviour",
        "behaviour_label",
        "steps",
        "ending",
        "ending_text",
        "failure_reason",
        "failure_message",
        "failure_step",
        "has_trace",
        "record",
        "video",
    ]
    rows = [
        {
            "number": r.number,
            "context": r.context,
            "rollout": r.rollout,
            "success": r.success,
            "behaviour": r.behaviour,
            "behaviour_label": r.behaviour_label,
            "steps": r.steps,
            "ending": r.ending,
            "ending_text": r.ending_text,
            "failure_reason": (r.failure or {}).get("reason"),
            "failure_message": (r.failure or {}).get("message"),
            "failure_step": (r.failure or {}).get("step"),
            "has_trace": r.has_trace,
            "record": r.links.record,
            "video": r.links.video,
        }
        for r in items
    ]
    return _frame(rows, columns)


# ---- comparisons and leaderboards --------------------------------------------


@dataclasses.dataclass(frozen=True)
class PairedDifference:
    """One metric of A and B, A − B with its paired interval, p-value and minimum detectable difference."""

    SCHEMA: ClassVar[str] = "PairedDifference"
    a: float
    b: float
    difference: Estimate
    p_value: float
    min_detectable: float
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Comparison:
    """A paired comparison A − B (``GET /api/v1/compare``, ``d3il compare``)."""

    SCHEMA: ClassVar[str] = "Comparison"
    task: str
    protocol: str
    initial_states: str
    initial_states_sha256: str
    n_contexts: int
    rollouts_per_context: int
    resamples: int
    confidence: float
    success_rate: PairedDifference
    conditional_entropy: PairedDifference
    #: What else differs between A and B (how they observe, how frames drew the robot).
    caveats: Tuple[str, ...] = ()
    raw: Dict[str, Any] = _raw()

    def frame(self) -> pd.DataFrame:
        """One row per metric: ``a``, ``b``, ``difference``, ``ci_low``, ``ci_high``, ``p_value``,
        ``min_detectable``.
        """
        rows = [
            {
                "metric": name,
                "a": d.a,
                "b": d.b,
                "difference": d.difference.value,
                "ci_low": d.difference.bounds()[0],
                "ci_high": d.difference.bounds()[1],
                "p_value": d.p_value,
                "min_detectable": d.min_detectable,
            }
            for name, d in (("success_rate", self.success_rate), ("conditional_entropy", self.conditional_entropy))
        ]
        return _frame(rows, ["metric", "a", "b", "difference", "ci_low", "ci_high", "p_value", "min_detectable"])


@dataclasses.dataclass(frozen=True)
class Stat:
    """Mean and sample standard deviation over training seeds."""

    SCHEMA: ClassVar[str] = "Stat"
    mean: float
    std: float
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class LeaderboardRow:
    """One leaderboard row: a method aggregated over its training seeds."""

    SCHEMA: ClassVar[str] = "BoardRow"
    method: str
    method_id: int
    paper_table: str
    task_title: str
    obs: str
    data_fraction: float
    #: ``reported`` (the paper's numbers) or ``evaluated`` (here).
    source: str
    success: Stat
    #: Conditional behaviour entropy (the paper's "Entropy").
    entropy: Stat
    n_seeds: int
    submission_ids: Tuple[int, ...]
    task: Optional[str] = None
    control: Optional[str] = None
    protocol: Optional[str] = None
    behaviour_entropy: Optional[Stat] = None
    inference_ms: Optional[float] = None
    bold_success: Optional[bool] = None
    bold_entropy: Optional[bool] = None
    initial_states: Optional[str] = None
    initial_states_label: Optional[str] = None
    robot_look: Optional[str] = None
    #: The method is marked a baseline by the instance's admins (docs/ops.md, Moderation).
    baseline: bool = False
    #: Where a zoo row's training data came from ("trained here on d3il demos v1",
    #: docs/zoo.md); None for submitted and reported rows.
    data_source: Optional[str] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Leaderboard:
    """A task's leaderboard for one observation type (``GET /api/v1/leaderboards/{task}``)."""

    SCHEMA: ClassVar[str] = "LeaderboardView"
    task: str
    title: str
    obs_type: str
    view: str
    rows: Tuple[LeaderboardRow, ...]
    raw: Dict[str, Any] = _raw()

    def frame(self) -> pd.DataFrame:
        """One row per leaderboard row, with the columns of the server's CSV
        (``GET /api/v1/leaderboards/{task}/csv``, in its order, without the
        board's own ``task`` and ``obs_type``) and then ``submission_ids``;
        tests/test_csv_columns.py holds the two together.
        """
        columns = [
            "method",
            "source",
            "protocol",
            "data_fraction",
            "control",
            "success_mean",
            "success_std",
            "conditional_entropy_mean",
            "conditional_entropy_std",
            "behaviour_entropy_mean",
            "behaviour_entropy_std",
            "n_seeds",
            "inference_ms",
            "initial_states",
            "robot_look",
            "data_source",
            "submission_ids",
        ]
        rows = [
            {
                "method": r.method,
                "source": r.source,
                "protocol": r.protocol,
                "data_fraction": r.data_fraction,
                "control": r.control,
                "success_mean": r.success.mean,
                "success_std": r.success.std,
                "conditional_entropy_mean": r.entropy.mean,
                "conditional_entropy_std": r.entropy.std,
                "behaviour_entropy_mean": r.behaviour_entropy.mean if r.behaviour_entropy else None,
                "behaviour_entropy_std": r.behaviour_entropy.std if r.behaviour_entropy else None,
                "n_seeds": r.n_seeds,
                "inference_ms": r.inference_ms,
                "initial_states": r.initial_states,
                "robot_look": r.robot_look,
                "data_source": r.data_source,
                "submission_ids": list(r.submission_ids),
            }
            for r in self.rows
        ]
        return _frame(rows, columns)


@dataclasses.dataclass(frozen=True)
class LeaderboardLink:
    """One leaderboard of ``GET /api/v1/leaderboards``, with its JSON, CSV and page URLs."""

    SCHEMA: ClassVar[str] = "LeaderboardLink"
    task: str
    title: str
    obs_type: str
    rows: int
    url: str
    csv: str
    page: str
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Method:
    """A method and its properties (``GET /api/v1/methods``)."""

    SCHEMA: ClassVar[str] = "MethodRow"
    id: int
    name: str
    from_paper: bool
    history: Optional[int] = None
    backbone: Optional[str] = None
    prediction: Optional[str] = None
    diversity: Optional[str] = None
    code_url: Optional[str] = None
    paper_url: Optional[str] = None
    description: Optional[str] = None
    state_inference_ms: Optional[float] = None
    image_inference_ms: Optional[float] = None
    submitter_id: Optional[int] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class RaceLive:
    """Where a running race stands after its latest pair (issue 41).

    One pair per initial state (its rollout 0 for both policies); ``both``,
    ``only_a``, ``only_b``, ``neither`` are the paired counts; ``e_value`` and
    ``p_value`` (anytime-valid: valid whenever one looks) the sequential
    test's now; ``decision`` once it decided.
    """

    SCHEMA: ClassVar[str] = "RaceLive"
    states: int
    states_total: int
    pairs: int
    both: int
    only_a: int
    only_b: int
    neither: int
    e_value: float
    p_value: float
    decision: Optional[str] = None
    raw: Dict[str, Any] = _raw()


@dataclasses.dataclass(frozen=True)
class Race:
    """A race of two submissions on the server (``POST /api/v1/races``).

    Both policies run on the same initial states in the same random order,
    and the race stops when the sequential paired test decides. (Not a
    paired comparison: that is :class:`Comparison`, of two finished
    results.) ``report`` (when ``status`` is ``completed``) is the document
    ``d3il race --task T A B --json`` prints: ``decision`` ("A better", "B
    better", "no difference larger than δ", or None at the protocol's full
    size), ``e_value``, ``p_value``, ``rollouts_used`` of ``rollouts_full``,
    ``fixed_pairs_for_power_90``, ...
    """

    SCHEMA: ClassVar[str] = "RaceView"
    id: int
    a: int
    b: int
    task: str
    protocol: str
    seed: int
    alpha: float
    status: str
    created_at: int
    updated_at: int
    delta: Optional[float] = None
    live: Optional[RaceLive] = None
    report: Optional[Dict[str, Any]] = None
    error: Optional[str] = None
    cancelled_by: Optional[str] = None
    raw: Dict[str, Any] = _raw()

    @property
    def decision(self) -> Optional[str]:
        """The decision, once the race has finished (None: none at full size, or not finished)."""
        return None if self.report is None else self.report.get("decision")

    @property
    def rollouts_used(self) -> Optional[int]:
        """Rollouts of both policies in the states used (None until finished)."""
        return None if self.report is None else int(self.report["rollouts_used"])


#: Every model with the OpenAPI schema it mirrors.
MODELS: Tuple[Type[Any], ...] = (
    Progress,
    PolicyInfo,
    SubmissionError,
    Estimate,
    Metrics,
    Rollout,
    Results,
    Submission,
    SubmissionSummary,
    RolloutLinks,
    RolloutItem,
    RolloutPage,
    PairedDifference,
    Comparison,
    RaceLive,
    Race,
    Stat,
    LeaderboardRow,
    Leaderboard,
    LeaderboardLink,
    Method,
)


def __getattr__(name: str) -> Any:
    """``RaceComparison``, the name of :class:`Race` before races had their own: deprecated."""
    if name == "RaceComparison":
        warnings.warn(
            "d3il_client.models.RaceComparison is deprecated; it is d3il_client.Race",
            DeprecationWarning,
            stacklevel=2,
        )
        return Race
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
