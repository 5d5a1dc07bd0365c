"""d3il_client.agents.loading and the worked example make_agent_example.py: a reference(-like)
agent rebuilt from config + checkpoint + saved scaler, without the dataset, computes what
the trained agent computes.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Dict

import make_agent_example as example
import numpy as np
import pytest
import torch
from reference_like import act as ref_act
from reference_like import bc as ref_bc
from reference_like import bet_mlp as ref_bet_mlp
from reference_like import vae as ref_vae
from reference_like.scaler import Scaler, aligning_like_data

from d3il_client.agents import act, bc, bet_mlp, vae
from d3il_client.agents.check import against_predict, observations
from d3il_client.agents.loading import (
    ARRAYS,
    WeightsNotPlain,
    load_scaler,
    load_weights,
    save_scaler,
    scaler_from_dataset,
)


def same_arrays(a: Any, b: Any) -> None:
    assert bool(a.scale_data) == bool(b.scale_data)
    for n in ARRAYS:
        x, y = np.asarray(getattr(a, n)), np.asarray(getattr(b, n))
        assert x.dtype == y.dtype and x.shape == y.shape, n
        assert np.array_equal(x, y), n


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_saved_scaler_round_trips_exactly(tmp_path: Path, suffix: str):
    x, y = aligning_like_data(20, 3)
    sc = Scaler(x, y, True, "cpu")
    path = save_scaler(sc, tmp_path / f"scaler{suffix}")
    back = load_scaler(path)
    same_arrays(sc, back)
    obs = torch.from_numpy(x[:7]) + 0.01
    for m in ("scale_input", "scale_output", "inverse_scale_input", "inverse_scale_output"):
        arg = obs if "input" in m else torch.from_numpy(y[:7])
        assert torch.equal(getattr(sc, m)(arg), getattr(back, m)(arg)), m
    big = torch.randn(5, 3) * 10
    assert torch.equal(sc.clip_action(big), back.clip_action(big))
    assert torch.isfinite(back.scale_input(torch.from_numpy(x[:3]))).all()  # std 0 dims: the 1e-12


def test_save_scaler_takes_the_agent(tmp_path: Path):
    agent = ref_bc.make_agent()
    same_arrays(agent.scaler, load_scaler(save_scaler(agent, tmp_path / "s.npz")))
    with pytest.raises(TypeError, match="not a reference Scaler"):
        save_scaler(object(), tmp_path / "t.npz")


@pytest.mark.parametrize("scale_data", [True, False])
def test_scaler_from_dataset_is_the_reference_arithmetic(scale_data: bool):
    x, y = aligning_like_data(20, 3)
    same_arrays(Scaler(x, y, scale_data, "cpu"), scaler_from_dataset(x, y, scale_data))
    # [S, T, dim] as the datasets keep it, torch tensors
    xs, ys = torch.from_numpy(x).reshape(8, 64, 20), torch.from_numpy(y).reshape(8, 64, 3)
    same_arrays(Scaler(x, y, scale_data, "cpu"), scaler_from_dataset(xs, ys, scale_data))


def test_load_weights_plain_and_pickled(tmp_path: Path):
    agent = ref_bet_mlp.make_agent()
    torch.save(agent.model.state_dict(), tmp_path / "plain.pth")
    sd = load_weights(tmp_path / "plain.pth")
    assert set(sd) == set(agent.model.state_dict())
    # BetMLP_Agent.store_model_weights: the modules themselves
    torch.save(
        {"model": agent.model, "action_ae": agent.action_ae, "obs_encoding_net": agent.obs_encoding_net},
        tmp_path / "bet.pth",
    )
    with pytest.raises(WeightsNotPlain, match=r"reference_like\.bet_mlp\.BeTPolicy.*trusted=True"):
        load_weights(tmp_path / "bet.pth")
    payload = load_weights(tmp_path / "bet.pth", trusted=True)
    assert torch.equal(payload["action_ae"].bin_centers, agent.action_ae.bin_centers)


# The composed configs of runs of the reference-like agents (what .hydra/config.yaml holds
# for a real run, with the reference classes as targets).
MLP = {"_target_": "reference_like.mlp.ResidualMLPNetwork", "hidden_dim": 16, "num_hidden_layers": 2}
CONFIGS: Dict[str, Dict[str, Any]] = {
    "bc": {
        "agents": {
            "_target_": "reference_like.bc.BC_Agent",
            "model": {
                "_target_": "reference_like.bc.BC_Policy",
                "model": {**MLP, "input_dim": 20, "output_dim": 3},
            },
        }
    },
    "vae_state": {
        "agents": {
            "_target_": "reference_like.vae.CVAEAgent",
            "model": {"_target_": "reference_like.vae.VariationalAE", "obs_dim": 20, "act_dim": 3},
        }
    },
    "vae_act": {
        "agents": {
            "_target_": "reference_like.act.ActAgent",
            "model": {"_target_": "reference_like.act.ActVAE", "state_dim": 20, "action_dim": 3},
            "window_size": 3,
            "action_seq_size": 3,
            "obs_size": 1,
            "goal_window_size": 1,
            "goal_conditioned": False,
        }
    },
    "bet_mlp": {"agents": {"_target_": "reference_like.bet_mlp.BetMLP_Agent", "window_size": 1}},
}
CASES = {
    "bc": (ref_bc, bc.FAMILY),
    "vae_state": (ref_vae, vae.FAMILY),
    "vae_act": (ref_act, act.FAMILY),
    "bet_mlp": (ref_bet_mlp, bet_mlp.FAMILY),
}


def train_and_store(name: str, run: Path) -> Any:
    """A "trained" agent and its run directory as the reference leaves it, plus the scaler."""
    mod, _ = CASES[name]
    agent = mod.make_agent()
    with torch.no_grad():  # weights other than make_agent's, so loading them matters
        for p in agent.model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    run.mkdir(parents=True, exist_ok=True)
    if name == "bet_mlp":
        payload = {"model": agent.model, "action_ae": agent.action_ae, "obs_encoding_net": agent.obs_encoding_net}
        torch.save(payload, run / "eval_best.pth")
    else:
        torch.save(agent.model.state_dict(), run / "eval_best.pth")
    save_scaler(agent, run / "scaler.npz")
    return agent


@pytest.mark.parametrize("name", list(CASES))
def test_example_rebuilds_the_agent_without_the_dataset(tmp_path: Path, name: str):
    trained = train_and_store(name, tmp_path / "run")
    _, family = CASES[name]
    rebuilt = example.make_agent(tmp_path / "run" / "eval_best.pth", config=CONFIGS[name], trusted=name == "bet_mlp")
    assert type(rebuilt) is type(trained)
    assert family.settings(rebuilt) == family.settings(trained)
    # the rebuilt agent passes the check, and its module computes the trained one's
    cases = against_predict(rebuilt, family, batch=3)
    g = family.graph(trained).eval()
    with torch.no_grad():
        for c in cases:
            assert torch.equal(g(c.obs, c.prev_actions, c.noise), c.actions)
    if name == "bc":  # deterministic: predict() itself agrees
        obs = observations(trained, 1, 1, torch.Generator().manual_seed(3))[0, 0].numpy()
        assert np.array_equal(copy.deepcopy(trained).predict(obs), rebuilt.predict(obs))


def test_example_refuses_pickled_modules_unless_trusted(tmp_path: Path):
    train_and_store("bet_mlp", tmp_path / "run")
    with pytest.raises(WeightsNotPlain, match="trusted=True"):
        example.make_agent(tmp_path / "run" / "eval_best.pth", config=CONFIGS["bet_mlp"])


def test_example_reads_the_hydra_run_directory(tmp_path: Path):
    """With OmegaConf (as where the agent was trained): .hydra/config.yaml of the run,
    with the reference's ${add:...} interpolation and device: cuda.
    """
    from omegaconf import OmegaConf

    run = tmp_path / "run"
    trained = train_and_store("vae_act", run)
    cfg = copy.deepcopy(CONFIGS["vae_act"])
    cfg.update({"device": "cuda", "obs_dim": 20, "action_dim": 3, "window_size": 3})
    cfg["agents"]["model"]["state_dim"] = "${obs_dim}"
    cfg["agents"]["window_size"] = "${window_size}"
    cfg["agents"]["action_seq_size"] = "${add:${window_size}, 0}"
    (run / ".hydra").mkdir()
    OmegaConf.save(OmegaConf.create(cfg), run / ".hydra" / "config.yaml")
    rebuilt = example.make_agent(run / "eval_best.pth")
    assert rebuilt.action_seq_size == 3 and rebuilt.device == "cpu"
    against_predict(rebuilt, act.FAMILY, batch=2)
    assert act.FAMILY.settings(rebuilt) == act.FAMILY.settings(trained)
