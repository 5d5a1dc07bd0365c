"""Train, export and evaluate the zoo, one cell at a time, resumably (docs/zoo.md).

    PYTHONPATH=clients/python ~/.cache/d3il/venvs/torch/bin/python scripts/zoo/grid.py \
        --reference /work/d3il-ref --demos-root /work/demos --out assets/zoo \
        --tasks avoiding,aligning,pushing --methods bc,cvae,bet_mlp,ddpm,beso --seeds 0

Cells run in a fixed order (task, then method, then seed, in the order given), each
in its own process (scripts/zoo/train_cell.py): a cell whose provenance.json is
complete is skipped; an incomplete one resumes at the stage it stopped (its work
directory keeps the finished stages). A failed cell is reported and the grid goes on;
the exit status is 1 if any cell failed. --dry-run lists the cells and their state.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import train_cell  # noqa: E402


def cells(tasks, methods, seeds):
    for t in tasks:
        for m in methods:
            for s in seeds:
                yield t, m, s


def split(text: str) -> list[str]:
    return [w.strip() for w in text.split(",") if w.strip()]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reference", required=True, type=Path)
    ap.add_argument("--demos-root", required=True, type=Path, help="holds <task>/manifest.json per task")
    ap.add_argument("--out", required=True, type=Path,
                    help="zoo root: <out>/<task>/<method-slug>-s<seed>/ (bc-mlp, vae-state, bet-mlp, ddpm-mlp, beso)")
    ap.add_argument("--tasks", default="avoiding,aligning,pushing")
    ap.add_argument("--methods", default="bc,cvae,bet_mlp,ddpm,beso")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--work-root", type=Path, default=Path.home() / ".cache" / "d3il" / "zoo-work")
    ap.add_argument("--budgets", type=Path, default=HERE / "budgets.json")
    ap.add_argument("--epochs", type=int, default=None, help="override every cell's epochs (smoke runs)")
    ap.add_argument("--protocol", default="paper")
    ap.add_argument("--d3il", default=None, help="d3il binary (default $D3IL_BIN or target/release/d3il)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--keep-work", action="store_true")
    ap.add_argument("--dry-run", action="store_true")
    a = ap.parse_args(argv)
    tasks, methods = split(a.tasks), split(a.methods)
    seeds = [int(s) for s in split(a.seeds)]
    for t in tasks:
        if t not in train_cell.TASKS:
            ap.error(f"unknown task {t!r} ({', '.join(sorted(train_cell.TASKS))})")
    for m in methods:
        if m not in train_cell.METHODS:
            ap.error(f"unknown method {m!r} ({', '.join(sorted(train_cell.METHODS))})")
    failed, done, ran = [], [], []
    t_grid = time.perf_counter()
    for task, method, seed in cells(tasks, methods, seeds):
        name = f"{task}/{train_cell.method_slug(method)}-s{seed}"
        out = a.out / task / f"{train_cell.method_slug(method)}-s{seed}"
        work = a.work_root / task / f"{method}-s{seed}"
        if train_cell.complete(out):
            print(f"[grid] {name}: complete", flush=True)
            done.append(name)
            continue
        stages = [s for s in train_cell.STAGES if (work / s).is_dir()]
        if a.dry_run:
            print(f"[grid] {name}: to run (finished stages: {', '.join(stages) or 'none'})", flush=True)
            continue
        cmd = [sys.executable, str(HERE / "train_cell.py"), "--reference", str(a.reference),
               "--demos", str(a.demos_root / task), "--task", task, "--method", method, "--seed", str(seed),
               "--out", str(out), "--work", str(work), "--budgets", str(a.budgets),
               "--protocol", a.protocol, "--threads", str(a.threads)]
        if a.epochs is not None:
            cmd += ["--epochs", str(a.epochs)]
        if a.d3il:
            cmd += ["--d3il", a.d3il]
        if a.keep_work:
            cmd.append("--keep-work")
        print(f"[grid] {name}: running (finished stages: {', '.join(stages) or 'none'})", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.run(cmd, env=os.environ.copy()).returncode
        secs = time.perf_counter() - t0
        if rc == 0 and train_cell.complete(out):
            m = json.loads((out / "provenance.json").read_text())["evaluation"]["metrics"]
            sr = m.get("success_rate", {})
            print(f"[grid] {name}: complete in {secs:.0f} s; success {sr.get('value') if isinstance(sr, dict) else sr}",
                  flush=True)
            ran.append(name)
        else:
            print(f"[grid] {name}: FAILED (exit {rc}) after {secs:.0f} s; rerun the grid to resume it", flush=True)
            failed.append(name)
    print(f"[grid] {len(done)} complete before, {len(ran)} run now, {len(failed)} failed"
          f"{': ' + ', '.join(failed) if failed else ''}; {time.perf_counter() - t_grid:.0f} s", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
