"""BeT family against the reference-like BeT_Agent (tests_torch/reference_like/bet.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, List

import onnx
import pytest
import torch
from family_helpers import export_and_compare, matching_families
from reference_like import bet as ref

from d3il_client.agents.base import Draw, multinomial_draw, uniform_from_noise
from d3il_client.agents.bet import FAMILY, BetFamily
from d3il_client.agents.check import CheckFailed, against_predict


def test_recognised_as_bet():
    assert matching_families(ref.make_agent()) == ["bet"]


@pytest.mark.parametrize("k", [3, 5])
def test_settings_from_the_object(k: int):
    s = FAMILY.settings(ref.make_agent(window_size=k))
    assert (s.obs_dim, s.act_dim, s.history, s.window, s.horizon, s.execute) == (20, 3, k, "grow", 1, 1)
    assert s.noise_shape == (1,) and not s.prev_actions


@pytest.mark.parametrize("k", [1, 3, 5])
def test_module_equals_predict_over_the_growing_window(k: int):
    cases = against_predict(ref.make_agent(window_size=k), FAMILY, batch=3, steps=k + 4)
    assert [c.window for c in cases] == [min(t + 1, k) for t in range(k + 4)]


def test_the_noise_picks_the_bin():
    """Different uniforms give different bins, hence actions: the sampling is live."""
    agent = ref.make_agent()
    module = FAMILY.graph(agent).eval()
    obs = agent.scaler.x_mean.expand(1, 3, 20)
    with torch.no_grad():
        acts = torch.cat([module(obs, None, torch.full((1, 1), z)) for z in torch.linspace(-3, 3, 25)])
    assert len({tuple(a.reshape(-1).tolist()) for a in acts}) >= 4


class _OtherDraws(BetFamily):
    """Draws the bin from 1 − u: the check must see it."""

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        u = 1.0 - uniform_from_noise(noise.reshape(1))
        return [multinomial_draw(u.expand(window).clone())]


def test_the_check_sees_other_draws():
    with pytest.raises(CheckFailed):
        against_predict(ref.make_agent(), _OtherDraws(), batch=3, steps=6)


def test_onnx_equals_the_module_at_every_window(tmp_path: Path):
    """Exported at window k, run at 1..k (the minGPT's x.size() slices stay symbolic)."""
    agent = ref.make_agent(window_size=5)
    cases = against_predict(agent, FAMILY, batch=3, steps=7)
    assert sorted({c.window for c in cases}) == [1, 2, 3, 4, 5]
    assert export_and_compare(FAMILY, agent, cases, tmp_path / "bet.onnx") <= 1e-5
    # the exporter writes squeeze() of a dynamic shape as an If, which tract cannot plan: none here
    ops = {n.op_type for n in onnx.load(str(tmp_path / "bet.onnx")).graph.node}
    assert "If" not in ops and not ops & {"RandomNormal", "RandomUniform", "Multinomial"}
