"""BeT-MLP family against the reference-like BetMLP_Agent (tests_torch/reference_like/bet_mlp.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from family_helpers import export_and_compare, matching_families
from reference_like import bet_mlp as ref

from d3il_client.agents.base import uniform_from_noise
from d3il_client.agents.bet_mlp import FAMILY
from d3il_client.agents.check import against_predict


def test_recognised_as_bet_mlp():
    assert matching_families(ref.make_agent()) == ["bet_mlp"]


def test_settings_from_the_object():
    s = FAMILY.settings(ref.make_agent())
    assert (s.obs_dim, s.act_dim, s.history, s.horizon, s.execute) == (20, 3, 1, 1, 1)
    assert s.noise_shape == (1,) and str(ref.VOCAB) in s.sampler


def test_module_equals_predict_with_several_bins():
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=8, steps=6)
    # several bins were actually picked: the actions of one observation under many
    # noises take more than one value
    obs = cases[0].obs[:1].expand(64, -1, -1)
    noise = torch.linspace(-2.5, 2.5, 64).unsqueeze(-1)
    with torch.no_grad():
        acts = FAMILY.graph(agent).eval()(obs, None, noise)[:, 0]
    distinct = torch.unique(acts.round(decimals=6), dim=0)
    assert len(distinct) >= 3, distinct


def test_inverse_cdf_follows_the_probabilities():
    """Φ(noise) below the first bin's probability picks bin 0, above the total the last."""
    agent = ref.make_agent()
    g = FAMILY.graph(agent).eval()
    obs = torch.as_tensor(agent.scaler.x_mean).reshape(1, 1, -1)
    with torch.no_grad():
        lo = g(obs, None, torch.tensor([[-8.0]]))
        hi = g(obs, None, torch.tensor([[8.0]]))
    assert uniform_from_noise(torch.tensor(-8.0)) < 1e-12
    centers = agent.action_ae.bin_centers
    assert not torch.allclose(lo, hi)
    assert centers.shape[0] == ref.VOCAB


def test_refuses_predict_offsets_false():
    agent = ref.make_agent()
    agent.model.predict_offsets = False
    with pytest.raises(ValueError, match="predict_offsets"):
        FAMILY.graph(agent)


def test_exports_and_matches_onnxruntime(tmp_path: Path):
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=4, steps=4)
    cases += against_predict(agent, FAMILY, batch=7, steps=2, seed=1)
    assert export_and_compare(FAMILY, agent, cases, tmp_path / "bet_mlp.onnx") <= 1e-5
