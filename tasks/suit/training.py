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

from dataclasses import asdict, dataclass, field

import numpy as np
import xarray as xr

from mocapflow.tasks.shared.samples import InMemorySamples, Samples, SampleSubset
from mocapflow.tasks.shared.weights import pack
from mocapflow.tasks.suit import codes as cd
from mocapflow.tasks.suit import corners as co
from mocapflow.tasks.suit.crop_pool import CROPS, USED, CropPool, PoolError
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
class StreamConfig:
    """How a suit training holds its samples and keeps its state (crop_pool.CropPool, augment.fit)."""

    slots: int = 64  # images whose crops are held at a time (the rest stay in storage)
    swap: int = 1  # held images swapped for others before each batch
    validation: tuple[str, ...] = ()  # sequences held out of the training and scored at its end
    # iterations between checkpoints (a killed training continues from the last; the weights are the same)
    checkpoint_every: int = field(default=500, metadata={"runtime": True})

    def __post_init__(self):
        if self.slots < 1 or self.swap < 0 or self.checkpoint_every < 1:
            raise PoolError(f"slots ({self.slots}) >= 1, swap ({self.swap}) >= 0 and checkpoint_every "
                            f"({self.checkpoint_every}) >= 1 needed")


@dataclass(frozen=True)
class TrainCornerdetConfig:
    train: co.TrainConfig = co.TrainConfig()
    stream: StreamConfig = StreamConfig()
    seed: int = 0
    init: str = ""  # a CornerdetNet file to start from (fine-tuning; its architecture train.net's); empty: scratch


def _split(samples: xr.Dataset | Samples, stream: StreamConfig) -> tuple[Samples, Samples | None]:
    """The training samples and the held-out validation ones (None without ``validation``), streamed."""
    if isinstance(samples, xr.Dataset):
        samples = InMemorySamples(samples, (CROPS,))
    if not stream.validation:
        return samples, None
    sequence = np.asarray(samples.table["sequence"].values).astype(str)
    unknown = sorted(set(stream.validation) - set(sequence))
    held = np.isin(sequence, list(stream.validation))
    if unknown or held.all():
        raise PoolError(f"validation sequences {unknown or list(stream.validation)} are "
                        f"{'not in the training dataset' if unknown else 'all of it'}; name some of "
                        f"{sorted(set(sequence))}, not every one")
    return SampleSubset(samples, np.flatnonzero(~held)), SampleSubset(samples, np.flatnonzero(held))


def _held_out(samples: Samples, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Every used crop of ``samples`` with its columns, in memory (the validation set)."""
    used = samples.table[USED].values
    rows = [samples.read(i, (CROPS,))[CROPS][used[i]] for i in range(len(used))]
    return {CROPS: np.concatenate(rows), **{c: samples.table[c].values[used] for c in columns}}


def train_cornerdet_stage(samples: xr.Dataset | Samples, config: TrainCornerdetConfig, checkpoint=None,
                          init: dict | None = None) -> xr.Dataset:
    """Task: CornerdetNet trained on every crop of a dataset (its images streamed through a pool), less the
    validation sequences, which are scored at the end; from the weights of ``init`` (the file ``config.init``
    names, loaded by the engine) or from scratch."""
    train, validation = _split(samples, config.stream)
    pool = CropPool(train, ("present", "position"), slots=config.stream.slots, swap=config.stream.swap)
    start = None if init is None else co.cornerdet_from_weights(init)
    net, fitted = co.train_cornerdet(pool, config.train, seed=config.seed, checkpoint=checkpoint,
                                     checkpoint_every=config.stream.checkpoint_every, start=start)
    arch = {"widths": list(config.train.net.widths), "hidden": config.train.net.hidden,
            "batch_norm": config.train.net.batch_norm}
    record = {"crops": len(pool), "positives": pool.count("present"), "images": pool.n_samples,
              "seconds": fitted.seconds, "device": fitted.device, "iterations": config.train.iterations,
              "seed": config.seed, "slots": pool.slots, "init": config.init}
    if validation is not None:
        record["validation"] = cornerdet_scores(net, _held_out(validation, ("present", "position")))
    return pack(net.state_dict(), arch, record, fitted.losses)


def cornerdet_scores(net, held: dict[str, np.ndarray]) -> dict:
    """CornerdetNet on held-out crops: positives found (logit > 0), negatives taken for a corner, and the found
    positives' position error in pixels (median, p95)."""
    out = co.crop_outputs(net, held[CROPS])
    present, found = held["present"].astype(bool), out[:, 0] > 0
    err = np.linalg.norm(out[present & found, 1:] - held["position"][present & found], axis=1) * co.CELL
    return {"crops": int(len(present)), "recall": float(found[present].mean()),
            "false_rate": float(found[~present].mean()),
            "position_median_px": float(np.median(err)) if len(err) else float("nan"),
            "position_p95_px": float(np.percentile(err, 95)) if len(err) else float("nan")}


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
    stream: StreamConfig = StreamConfig()
    seed: int = 0
    init: str = ""  # a code networks file to start from (fine-tuning; their architectures train's); empty: scratch


def train_codes_stage(samples: xr.Dataset | Samples, config: TrainCodesConfig, checkpoint=None,
                      init: dict | None = None) -> xr.Dataset:
    """Task: RejectorNet and RecogNet trained on a dataset's candidate quads (streamed through a pool) plus
    synthetic crops of every code, less the validation sequences, which are scored at the end; from the weights
    of ``init`` (the file ``config.init`` names, loaded by the engine) or from scratch."""
    train, validation = _split(samples, config.stream)
    rng = np.random.default_rng([config.seed, 625])
    synthetic = cd.synthetic_quads(config.train.synthetic, config.train.synth, rng)
    columns = ("valid", "rotation", "code")
    pool = CropPool(train, columns, slots=config.stream.slots, swap=config.stream.swap,
                    fixed={CROPS: synthetic.crops, **{c: getattr(synthetic, c) for c in columns}})
    start = None if init is None else cd.nets_from_weights(init)
    rejector, recog, fitted = cd.train_code_nets(pool, config.train, seed=config.seed, checkpoint=checkpoint,
                                                 checkpoint_every=config.stream.checkpoint_every, start=start)
    state, arch = cd.pack_state(rejector, recog)
    record = {"studio_crops": len(pool) - pool.n_fixed, "studio_valid": pool.count("valid") - int(synthetic.valid.sum()),
              "synthetic_crops": pool.n_fixed, "images": pool.n_samples, "seconds": fitted.seconds,
              "device": fitted.device, "iterations": config.train.iterations, "seed": config.seed,
              "slots": pool.slots, "synth": asdict(config.train.synth), "init": config.init}
    if validation is not None:
        record["validation"] = codes_scores(rejector, recog, _held_out(validation, columns))
    return pack(state, arch, record, fitted.losses)


def codes_scores(rejector, recog, held: dict[str, np.ndarray]) -> dict:
    """RejectorNet and RecogNet on held-out candidate quads: the rejector's recall and precision on coded
    squares, and the share of coded squares read right (accepted, right code and rotation)."""
    reading = cd.read_crops(held[CROPS], rejector, recog)
    valid = held["valid"].astype(bool)
    right = reading.accepted & (reading.code == held["code"]) & (reading.rotation == held["rotation"])
    return {"crops": int(len(valid)), "valid": int(valid.sum()),
            "rejector_recall": float(reading.accepted[valid].mean()) if valid.any() else float("nan"),
            "rejector_precision": float(valid[reading.accepted].mean()) if reading.accepted.any() else float("nan"),
            "read_right": float(right[valid].mean()) if valid.any() else float("nan")}
