"""Does diversity buy robustness? The zoo's answer, per task (docs/robustness.md).

For every zoo cell of a task that has a robustness document (robustness.json, written
by scripts/zoo/suites.py), pairs

* x: the cell's conditional behaviour entropy under the paper protocol (result.json;
  the suite's own control arm runs too few rollouts a state to measure it), and
* y: success retained under perturbation, the service's overall robustness score
  (metrics/src/robustness.rs: per level sum_s min(p0(s), pL(s)) / sum_s p0(s),
  averaged over each axis's levels, then over the axes), and, beside it, the plain
  ratio of success rates (level / control, averaged the same way), which a sampled
  protocol's churn does not pull down;

and reports Spearman's rank correlation of x and y across methods with

* a 95 % interval from a cluster bootstrap over initial states (the states resampled
  once per replicate and used for every method, the paper result and the suite alike:
  the same states are in both), i.e. the uncertainty of the evaluation given these
  trained models, not of training; and
* the exact permutation p-value of the observed rho (all orderings of the methods).

    python3 scripts/zoo/diversity.py [--zoo assets/zoo] [--tasks aligning,pushing] [--markdown]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import random
from pathlib import Path

from pack import read_json_doc as doc


def ranks(v):
    order = sorted(range(len(v)), key=lambda i: v[i])
    r = [0.0] * len(v)
    i = 0
    while i < len(v):
        j = i
        while j + 1 < len(v) and v[order[j + 1]] == v[order[i]]:
            j += 1
        for k in range(i, j + 1):
            r[order[k]] = (i + j) / 2 + 1
        i = j + 1
    return r


def spearman(x, y):
    rx, ry = ranks(x), ranks(y)
    mx, my = sum(rx) / len(rx), sum(ry) / len(ry)
    sxy = sum((a - mx) * (b - my) for a, b in zip(rx, ry))
    sxx = sum((a - mx) ** 2 for a in rx)
    syy = sum((b - my) ** 2 for b in ry)
    if sxx == 0 or syy == 0:
        return float("nan")
    return sxy / math.sqrt(sxx * syy)


def by_state(per_context):
    return {c["context_index"]: c for c in per_context}


def scores(robust, picks):
    """(bounded retained score, ratio score) of a robustness document on the picked states."""
    ctrl = by_state(robust["control"]["per_context"])
    base = sum(ctrl[s]["success_rate"] for s in picks)
    if base <= 0:
        return None, None
    axes_b, axes_r = {}, {}
    for lvl in robust["levels"]:
        pcs = by_state(lvl["result"]["per_context"])
        kept = sum(min(pcs[s]["success_rate"], ctrl[s]["success_rate"]) for s in picks)
        plain = sum(pcs[s]["success_rate"] for s in picks)
        axes_b.setdefault(lvl["axis"], []).append(kept / base)
        axes_r.setdefault(lvl["axis"], []).append(plain / base)
    mean = lambda d: sum(sum(v) / len(v) for v in d.values()) / len(d)
    return mean(axes_b), mean(axes_r)


def cond_entropy(result, picks):
    pcs = by_state(result["per_context"])
    return sum(pcs[s]["conditional_entropy"] for s in picks) / len(picks)


def load(zoo: Path, task: str):
    cells = []
    for d in sorted((zoo / task).glob("*")):
        result, robust = doc(d, "result.json"), doc(d, "robustness.json")
        if result is None or robust is None:
            continue
        prov = json.loads((d / "provenance.json").read_text())
        cells.append({"cell": d.name, "method": prov["method"], "result": result, "robust": robust})
    return cells


def analyse(cells, resamples=2000, seed=0):
    states = sorted(by_state(cells[0]["result"]["per_context"]))
    for c in cells:
        have = set(by_state(c["robust"]["control"]["per_context"]))
        if not set(states) <= have:
            raise SystemExit(f"{c['cell']}: the suite did not run every state of the paper protocol")
    x = [cond_entropy(c["result"], states) for c in cells]
    yb, yr = zip(*[scores(c["robust"], states) for c in cells])
    rho_b, rho_r = spearman(x, list(yb)), spearman(x, list(yr))
    rng = random.Random(seed)
    boot_b, boot_r = [], []
    for _ in range(resamples):
        picks = [rng.choice(states) for _ in states]
        bx = [cond_entropy(c["result"], picks) for c in cells]
        sc = [scores(c["robust"], picks) for c in cells]
        if any(s[0] is None for s in sc):
            continue
        rb, rr = spearman(bx, [s[0] for s in sc]), spearman(bx, [s[1] for s in sc])
        if not math.isnan(rb):
            boot_b.append(rb)
        if not math.isnan(rr):
            boot_r.append(rr)

    def interval(v):
        v = sorted(v)
        if not v:
            return (float("nan"), float("nan"))
        return (v[int(0.025 * (len(v) - 1))], v[int(0.975 * (len(v) - 1))])

    def perm_p(y, rho):
        if math.isnan(rho):
            return float("nan")
        perms = list(itertools.permutations(y))
        return sum(abs(spearman(x, list(p))) >= abs(rho) - 1e-12 for p in perms) / len(perms)

    return {
        "rows": [
            {
                "cell": c["cell"],
                "method": c["method"],
                "success": c["result"]["metrics"]["success_rate"]["value"],
                "behaviour_entropy": c["result"]["metrics"]["behaviour_entropy"]["value"],
                "conditional_entropy": xi,
                "retained": b,
                "ratio": r,
            }
            for c, xi, b, r in zip(cells, x, yb, yr)
        ],
        "retained": {"rho": rho_b, "ci": interval(boot_b), "p": perm_p(list(yb), rho_b)},
        "ratio": {"rho": rho_r, "ci": interval(boot_r), "p": perm_p(list(yr), rho_r)},
        "resamples": resamples,
    }


PAPER_TASK = {"avoiding": "Avoiding (T1)", "aligning": "Aligning (T2)", "pushing": "Pushing (T3)"}


def entropy_order(zoo: Path, task: str):
    """The zoo's methods by conditional entropy (paper protocol) next to the paper's
    reported entropy of the same methods (main table, state, all data): a sanity
    check of our entropy on real methods (the paper: BC-MLP 0, VAE-State low, the
    diffusion methods high)."""
    paper = json.loads((zoo.parent / "paper-results.json").read_text())
    reported = {
        r["method"]: r["entropy"]["mean"]
        for r in paper["results"]
        if r["table"] == "main" and r["obs"] == "state" and r["task"] == PAPER_TASK.get(task)
        and r["data_fraction"] == 1.0
    }
    rows = []
    for d in sorted((zoo / task).glob("*")):
        result = doc(d, "result.json")
        if result is None:
            continue
        prov = json.loads((d / "provenance.json").read_text())
        m = result["metrics"]
        rows.append((prov["method"], m["success_rate"]["value"], m["conditional_entropy"]["value"],
                     reported.get(prov["method"])))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--zoo", type=Path, default=Path(__file__).resolve().parents[2] / "assets" / "zoo")
    ap.add_argument("--tasks", default="aligning,pushing")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--entropy-order", action="store_true",
                    help="print each task's methods by conditional entropy, ours and the paper's")
    a = ap.parse_args()
    if a.entropy_order:
        for task in a.tasks.split(","):
            rows = entropy_order(a.zoo, task)
            print(f"\n### {task}\n\n| method | success (zoo) | conditional entropy (zoo) | entropy (paper) |\n|---|---|---|---|")
            for m, sr, ce, pe in sorted(rows, key=lambda r: r[2]):
                print(f"| {m} | {sr:.3f} | {ce:.3f} | {'-' if pe is None else f'{pe:.2f}'} |")
            ours = [r[0] for r in sorted(rows, key=lambda r: r[2])]
            paper = [r[0] for r in sorted((r for r in rows if r[3] is not None), key=lambda r: r[3])]
            print(f"\nzoo order: {' < '.join(ours)}\npaper order: {' < '.join(paper)}")
        return
    out = {}
    for task in a.tasks.split(","):
        cells = load(a.zoo, task)
        # a suite whose control level had no success retains nothing it could lose:
        # no score (as the service says), so no rank
        unscored = [c for c in cells
                    if scores(c["robust"], sorted(by_state(c["robust"]["control"]["per_context"])))[0] is None]
        cells = [c for c in cells if c not in unscored]
        if len(cells) < 3:
            print(f"{task}: {len(cells)} cells with a robustness score; need 3 or more")
            continue
        res = analyse(cells)
        out[task] = res
        if a.json:
            continue
        print(f"\n### {task}\n")
        print("| cell | method | success | behaviour entropy | conditional entropy | retained (bounded) | retained (ratio) |")
        print("|---|---|---|---|---|---|---|")
        for r in sorted(res["rows"], key=lambda r: r["conditional_entropy"]):
            print(f"| {r['cell']} | {r['method']} | {r['success']:.3f} | {r['behaviour_entropy']:.3f} | "
                  f"{r['conditional_entropy']:.3f} | {r['retained']:.3f} | {r['ratio']:.3f} |")
        if unscored:
            print("\nNo score (no success at the suite's level 0): "
                  + ", ".join(f"{c['method']} ({c['cell']})" for c in unscored))
        for k in ("retained", "ratio"):
            s = res[k]
            print(f"\nSpearman rho(conditional entropy, {k}) = {s['rho']:+.2f}, 95 % state-bootstrap interval "
                  f"[{s['ci'][0]:+.2f}, {s['ci'][1]:+.2f}], exact permutation p = {s['p']:.3f} "
                  f"({len(res['rows'])} methods)")
    if a.json:
        print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
