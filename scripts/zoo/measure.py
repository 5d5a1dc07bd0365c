"""Measure seconds per training epoch of each (task, method) on the demonstrations and
suggest the epochs of budgets.json for a target training time (docs/zoo.md, Budgets).

    PYTHONPATH=clients/python ~/.cache/d3il/venvs/torch/bin/python scripts/zoo/measure.py \
        --reference /work/d3il-ref --demos-root /work/demos --tasks avoiding,aligning,pushing \
        --methods bc,cvae,bet_mlp,ddpm,beso --epochs 3 --target-seconds 240

Each measurement trains the reference agent for --epochs epochs without evaluations
(scripts/zoo/train_cell.py --until train) in a scratch work directory and takes the
median of the epochs after the first (the first pays for warm-up). Prints one row per
cell; --write puts the suggested epochs into budgets.json. Run it on an otherwise idle
machine: the numbers are only as good as the machine is quiet (the load average is
printed with them).
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import train_cell  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reference", required=True)
    ap.add_argument("--demos-root", required=True, type=Path)
    ap.add_argument("--tasks", default="avoiding,aligning,pushing")
    ap.add_argument("--methods", default="bc,cvae,bet_mlp,ddpm,beso")
    ap.add_argument("--epochs", type=int, default=3)
    ap.add_argument("--target-seconds", type=float, default=240.0)
    ap.add_argument("--min-epochs", type=int, default=5)
    ap.add_argument("--budgets", type=Path, default=HERE / "budgets.json")
    ap.add_argument("--write", action="store_true", help="write the suggested epochs into --budgets")
    a = ap.parse_args(argv)
    rows = []
    for task in [t for t in a.tasks.split(",") if t]:
        for method in [m for m in a.methods.split(",") if m]:
            with tempfile.TemporaryDirectory(prefix="zoo-measure-") as tmp:
                work = Path(tmp) / "work"
                # one process per cell: the reference's modules are imported from the cell's mirror
                subprocess.run([sys.executable, str(HERE / "train_cell.py"), "--reference", a.reference,
                                "--demos", str(a.demos_root / task), "--task", task, "--method", method,
                                "--out", str(Path(tmp) / "out"), "--work", str(work), "--epochs", str(a.epochs),
                                "--eval-every", str(a.epochs + 1), "--until", "train"], check=True)
                doc = json.loads((work / "train" / "train.json").read_text())
            secs = [r["seconds"] for r in doc["loss_curve"] if "seconds" in r]
            per_epoch = statistics.median(secs[1:] or secs)
            epochs = max(a.min_epochs, min(500, math.floor(a.target_seconds / per_epoch)))
            row = {"task": task, "method": method, "samples": doc["train_samples"],
                   "batches": doc["batches_per_epoch"], "seconds_per_epoch": round(per_epoch, 2),
                   "setup_seconds": doc["setup_seconds"], "suggested_epochs": epochs,
                   "load_average": round(os.getloadavg()[0], 2)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("| task | method | samples | batches/epoch | s/epoch | epochs for %.0f s |" % a.target_seconds)
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['task']} | {r['method']} | {r['samples']} | {r['batches']} | {r['seconds_per_epoch']} | "
              f"{r['suggested_epochs']} |")
    if a.write:
        doc = json.loads(a.budgets.read_text())
        for r in rows:
            doc.setdefault("cells", {}).setdefault(r["task"], {}).setdefault(r["method"], {})["epoch"] = \
                r["suggested_epochs"]
        a.budgets.write_text(json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
