"""Robustness suites for the zoo (docs/zoo.md, docs/robustness.md): for every finished
cell of the given tasks that has no robustness.json yet, runs

    d3il eval --task T --policy <cell>/policy.onnx --suite robustness \
        --rollouts-per-state K --seed <the result's seed> --json <cell>/robustness.json

(a sampled protocol when K is below the paper protocol's rollouts per state: the
paper's initial states, K rollouts of each, at every level of the task's suite),
then records the run in the cell's provenance.json (`robustness`: command, wall
time, rollouts per state; `sha256.robustness`), which the server checks when it
loads the cell. Resumable: a cell with a robustness.json is skipped; the document
is written to a temporary name and renamed when the run ends.

    python3 scripts/zoo/suites.py [--zoo assets/zoo] [--tasks aligning,pushing] \
        [--methods bc,cvae,bet_mlp,ddpm,beso] [--rollouts-per-state 1]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import time
from pathlib import Path

from pack import read_json_doc

PROJECT = Path(__file__).resolve().parents[2]
# cell directory prefixes of the methods (train_cell.py names cells <paper-name-slug>-s<seed>)
SLUGS = {
    "bc": "bc-mlp",
    "cvae": "vae-state",
    "act": "vae-act",
    "bet_mlp": "bet-mlp",
    "bet": "bet",
    "ibc": "ibc",
    "ddpm": "ddpm-mlp",
    "ddpm_transformer": "ddpm-gpt",
    "ddpm_encdec": "ddpm-act",
    "beso": "beso",
    "gpt_bc": "bc-gpt",
}


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run_cell(d3il: str, cell: Path, task: str, per_state: int) -> None:
    result = read_json_doc(cell, "result.json")
    seed = result["manifest"].get("seed", 0)
    tmp = cell / ".robustness.json.tmp"
    cmd = [d3il, "eval", "--task", task, "--policy", str(cell / "policy.onnx"), "--suite", "robustness",
           "--rollouts-per-state", str(per_state), "--seed", str(seed), "--json", str(tmp)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    os.replace(tmp, cell / "robustness.json")
    prov_path = cell / "provenance.json"
    prov = json.loads(prov_path.read_text())
    shown = ["d3il"] + [str(Path(c).relative_to(PROJECT)) if c.startswith(str(PROJECT)) else c for c in cmd[1:]]
    prov["robustness"] = {
        "command": shown,
        "wall_s": round(wall, 2),
        "rollouts_per_state": per_state,
        "protocol": "sampled: the paper protocol's initial states, "
        f"{per_state} rollout(s) of each at every level of the suite",
    }
    prov["sha256"]["robustness"] = sha256(cell / "robustness.json")
    tmp_prov = cell / ".provenance.json.tmp"
    tmp_prov.write_text(json.dumps(prov, indent=2) + "\n")
    os.replace(tmp_prov, prov_path)
    print(f"[suites] {cell.relative_to(PROJECT) if cell.is_relative_to(PROJECT) else cell}: {wall:.0f} s", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zoo", type=Path, default=PROJECT / "assets" / "zoo")
    ap.add_argument("--tasks", default="aligning,pushing")
    ap.add_argument("--methods", default="bc,cvae,bet_mlp,ddpm,beso")
    ap.add_argument("--rollouts-per-state", type=int, default=1)
    ap.add_argument("--min-success", type=float, default=0.03,
                    help="skip cells whose paper-protocol success is below this: a suite measures what "
                    "success is retained, and a policy that almost never succeeds runs every rollout to "
                    "the step limit at every level (the most expensive suite) to retain nothing")
    ap.add_argument("--d3il", default=os.environ.get("D3IL_BIN", str(PROJECT / "target" / "release" / "d3il")))
    a = ap.parse_args()
    for method in a.methods.split(","):
        for task in a.tasks.split(","):
            for cell in sorted((a.zoo / task).glob(f"{SLUGS[method]}-s*")):
                done = (cell / "robustness.json").is_file() or (cell / "robustness.json.gz").is_file()
                if not (cell / "provenance.json").is_file() or done:
                    continue
                sr = read_json_doc(cell, "result.json")["metrics"]["success_rate"]["value"]
                if sr < a.min_success:
                    print(f"[suites] {task}/{cell.name}: skipped, success {sr:.3f} < {a.min_success}", flush=True)
                    continue
                run_cell(a.d3il, cell, task, a.rollouts_per_state)


if __name__ == "__main__":
    main()
