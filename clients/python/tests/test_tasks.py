"""d3il_client.tasks agrees with the Rust sources it copies: the paper protocols
(protocol/src/task.rs), the default live rollouts (evaluator/src/eval.rs), the wall
limit and the remote deadline (protocol/src/job.rs).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from d3il_client import tasks

ROOT = Path(__file__).resolve().parents[3]


def rust(path: str) -> str:
    return (ROOT / path).read_text()


def block(text: str, start: str) -> str:
    """The text of the function or impl starting at ``start`` (up to its closing brace)."""
    i = text.index(start)
    depth, j = 0, text.index("{", i)
    while True:
        depth += {"{": 1, "}": -1}.get(text[j], 0)
        if depth == 0:
            return text[i : j + 1]
        j += 1


def test_paper_protocols_are_the_evaluators() -> None:
    src = rust("protocol/src/task.rs")
    slugs = dict(re.findall(r'TaskId::(\w+) => "([a-z0-9-]+)"', block(src, "pub fn slug")))
    sizes = re.findall(r"TaskId::(\w+) => \((\d+), (\d+), (\d+)\)", block(src, "pub fn paper_protocol"))
    assert len(sizes) == len(slugs) == 8
    rust_table = {slugs[v]: tasks.PaperProtocol(int(c), int(r), int(s)) for v, c, r, s in sizes}
    assert rust_table == tasks.PAPER_PROTOCOL


def test_max_live_wall_limit_and_deadline_are_the_evaluators() -> None:
    ev = block(rust("evaluator/src/eval.rs"), "impl Default for EvalOptions")
    assert int(re.search(r"max_live: (\d+),", ev).group(1)) == tasks.MAX_LIVE  # type: ignore[union-attr]
    cli = rust("src/common/evaluation.rs")
    assert re.search(r"default_value_t = (\d+)\)\]\s*pub max_live", cli).group(1) == str(tasks.MAX_LIVE)  # type: ignore[union-attr]
    lim = block(rust("protocol/src/job.rs"), "impl Default for Limits")
    assert int(re.search(r"wall_seconds: (\d+),", lim).group(1)) == tasks.WALL_SECONDS  # type: ignore[union-attr]
    ms = re.search(r"remote_deadline_ms: ([\d_]+),", lim).group(1)  # type: ignore[union-attr]
    assert int(ms.replace("_", "")) / 1000 == tasks.REMOTE_DEADLINE_S


def test_projection_counts_groups_times_calls() -> None:
    p = tasks.project("aligning", 0.5)
    assert p.calls == 5 * 400  # 480 rollouts in groups of 96, one call per step
    assert p.seconds == pytest.approx(1000.0)
    assert p.ratio == pytest.approx(1000 / 3600)
    assert "ratio 0.28" in p.line()
    assert tasks.project("aligning", 0.5, execute=4).calls == 5 * 100
    assert tasks.paper_protocol("sorting_4") is tasks.PAPER_PROTOCOL["sorting-4"]
    with pytest.raises(KeyError, match="expected one of"):
        tasks.paper_protocol("juggling")
