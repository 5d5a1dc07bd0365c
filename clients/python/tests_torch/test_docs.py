"""Every Python example of docs/export.md and docs/submission.md runs as written.

The ```python blocks of each page run in order in one fresh interpreter (a page's
blocks build on each other) in a scratch directory, with the reference-like agents
(tests_torch/reference_like) importable for examples that need a trained agent. A
block whose info string says ``python no-run`` is left out (none should be). What
the examples write is then checked: the BC example gives finite actions on Aligning
observations whose constant dimensions differ from the training data's (the NaN of
the old recipe), and every ONNX file they write passes ``d3il infer``.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import List

import numpy as np
import onnxruntime as ort
import pytest

ROOT = Path(__file__).resolve().parents[3]
D3IL = os.environ.get("D3IL_BIN", "d3il")


def python_blocks(page: Path) -> List[str]:
    return [m.group(1) for m in re.finditer(r"```python\n(.*?)```", page.read_text(), re.S)]


@pytest.mark.parametrize("page", ["docs/export.md", "docs/submission.md"])
def test_examples_run(page: str, tmp_path: Path):
    blocks = python_blocks(ROOT / page)
    script = tmp_path / "examples.py"
    script.write_text("\n\n".join(blocks))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "clients/python"), str(ROOT / "clients/python/tests_torch")])
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert p.returncode == 0, f"{page}'s examples failed:\n{p.stdout}\n{p.stderr}"
    for onnx in tmp_path.glob("*.onnx"):
        manifest = onnx.with_suffix(".json")
        assert manifest.exists(), f"{page} wrote {onnx.name} without its manifest"
        task = json.loads(manifest.read_text())["task"]
        q = subprocess.run(
            [D3IL, "eval", "--task", task, "--policy", str(onnx), "--protocol", "quick"],
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert q.returncode == 0, f"d3il eval refused {page}'s {onnx.name}:\n{q.stderr}"
    if page == "docs/submission.md":
        sess = ort.InferenceSession(str(tmp_path / "bc_mlp_aligning.onnx"))
        obs = np.full((4, 1, 20), 0.5, np.float32)
        obs[:, 0, 16:] = 0.3  # a target pose the training data never had (std 0 there)
        (actions,) = sess.run(None, {"obs": obs})
        assert np.isfinite(actions).all(), actions
