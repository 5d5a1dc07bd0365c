"""Smoke test of the zoo driver on a tiny synthetic demonstration set (docs/zoo.md).

    D3IL_REFERENCE=/work/d3il-ref PYTHONPATH=clients/python \
        ~/.cache/d3il/venvs/torch/bin/python -m pytest scripts/zoo/test_zoo.py -q

Needs a work-tree checkout of ALRhub/d3il (D3IL_REFERENCE), the torch virtualenv with
scripts/zoo/requirements.txt and a d3il binary (D3IL_BIN or target/release/d3il): without
them the run stops at once and says which is missing, as a skipped test would not run at all.
The cell runs to its provenance record at the quick protocol. One BC cell, 2 epochs: a few
seconds of training. Not part of ./dev test: the checkout is fetched from GitHub, which the
tests do not reach (docs/zoo.md says how to fetch it).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import grid  # noqa: E402
import synth_demos  # noqa: E402
import train_cell  # noqa: E402

REFERENCE = os.environ.get("D3IL_REFERENCE")
D3IL = os.environ.get("D3IL_BIN") or str(HERE.parent.parent / "target" / "release" / "d3il")
if not REFERENCE or not Path(REFERENCE, "configs").is_dir():
    raise pytest.UsageError(f"D3IL_REFERENCE={REFERENCE!r} is not a work-tree checkout of ALRhub/d3il "
                            "(its configs/ folder): set it to one (docs/zoo.md)")
if not Path(D3IL).is_file():
    raise pytest.UsageError(f"no d3il binary at {D3IL}: build one (cargo build --release) or set D3IL_BIN")


def test_script_overrides_are_read_from_the_checkout():
    got = train_cell.script_overrides(Path(REFERENCE), "avoiding", "beso")
    assert "agents=beso_agent" in got and "window_size=5" in got and "agents.num_sampling_steps=4" in got
    assert not any(w.startswith("seed=") or w.startswith("--") for w in got)


def test_budgets_rename_a_scripts_keys_and_replace_its_values():
    script = train_cell.script_overrides(Path(REFERENCE), "avoiding", "ddpm_encdec")
    assert "agents=ddpm_encdec" in script  # a config the checkout does not have
    assert not Path(REFERENCE, "configs", "agents", "ddpm_encdec.yaml").exists()
    budgets = json.loads((HERE / "budgets.json").read_text())
    cell = budgets["methods"]["ddpm_encdec"]
    got = train_cell.rename_keys(script, cell.get("script_renames", {}), cell["script_values"])
    assert "agents=ddpm_encdec_agent" in got and "agents=ddpm_encdec" not in got
    assert Path(REFERENCE, "configs", "agents", "ddpm_encdec_agent.yaml").is_file()
    assert train_cell.rename_keys(["a.b=1", "c=2"], {"a.b": "a.x.b"}) == ["a.x.b=1", "c=2"]


def test_mirror_points_the_data_dir_at_the_demos_and_leaves_the_checkout_alone(tmp_path):
    demos = synth_demos.write("aligning", 4, 20, tmp_path / "demos")
    before = subprocess.run(["git", "-C", REFERENCE, "status", "--porcelain"], capture_output=True, text=True).stdout
    m = train_cell.mirror(Path(REFERENCE), demos, "aligning", tmp_path / "ref")
    data = m / "environments" / "dataset" / "data"
    assert (data / "aligning").resolve() == demos.resolve()
    assert (data / "pushing").resolve() == (Path(REFERENCE) / "environments/dataset/data/pushing").resolve()
    assert (m / "environments" / "dataset" / "aligning_dataset.py").is_file()
    after = subprocess.run(["git", "-C", REFERENCE, "status", "--porcelain"], capture_output=True, text=True).stdout
    assert before == after


def test_one_cell_end_to_end_and_the_grid_skips_it(tmp_path):
    demos_root = tmp_path / "demos"
    synth_demos.write("avoiding", 6, 40, demos_root / "avoiding")
    out = tmp_path / "zoo" / "avoiding" / "bc-mlp-s0"
    work = tmp_path / "work" / "avoiding" / "bc-s0"
    args = ["--reference", REFERENCE, "--demos", str(demos_root / "avoiding"), "--task", "avoiding",
            "--method", "bc", "--seed", "0", "--out", str(out), "--work", str(work), "--epochs", "2",
            "--protocol", "quick", "--d3il", D3IL]
    assert train_cell.main(args) == 0
    prov = json.loads((out / "provenance.json").read_text())
    # the fields server/src/zoo.rs reads
    assert prov["zoo_version"] == "v1" and prov["task"] == "avoiding" and prov["method"] == "BC-MLP"
    assert prov["seed"] == 0 and prov["demos"]["version"] == "synthetic-1"
    assert prov["complete"] and prov["demos"]["manifest"]["synthetic"] is True
    assert len(prov["training"]["loss_curve"]) == 2 and prov["budget"]["epochs"] == 2
    assert "agents=bc_agent" in prov["overrides"] and "device=cpu" in prov["overrides"]
    for kind, name in (("onnx", "policy.onnx"), ("result", "result.json"), ("manifest", "policy.json"),
                       ("checkpoint", "checkpoint.pt")):
        assert prov["sha256"][kind] == train_cell.sha256(out / name)
    assert not work.exists()
    assert grid.main(["--reference", REFERENCE, "--demos-root", str(demos_root), "--out", str(tmp_path / "zoo"),
                      "--tasks", "avoiding", "--methods", "bc", "--seeds", "0"]) == 0
