"""BC-GPT family against the reference-like Gpt_Agent (tests_torch/reference_like/gpt_bc.py)."""

from __future__ import annotations

from pathlib import Path

import onnxruntime as ort
import pytest
import torch
from family_helpers import export_and_compare, matching_families
from reference_like import gpt_bc as ref

from d3il_client.agents.check import against_predict
from d3il_client.agents.gpt_bc import FAMILY


def test_recognised_as_bc_gpt():
    assert matching_families(ref.make_agent()) == ["bc_gpt"]


def test_a_vision_agent_is_not_recognised():
    agent = ref.make_agent()
    agent.model.visual_input = True
    assert not FAMILY.matches(agent)


@pytest.mark.parametrize("k", [3, 5])
def test_settings_from_the_object(k: int):
    s = FAMILY.settings(ref.make_agent(window_size=k))
    assert (s.obs_dim, s.act_dim, s.history, s.window, s.horizon, s.execute) == (20, 3, k, "grow", 1, 1)
    assert s.noise_shape is None and not s.prev_actions


@pytest.mark.parametrize("k", [1, 3, 5])
def test_module_equals_predict_over_the_growing_window(k: int):
    cases = against_predict(ref.make_agent(window_size=k), FAMILY, batch=3, steps=k + 3)
    assert [c.window for c in cases] == [min(t + 1, k) for t in range(k + 3)]


def test_onnx_equals_the_module_at_every_window(tmp_path: Path):
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=3, steps=5)
    assert export_and_compare(FAMILY, agent, cases, tmp_path / "gpt_bc.onnx") <= 1e-5


def test_exported_at_window_k_runs_at_window_1(tmp_path: Path):
    """The minGPT slices pos_emb and its causal mask with sizes from x.size(): the
    trace exported with a window of k must still be right with one observation
    (the first call of an episode) and with a batch of another size.
    """
    agent = ref.make_agent(window_size=5)
    module = FAMILY.graph(agent).eval()
    path = tmp_path / "gpt_bc.onnx"
    with torch.no_grad():
        torch.onnx.export(
            module,
            (torch.randn(2, 5, 20),),
            str(path),
            input_names=["obs"],
            output_names=["actions"],
            dynamic_axes={"obs": {0: "B", 1: "T"}, "actions": {0: "B"}},
            opset_version=18,
            dynamo=False,
        )
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    mean, std = agent.scaler.x_mean, agent.scaler.x_std
    for b, t in ((3, 1), (1, 2), (4, 5)):
        obs = mean + std * torch.randn(b, t, 20)
        (got,) = sess.run(["actions"], {"obs": obs.numpy()})
        with torch.no_grad():
            want = module(obs)
        assert got.shape == (b, 1, 3)
        assert float((torch.as_tensor(got) - want).abs().max()) <= 1e-5
