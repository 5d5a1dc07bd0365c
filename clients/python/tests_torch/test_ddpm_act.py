"""DDPM-ACT against the reference-like encoder-decoder DiffusionAgent
(tests_torch/reference_like/ddpm_act.py): recognised (not as DDPM-MLP/GPT, the same
class name), settings read from the object (the reference's Aligning setting and
its other tasks' one), the module equal to predict() fed the same draws over chunk
boundaries and windows 1..k, and the export traced at window k right at every window.
"""

from __future__ import annotations

import onnx
import pytest
import torch
from family_helpers import export_and_compare, matching_families
from reference_like import ddpm_act as ref
from test_ddpm import slices_from_shapes

from d3il_client.agents.check import against_predict
from d3il_client.agents.ddpm import FAMILIES
from d3il_client.agents.ddpm_act import FAMILY

torch.set_num_threads(1)

ALIGNING = dict(obs_seq_len=1, action_seq_size=10, action_seq_len=10, window_size=10)


def test_recognised_as_ddpm_act():
    a = ref.make_agent()
    assert FAMILY.matches(a)
    assert not any(f.matches(a) for f in FAMILIES)
    assert matching_families(a) == ["ddpm_act"]


def test_settings_come_from_the_object():
    s = FAMILY.settings(ref.make_agent(n_timesteps=6))
    assert (s.obs_dim, s.act_dim, s.history, s.window, s.horizon, s.execute) == (20, 3, 5, "grow", 4, 4)
    assert s.noise_shape == (6, 4, 3) and not s.prev_actions
    s = FAMILY.settings(ref.make_agent(**ALIGNING))
    assert (s.history, s.horizon, s.execute, s.noise_shape) == (1, 10, 10, (8, 10, 3))
    assert FAMILY.settings(ref.make_agent(action_seq_size=3)).execute == 3


def test_equals_predict_over_chunk_boundaries():
    a = ref.make_agent(n_timesteps=4)
    cases = against_predict(a, FAMILY)  # k + 2E + 1 steps: calls at 0, 4, 8, 12
    assert [c.window for c in cases] == [1, 5, 5, 5]


def test_equals_predict_at_every_window():
    cases = against_predict(ref.make_agent(action_seq_size=1, n_timesteps=3), FAMILY, steps=6)
    assert [c.window for c in cases] == [1, 2, 3, 4, 5, 5]


def test_equals_predict_executing_part_of_the_chunk():
    cases = against_predict(ref.make_agent(action_seq_size=3, n_timesteps=3), FAMILY, steps=8)
    assert [c.window for c in cases] == [1, 4, 5]


def test_aligning_setting_equals_predict():
    against_predict(ref.make_agent(n_timesteps=3, **ALIGNING), FAMILY, steps=12)


def test_a_chunk_shorter_than_executed_is_refused():
    a = ref.make_agent()
    a.action_seq_size = 5
    with pytest.raises(ValueError, match="action_seq_len=4"):
        FAMILY.settings(a)


def test_traced_at_window_k_runs_at_windows_1_to_k(tmp_path):
    a = ref.make_agent(action_seq_size=1, n_timesteps=3)
    cases = against_predict(a, FAMILY, steps=5)
    assert [c.window for c in cases] == [1, 2, 3, 4, 5]
    assert export_and_compare(FAMILY, a, cases, tmp_path / "act.onnx") <= 1e-5
    # the action positions start at w - 1: gathered, not sliced from a shape
    assert slices_from_shapes(onnx.load(str(tmp_path / "act.onnx"))) == []


def test_aligning_setting_exports(tmp_path):
    a = ref.make_agent(n_timesteps=3, **ALIGNING)
    cases = against_predict(a, FAMILY, steps=11)
    assert export_and_compare(FAMILY, a, cases, tmp_path / "act.onnx") <= 1e-5
