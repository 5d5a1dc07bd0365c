"""DDPM-MLP and DDPM-GPT against the reference-like DiffusionAgent
(tests_torch/reference_like/ddpm.py): recognised apart, settings read from the
object, the module equal to predict() fed the same draws (windows 1..k and beyond,
the 2-D state of window 1, diffusion_x, every schedule), and the tracing trap of
DiffusionTransformerNetwork at the ONNX level.
"""

from __future__ import annotations

import io

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from family_helpers import export_and_compare, matching_families
from reference_like import ddpm as ref

from d3il_client.agents.check import CheckFailed, against_predict
from d3il_client.agents.ddpm import DdpmGpt, DdpmMlp

# A loaded 2-core machine runs these small calls far faster on one thread.
torch.set_num_threads(1)

MLP, GPT = DdpmMlp(), DdpmGpt()


def test_mlp_and_gpt_are_told_apart():
    mlp, gpt = ref.make_mlp_agent(), ref.make_gpt_agent()
    assert MLP.matches(mlp) and not GPT.matches(mlp)
    assert GPT.matches(gpt) and not MLP.matches(gpt)
    assert matching_families(mlp) == ["ddpm_mlp"]
    assert matching_families(gpt) == ["ddpm_gpt"]
    assert matching_families(ref.make_gpt_agent(window_size=1)) == ["ddpm_gpt"]


def test_settings_come_from_the_object():
    s = MLP.settings(ref.make_mlp_agent(n_timesteps=6))
    assert (s.obs_dim, s.act_dim, s.history, s.window, s.horizon, s.execute) == (20, 3, 1, "grow", 1, 1)
    assert s.noise_shape == (6, 1, 3) and not s.prev_actions
    assert "6 steps" in s.sampler
    s = GPT.settings(ref.make_gpt_agent(window_size=4, n_timesteps=5))
    assert (s.history, s.window, s.horizon, s.execute, s.noise_shape) == (4, "grow", 1, 1, (5, 4, 3))
    assert "3 extra steps" in MLP.settings(ref.make_mlp_agent(diffusion_x=True)).sampler


def test_the_mimics_predict_with_the_ema_weights():
    # Otherwise the checks below could not tell the EMA weights from the live ones.
    a = ref.make_mlp_agent()
    live = [p for p in a.model.parameters() if p.requires_grad]
    assert any(not torch.equal(s, p) for s, p in zip(a.ema_helper.shadow_params, live, strict=True))


def test_without_ema_the_module_uses_the_live_weights():
    a = ref.make_mlp_agent(n_timesteps=3)
    a.use_ema = False
    against_predict(a, MLP, steps=2)


def test_a_module_of_the_live_weights_is_caught():
    a = ref.make_mlp_agent(n_timesteps=3)
    live = ref.make_mlp_agent(n_timesteps=3)
    live.use_ema = False
    with pytest.raises(CheckFailed):
        against_predict(a, MLP, steps=1, module=MLP.graph(live).eval())


@pytest.mark.parametrize("schedule", ["cosine", "linear", "vp"])
def test_mlp_equals_predict(schedule):
    a = ref.make_mlp_agent(beta_schedule=schedule)
    cases = against_predict(a, MLP, steps=3)
    assert len(cases) == 3


@pytest.mark.parametrize("flags", [dict(predict_epsilon=False), dict(clip_denoised=False)])
def test_mlp_with_other_sampler_flags_equals_predict(flags):
    a = ref.make_mlp_agent(n_timesteps=3)
    for k, v in flags.items():
        setattr(a.model, k, v)
    against_predict(a, MLP, steps=2)


def test_mlp_with_extra_steps_at_t0_equals_predict():
    against_predict(ref.make_mlp_agent(diffusion_x=True, n_timesteps=4), MLP, steps=2)


def test_gpt_equals_predict_at_growing_windows():
    cases = against_predict(ref.make_gpt_agent(window_size=4, n_timesteps=4), GPT, steps=6)
    assert [c.window for c in cases] == [1, 2, 3, 4, 4, 4]


def test_gpt_with_window_1_equals_predict():
    # predict's 2-D state: its sample turns [1, 1, act] after the first step
    against_predict(ref.make_gpt_agent(window_size=1, n_timesteps=4), GPT, steps=3)


def test_the_check_sees_wrong_draws():
    a = ref.make_gpt_agent(window_size=2, n_timesteps=3)

    class Shifted(DdpmGpt):
        def draws(self, agent, noise, window):
            return super().draws(agent, noise.roll(1, dims=0), window)

    with pytest.raises(CheckFailed):
        against_predict(a, Shifted(), steps=2)


def test_unexportable_agents_are_refused():
    a = ref.make_mlp_agent()
    a.diffusion_kde = True
    with pytest.raises(ValueError, match="serve"):
        MLP.settings(a)
    b = ref.make_mlp_agent()
    b.window_size = 3
    with pytest.raises(ValueError, match="window_size=1"):
        MLP.settings(b)


def test_mlp_exports(tmp_path):
    a = ref.make_mlp_agent()
    cases = against_predict(a, MLP, steps=2)
    assert export_and_compare(MLP, a, cases, tmp_path / "mlp.onnx") <= 1e-5


def test_gpt_traced_at_window_k_runs_at_windows_1_to_k(tmp_path):
    a = ref.make_gpt_agent(window_size=4, n_timesteps=4)
    cases = against_predict(a, GPT, steps=5)
    assert max(c.window for c in cases) == 4
    assert export_and_compare(GPT, a, cases, tmp_path / "gpt.onnx") <= 1e-5


def test_the_transformer_trap_is_real():
    """The reference forward traced at window 4 is wrong at window 2 (its Python
    int(x.size()[1] / 2) and window branch froze), which is why the module re-runs its
    submodules with a symbolic reshape.
    """
    net = ref.make_gpt_agent(window_size=4).model.model.eval()

    class Naive(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, states):
            x = torch.zeros(states.shape[0], states.shape[1], 3)
            return self.net(x, torch.full((states.shape[0],), 2, dtype=torch.long), states, None)

    buf = io.BytesIO()
    with torch.no_grad():
        torch.onnx.export(
            Naive().eval(),
            (torch.randn(2, 4, 20),),
            buf,
            input_names=["obs"],
            output_names=["out"],
            dynamic_axes={"obs": {0: "B", 1: "T"}, "out": {0: "B"}},
            opset_version=18,
            dynamo=False,
        )
    sess = ort.InferenceSession(buf.getvalue(), providers=["CPUExecutionProvider"])
    obs = torch.randn(2, 2, 20)
    with torch.no_grad():
        want = Naive().eval()(obs).numpy()
    try:
        (got,) = sess.run(["out"], {"obs": obs.numpy()})
    except Exception:  # onnxruntime refuses the frozen reshape
        return
    assert got.shape != want.shape or not np.allclose(got, want, atol=1e-5)


def test_the_gpt_graph_has_no_slice_starting_at_a_shape(tmp_path):
    a = ref.make_gpt_agent(window_size=3, n_timesteps=2)
    cases = against_predict(a, GPT, steps=3)
    export_and_compare(GPT, a, cases, tmp_path / "gpt.onnx")
    assert slices_from_shapes(onnx.load(str(tmp_path / "gpt.onnx"))) == []


def slices_from_shapes(model: onnx.ModelProto) -> list:
    """Slice nodes whose starts are computed from a Shape (a suffix ``x[K - T:]``,
    which tract cannot reduce to the window).
    """
    producer = {o: n for n in model.graph.node for o in n.output}

    def from_shape(name: str, seen: set) -> bool:
        n = producer.get(name)
        if n is None or n.name in seen:
            return False
        seen.add(n.name)
        return n.op_type == "Shape" or any(from_shape(i, seen) for i in n.input)

    return [n.name for n in model.graph.node if n.op_type == "Slice" and from_shape(n.input[1], set())]
