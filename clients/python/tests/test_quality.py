"""ruff (lint, docstrings on the public API, format) and mypy --strict are clean."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@pytest.mark.parametrize(
    "command",
    [
        ["ruff", "check", "."],
        ["ruff", "format", "--check", "."],
        ["mypy"],
    ],
    ids=["ruff-check", "ruff-format", "mypy"],
)
def test_the_package_is_clean(command: list[str]) -> None:
    out = subprocess.run([BIN / command[0], *command[1:]], capture_output=True, text=True, cwd=PACKAGE, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr


def test_the_public_api_is_documented() -> None:
    import d3il_client
    import d3il_client.serve

    for module in (d3il_client, d3il_client.serve):
        assert module.__doc__
        for name in module.__all__:
            obj = getattr(module, name)
            if callable(obj):
                assert obj.__doc__, f"{module.__name__}.{name} has no docstring"
    for name, member in vars(d3il_client.Client).items():
        if not name.startswith("_") and callable(member):
            assert member.__doc__, f"Client.{name} has no docstring"
