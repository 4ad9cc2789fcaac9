"""A trained network as labelled data: its tensors flattened into one vector with their layout, its architecture
(the config that rebuilds it) and its training record, so the engine caches it like any artifact and
``unpack`` gives back the plain-tensor state that ``torch.load(..., weights_only=True)`` reads."""

from __future__ import annotations

from typing import Mapping

import numpy as np
import xarray as xr


def pack(state: Mapping, architecture: dict, training: dict, losses) -> xr.Dataset:
    """state: a module's state_dict (name -> tensor)."""
    layout = [[name, list(t.shape), str(t.dtype).removeprefix("torch.")] for name, t in state.items()]
    flat = np.concatenate([t.detach().cpu().numpy().astype(np.float32).ravel() for t in state.values()])
    return xr.Dataset({"weights": (("parameter",), flat), "loss": (("iteration",), np.asarray(losses, np.float32))},
                      attrs={"architecture": dict(architecture), "layout": layout, "training": dict(training)})


def unpack(ds: xr.Dataset) -> dict:
    """{"architecture": dict, "training": dict, "state": {name: tensor}} of a packed network."""
    import torch

    flat, state, at = ds["weights"].values, {}, 0
    for name, shape, dtype in ds.attrs["layout"]:
        n = int(np.prod(shape))
        state[name] = torch.from_numpy(flat[at:at + n].reshape(shape).astype(dtype))
        at += n
    assert at == len(flat), (at, len(flat))
    return {"architecture": dict(ds.attrs["architecture"]), "training": dict(ds.attrs["training"]), "state": state}
