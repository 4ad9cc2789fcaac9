"""Training the suit's 2D chain from studio takes (Chen et al. 2021, §4): the per-image samples and the training
stages, as tasks of the engine.

``corner_training_samples`` cuts CornerdetNet's crops from each image with its truth (the readable corners are the
positives, every visible corner keeps negatives away); ``train_cornerdet_stage`` trains on every crop of a
training dataset. ``quad_training_samples`` runs the detector and the quad search of the chain on each image
(``corners`` and ``quads`` are the chain's own stages, run with the trained CornerdetNet) and labels every candidate
from the truth; ``train_codes_stage`` trains RejectorNet and RecogNet on them together with synthetic crops of every
code. Each training is seeded and writes a suit_net_weights artifact (tasks/shared/weights.py), which
``mocapflow train --stage NAME`` exports for the chain's stages.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
import xarray as xr

from mocapflow.tasks.shared.weights import pack
from mocapflow.tasks.suit import codes as cd
from mocapflow.tasks.suit import corners as co
from mocapflow.tasks.suit.quads import warp_quads


@dataclass(frozen=True)
class CornerSampleStageConfig:
    sample: co.SampleConfig = co.SampleConfig()
    positives: str = "readable"  # "readable": corners of a square seen whole near face-on; "visible": every one
    capacity: int = 6000  # crops kept per image (the artifact's padding)
    seed: int = 0

    def __post_init__(self):
        if self.positives not in ("readable", "visible") or self.capacity < 1:
            raise co.CornerError(f"positives must be 'readable' or 'visible' (got {self.positives!r}) and capacity "
                                 f">= 1 (got {self.capacity})")


def _truth(images: xr.Dataset, what: str, needed: tuple[str, ...] = ("gt_corners2d", "gt_visible")) -> None:
    missing = [v for v in needed if v not in images]
    if missing:
        raise co.CornerError(f"{what} needs studio takes with the truth ({', '.join(missing)} missing); train on a "
                             "studio_suit dataset")


def corner_training_samples(images: xr.Dataset, config: CornerSampleStageConfig) -> xr.Dataset:
    """Task: suit_corner_samples of every view and frame."""
    _truth(images, "corner_training_samples", ("gt_corners2d", "gt_visible", "gt_readable"))
    views, frames = images["view"].values, images["frame"].values
    cap = config.capacity
    crops = np.zeros((len(views), len(frames), cap, co.CROP, co.CROP), np.uint8)
    present, used = np.zeros((len(views), len(frames), cap), bool), np.zeros((len(views), len(frames), cap), bool)
    position = np.zeros((len(views), len(frames), cap, 2), np.float32)
    for v, view in enumerate(views):
        for f, frame in enumerate(frames):
            rng = np.random.default_rng([config.seed, int(frame), sum(map(ord, str(view)))])
            truth = images["gt_corners2d"].values[v, f]
            visible = images["gt_visible"].values[v, f]
            allowed = images["gt_readable"].values[v, f] if config.positives == "readable" else visible
            s = co.corner_samples(images["image"].values[v, f], truth, visible, config.sample, rng, positive=allowed)
            keep = rng.permutation(len(s))[:cap]
            n = len(keep)
            crops[v, f, :n], present[v, f, :n] = s.crops[keep], s.present[keep]
            position[v, f, :n], used[v, f, :n] = s.position[keep], True
    dims = ("view", "frame", "crop")
    return xr.Dataset({"crops": (dims + ("cy", "cx"), crops), "present": (dims, present),
                       "position": (dims + ("uv",), position), "used": (dims, used)},
                      coords={"view": views, "frame": frames})


@dataclass(frozen=True)
class TrainCornerdetConfig:
    train: co.TrainConfig = co.TrainConfig()
    seed: int = 0


def train_cornerdet_stage(samples: xr.Dataset, config: TrainCornerdetConfig) -> xr.Dataset:
    """Task: CornerdetNet trained on every crop of a dataset (samples stacked along ``sample``)."""
    used = samples["used"].values
    s = co.CornerSamples(samples["crops"].values[used], samples["present"].values[used],
                         samples["position"].values[used], np.zeros(int(used.sum()), np.int8))
    started = time.perf_counter()
    net = co.train_cornerdet(s, config.train, seed=config.seed)
    arch = {"widths": list(config.train.net.widths), "hidden": config.train.net.hidden,
            "batch_norm": config.train.net.batch_norm}
    record = {"crops": len(s), "positives": int(s.present.sum()), "seconds": round(time.perf_counter() - started, 1),
              "iterations": config.train.iterations, "seed": config.seed}
    return pack(net.state_dict(), arch, record, [])


@dataclass(frozen=True)
class QuadSampleStageConfig:
    match_px: float = 1.5  # a detection within this of a true corner is that corner
    positives: int = 20  # valid crops kept per image, at most (synthetic crops add every code); invalid ones all
    capacity: int = 200  # crops kept per image (the artifact's padding)
    seed: int = 0


def quad_training_samples(images: xr.Dataset, corners: xr.Dataset, quads: xr.Dataset,
                          config: QuadSampleStageConfig) -> xr.Dataset:
    """Task: suit_quad_samples: every candidate quad of the chain, labelled from the truth."""
    _truth(images, "quad_training_samples")
    views, frames = images["view"].values, images["frame"].values
    codes = [str(c) for c in images["code"].values]
    square_corners = images["square_corners"].values
    cap = config.capacity
    shape = (len(views), len(frames), cap)
    crops = np.zeros(shape + (cd.CROP, cd.CROP), np.uint8)
    valid, used = np.zeros(shape, bool), np.zeros(shape, bool)
    rotation, code = np.full(shape, -1, np.int8), np.full(shape, -1, np.int16)
    for v, view in enumerate(views):
        for f, frame in enumerate(frames):
            rng = np.random.default_rng([config.seed, int(frame), sum(map(ord, str(view)))])
            det = quads["detections"].values[v, f]
            det = det[det[:, 0] >= 0]
            xy = np.column_stack([corners["x"].values[v, f], corners["y"].values[v, f]])
            ok, rot, cid = cd.label_quads(xy, det, images["gt_corners2d"].values[v, f],
                                          images["gt_visible"].values[v, f], square_corners, codes, config.match_px)
            pos = rng.permutation(np.flatnonzero(ok))[:config.positives]
            keep = rng.permutation(np.concatenate([pos, np.flatnonzero(~ok)]))[:cap]
            n = len(keep)
            if n:
                crops[v, f, :n] = warp_quads(images["image"].values[v, f], xy[det[keep]])
            valid[v, f, :n], rotation[v, f, :n], code[v, f, :n] = ok[keep], rot[keep], cid[keep]
            used[v, f, :n] = True
    dims = ("view", "frame", "crop")
    return xr.Dataset({"crops": (dims + ("qy", "qx"), crops), "valid": (dims, valid), "rotation": (dims, rotation),
                       "code": (dims, code), "used": (dims, used)}, coords={"view": views, "frame": frames})


@dataclass(frozen=True)
class TrainCodesConfig:
    train: cd.CodeTrainConfig = field(default_factory=cd.CodeTrainConfig)
    seed: int = 0


def train_codes_stage(samples: xr.Dataset, config: TrainCodesConfig) -> xr.Dataset:
    """Task: RejectorNet and RecogNet trained on a dataset's candidate quads plus synthetic crops of every code."""
    used = samples["used"].values
    studio = cd.QuadSamples(samples["crops"].values[used], samples["valid"].values[used],
                            samples["rotation"].values[used], samples["code"].values[used])
    rng = np.random.default_rng([config.seed, 625])
    synthetic = cd.synthetic_quads(config.train.synthetic, config.train.synth, rng)
    both = cd.concat_quad_samples([studio, synthetic])
    started = time.perf_counter()
    rejector, recog, losses = cd.train_code_nets(both, config.train, seed=config.seed)
    state, arch = cd.pack_state(rejector, recog)
    record = {"studio_crops": len(studio), "studio_valid": int(studio.valid.sum()), "synthetic_crops": len(synthetic),
              "seconds": round(time.perf_counter() - started, 1), "iterations": config.train.iterations,
              "seed": config.seed, "synth": asdict(config.train.synth)}
    return pack(state, arch, record, losses)
