"""Worked example: a D3IL reference agent rebuilt from its run directory — the Hydra
config, the checkpoint and the saved scaler — without the dataset and without wandb
(docs/export.md, "Loading a checkpoint without the dataset").

A reference training run (``python run.py ...``) leaves in its Hydra run directory
(``logs/<task>/runs/<agent>/<date>/<time>/``)::

    .hydra/config.yaml     the composed config (cfg.agents is the agent's)
    eval_best_bc.pth       store_model_weights: the network's state dict
                           (BeT-MLP: a pickled dict of modules, see below)

and, if you called it after training, ``scaler.npz`` from
``d3il_client.agents.loading.save_scaler(agent, ...)`` (or recover it with
``scaler_from_dataset`` from the training data). Then::

    agent = make_agent("logs/aligning/runs/bc/.../eval_best_bc.pth")
    export_agent(agent, "aligning", "policy.onnx")            # or serve it:
    python -m d3il_client.serve --agent make_agent_example:make_agent --checkpoint .../eval_best_bc.pth

The agent is made with ``object.__new__`` — its constructor would build the
datasets (the data files must exist), fit the scaler on them and call
``wandb.log`` — and given the attributes its ``predict`` reads, as its constructor
would set them. The tests run this file on the reference-like agents
(tests_torch/reference_like), whose attributes are the reference's.
"""

from __future__ import annotations

import importlib
from collections import deque
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import torch

from d3il_client.agents.loading import load_scaler, load_weights

PathLike = Union[str, Path]


def load_config(run_dir: PathLike, device: str = "cpu") -> Any:
    """The run's composed Hydra config (``.hydra/config.yaml``), on ``device``.

    The reference configs use an ``add`` resolver that run.py registers
    (``${add:${action_dim}, ${obs_dim}}``); without it OmegaConf fails with
    "Unsupported interpolation type add".
    """
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("add"):
        OmegaConf.register_new_resolver("add", lambda *numbers: sum(numbers))
    cfg = OmegaConf.load(Path(run_dir) / ".hydra" / "config.yaml")
    if "device" in cfg:
        cfg.device = device  # the models' device: ${device} ('cuda' in the reference configs)
    return cfg


def import_target(path: str) -> Any:
    """The class or function a ``_target_`` names."""
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def instantiate(node: Any, **kwargs: Any) -> Any:
    """``hydra.utils.instantiate`` when Hydra is installed (as where the agent was
    trained), else the same for plain ``_target_`` mappings: nested targets are built
    first unless ``_recursive_`` is false.
    """
    try:
        import hydra
    except ImportError:
        return _instantiate(node, **kwargs)
    return hydra.utils.instantiate(node, **kwargs)


def _instantiate(node: Any, **kwargs: Any) -> Any:
    if not isinstance(node, Mapping) or "_target_" not in node:
        return node
    recursive = node.get("_recursive_", True)
    args = {k: v for k, v in node.items() if not k.startswith("_")}
    if recursive:
        args = {k: _instantiate(v) for k, v in args.items()}
    return import_target(node["_target_"])(**{**args, **kwargs})


def make_agent(
    checkpoint: PathLike,
    config: Any = None,
    scaler: Optional[PathLike] = None,
    device: str = "cpu",
    trusted: bool = False,
) -> Any:
    """The reference agent of ``checkpoint`` (module docstring). ``config``: the
    composed config (default: the run directory's ``.hydra/config.yaml``);
    ``scaler``: the file of ``save_scaler`` (default: ``scaler.npz`` next to the
    checkpoint); ``trusted``: allow a checkpoint of pickled modules (BeT-MLP's own
    files; unpickling runs code, so only for files you made).
    """
    ckpt = Path(checkpoint)
    cfg = config if config is not None else load_config(ckpt.parent, device)
    acfg = cfg["agents"]
    cls = import_target(acfg["_target_"])
    kinds = {c.__name__ for c in cls.__mro__}

    agent = object.__new__(cls)  # no dataset, no DataLoaders, no wandb.log
    agent.device = device
    agent.scaler = load_scaler(scaler if scaler is not None else ckpt.parent / "scaler.npz", device)
    # what every constructor of BC, CVAE, ACT and BeT-MLP sets from the scaler
    agent.min_action = torch.from_numpy(agent.scaler.y_bounds[0, :]).to(device)
    agent.max_action = torch.from_numpy(agent.scaler.y_bounds[1, :]).to(device)

    if "BetMLP_Agent" in kinds:
        # BetMLP_Agent.store_model_weights pickles the modules themselves (the k-means
        # bin centres live in action_ae, outside any state dict)
        payload = load_weights(ckpt, trusted=trusted, map_location=device)
        agent.model = payload["model"]
        agent.action_ae = payload["action_ae"]
        agent.obs_encoding_net = payload["obs_encoding_net"]
        agent.window_size = int(acfg["window_size"])
        agent.obs_context = deque(maxlen=agent.window_size)
        return agent

    agent.model = instantiate(acfg["model"]).to(device)
    agent.model.load_state_dict(load_weights(ckpt, map_location=device))

    if "ActAgent" in kinds:
        agent.gc = bool(acfg.get("goal_conditioned", False))
        agent.window_size = int(acfg["window_size"])
        agent.goal_window_size = int(acfg.get("goal_window_size", 1))
        agent.action_seq_size = int(acfg["action_seq_size"])
        agent.obs_size = int(acfg["obs_size"])
        agent.que_actions = bool(acfg.get("que_actions", False))
        agent.obs_context = deque(maxlen=agent.obs_size)
        agent.goal_context = deque(maxlen=agent.goal_window_size)
        agent.action_context = deque(maxlen=agent.action_seq_size)
        agent.pred_counter = 0
        agent.action_counter = agent.action_seq_size  # the first predict() calls the model
    return agent
