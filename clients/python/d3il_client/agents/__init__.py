"""Reference D3IL agent objects onto the leaderboard: export, check, serve.

``recognise(agent)`` names the family of a reference agent object (BC, VAE-State,
VAE-ACT, BeT-MLP, BeT, IBC, DDPM-MLP, DDPM-GPT, DDPM-ACT, BESO, BC-GPT); each family
(``d3il_client.agents.base.Family``) reads the agent's settings from the object and
builds one batched torch module of its ``predict`` path, used for export
(``export_agent``), for checks against ``predict`` and for serving a batch of
rollouts with one model call (``d3il_client.serve``). docs/export.md has the
details; torch is needed (the ``export`` extra).
"""

from __future__ import annotations

import importlib
from typing import Any, List

from .base import FAMILY_NAMES, Draw, Family, Settings, Tape, TapeError

#: Modules of d3il_client.agents holding one Family subclass each, named FAMILY.
_MODULES = {
    "bc": "bc",
    "vae_state": "vae",
    "vae_act": "act",
    "bet_mlp": "bet_mlp",
    "bet": "bet",
    "ibc": "ibc",
    "ddpm_mlp": "ddpm",
    "ddpm_gpt": "ddpm",
    "ddpm_act": "ddpm_act",
    "beso": "beso",
    "bc_gpt": "gpt_bc",
}


class UnknownAgent(TypeError):
    """An agent object of no known family: it can still be served, not exported."""


def families() -> List[Family]:
    """One instance of every family, in FAMILY_NAMES order."""
    out: List[Family] = []
    for name in FAMILY_NAMES:
        mod = importlib.import_module(f"{__name__}.{_MODULES[name]}")
        fams = getattr(mod, "FAMILIES", None) or [mod.FAMILY]
        out.extend(f for f in fams if f.name == name)
    return out


def recognise(agent: Any) -> Family:
    """The family of ``agent``, or :class:`UnknownAgent` saying to serve it instead."""
    found = [f for f in families() if f.matches(agent)]
    if len(found) == 1:
        return found[0]
    cls = type(agent)
    what = f"{cls.__module__}.{cls.__qualname__}"
    if not found:
        raise UnknownAgent(
            f"{what} is not one of the D3IL reference agents this exporter knows "
            f"({', '.join(FAMILY_NAMES)}), so its predict() cannot be exported faithfully. "
            "Serve it instead: python -m d3il_client.serve --agent MODULE:make_agent --checkpoint CKPT "
            "(docs/remote-protocol.md), or export it by hand (docs/submission.md)."
        )
    raise UnknownAgent(f"{what} matches several families ({', '.join(f.name for f in found)}); report this")


__all__ = ["Draw", "Family", "Settings", "Tape", "TapeError", "UnknownAgent", "families", "recognise", "FAMILY_NAMES"]
