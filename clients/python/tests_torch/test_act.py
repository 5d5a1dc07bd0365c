"""VAE-ACT family against the reference-like ActAgent (tests_torch/reference_like/act.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from family_helpers import export_and_compare, matching_families
from reference_like import act as ref

from d3il_client.agents.act import FAMILY
from d3il_client.agents.check import against_predict


def test_recognised_as_vae_act():
    assert matching_families(ref.make_agent()) == ["vae_act"]


def test_settings_from_the_object():
    s = FAMILY.settings(ref.make_agent())
    assert (s.obs_dim, s.act_dim, s.history, s.horizon, s.execute) == (20, 3, 1, 3, 3)
    assert s.noise_shape == (ref.LATENT_DIM,) and s.window == "pad"


def test_module_equals_predict_over_chunk_boundaries():
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=3, steps=10)  # calls at steps 0, 3, 6, 9
    assert len(cases) == 4
    chunk = cases[0].actions
    assert (chunk[:, 0] - chunk[:, 1]).abs().max() > 1e-4, "the chunk's actions should differ"


def test_executing_fewer_than_the_chunk():
    """action_seq_size below the model's chunk: predict re-plans every E steps, H stays
    the model's (the agent's own assert on window_size is kept by the mimic).
    """
    agent = ref.make_agent()
    agent.action_seq_size = 2
    agent.window_size = 2
    agent.reset()
    s = FAMILY.settings(agent)
    assert (s.horizon, s.execute) == (3, 2)
    assert len(against_predict(agent, FAMILY, batch=2, steps=7)) == 4


def test_refuses_an_execute_beyond_the_chunk():
    agent = ref.make_agent()
    agent.action_seq_size = 4
    with pytest.raises(ValueError, match="action_seq_size"):
        FAMILY.settings(agent)


def test_exports_and_matches_onnxruntime(tmp_path: Path):
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=3, steps=7)
    cases += against_predict(agent, FAMILY, batch=5, steps=1, seed=1)
    assert export_and_compare(FAMILY, agent, cases, tmp_path / "act.onnx") <= 1e-5
