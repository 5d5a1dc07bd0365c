"""The BESO family against the reference-like BesoAgent (tests_torch/reference_like/beso.py):
settings read from the object, the module equal to predict() fed the same draws at
windows 1..k and beyond, and the two tracing traps at the ONNX level.
"""

from __future__ import annotations

import io

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from reference_like import beso as ref

from d3il_client.agents import UnknownAgent, recognise
from d3il_client.agents.beso import FAMILY, UnsupportedBeso
from d3il_client.agents.check import against_predict

# A loaded 2-core machine runs these small calls far faster on one thread.
torch.set_num_threads(1)

SMALL = dict(embed_dim=16, n_layers=2, n_heads=2)


def small(**kw):
    return ref.make_agent(**{**SMALL, "num_sampling_steps": 4, **kw})


def test_recognised_as_beso():
    agent = small()
    assert FAMILY.matches(agent)
    assert not FAMILY.matches(object())
    assert recognise(agent).name == "beso"
    with pytest.raises(UnknownAgent):
        recognise(object())


def test_settings_come_from_the_object():
    a = ref.make_agent(**SMALL, window_size=3, num_sampling_steps=7, sigma_min=0.1, sigma_max=1.0, sampler_type="ddim")
    s = FAMILY.settings(a)
    assert (s.obs_dim, s.act_dim, s.history, s.window, s.horizon, s.execute) == (20, 3, 3, "grow", 1, 1)
    assert s.prev_actions
    assert s.noise_shape == (1, 3, 3)  # ddim: only the initial draw
    assert s.sampler.startswith("ddim, 7 steps, linear sigmas 1..0.1")

    a = ref.make_agent(**SMALL)  # the reference's Aligning BESO settings
    s = FAMILY.settings(a)
    assert s.history == 5 and s.noise_shape == (16, 5, 3)  # 1 + 15 ancestral draws (none at the last step)
    assert s.sampler.startswith("euler_ancestral, 16 steps, linear sigmas 3..0.01")

    a.noise_scheduler = "karras"  # read from the attribute, as predict does
    assert "karras sigmas" in FAMILY.settings(a).sampler
    a.window_size = 1
    assert not FAMILY.settings(a).prev_actions


def test_unsupported_sampler_is_refused_with_a_way_out():
    a = small()
    a.sampler_type = "dpmpp_2m_sde"
    with pytest.raises(UnsupportedBeso, match="serve this agent"):
        FAMILY.graph(a)


def test_module_equals_predict_at_growing_windows_aligning_size():
    # The reference's Aligning BESO: window 5, 16 steps, sigma 0.01..3, euler_ancestral,
    # 'linear' sigmas, 4 layers of width 72; windows 1, 2, 3, 4, 5, 5, 5, 5.
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=3, steps=8, atol=1e-5)
    assert [c.window for c in cases] == [1, 2, 3, 4, 5, 5, 5, 5]
    assert max(c.predict_diff for c in cases) < 1e-5


@pytest.mark.parametrize(
    "kw",
    [
        dict(sampler_type="euler_ancestral"),
        dict(sampler_type="euler"),
        dict(sampler_type="heun"),
        dict(sampler_type="ddim"),
        dict(window_size=1),
        dict(window_size=3, sigma_min=0.1, sigma_max=1.0),
    ],
)
@pytest.mark.parametrize("schedule", ["linear", "exponential", "karras"])
def test_module_equals_predict_per_sampler_and_schedule(kw, schedule):
    agent = small(**kw)
    agent.noise_scheduler = schedule
    k = agent.window_size
    cases = against_predict(agent, FAMILY, batch=2, steps=k + 3, atol=1e-5)
    assert [c.window for c in cases] == [min(t + 1, k) for t in range(k + 3)]


def test_module_without_ema_uses_the_live_weights():
    agent = small()
    agent.use_ema = False
    against_predict(agent, FAMILY, batch=2, steps=6)


def test_predict_differs_from_a_module_of_the_wrong_weights():
    # The mimic's EMA shadow differs from its live weights: a module built without
    # swapping them in must fail the check (the check has teeth).
    agent = small()
    wrong = ref.make_agent(**SMALL, num_sampling_steps=4)
    wrong.use_ema = False
    with pytest.raises(AssertionError):
        against_predict(agent, FAMILY, batch=2, steps=3, module=FAMILY.graph(wrong).eval())


def export(graph: torch.nn.Module, k: int, act: int, obs_dim: int, noise_shape) -> bytes:
    """The ONNX export the docs give, traced at example window ``k``."""
    b = 2
    args = (torch.zeros(b, k, obs_dim), torch.zeros(b, k - 1, act), torch.randn(b, *noise_shape))
    buf = io.BytesIO()
    torch.onnx.export(
        graph,
        args,
        buf,
        input_names=["obs", "prev_actions", "noise"],
        output_names=["actions"],
        dynamic_axes={
            "obs": {0: "B", 1: "T"},
            "prev_actions": {0: "B", 1: "P"},
            "noise": {0: "B"},
            "actions": {0: "B"},
        },
        opset_version=18,
        dynamo=False,
    )
    return buf.getvalue()


def slices_with_shape_dependent_starts(model: onnx.ModelProto) -> list:
    """Slice nodes whose `starts` are computed from a Shape (``x[K - T:]``):
    tract cannot unify such a start with the symbolic window.
    """
    producer = {o: n for n in model.graph.node for o in n.output}

    def from_shape(name: str, seen: set) -> bool:
        n = producer.get(name)
        if n is None or name in seen:
            return False
        seen.add(name)
        return n.op_type == "Shape" or any(from_shape(i, seen) for i in n.input)

    return [n.name for n in model.graph.node if n.op_type == "Slice" and from_shape(n.input[1], set())]


def test_onnx_traced_at_window_5_runs_at_windows_1_to_5():
    agent = small()
    s = FAMILY.settings(agent)
    graph = FAMILY.graph(agent)
    data = export(graph, 5, s.act_dim, s.obs_dim, s.noise_shape)
    model = onnx.load_from_string(data)
    assert slices_with_shape_dependent_starts(model) == []
    sess = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
    gen = torch.Generator().manual_seed(1)
    for w in range(1, 6):
        obs = torch.randn(3, w, s.obs_dim, generator=gen) * 0.1 + 0.5
        prev = torch.randn(3, w - 1, s.act_dim, generator=gen) * 0.01
        noise = torch.randn(3, *s.noise_shape, generator=gen)
        with torch.no_grad():
            want = graph(obs, prev, noise).numpy()
        got = sess.run(None, {"obs": obs.numpy(), "prev_actions": prev.numpy(), "noise": noise.numpy()})[0]
        assert got.shape == (3, 1, s.act_dim)
        np.testing.assert_allclose(got, want, atol=1e-5, rtol=0)


def test_the_traps_are_real():
    # Tracing the reference's own DiffusionGPT at window 5 freezes its
    # int(x.size()[1] / 2): the graph fails at window 3 (why the module re-expresses it).
    inner = small().model.inner_model.eval()
    args = (torch.zeros(2, 5, 20), torch.zeros(2, 5, 3), torch.zeros(2, 5, 3), torch.ones(2))

    class Call(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, s, a, _g, sig):
            return self.inner(s, a, None, sig)

    buf = io.BytesIO()
    torch.onnx.export(
        Call(),
        args,
        buf,
        input_names=["s", "a", "g", "sigma"],
        dynamic_axes={"s": {0: "B", 1: "T"}, "a": {0: "B", 1: "T"}, "sigma": {0: "B"}},
        opset_version=18,
        dynamo=False,
    )
    sess = ort.InferenceSession(buf.getvalue(), providers=["CPUExecutionProvider"])
    feeds = {"s": np.zeros((2, 3, 20), np.float32), "a": np.zeros((2, 3, 3), np.float32)}
    feeds["sigma"] = np.ones(2, np.float32)
    feeds = {i.name: feeds[i.name] for i in sess.get_inputs()}
    with pytest.raises(Exception, match="Reshape"):
        sess.run(None, feeds)


def test_the_suffix_slice_detector_sees_a_suffix_slice():
    class Suffix(torch.nn.Module):
        def forward(self, obs, noise):
            return noise[:, 0, 5 - obs.shape[1] :] + obs[..., :3]

    buf = io.BytesIO()
    args = (torch.zeros(2, 5, 4), torch.zeros(2, 2, 5, 3))
    dyn = {"obs": {0: "B", 1: "T"}, "noise": {0: "B"}}
    torch.onnx.export(
        Suffix(), args, buf, input_names=["obs", "noise"], dynamic_axes=dyn, opset_version=18, dynamo=False
    )
    assert slices_with_shape_dependent_starts(onnx.load_from_string(buf.getvalue())) != []
