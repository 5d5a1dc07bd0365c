"""BC (MLP) family against the reference-like BC_Agent (tests_torch/reference_like/bc.py)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import torch
from family_helpers import export_and_compare, matching_families
from reference_like import bc as ref
from reference_like.scaler import Scaler, aligning_like_data

from d3il_client.agents.bc import FAMILY
from d3il_client.agents.check import against_predict, observations


def test_recognised_as_bc():
    assert matching_families(ref.make_agent()) == ["bc"]


def test_settings_from_the_object():
    s = FAMILY.settings(ref.make_agent())
    assert (s.obs_dim, s.act_dim, s.history, s.horizon, s.execute) == (20, 3, 1, 1, 1)
    assert s.noise_shape is None and not s.prev_actions


def test_module_equals_predict():
    cases = against_predict(ref.make_agent(), FAMILY, batch=3, steps=6)
    assert len(cases) == 6 and all(c.window == 1 for c in cases)


def test_clamp_before_inverse_scaling():
    """Outputs far outside the data bounds: predict clamps the scaled output to
    y_bounds, and so does the module (checked against predict, so both clamp).
    """
    agent = ref.make_agent()
    with torch.no_grad():
        agent.model.model.layers[-1].weight.mul_(50.0)
    cases = against_predict(agent, FAMILY, batch=3, steps=3)
    lo = agent.scaler.inverse_scale_output(agent.min_action.float()).float()
    hi = agent.scaler.inverse_scale_output(agent.max_action.float()).float()
    acts = torch.cat([c.actions.reshape(-1, 3) for c in cases])
    at_bound = ((acts - lo).abs() < 1e-6) | ((acts - hi).abs() < 1e-6)
    assert at_bound.any(), "the scaled test did not reach the bounds"


def test_old_recipe_without_eps_is_nan_on_constant_dims():
    """Regression (issue 39): the old recipe, (obs - mean) / std without the 1e-12,
    gives NaN on Aligning-like data (4 observation dims with std 0) at the first step,
    while the module is finite and equal to predict().
    """
    agent = ref.make_agent()
    sc = agent.scaler
    assert (sc.x_std == 0).sum() == 4
    obs = observations(agent, 3, 1, torch.Generator().manual_seed(0))  # [3, 1, 20]
    mlp = agent.model
    old = mlp((obs[:, -1] - sc.x_mean) / sc.x_std) * sc.y_std + sc.y_mean
    assert torch.isnan(old).any()
    module = FAMILY.graph(agent).eval()
    with torch.no_grad():
        ours = module(obs, None, None)
    assert torch.isfinite(ours).all()
    for b in range(3):
        want = copy.deepcopy(agent).predict(obs[b, 0].numpy().astype(np.float32))
        assert np.abs(np.asarray(want).reshape(-1) - ours[b, 0].numpy()).max() <= 1e-6


def test_exports_and_matches_onnxruntime(tmp_path: Path):
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=3, steps=4)
    assert export_and_compare(FAMILY, agent, cases, tmp_path / "bc.onnx") <= 1e-5
    # another batch size than the example's
    cases5 = against_predict(agent, FAMILY, batch=5, steps=2, seed=1)
    assert export_and_compare(FAMILY, agent, cases5, tmp_path / "bc5.onnx") <= 1e-5


def test_constant_dims_off_their_training_value():
    """In the simulator a constant dimension may differ from its training value by a
    rounding: (x - mean) / 1e-12 is then huge, the network saturates and the clamp
    bounds the action; the module computes the same as predict() (finite, clamped).
    """
    agent = ref.make_agent()
    obs = observations(agent, 4, 1, torch.Generator().manual_seed(1))
    obs[:, :, -4:] += torch.tensor([1e-7, -3e-8, 2e-6, 0.0])
    with torch.no_grad():
        ours = FAMILY.graph(agent).eval()(obs, None, None)
    assert torch.isfinite(ours).all()
    for b in range(4):
        want = copy.deepcopy(agent).predict(obs[b, 0].numpy().astype(np.float32))
        assert np.abs(np.asarray(want).reshape(-1) - ours[b, 0].numpy()).max() <= 1e-6


def test_unscaled_agent():
    """scale_data: False — no scaling at all, the bounds are the raw data's."""
    agent = ref.make_agent()
    x, y = aligning_like_data(ref.OBS_DIM, ref.ACT_DIM)
    agent = ref.BC_Agent(agent.model, Scaler(x, y, False, "cpu"))
    against_predict(agent, FAMILY, batch=3, steps=3)
