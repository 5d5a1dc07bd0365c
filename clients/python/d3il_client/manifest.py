"""The checks ``d3il submit`` makes before it sends anything.

The limits are the server's (``PolicyManifest::validate`` in protocol/src/job.rs,
docs/submission.md); checking them here turns a typo into an error before a large
upload starts, with the same words the server would use.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Tuple, Union

from .errors import ManifestError

#: The task slugs the leaderboard evaluates.
TASKS = (
    "avoiding",
    "aligning",
    "pushing",
    "sorting-2",
    "sorting-4",
    "sorting-6",
    "stacking",
    "inserting",
)
#: Observation types.
OBS_TYPES = ("state", "image")
#: Evaluation protocols: ``paper`` (the full protocol) or ``quick`` (a smoke test).
PROTOCOLS = ("paper", "quick")
#: Suites a submission can ask for besides the plain evaluation (docs/robustness.md).
SUITES = ("robustness",)
#: Largest history k a manifest may declare.
MAX_HISTORY = 64
#: Largest chunk length H (and so execute E) a manifest may declare.
MAX_HORIZON = 1024

PathLike = Union[str, "os.PathLike[str]"]
ManifestArg = Union[PathLike, Mapping[str, Any]]


def check_choice(field: str, value: str, allowed: Tuple[str, ...]) -> None:
    """Raise :class:`ManifestError` unless ``value`` is one of ``allowed``."""
    if value not in allowed:
        raise ManifestError(f"{field} `{value}` is not one of {', '.join(allowed)}", field)


def _count(m: Mapping[str, Any], field: str) -> int:
    v = m.get(field, 1)
    if isinstance(v, bool) or not isinstance(v, int):
        raise ManifestError(f"{field} must be a whole number, got {v!r}", field)
    return v


def validate_manifest(m: Mapping[str, Any]) -> None:
    """Check a policy manifest as the server does (docs/submission.md, "The manifest").

    Raises :class:`ManifestError` naming the field: an unknown task or observation
    type, history k outside 1..64, horizon H outside 1..1024, execute E outside
    1..H, normalisation vectors that are not finite or whose stds are not positive,
    a window other than ``pad`` or ``grow``.
    """
    if not isinstance(m, Mapping):
        raise ManifestError("the manifest must be a JSON object")
    if "task" not in m:
        raise ManifestError("the manifest has no `task`", "task")
    check_choice("task", str(m["task"]), TASKS)
    check_choice("obs_type", str(m.get("obs_type", "state")), OBS_TYPES)
    history, horizon, execute = _count(m, "history"), _count(m, "horizon"), _count(m, "execute")
    if not 1 <= history <= MAX_HISTORY:
        raise ManifestError(f"history k = {history} must be from 1 to {MAX_HISTORY}", "history")
    if not 1 <= horizon <= MAX_HORIZON:
        raise ManifestError(f"horizon H = {horizon} must be from 1 to {MAX_HORIZON}", "horizon")
    if not 1 <= execute <= horizon:
        raise ManifestError(f"execute E = {execute} must be from 1 to the horizon H = {horizon}", "execute")
    window = m.get("window", "pad")
    if window not in ("pad", "grow"):
        raise ManifestError(f"window `{window}` is not one of pad, grow", "window")
    norm = m.get("normalisation")
    if norm is None:
        return
    if not isinstance(norm, Mapping):
        raise ManifestError("normalisation must be an object or null", "normalisation")
    for key in ("obs_mean", "obs_std", "act_mean", "act_std"):
        field = f"normalisation.{key}"
        v = norm.get(key)
        if v is None:
            continue
        if not isinstance(v, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            raise ManifestError("must be a list of numbers", field)
        if not all(math.isfinite(x) for x in v):
            raise ManifestError(f"{field} contains a non-finite value", field)
        if key.endswith("std") and any(x <= 0 for x in v):
            raise ManifestError(f"{field} must be positive everywhere", field)


def load_manifest(onnx: Optional[PathLike], manifest: Optional[ManifestArg]) -> Tuple[Dict[str, Any], str]:
    """The manifest for a submission and its JSON text, checked.

    ``manifest`` is a path to a JSON file or the manifest itself as a mapping;
    without it the manifest is the ``.json`` file next to ``onnx`` with the same
    name, as ``d3il eval`` and ``d3il submit`` find it.
    """
    if manifest is not None and isinstance(manifest, Mapping):
        parsed: Any = dict(manifest)
        text = json.dumps(parsed)
    else:
        if manifest is not None:
            path = Path(manifest)
        elif onnx is not None:
            path = Path(onnx).with_suffix(".json")
        else:
            raise ManifestError("give onnx=FILE (its manifest next to it as FILE.json, or manifest=)")
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise ManifestError(
                f"reading the policy manifest {path} ({e.strerror or e}): put it next to the .onnx file "
                "with the same name, or pass manifest=; format in docs/submission.md",
                "manifest",
            ) from e
        try:
            parsed = json.loads(text)
        except ValueError as e:
            raise ManifestError(f"{path} is not a valid policy manifest: {e}", "manifest") from e
    validate_manifest(parsed)
    return parsed, text


def check_policy_file(onnx: PathLike) -> int:
    """The size in bytes of the ONNX file ``onnx``; raises if it is missing, not a file or empty."""
    path = Path(onnx)
    if not path.exists():
        raise ManifestError(f"the ONNX file {path} does not exist", "onnx")
    if not path.is_file():
        raise ManifestError(f"{path} is not a file", "onnx")
    size = path.stat().st_size
    if size == 0:
        raise ManifestError(f"the ONNX file {path} is empty", "onnx")
    return size
