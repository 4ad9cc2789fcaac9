"""Small test-only tasks that exercise the engine (registered when a catalog lists this plugin).

- ``scale``: per-view, depth * factor (+ an optional per-region sleep to kill runs part-way, and a hold:
  while the file named in $TOY_HOLD_WHILE exists the task waits, so a test decides when a run ends)
- ``diff``: per-view, depth[f] - depth[f-1] (halo of one frame before)
- ``total``: per-sequence, sum over views
- ``boom``: per-view, raises for one chosen view (tests --keep-going)
- ``flaky``: per-view, value + 1; raises for one chosen view from the frame in $TOY_FLAKY_FROM on, if set
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np
import xarray as xr

from mocapflow.pipeline.registry import TaskSpec, register
from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

register_schema(ArtifactSchema(
    name="toy_view", version=1, frame_chunk=4,
    coords={"view": VarSpec(("view",), "str"), "frame": VarSpec(("frame",), "int64")},
    variables={"value": VarSpec(("view", "frame", "y", "x"), "float32", "mm")},
))
register_schema(ArtifactSchema(
    name="toy_sequence", version=1, frame_chunk=4,
    coords={"frame": VarSpec(("frame",), "int64")},
    variables={"total": VarSpec(("frame", "y", "x"), "float32", "mm")},
))


@dataclass(frozen=True)
class ScaleParams:
    factor: float = 2.0
    sleep: float = 0.0


def scale(frames: xr.Dataset, config: ScaleParams) -> xr.Dataset:
    time.sleep(config.sleep)
    hold = os.environ.get("TOY_HOLD_WHILE")  # not part of the cache key: concurrency tests
    while hold and os.path.exists(hold):
        time.sleep(0.05)
    value = frames["depth"].astype(np.float32) * np.float32(config.factor)
    return xr.Dataset({"value": value})


def scale_plus(frames: xr.Dataset, config: ScaleParams) -> xr.Dataset:
    return xr.Dataset({"value": frames["depth"].astype(np.float32) * np.float32(config.factor) + 1})


@dataclass(frozen=True)
class NoParams:
    pass


def diff(scaled: xr.Dataset, config: NoParams) -> xr.Dataset:
    value = scaled["value"]
    return xr.Dataset({"value": value - value.shift(frame=1).fillna(0)})


def total(scaled: xr.Dataset, config: NoParams) -> xr.Dataset:
    return xr.Dataset({"total": scaled["value"].sum("view")})


@dataclass(frozen=True)
class BoomParams:
    bad_view: str = "cam1"


def boom(frames: xr.Dataset, config: BoomParams) -> xr.Dataset:
    if str(frames["view"].values[0]) == config.bad_view:
        raise RuntimeError(f"boom on {config.bad_view}")
    return xr.Dataset({"value": frames["depth"].astype(np.float32)})


@dataclass(frozen=True)
class FlakyParams:
    bad_view: str = "cam1"


def flaky(scaled: xr.Dataset, config: FlakyParams) -> xr.Dataset:
    from_frame = os.environ.get("TOY_FLAKY_FROM")  # a failure that is not part of the cache key: resume tests
    if from_frame and str(scaled["view"].values[0]) == config.bad_view and int(scaled["frame"].values[-1]) >= int(from_frame):
        raise RuntimeError(f"flaky on {config.bad_view} from frame {from_frame}")
    return xr.Dataset({"value": scaled["value"] + 1})


@dataclass(frozen=True)
class WeightedParams:
    weights: str = ""


def weighted(frames: xr.Dataset, config: WeightedParams, weights) -> xr.Dataset:
    """depth * the ``gain`` tensor of a weights file (the engine hands over the loaded tensors)."""
    return xr.Dataset({"value": frames["depth"].astype(np.float32) * np.float32(weights["gain"].item())})


register(TaskSpec("weighted", weighted, "1", WeightedParams, "toy_view", "view", {"frames": "raw_sequence"},
                  weights_params=("weights",)))
register(TaskSpec("scale", scale, "1", ScaleParams, "toy_view", "view", {"frames": "raw_sequence"}))
register(TaskSpec("scale_plus", scale_plus, "1", ScaleParams, "toy_view", "view", {"frames": "raw_sequence"}))
register(TaskSpec("diff", diff, "1", NoParams, "toy_view", "view", {"scaled": "toy_view"}, halo=(1, 0)))
register(TaskSpec("total", total, "1", NoParams, "toy_sequence", "sequence", {"scaled": "toy_view"}))
register(TaskSpec("boom", boom, "1", BoomParams, "toy_view", "view", {"frames": "raw_sequence"}))
register(TaskSpec("flaky", flaky, "1", FlakyParams, "toy_view", "view", {"scaled": "toy_view"}))


def true_reflectors(frames: xr.Dataset, config: NoParams) -> xr.Dataset:
    """The studio's ground-truth 2D reflectors (seen with >= 5 px) as a `reflectors2d` artifact: a stand-in
    for the FCN, to test the 3D stages alone."""
    seen = frames["gt_pixels"].values >= 5
    uv = frames["gt_reflectors2d"].values
    x, y = (np.where(seen, uv[..., k], np.nan).astype(np.float32) for k in (0, 1))
    dims = ("view", "frame", "reflector")
    return xr.Dataset({"x": (dims, x), "y": (dims, y), "confidence": (dims, seen.astype(np.float32)),
                       "region_size": (dims, frames["gt_pixels"].values.astype(np.int32)),
                       "candidate_x": (dims, x), "candidate_y": (dims, y),
                       "candidate_confidence": (dims, seen.astype(np.float32))},
                      coords={"view": frames["view"].values, "frame": frames["frame"].values,
                              "reflector": frames["reflector"].values}, attrs={"b_min": 5, "c_min": 0.0})


register(TaskSpec("true_reflectors", true_reflectors, "1", NoParams, "reflectors2d", "view", {"frames": "raw_sequence"},
                  reads={"frames": ("gt_pixels", "gt_reflectors2d")}))


def exchanged_reflectors(frames: xr.Dataset, config: NoParams) -> xr.Dataset:
    """`true_reflectors` with a side view's mistakes: view kinect0's legs (calf, ankle, foot) under the
    other side's labels, and view kinect1 missing R_ELBOW."""
    out = true_reflectors(frames, config)
    names = [str(n) for n in out["reflector"].values]
    order = np.arange(len(names))
    for part in ("CALF", "ANKLE", "FOOT"):
        left, right = names.index("L_" + part), names.index("R_" + part)
        order[left], order[right] = right, left
    views = [str(v) for v in out["view"].values]
    if "kinect0" in views:
        for k in ("x", "y", "confidence", "region_size"):
            out[k].loc[{"view": "kinect0"}] = out[k].sel(view="kinect0").values[:, order]
    if "kinect1" in views:
        for k, value in (("x", np.nan), ("y", np.nan), ("confidence", 0.0), ("region_size", 0)):
            out[k].loc[{"view": "kinect1", "reflector": "R_ELBOW"}] = value
    return out


register(TaskSpec("exchanged_reflectors", exchanged_reflectors, "1", NoParams, "reflectors2d", "view",
                  {"frames": "raw_sequence"}, reads={"frames": ("gt_pixels", "gt_reflectors2d")}))


def flying_marker(markers: xr.Dataset, config: NoParams) -> xr.Dataset:
    """Smoothed markers with two gross errors planted: F_L_HEAD 3.7 m off above and behind the rig (as the demo's
    export once held) in the first 10 frames, and L_WRIST 40 cm in front of the markers' centroid (inside the rig,
    off the body) in frames 10-19."""
    out = markers.copy(deep=True)
    position = out["position"].values
    names = [str(n) for n in out["reflector"].values]
    position[:10, names.index("F_L_HEAD")] = [-0.075, -3.414, 3.051]
    position[10:20, names.index("L_WRIST")] = np.nanmean(position[10:20], axis=1) + [0.0, 0.4, 0.0]
    out["position"] = (out["position"].dims, position)
    return out


register(TaskSpec("flying_marker", flying_marker, "1", NoParams, "smoothed_markers", "sequence",
                  {"markers": "smoothed_markers"}, whole_sequence=True))
