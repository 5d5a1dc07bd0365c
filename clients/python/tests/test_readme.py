"""README.md's "From Python" example, run exactly as written (in the fresh virtualenv)."""

from __future__ import annotations

import os
import re
import subprocess

from conftest import REPO, Server, fresh_python


def readme_example() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## From Python", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the From Python section has one Python example"
    return str(blocks[0])


def test_the_example_is_ten_lines() -> None:
    lines = [line for line in readme_example().splitlines() if line.strip()]
    assert len(lines) <= 10, lines


def test_the_readme_example_runs_as_written(server: Server) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env.update(D3IL_SERVER=server.base, D3IL_TOKEN=server.token)
    out = subprocess.run(
        [fresh_python(), "-I", "-c", readme_example()],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
        timeout=1200,
    )
    assert out.returncode == 0, out.stderr
    # The per-behaviour success rate of the path follower, then the comparison table.
    assert "behaviour_label" in out.stdout
    assert "success_rate" in out.stdout and "conditional_entropy" in out.stdout
    assert "p_value" in out.stdout
