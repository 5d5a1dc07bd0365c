"""Objects named on the command line as ``MODULE:NAME`` (agents, factories, policies)."""

from __future__ import annotations

import importlib
import sys
from typing import Any, Optional


def load_object(spec: str) -> Any:
    """The object ``MODULE:NAME`` names (``NAME`` may be dotted: ``module:Class.factory``);
    MODULE is importable from the current directory or ``sys.path``.
    """
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise SystemExit(f"error: {spec!r} is not MODULE:NAME (e.g. my_agents:make_agent)")
    if "" not in sys.path:
        sys.path.insert(0, "")  # the current directory, as `python -m` sees it
    try:
        obj: Any = importlib.import_module(module_name)
    except ImportError as e:
        raise SystemExit(f"error: cannot import {module_name}: {e}") from e
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError as e:
            raise SystemExit(f"error: {module_name} has no {attr}") from e
    return obj


def make_agent(spec: str, checkpoint: Optional[str]) -> Any:
    """Call the factory ``spec`` names (with ``checkpoint`` when given) and check that
    the result has the reference agents' ``reset()`` and ``predict(obs)``.
    """
    make = load_object(spec)
    agent = make(checkpoint) if checkpoint is not None else make()
    if not (hasattr(agent, "reset") and hasattr(agent, "predict")):
        raise SystemExit(f"error: {spec} returned {type(agent).__name__}, which has no reset() and predict(obs)")
    return agent
