"""Gzips the zoo cells' JSON documents for shipping (docs/zoo.md, size budget):
`result.json` and `robustness.json` become `result.json.gz` and
`robustness.json.gz` (deterministic: no name, mtime 0, level 9), and the cell's
provenance.json gets the shipped files' sha256 (`sha256.result`,
`sha256.robustness`; the plain file's sha256 is kept under `sha256_unpacked`).
The server and `d3il zoo` read either form. Idempotent.

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


def pack_cell(cell: Path) -> int:
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
        packed = gzip.compress(raw, compresslevel=9, mtime=0)
        tmp = cell / f".{name}.gz.tmp"
        tmp.write_bytes(packed)
        os.replace(tmp, cell / f"{name}.gz")
        prov.setdefault("sha256_unpacked", {})[kind] = prov["sha256"][kind]
        prov["sha256"][kind] = hashlib.sha256(packed).hexdigest()
        saved += len(raw) - len(packed)
        tmpp = cell / ".provenance.json.tmp"
        tmpp.write_text(json.dumps(prov, indent=2) + "\n")
        os.replace(tmpp, prov_path)
        plain.unlink()
    return saved


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zoo", type=Path, default=PROJECT / "assets" / "zoo")
    a = ap.parse_args()
    total = 0
    for prov in sorted(a.zoo.glob("*/*/provenance.json")):
        total += pack_cell(prov.parent)
    size = sum(f.stat().st_size for f in a.zoo.rglob("*") if f.is_file())
    print(f"packed: {total / 1e6:.1f} MB saved; the zoo is {size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
