"""Loading a trained reference agent without its dataset (docs/export.md, "Loading a
checkpoint without the dataset").

The reference agents fit their ``Scaler`` on the training set in their constructor
(agents/utils/scaler.py) and save only the network (``store_model_weights``), so a
checkpoint alone cannot rebuild ``predict``: the scaler's arrays are missing. Here:

* :func:`save_scaler` — once, after training: the scaler's arrays (x/y mean, std,
  min, max, bounds, ``scale_data``) to a small ``.npz`` (or ``.json``) next to the
  checkpoint;
* :func:`scaler_from_dataset` — when the training data are still at hand: the same
  arithmetic as the reference ``Scaler`` (float32 data, ``std + 1e-12``);
* :func:`load_scaler` — a :class:`SavedScaler` with the reference Scaler's attributes
  and the methods ``predict`` uses (``scale_input``, ``inverse_scale_output``,
  ``clip_action``, ``y_bounds``, ...), computing exactly as the reference does;
* :func:`load_weights` — a state dict under torch >= 2.6 (``weights_only=True``),
  with a clear error for a checkpoint of pickled objects.
"""

from __future__ import annotations

import json
import os
import pickle
import re
from pathlib import Path
from typing import Any, Dict, Union

import numpy as np
import torch

PathLike = Union[str, "os.PathLike[str]"]

#: The arrays a scaler file holds, as the reference Scaler names its attributes.
ARRAYS = ("x_mean", "x_std", "y_mean", "y_std", "x_min", "x_max", "y_min", "y_max", "x_bounds", "y_bounds")
FORMAT = "d3il-scaler/1"


class WeightsNotPlain(RuntimeError):
    """The checkpoint holds pickled Python objects, not only tensors; the message says what to do."""


def _numpy(v: Any) -> np.ndarray:
    if isinstance(v, torch.Tensor):
        return v.detach().cpu().numpy()
    return np.asarray(v)


def scaler_arrays(agent_or_scaler: Any) -> Dict[str, Any]:
    """The scaler's arrays (numpy, in their own dtypes) and ``scale_data``."""
    sc = getattr(agent_or_scaler, "scaler", agent_or_scaler)
    missing = [n for n in ARRAYS if not hasattr(sc, n)]
    if missing or not hasattr(sc, "scale_data"):
        raise TypeError(
            f"{type(sc).__name__} is not a reference Scaler (agents/utils/scaler.py): it has no "
            f"{', '.join(missing or ['scale_data'])}; pass the agent or agent.scaler"
        )
    out: Dict[str, Any] = {n: _numpy(getattr(sc, n)) for n in ARRAYS}
    out["scale_data"] = bool(sc.scale_data)
    return out


def save_scaler(agent_or_scaler: Any, path: PathLike) -> Path:
    """Write the scaler of ``agent_or_scaler`` (an agent with ``.scaler`` or the
    Scaler itself) to ``path``: ``.npz`` (numpy, no pickle), or ``.json`` by suffix.
    Call it once after training, next to the checkpoint.
    """
    arrays = scaler_arrays(agent_or_scaler)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".json":
        doc: Dict[str, Any] = {"format": FORMAT, "scale_data": arrays["scale_data"]}
        for n in ARRAYS:
            a = arrays[n]
            # float32 -> Python float is exact, and JSON keeps the shortest repr that round-trips
            doc[n] = {"dtype": str(a.dtype), "shape": list(a.shape), "values": a.reshape(-1).tolist()}
        path.write_text(json.dumps(doc) + "\n")
    else:
        if path.suffix != ".npz":
            raise ValueError(f"{path}: a scaler file ends in .npz or .json")
        with open(path, "wb") as f:  # np.savez would append .npz to other names
            np.savez(
                f,
                format=np.asarray(FORMAT),
                scale_data=np.asarray(arrays["scale_data"]),
                **{n: arrays[n] for n in ARRAYS},
            )
    return path


class SavedScaler:
    """The reference Scaler's attributes and predict-time methods, from saved arrays.

    Attributes as the reference (``x_mean``, ``x_std``, ``y_mean``, ``y_std``,
    ``x_min``, ``x_max``, ``y_min``, ``y_max`` torch tensors; ``x_bounds``,
    ``y_bounds`` float64 numpy [2, dim]; ``y_bounds_tensor``, ``x_bounds_tensor``,
    ``tensor_y_bounds``), and the same arithmetic: ``(x - mean) / (std + 1e-12 *
    torch.ones(...))``. The reference's goal-scaling special cases (a 4-dimensional
    input to a 16-dimensional scaler, 7 to 30) are not part of any predict() on full
    observations; an input of another width than the scaler's is refused here.
    """

    def __init__(self, arrays: Dict[str, Any], device: str = "cpu") -> None:
        self.scale_data = bool(arrays["scale_data"])
        self.device = device

        def t(n: str) -> Any:
            return torch.from_numpy(np.array(arrays[n])).to(device)

        self.x_mean, self.x_std, self.y_mean, self.y_std = t("x_mean"), t("x_std"), t("y_mean"), t("y_std")
        self.x_min, self.x_max, self.y_min, self.y_max = t("x_min"), t("x_max"), t("y_min"), t("y_max")
        self.x_bounds = np.array(arrays["x_bounds"], dtype=np.float64)
        self.y_bounds = np.array(arrays["y_bounds"], dtype=np.float64)
        self.y_bounds_tensor = torch.from_numpy(self.y_bounds).to(device)
        self.x_bounds_tensor = torch.from_numpy(self.x_bounds).to(device)
        self.tensor_y_bounds = torch.from_numpy(self.y_bounds).to(device)

    def _ones(self, like: torch.Tensor) -> torch.Tensor:
        return torch.ones(like.shape, device=self.device)

    def _width(self, x: torch.Tensor, mean: torch.Tensor, what: str) -> None:
        if x.shape[-1] != mean.shape[-1]:
            raise ValueError(f"{what} of width {x.shape[-1]}, the scaler was fitted on {mean.shape[-1]} dimensions")

    def scale_input(self, x: torch.Tensor) -> torch.Tensor:
        """Observations -> network inputs, ``(x - x_mean) / (x_std + 1e-12)`` in float32."""
        with torch.no_grad():  # as the reference's @torch.no_grad()
            x = x.to(self.device)
            self._width(x, self.x_mean, "observations")
            if not self.scale_data:
                return x
            return ((x - self.x_mean) / (self.x_std + 1e-12 * self._ones(self.x_std))).to(torch.float32)

    def scale_output(self, y: torch.Tensor) -> torch.Tensor:
        """Actions -> network targets, ``(y - y_mean) / (y_std + 1e-12)`` in float32."""
        with torch.no_grad():  # as the reference's @torch.no_grad()
            y = y.to(self.device)
            self._width(y, self.y_mean, "actions")
            if not self.scale_data:
                return y
            return ((y - self.y_mean) / (self.y_std + 1e-12 * self._ones(self.y_std))).to(torch.float32)

    def inverse_scale_input(self, x: torch.Tensor) -> torch.Tensor:
        """Network inputs -> observations."""
        with torch.no_grad():  # as the reference's @torch.no_grad()
            if not self.scale_data:
                return x.to(self.device)
            return (x * (self.x_std + 1e-12 * self._ones(self.x_std)) + self.x_mean).to(torch.float32)

    def inverse_scale_output(self, y: torch.Tensor) -> torch.Tensor:
        """Network outputs -> actions, ``y * (y_std + 1e-12) + y_mean`` (the statistics' dtype)."""
        with torch.no_grad():  # as the reference's @torch.no_grad()
            if not self.scale_data:
                return y.to(self.device)
            return y * (self.y_std + 1e-12 * self._ones(self.y_std)) + self.y_mean

    def clip_action(self, y: torch.Tensor) -> torch.Tensor:
        """Clamp scaled actions to the scaled data bounds × 1.1, as float32."""
        with torch.no_grad():  # as the reference's @torch.no_grad()
            lo, hi = self.y_bounds_tensor[0, :] * 1.1, self.y_bounds_tensor[1, :] * 1.1
            return torch.clamp(y, lo, hi).to(self.device).to(torch.float32)


def scaler_from_dataset(x_data: Any, y_data: Any, scale_data: bool = True, device: str = "cpu") -> SavedScaler:
    """The reference Scaler of training data ``x_data`` [N, obs] or [S, T, obs] and
    ``y_data`` (torch or numpy; the D3IL datasets are float32): per-dimension mean,
    std (numpy's, ddof 0), min and max, and the bounds of the (scaled) data.
    """
    x, y = _numpy(x_data), _numpy(y_data)
    if x.ndim == 3:
        x, y = x.reshape(-1, x.shape[-1]), y.reshape(-1, y.shape[-1])
    elif x.ndim != 2:
        raise ValueError(f"training observations of shape {x.shape}: expected [N, obs_dim] or [S, T, obs_dim]")
    arrays: Dict[str, Any] = {
        "x_mean": x.mean(0),
        "x_std": x.std(0),
        "y_mean": y.mean(0),
        "y_std": y.std(0),
        "x_min": x.min(0),
        "x_max": x.max(0),
        "y_min": y.min(0),
        "y_max": y.max(0),
        "scale_data": scale_data,
    }
    for p, d in (("x", x), ("y", y)):
        b = np.zeros((2, d.shape[-1]))
        if scale_data:
            den = d.std(0) + 1e-12 * np.ones(d.shape[-1])  # float64 as the reference's bounds
            b[0] = (d.min(0) - d.mean(0)) / den
            b[1] = (d.max(0) - d.mean(0)) / den
        else:
            b[0], b[1] = d.min(0), d.max(0)
        arrays[f"{p}_bounds"] = b
    return SavedScaler(arrays, device)


def load_scaler(path: PathLike, device: str = "cpu") -> SavedScaler:
    """The scaler :func:`save_scaler` wrote to ``path`` (``.npz`` or ``.json``)."""
    path = Path(path)
    if path.suffix == ".json":
        doc = json.loads(path.read_text())
        if doc.get("format") != FORMAT:
            raise ValueError(f"{path} is not a scaler file of save_scaler (format {doc.get('format')!r})")
        arrays: Dict[str, Any] = {"scale_data": doc["scale_data"]}
        for n in ARRAYS:
            e = doc[n]
            arrays[n] = np.asarray(e["values"], dtype=e["dtype"]).reshape(e["shape"])
        return SavedScaler(arrays, device)
    with np.load(path, allow_pickle=False) as z:
        if "format" not in z or str(z["format"]) != FORMAT:
            raise ValueError(f"{path} is not a scaler file of save_scaler")
        return SavedScaler({n: z[n] for n in (*ARRAYS, "scale_data")}, device)


def load_weights(path: PathLike, trusted: bool = False, map_location: Any = "cpu") -> Any:
    """The state dict in ``path``, loaded with ``weights_only=True`` (the default of
    torch >= 2.6, and what the reference's ``store_model_weights`` files need: plain
    state dicts). A checkpoint of pickled objects (BeT-MLP's and BeT's
    ``store_model_weights`` save whole modules) raises :class:`WeightsNotPlain`
    saying to re-save the state dict, or — only for a file you trust, since unpickling
    runs code — to pass ``trusted=True`` (``weights_only=False``), which returns
    whatever the file holds.
    """
    try:
        return torch.load(path, map_location=map_location, weights_only=not trusted)
    except pickle.UnpicklingError as e:
        found = re.search(r"GLOBAL ([\w.]+)", str(e))
        culprit = f" such as {found.group(1)}" if found else ""
        raise WeightsNotPlain(
            f"{path} holds pickled Python objects{culprit}, not only tensors; torch >= 2.6 loads "
            "plain state dicts only (weights_only=True). Re-save it as a state dict in the environment that "
            "wrote it (torch.save(agent.model.state_dict(), path)), or, if you trust the file (unpickling "
            "runs its code), load it with load_weights(path, trusted=True)."
        ) from e
