"""A near-free task for measuring the engine's per-partition overhead."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from mocapflow.pipeline.registry import TaskSpec, register
from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

register_schema(ArtifactSchema(
    name="bench_view", version=1, frame_chunk=8,
    coords={"view": VarSpec(("view",), "str"), "frame": VarSpec(("frame",), "int64")},
    variables={"mean_depth": VarSpec(("view", "frame"), "float32", "mm")},
))


@dataclass(frozen=True)
class NoParams:
    pass


def mean_depth(frames: xr.Dataset, config: NoParams) -> xr.Dataset:
    return xr.Dataset({"mean_depth": frames["depth"].astype(np.float32).mean(("y", "x"))})


register(TaskSpec("bench_mean_depth", mean_depth, "1", NoParams, "bench_view", "view", {"frames": "raw_sequence"},
                  reads={"frames": ("depth",)}))
