"""Inference of the two-stream FCN: confidence maps S and optical flow fields L per view and frame
(DeepMoCap §3.3.1). Each frame's two streams are cropped around the subject exactly as in training
(tasks/deepmocap/training.py), the network runs on batches of crops, and the last stage's maps are kept with
the affine that takes their input pixels back to the image.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from mocapflow.tasks.deepmocap import targets
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.shared.precision import native_bfloat16, resolve_precision
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES
from mocapflow.tasks.deepmocap.training import CropConfig, sample_inputs


log = logging.getLogger(__name__)

PRECISIONS = ("auto", "float32", "bfloat16")
_MODELS: BoundedCache[tuple, tuple] = BoundedCache(4)  # (id(weights), stages) -> (weights, model), see inference_model


@dataclass(frozen=True)
class HeatmapConfig:
    weights: str = ""  # a file written by `mocapflow train`; empty: the weights shipped with mocapflow
    batch: int = field(default=8, metadata={"runtime": True})  # crops per network call: speed and memory only
    # "bfloat16": the network's convolutions in bfloat16 (torch autocast); "auto": bfloat16 where the CPU has AMX
    # tiles, float32 elsewhere (see resolve_precision). The maps differ by rounding only (same 2D mAP).
    precision: str = "auto"
    stages: int = 0  # refinement stages run (the last one's maps kept): 0 all; fewer is faster, every stage was trained

    def __post_init__(self):
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {self.precision!r}")
        if self.batch < 1:
            raise ValueError(f"batch must be >= 1 crops, got {self.batch}")
        if self.stages < 0:
            raise ValueError(f"stages must be >= 0 (0: all of the network's), got {self.stages}")


def crop_to_image(m: np.ndarray, sample_scale: float) -> np.ndarray:
    """2x3 affine: crop pixel -> image pixel, for the image->crop affine ``m`` of a sample-scale image."""
    to_sample = targets.invert_affine(m)  # crop -> sample pixels
    # sample pixel s -> image pixel (s + 0.5) / scale - 0.5
    return np.vstack([to_sample[0] / sample_scale, to_sample[1] / sample_scale]) + np.array(
        [[0, 0, 0.5 / sample_scale - 0.5], [0, 0, 0.5 / sample_scale - 0.5]])


@functools.lru_cache(maxsize=1)
def _warn_emulated() -> None:
    """Once per process."""
    log.warning("heatmaps: precision 'bfloat16' on a CPU without AVX512-BF16 or AMX is emulated and slower than "
                "float32; set the heatmaps stage's params to {precision: auto}")


def half(x) -> np.ndarray:
    """float32 torch tensor or array -> float16 array, rounded as numpy rounds. torch's conversion runs in
    hardware; numpy's goes through software for values below float16's normal range (most of a confidence map),
    50x slower."""
    import torch

    return torch.as_tensor(x).to(torch.float16).numpy()


def infer(model, depth_images: np.ndarray, flow_images: np.ndarray, batch: int,
          precision: str = "float32") -> tuple[np.ndarray, np.ndarray]:
    """Last-stage maps of ``model`` on crops.  (n, s, s, 3) uint8 x2 -> S (n, 26, g, g), L (n, 26, g, g, 2)"""
    import torch

    from mocapflow.tasks.deepmocap.fcn import N_REFLECTORS, to_input

    precision = resolve_precision(precision)
    if precision == "bfloat16" and not native_bfloat16():
        _warn_emulated()
    s_out, l_out = [], []
    low = torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bfloat16")
    with torch.inference_mode(), low:
        for a in range(0, len(depth_images), batch):
            depth = to_input(depth_images[a:a + batch], channels_last=True)
            flow = to_input(flow_images[a:a + batch], channels_last=True) if model.arch.flow_stream else None
            s, fields = model(depth, flow)[-1]
            n, _, gh, gw = s.shape
            s_out.append(s[:, :N_REFLECTORS].clamp(0, 1).float().numpy())
            l_out.append(np.zeros((n, N_REFLECTORS, gh, gw, 2), np.float32) if fields is None else
                         fields.reshape(n, N_REFLECTORS, 2, gh, gw).permute(0, 1, 3, 4, 2).float().numpy())
    return np.concatenate(s_out), np.concatenate(l_out)


def inference_model(weights: dict, stages: int = 0):
    """The network of ``weights`` prepared for inference (``fcn.for_inference``), its first ``stages`` refinement
    stages only if > 0, built once per process, weights and stages: a worker's regions share it (the weights dicts
    themselves are cached per process, pipeline/models.py)."""
    from mocapflow.tasks.deepmocap.fcn import for_inference, unpack

    kept = _MODELS.get((id(weights), stages))
    if kept is None or kept[0] is not weights:
        model = for_inference(unpack(weights))
        if stages > len(model.stages):
            raise ValueError(f"heatmaps: stages {stages} asked of a network with {len(model.stages)}; use 1 to "
                             f"{len(model.stages)}, or 0 for all")
        if stages:
            model.stages = model.stages[:stages]
        kept = (weights, model)  # holding the dict keeps its id from being reused
        _MODELS.put((id(weights), stages), kept)
    return kept[1]


def network_inputs(masks: xr.Dataset, flow: xr.Dataset, crop: CropConfig, size: int):
    """Both streams cropped around the subject for every view-frame, views outer, and each crop's affine back to
    the image.  -> (view * frame, size, size, 3) uint8 x2, (view * frame, 6)"""
    depth_crops, flow_crops, affines = [], [], []
    for view in masks["view"].values:
        m, f = masks.sel(view=view), flow.sel(view=view)
        for i in range(m.sizes["frame"]):
            depth_s, flow_s, box = sample_inputs(
                m["colorized_depth"].values[i], f["colorized_flow"].values[i], m["blob_id"].values[i],
                m["blob_area"].values[i], sample_scale=crop.sample_scale, box=crop.box_rule())
            a = targets.crop_affine(box, size=size, margin=crop.margin, min_side=crop.min_side,
                                    jitter=targets.CropJitter(scale=crop.scale))
            depth_crops.append(targets.warp_depth(depth_s, a, size))
            flow_crops.append(targets.warp_flow(flow_s, a, size))
            affines.append(crop_to_image(a, crop.sample_scale).ravel())
    return np.stack(depth_crops), np.stack(flow_crops), np.stack(affines)


def fcn_heatmaps(masks: xr.Dataset, flow: xr.Dataset, config: HeatmapConfig, weights: dict) -> xr.Dataset:
    """Confidence maps, OFFs and crop affines for every view and frame of ``masks``/``flow``; ``weights``: the
    tensors of the file ``config.weights`` names (the engine loads them)."""
    model = inference_model(weights, config.stages)
    depth_crops, flow_crops, affines = network_inputs(masks, flow, CropConfig(**weights.get("crop", {})),
                                                      model.arch.input_size)
    # one network call per `batch` crops across views and frames
    s, fields = infer(model, depth_crops, flow_crops, config.batch, config.precision)
    shape = (masks.sizes["view"], masks.sizes["frame"])
    confidence, off = s.reshape(shape + s.shape[1:]), fields.reshape(shape + fields.shape[1:])
    dims = ("view", "frame", "reflector", "hy", "hx")
    return xr.Dataset(
        {"confidence": (dims, half(confidence)),
         "off": (dims + ("uv",), half(off)),
         "crop": (("view", "frame", "affine"), affines.reshape(shape + (6,)))},
        coords={"view": masks["view"].values, "frame": masks["frame"].values, "reflector": list(REFLECTOR_NAMES)},
        attrs={"stride": int(model.arch.stride), "precision": resolve_precision(config.precision)},
    )
