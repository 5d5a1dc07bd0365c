"""The zoo as shipped, one Markdown row per cell (docs/zoo.md "The first zoo"): budget,
training time, paper-protocol metrics with their intervals, evaluation time and, where a
robustness suite ran, its overall retained-success score.

    python3 scripts/zoo/summary.py [--zoo assets/zoo]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pack import read_json_doc

PROJECT = Path(__file__).resolve().parents[2]
ORDER = ["BC-MLP", "VAE-State", "VAE-ACT", "BeT-MLP", "BeT", "IBC", "DDPM-MLP", "DDPM-GPT", "DDPM-ACT", "BESO", "BC-GPT"]


def est(e) -> str:
    return f"{e['value']:.3f} [{e['ci_low']:.3f}, {e['ci_high']:.3f}]"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zoo", type=Path, default=PROJECT / "assets" / "zoo")
    a = ap.parse_args()
    print("| task | method | seed | epochs × batch (samples seen) | training | success | behaviour entropy "
          "| conditional entropy | evaluation | robustness (sampled suite) | size |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    total = 0
    cells = []
    for prov_path in sorted(a.zoo.glob("*/*/provenance.json")):
        cell = prov_path.parent
        p = json.loads(prov_path.read_text())
        cells.append((["avoiding", "aligning", "pushing"].index(p["task"]) if p["task"] in
                      ("avoiding", "aligning", "pushing") else 9,
                      ORDER.index(p["method"]) if p["method"] in ORDER else 99, cell, p))
    for _, _, cell, p in sorted(cells, key=lambda c: c[:2]):
        m = p["evaluation"]["metrics"]
        b = p["budget"]
        size = sum(f.stat().st_size for f in cell.iterdir() if f.is_file())
        total += size
        rob = read_json_doc(cell, "robustness.json")
        rtext = "not run"
        if rob is not None:
            o = rob.get("overall")
            rtext = est(o) if o else "no score (no success at level 0)"
        print(f"| {p['task']} | {p['method']} | {p['seed']} | {b['epochs']} × {b['train_batch_size']} "
              f"({b['samples_seen'] / 1e6:.2f} M) | {p['training']['wall_s']:.0f} s | {est(m['success_rate'])} "
              f"| {est(m['behaviour_entropy'])} | {est(m['conditional_entropy'])} | "
              f"{p['evaluation']['wall_s']:.0f} s | {rtext} | {size / 1e6:.1f} MB |")
    print(f"\n{len(cells)} cells, {total / 1e6:.1f} MB in all.")


if __name__ == "__main__":
    main()
