"""Plain-text tables, as the ``d3il`` command prints them (``d3il eval``, ``d3il compare``)."""

from __future__ import annotations

from collections import Counter
from typing import Iterable, List, Optional, Tuple

from .models import Comparison, Estimate, Leaderboard, Results, RolloutItem

_ROBOT_LOOK_NOTES = {
    "primitives": "robot drawn with primitive shapes (capsules and boxes), not the Panda's meshes: "
    "the evaluating host had no converted meshes",
    None: "robot look not recorded (evaluated before results recorded it)",
}


def behaviour_counts(items: Iterable[RolloutItem]) -> List[Tuple[str, int]]:
    """The successful rollouts' behaviours by name, most frequent first (as the server's plot counts them)."""
    counts = Counter(r.behaviour_label for r in items if r.success)
    return sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))


def metrics_table(results: Results, items: Optional[List[RolloutItem]] = None) -> str:
    """The metrics table of ``d3il eval`` and ``d3il submit --wait``.

    ``items`` (the rollouts with their behaviour names) adds the histogram of
    the successful rollouts' behaviours.
    """
    man = results.protocol_manifest
    m = results.metrics
    out = [
        f"task {man.get('task')}, {man.get('obs_type')} observations ({man.get('n_contexts')} x "
        f"{man.get('rollouts_per_context')} rollouts, {man.get('protocol')} protocol, seed {man.get('seed')})"
    ]
    if man.get("obs_type") == "image" and man.get("robot_look") != "meshes":
        out.append(f"note: {_ROBOT_LOOK_NOTES.get(man.get('robot_look'), _ROBOT_LOOK_NOTES[None])}")
    out.append(f"{'metric':<28} {'value':>8} {'95% CI':>20}")

    def line(name: str, e: Estimate) -> None:
        out.append(f"{name:<28} {e.value:>8.3f} {e.ci_low:>9.3f} – {e.ci_high:<8.3f}")

    line("success rate", m.success_rate)
    line("conditional entropy", m.conditional_entropy)
    line("behaviour entropy", m.behaviour_entropy)
    if m.stacking_levels:
        for i, level in enumerate(m.stacking_levels):
            line(f"stacking-{i + 1} success", level.success_rate)
            line(f"stacking-{i + 1} cond. entropy", level.conditional_entropy)
            line(f"stacking-{i + 1} behaviour entropy", level.behaviour_entropy)
    elif m.stacking:
        s = m.stacking
        out.append(f"{'stacking-1/2/3 success':<28} {s[0]:.3f} / {s[1]:.3f} / {s[2]:.3f}")
    out.append(f"{'inference ms per call':<28} {m.inference_ms:>8.3f}")
    out.append(
        f"initial states: {results.initial_states} ({results.initial_states_label}), "
        f"sha256 {man.get('initial_states_sha256')}"
    )
    out.append(
        f"rollouts ended unstable: {results.rollouts_ended_unstable} of {len(results.rollouts)} (counted as failures)"
    )
    if results.mostly_unstable:
        out.append(
            "WARNING: more than half of the rollouts ended with an unstable simulation; "
            "these numbers say more about the simulation than about the policy"
        )
    if items is not None:
        counts = behaviour_counts(items)
        if not counts:
            out.append("behaviours: no successful rollout")
        else:
            successes = sum(n for _, n in counts)
            out.append(f"behaviours of the {successes} successful rollouts:")
            top = max(n for _, n in counts) or 1
            width = max(len(label) for label, _ in counts)
            for label, n in counts:
                bar = "#" * -(-n * 40 // top)
                out.append(f"  {label:<{width}} {n:>6}  {bar}")
    return "\n".join(out) + "\n"


def comparison_table(c: Comparison) -> str:
    """The comparison as ``d3il compare`` prints it."""
    out = [
        f"paired comparison A − B: task {c.task}, {c.protocol} protocol, {c.n_contexts} initial states × "
        f"{c.rollouts_per_context} rollouts",
        f"initial states: {c.initial_states} (sha256 {c.initial_states_sha256})",
        f"{'metric':<22} {'A':>7} {'B':>7} {'A − B':>8} {'95% CI':>21} {'p':>8} {'min. det.':>9}",
    ]
    for name, d in (("success rate", c.success_rate), ("conditional entropy", c.conditional_entropy)):
        e = d.difference
        out.append(
            f"{name:<22} {d.a:>7.3f} {d.b:>7.3f} {e.value:>+8.3f} {e.ci_low:>+9.3f} – {e.ci_high:<+9.3f} "
            f"{d.p_value:>8.4f} {d.min_detectable:>9.3f}"
        )
    out += [f"note: {caveat}" for caveat in c.caveats]
    out.append(
        f"p: randomisation test paired by initial state ({c.resamples} permutations); min. det.: the difference "
        "detected with 80 % power at the 5 % level at this size"
    )
    return "\n".join(out) + "\n"


def leaderboard_table(board: Leaderboard) -> str:
    """A leaderboard as a plain-text table: method, source, success and entropy (mean ± std over seeds)."""
    out = [f"{board.title}, {board.obs_type} observations ({board.view})"]
    width = max([len("method")] + [len(r.method) for r in board.rows])
    out.append(f"{'method':<{width}} {'source':<9} {'fraction':>8} {'success':>15} {'entropy':>15} {'seeds':>5}")
    for r in board.rows:
        out.append(
            f"{r.method:<{width}} {r.source:<9} {r.data_fraction:>8.2f} "
            f"{r.success.mean:>7.3f} ± {r.success.std:<5.3f} {r.entropy.mean:>7.3f} ± {r.entropy.std:<5.3f} "
            f"{r.n_seeds:>5}"
        )
    return "\n".join(out) + "\n"
