"""IBC family against the reference-like IBCAgent (tests_torch/reference_like/ibc.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, List

import onnx
import pytest
import torch
from family_helpers import export_and_compare, matching_families
from reference_like import ibc as ref
from torch import nn

from d3il_client.agents import UnknownAgent, recognise
from d3il_client.agents.base import Draw
from d3il_client.agents.check import CheckFailed, against_predict
from d3il_client.agents.ibc import FAMILY, EnergyGradient, IbcFamily, step_sizes


def test_recognised_as_ibc():
    assert matching_families(ref.make_agent()) == ["ibc"]


def test_another_sampler_is_left_to_serving():
    class DerivativeFreeOptimizer(ref.LangevinMCMCSampler):
        pass

    agent = ref.make_agent()
    agent.sampler = DerivativeFreeOptimizer()
    assert not FAMILY.matches(agent)
    with pytest.raises(UnknownAgent, match="Serve it instead"):
        recognise(agent)


def test_settings_from_the_object():
    agent = ref.make_agent(samples=16, iterations=3)
    s = FAMILY.settings(agent)
    assert (s.obs_dim, s.act_dim, s.history, s.window, s.horizon, s.execute) == (20, 3, 1, "pad", 1, 1)
    assert s.noise_shape == (3 + 3 + 2, 16, 3) and not s.prev_actions
    agent.sampler.second_infer = False
    assert FAMILY.settings(agent).noise_shape == (3 + 2, 16, 3)


def test_step_sizes_as_the_reference_runs_them():
    """First step at sampler_stepsize_init_infer (0.5), then the polynomial schedule
    built from sampler_stepsize_init (0.0493), then the second loop's constant 1e-5.
    """
    sizes = step_sizes(ref.make_agent(iterations=3).sampler)
    want = [0.5, (0.0493 - 1e-5) * (1 - 1 / 2) ** 2 + 1e-5, 1e-5, 1e-5, 1e-5, 1e-5]
    assert sizes == pytest.approx(want, rel=1e-12)


def test_module_equals_predict():
    cases = against_predict(ref.make_agent(), FAMILY, batch=3, steps=4)
    assert len(cases) == 4 and all(c.window == 1 for c in cases)


def test_module_equals_predict_with_ema_parameters():
    agent = ref.make_agent(iterations=2)
    agent.use_ema = True
    with torch.no_grad():
        for p in agent.ema_helper.shadow_params:
            p.add_(0.1 * torch.randn_like(p))
    against_predict(agent, FAMILY, batch=3, steps=3)


class _FlippedStepNoise(IbcFamily):
    """Hands predict the negated step noise: the check must see it."""

    def draws(self, agent: Any, noise: torch.Tensor, window: int) -> List[Draw]:
        out = super().draws(agent, noise, window)
        return [Draw(d.kind, -d.value, d.given) if d.kind == "randn_like" else d for d in out]


def test_the_check_sees_other_draws():
    with pytest.raises(CheckFailed):
        against_predict(ref.make_agent(), _FlippedStepNoise(), batch=3, steps=3)


class _Mlp(nn.Module):
    """MLPNetwork's layout: act after every layer but the last."""

    def __init__(self, act: nn.Module) -> None:
        super().__init__()
        self.layers = nn.ModuleList([nn.Linear(23, 16), nn.Linear(16, 16), nn.Linear(16, 1)])
        self.act = act

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = self.act(x)
        return x


@pytest.mark.parametrize(
    "act",
    [nn.Mish(), nn.ReLU(), nn.Sigmoid(), nn.Tanh(), nn.SiLU(), nn.GELU(), nn.PReLU()],
    ids=lambda a: type(a).__name__,
)
def test_the_hand_written_gradient_is_autograds(act: nn.Module):
    torch.manual_seed(0)
    for net in (_Mlp(act), ref.ResidualMLPNetwork(23, hidden_dim=16, num_hidden_layers=4)):
        if isinstance(net, ref.ResidualMLPNetwork):
            for b in net.layers[1:-1]:
                b.act = act
        x = (3.0 * torch.randn(64, 23)).requires_grad_(True)
        e = net(x).squeeze(-1)
        (want,) = torch.autograd.grad(e.sum(), x)
        e2, got = EnergyGradient(net)(x.detach())
        assert float((e - e2).abs().max()) <= 1e-6
        assert float((want - got).abs().max()) <= 1e-5 * max(1.0, float(want.abs().max()))


def test_an_unknown_activation_is_refused_naming_serve():
    net = ref.ResidualMLPNetwork(23, hidden_dim=8, num_hidden_layers=2)
    net.layers[1].act = nn.Softsign()
    with pytest.raises(ValueError, match="serve"):
        EnergyGradient(net)


def test_onnx_equals_the_module_and_draws_nothing_itself(tmp_path: Path):
    agent = ref.make_agent()
    cases = against_predict(agent, FAMILY, batch=3, steps=3)
    path = tmp_path / "ibc.onnx"
    assert export_and_compare(FAMILY, agent, cases, path) <= 1e-5
    ops = {n.op_type for n in onnx.load(str(path)).graph.node}
    assert not ops & {"RandomNormal", "RandomUniform", "RandomNormalLike", "RandomUniformLike", "Multinomial"}
