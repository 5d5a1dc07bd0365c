"""The robustness track through the client: ``submit(..., suite="robustness")`` of the
deterministic Aligning MLP fixture under the quick protocol against a real server, the
robustness document and its DataFrame, and the refusals (unknown suite before sending;
a task whose suite file the server's assets lack, by the server, naming the field)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import FIXTURES, REPO, run_server

from d3il_client import Client, errors


def test_a_robustness_submission_gives_its_document_and_frame(client: Client) -> None:
    sub = client.submit(
        onnx=FIXTURES / "aligning_mlp.onnx",
        method="pytest-robust",
        task="aligning",
        training_seed=0,
        protocol="quick",
        suite="robustness",
    )
    done = client.wait(sub, timeout=1500, progress=False)
    assert done.status == "completed"
    doc = client.robustness(done)
    assert doc["format"] == "d3il-robustness-v1" and doc["suite"].startswith("aligning-v")
    # Level 0 is the submission's plain result.
    assert doc["control"]["metrics"]["success_rate"]["value"] == client.results(done).metrics.success_rate.value
    assert all(level["result"]["rollouts"] == [] for level in doc["levels"]), "no records unless asked"
    whole = client.robustness(done, rollouts=True)
    assert all(len(level["result"]["rollouts"]) == 6 for level in whole["levels"])
    frame = client.robustness_frame(done)
    assert len(frame) == 1 + len(doc["levels"])
    assert frame["axis"].iloc[0] == "control" and frame["retained"].iloc[0] == 1.0
    assert set(frame["axis"].iloc[1:]) == {"start_shift", "obs_noise", "latency", "dynamics"}
    assert frame["drop"].iloc[1:].notna().all()


def test_suites_are_checked(client: Client, tmp_path: Path) -> None:
    with pytest.raises(errors.ManifestError, match="suite `sturdy`"):
        client.submit(
            onnx=FIXTURES / "aligning_mlp.onnx",
            method="pytest-robust",
            task="aligning",
            training_seed=1,
            suite="sturdy",
        )
    # Every task has a state suite and every image variant an image suite: a
    # server whose assets lack a task's suite file refuses it by the field.
    assets = tmp_path / "assets"
    (assets / "robustness").mkdir(parents=True)
    for entry in (REPO / "assets").iterdir():
        if entry.name != "robustness":
            (assets / entry.name).symlink_to(entry)
    for suite in (REPO / "assets" / "robustness").iterdir():
        if not suite.name.startswith("stacking-image-v"):
            (assets / "robustness" / suite.name).write_bytes(suite.read_bytes())
    with run_server(tmp_path, "--assets", str(assets)) as partial:
        with pytest.raises(errors.BadRequest) as e:
            Client(partial.base, partial.token).submit(
                onnx=FIXTURES / "aligning_image.onnx",
                manifest={"task": "stacking", "obs_type": "image", "history": 1, "horizon": 1, "execute": 1},
                method="pytest-robust",
                task="stacking",
                obs_type="image",
                training_seed=1,
                protocol="quick",
                suite="robustness",
            )
    assert e.value.field == "suite" and "no robustness suite" in e.value.message
    assert "image observations: aligning, sorting-4, sorting-6;" in e.value.message
