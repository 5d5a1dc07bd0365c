"""VAE-State family against the reference-like CVAEAgent (tests_torch/reference_like/vae.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from family_helpers import export_and_compare, matching_families
from reference_like import vae as ref

from d3il_client.agents.base import TapeError
from d3il_client.agents.check import CheckFailed, against_predict
from d3il_client.agents.vae import FAMILY


def test_recognised_as_vae_state():
    assert matching_families(ref.make_agent()) == ["vae_state"]


def test_settings_from_the_object():
    agent = ref.make_agent()
    s = FAMILY.settings(agent)
    assert (s.obs_dim, s.act_dim, s.history, s.horizon, s.execute) == (20, 3, 1, 1, 1)
    assert s.noise_shape == (ref.LATENT_DIM,)
    agent.model.latent_dim = 7  # read from the object, not assumed
    assert FAMILY.settings(agent).noise_shape == (7,)


def test_module_equals_predict():
    cases = against_predict(ref.make_agent(), FAMILY, batch=3, steps=6)
    assert len(cases) == 6
    # the latent's clamp to ±0.5 is exercised: some noise is beyond it
    assert any((c.noise.abs() > 0.5).any() for c in cases if c.noise is not None)


def test_the_latent_matters():
    """A wrong draw is caught: predict fed other draws than the module's noise differs."""
    agent = ref.make_agent()

    class Shifted(type(FAMILY)):  # type: ignore[misc]
        def draws(self, agent, noise, window):
            return super().draws(agent, -noise, window)

    with pytest.raises(CheckFailed):
        against_predict(agent, Shifted(), batch=3, steps=3)

    class Wrong(type(FAMILY)):  # type: ignore[misc]
        def draws(self, agent, noise, window):
            return []  # predict draws a latent the family did not announce

    with pytest.raises(TapeError):
        against_predict(agent, Wrong(), batch=1, steps=1)


def test_exports_and_matches_onnxruntime(tmp_path: Path):
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=3, steps=4)
    cases += against_predict(agent, FAMILY, batch=5, steps=2, seed=1)
    assert export_and_compare(FAMILY, agent, cases, tmp_path / "vae.onnx") <= 1e-5
