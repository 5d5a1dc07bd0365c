"""Gzips the zoo cells' JSON documents for shipping (docs/zoo.md, size budget):
`result.json` and `robustness.json` become `result.json.gz` and
`robustness.json.gz` (deterministic: no name, mtime 0, level 9), and the cell's
provenance.json gets the shipped files' sha256 (`sha256.result`,
`sha256.robustness`; the plain file's sha256 is kept under `sha256_unpacked`).
The server and `d3il zoo` read either form. Idempotent.

A result ships with the traces of a sample of its rollouts: the first
ceil(60 / states) rollouts of every initial state (rollout 0 of each of Aligning's
60 states, the first 2 of each of Pushing's 30, the first 60 of Avoiding's one
start), 60 traces whatever the protocol. The traces of the other rollouts are 7/8
of a stochastic cell's bytes; the metrics, per-state outcomes, behaviours and paths
of every rollout stay, and so does every state's rollout 0, which the copies of a
policy simulated once per state share. The rollouts without a trace say so on their
pages ("this rollout's trace was not stored"); the provenance's command re-runs the
evaluation to the whole document (`sha256_unpacked.result`), and `shipped_traces`
records the rule and the count.

A robustness document ships without the traces of its perturbed levels' rollouts
(`--keep-suite-traces` keeps them): they are 97 % of its bytes (about 6 MB gzipped for
an Aligning suite, already-deflated data that gzip cannot shrink), the Robustness view
and the scores do not read them, and the provenance's command re-runs the suite to
the same document (same seed). The control arm keeps its traces; the sha256 of the
document as the suite wrote it stays in `sha256_unpacked.robustness`.

    python3 scripts/zoo/pack.py [--zoo assets/zoo]
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import os
from pathlib import Path

PROJECT = Path(__file__).resolve().parents[2]


def read_json_doc(cell: Path, name: str):
    """A cell document, plain or gzipped (None when neither is there)."""
    if (cell / name).is_file():
        return json.loads((cell / name).read_bytes())
    if (cell / f"{name}.gz").is_file():
        return json.loads(gzip.decompress((cell / f"{name}.gz").read_bytes()))
    return None


def strip_suite_traces(raw: bytes) -> bytes:
    doc = json.loads(raw)
    for level in doc["levels"]:
        for r in level["result"]["rollouts"]:
            r.pop("trace", None)
    doc["traces_stripped"] = "perturbed levels' rollout traces removed for shipping (scripts/zoo/pack.py)"
    return json.dumps(doc, separators=(",", ":")).encode()


SAMPLED_TRACES = 60


def replace_file(path: Path, data: bytes) -> None:
    """Writes `data` to `path` atomically (a temporary file beside it, then a rename)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def write_provenance(cell: Path, prov: dict) -> None:
    replace_file(cell / "provenance.json", (json.dumps(prov, indent=2) + "\n").encode())


def sample_result_traces(doc: dict) -> dict:
    """Drops the traces of every rollout but the first ceil(SAMPLED_TRACES / states)
    of each initial state; returns what `shipped_traces` records."""
    rollouts = doc["rollouts"]
    states = len({r["context_index"] for r in rollouts}) or 1
    per_state = -(-SAMPLED_TRACES // states)
    for r in rollouts:
        if r["rollout_index"] >= per_state:
            r.pop("trace", None)
    return {
        "rule": f"the first {per_state} rollouts of each of the {states} initial states keep their traces "
        "(scripts/zoo/pack.py); the others' were dropped for shipping",
        "rollouts_per_state": per_state,
        "with_trace": sum(1 for r in rollouts if r.get("trace")),
        "rollouts": len(rollouts),
    }


def pack_cell(cell: Path, keep_suite_traces: bool = False) -> int:
    prov_path = cell / "provenance.json"
    prov = json.loads(prov_path.read_text())
    saved = 0
    for kind, name in (("result", "result.json"), ("robustness", "robustness.json")):
        plain = cell / name
        if not plain.is_file():
            continue
        raw = plain.read_bytes()
        if hashlib.sha256(raw).hexdigest() != prov["sha256"].get(kind):
            raise SystemExit(f"{plain}: sha256 differs from its provenance; not packing a changed file")
        if kind == "result":
            doc = json.loads(raw)
            prov["shipped_traces"] = sample_result_traces(doc)
            body = json.dumps(doc, separators=(",", ":")).encode()
        else:
            body = raw if keep_suite_traces else strip_suite_traces(raw)
        packed = gzip.compress(body, compresslevel=9, mtime=0)
        replace_file(cell / f"{name}.gz", packed)
        prov.setdefault("sha256_unpacked", {})[kind] = prov["sha256"][kind]
        prov["sha256"][kind] = hashlib.sha256(packed).hexdigest()
        saved += len(raw) - len(packed)
        write_provenance(cell, prov)
        plain.unlink()
    saved += sample_packed_result(cell, prov)
    return saved


def sample_packed_result(cell: Path, prov: dict) -> int:
    """A cell packed before results shipped sampled traces: samples its gzipped
    result in place (its sha256_unpacked, the document as evaluated, stays)."""
    gz = cell / "result.json.gz"
    if "shipped_traces" in prov or not gz.is_file():
        return 0
    packed = gz.read_bytes()
    if hashlib.sha256(packed).hexdigest() != prov["sha256"]["result"]:
        raise SystemExit(f"{gz}: sha256 differs from its provenance; not packing a changed file")
    doc = json.loads(gzip.decompress(packed))
    prov["shipped_traces"] = sample_result_traces(doc)
    new = gzip.compress(json.dumps(doc, separators=(",", ":")).encode(), compresslevel=9, mtime=0)
    replace_file(gz, new)
    prov["sha256"]["result"] = hashlib.sha256(new).hexdigest()
    write_provenance(cell, prov)
    return len(packed) - len(new)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zoo", type=Path, default=PROJECT / "assets" / "zoo")
    ap.add_argument("--keep-suite-traces", action="store_true")
    a = ap.parse_args()
    total = 0
    for prov in sorted(a.zoo.glob("*/*/provenance.json")):
        total += pack_cell(prov.parent, a.keep_suite_traces)
    size = sum(f.stat().st_size for f in a.zoo.rglob("*") if f.is_file())
    print(f"packed: {total / 1e6:.1f} MB saved; the zoo is {size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
