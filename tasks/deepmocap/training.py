"""Training the two-stream FCN on studio data (DeepMoCap §3.3.1, §5.1.1).

Two tasks: ``fcn_samples`` turns one view of a studio sequence into training samples (both input
streams at the sample scale, the subject box, ground-truth 2D at f and f-1); ``train_fcn`` draws
augmented crops from every sample of a dataset — scale [0.6, 1.1], rotation ±40°, flips that swap
left and right reflector labels, shifted crops around the subject (§5.1.1) — builds the targets of
Eq. 4-6 and minimizes the loss of Eq. 2-3 with Adam, seeded, on a GPU when there is one (the forward
pass in bfloat16 where the hardware has it; the loss and the weights stay float32). With ``workers``
> 0, worker processes draw the augmented batches, so a GPU is not left waiting on them. The images are read one
sample at a time as batches are drawn (tasks/shared/samples.py), so the set need not fit in memory, and the state
is checkpointed every ``checkpoint_every`` iterations, so a killed training continues where it stopped.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np
import xarray as xr

from mocapflow.tasks.deepmocap import targets
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES
from mocapflow.tasks.shared.progress import TrainingProgress
from mocapflow.tasks.shared.samples import InMemorySamples, Samples
from mocapflow.tasks.shared.weights import pack, unpack

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SampleConfig:
    sample_scale: float = 0.5  # the network's inputs are cropped from images resized by this factor
    box_min_area: int = 3  # reflector regions (pixels, full resolution) that define the subject box
    box_speck_area: int = 20  # a region under this many pixels with no other within box_link_px is a speck, not
    box_link_px: float = 120.0  # in the subject box (targets.subject_box); 120 px: about 1 m at 3 m from a Kinect v2

    def box_rule(self) -> targets.BoxRule:
        return targets.BoxRule(self.box_min_area, self.box_speck_area, self.box_link_px)


@dataclass(frozen=True)
class CropConfig:
    """How a crop is cut around the subject box (sample pixels); stored with the weights for inference."""

    sample_scale: float = 0.5
    margin: float = 1.3  # crop side = box long side x margin at scale 1
    min_side: float = 50.0  # sample pixels, so a lone reflector still gives a body-sized crop
    box_min_area: int = 3
    box_speck_area: int = 20  # see SampleConfig; 0: every region counts
    box_link_px: float = 120.0
    scale: float = 0.85  # inference crop scale, inside the training range

    def box_rule(self) -> targets.BoxRule:
        return targets.BoxRule(self.box_min_area, self.box_speck_area, self.box_link_px)


@dataclass(frozen=True)
class TrainConfig:
    # architecture (tasks/deepmocap/fcn.py FcnArchitecture)
    input_size: int = 128
    stream_width: int = 32
    fused_width: int = 64
    stage_width: int = 64
    stages: int = 3
    flow_stream: bool = True
    off_branch: bool = True
    # targets (Eq. 4-6), in output cells
    sigma: float = 1.0
    sigma_r: float = 1.0
    min_pixels: int = 3  # a reflector with fewer visible pixels has no target
    foreground_weight: float = 10.0  # L2 weight of a cell: 1 + this x the strongest reflector target there
    # augmentation (§5.1.1)
    scale_min: float = 0.6
    scale_max: float = 1.1
    rotation_deg: float = 40.0
    shift: float = 0.08
    flip: bool = True
    margin: float = 1.3
    min_side: float = 50.0
    # a weights file written by `mocapflow train` to start from (fine-tuning; its architecture must be this one's);
    # empty: from scratch
    init: str = ""
    # a trained network's weights file (same input_size) whose maps each target also holds: distillation, the
    # target being `distill` x the teacher's last-stage maps + (1 - distill) x the truth; empty: the truth alone
    teacher: str = ""
    distill: float = 0.5
    # optimization
    iterations: int = 6000
    batch: int = 16
    learning_rate: float = 5e-3
    bfloat16: bool = True  # forward pass in bfloat16 where the processor supports it (~1.7x faster on a CPU)
    frame_step: int = 2  # every n-th frame of each view is a sample
    seed: int = 0
    # false: one generator seeded `seed` draws every batch in turn (the shipped weights were trained so);
    # true: batch i comes from a generator seeded (seed, i), so any number of processes draws the same batches
    per_batch_seeds: bool = False
    # processes that draw the augmented batches (per_batch_seeds only; 0: the training process): a GPU waits
    # on the crops otherwise (one process draws 300-500 crops/s). Which batches are drawn does not depend on it.
    workers: int = field(default=0, metadata={"runtime": True})
    # iterations between checkpoints (a killed training continues from the last; the weights are the same)
    checkpoint_every: int = field(default=200, metadata={"runtime": True})

    def __post_init__(self):
        if self.checkpoint_every < 1:
            raise ValueError(f"checkpoint_every must be >= 1 iteration, got {self.checkpoint_every}")
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0 (0 = draw batches in the training process), got {self.workers}")
        if not 0.0 <= self.distill <= 1.0:
            raise ValueError(f"distill is the teacher's share of each target, in [0, 1]; got {self.distill}")
        if self.workers and not self.per_batch_seeds:
            raise ValueError(f"workers = {self.workers} draws batches in other processes, which needs "
                             "per_batch_seeds: true (one seeded stream cannot be shared); set both")


def to_sample_scale(points: np.ndarray, sample_scale: float) -> np.ndarray:
    """Image pixel coordinates -> sample-scale ones (pixel centres stay centres)."""
    return ((points + 0.5) * sample_scale - 0.5).astype(np.float32)


def sample_inputs(depth_image, flow_image, blob_id, blob_area, *, sample_scale: float, box: targets.BoxRule):
    """Both streams at the sample scale and the subject box in its pixels (training and inference alike).
    (y, x, 3) x2, (y, x), (blob,) -> (y', x', 3) x2, (4,)"""
    h, w = depth_image.shape[:2]
    size = (int(round(w * sample_scale)), int(round(h * sample_scale)))
    subject = targets.subject_box(blob_id, blob_area, box)
    return (cv2.resize(depth_image, size, interpolation=cv2.INTER_AREA),
            cv2.resize(flow_image, size, interpolation=cv2.INTER_AREA), to_sample_scale(subject, sample_scale))


def sample_view(depth_image, flow_image, blob_id, blob_area, uv, uv_prev, pixels, *, sample_scale: float,
                box: targets.BoxRule):
    """One view-frame's training sample: :func:`sample_inputs` and the 2D ground truth at f and f-1."""
    return (*sample_inputs(depth_image, flow_image, blob_id, blob_area, sample_scale=sample_scale, box=box),
            to_sample_scale(uv, sample_scale), to_sample_scale(uv_prev, sample_scale), pixels.astype(np.int32))


def fcn_samples(masks: xr.Dataset, flow: xr.Dataset, frames: xr.Dataset, config: SampleConfig) -> xr.Dataset:
    """Training samples of every view and frame (frames carries one frame before the region, for f-1)."""
    uv_all = frames["gt_reflectors2d"]
    out = {k: [] for k in ("depth_image", "flow_image", "box", "gt_uv", "gt_uv_prev", "gt_pixels")}
    frame_ids = masks["frame"].values
    for view in masks["view"].values:
        per_view = {k: [] for k in out}
        for frame in frame_ids:
            prev = frame - 1 if frame - 1 in frames["frame"].values else frame  # frame 0: no motion before it
            m = masks.sel(view=view, frame=frame)
            sample = sample_view(m["colorized_depth"].values, flow["colorized_flow"].sel(view=view, frame=frame).values,
                                 m["blob_id"].values, m["blob_area"].values, uv_all.sel(view=view, frame=frame).values,
                                 uv_all.sel(view=view, frame=prev).values,
                                 frames["gt_pixels"].sel(view=view, frame=frame).values,
                                 sample_scale=config.sample_scale, box=config.box_rule())
            for key, value in zip(per_view, sample):
                per_view[key].append(value)
        for key in out:
            out[key].append(np.stack(per_view[key]))
    vf, vfr = ("view", "frame"), ("view", "frame", "reflector")
    return xr.Dataset(
        {"depth_image": (vf + ("y", "x", "rgb"), np.stack(out["depth_image"])),
         "flow_image": (vf + ("y", "x", "rgb"), np.stack(out["flow_image"])),
         "box": (vf + ("corner",), np.stack(out["box"])),
         "gt_uv": (vfr + ("uv",), np.stack(out["gt_uv"])), "gt_uv_prev": (vfr + ("uv",), np.stack(out["gt_uv_prev"])),
         "gt_pixels": (vfr, np.stack(out["gt_pixels"]))},
        coords={"view": masks["view"].values, "frame": frame_ids, "reflector": list(REFLECTOR_NAMES)},
        attrs={"sample_scale": float(config.sample_scale)},
    )


def augmented(sample: dict, rng: np.random.Generator, *, size: int, stride: int, crop: CropConfig,
              config: TrainConfig):
    """One augmented crop and its targets: streams (size, size, 3) x2, S* (27, g, g), L* (26, 2, g, g)."""
    jitter = targets.draw_jitter(rng, scale=(config.scale_min, config.scale_max), rotation_deg=config.rotation_deg,
                                 shift=config.shift)
    if not config.flip:
        jitter = targets.CropJitter(jitter.scale, jitter.rotation_deg, False, jitter.shift)
    m = targets.crop_affine(sample["box"], size=size, margin=crop.margin, min_side=crop.min_side, jitter=jitter)
    depth = targets.warp_depth(sample["depth_image"], m, size)
    flow = targets.warp_flow(sample["flow_image"], m, size)
    uv = targets.to_cells(targets.apply_affine(m, sample["gt_uv"]), stride)  # (26, 2)
    uv_prev = targets.to_cells(targets.apply_affine(m, sample["gt_uv_prev"]), stride)
    visible = sample["gt_pixels"] >= config.min_pixels
    if jitter.flip:  # the subject's left now shows where a right reflector would: swap the labels
        uv, uv_prev, visible = uv[targets.FLIP_ORDER], uv_prev[targets.FLIP_ORDER], visible[targets.FLIP_ORDER]
    grid = (size // stride, size // stride)
    return (depth, flow, targets.confidence_maps(uv, visible, grid, config.sigma),
            targets.flow_fields(uv_prev, uv, visible, grid, config.sigma_r))


IMAGES = ("depth_image", "flow_image")  # a sample's large variables, read one sample at a time (streamed)
TABLE = ("box", "gt_uv", "gt_uv_prev", "gt_pixels")  # its small ones, in memory for every sample


def train_fcn(samples: xr.Dataset | Samples, config: TrainConfig, checkpoint=None, init: dict | None = None,
              teacher: dict | None = None) -> xr.Dataset:
    """Train the network on ``samples`` (dims sample, y, x, ...; a loaded dataset or samples streamed from
    storage); the weights as a flat vector with their layout. With a ``checkpoint`` (``load() -> dict | None``,
    ``save(dict)``), the state is saved every ``checkpoint_every`` iterations and a saved state is continued
    from: the weights are those of an uninterrupted run. ``init``: the tensors of the file ``config.init`` names
    (the engine loads them), the weights the training starts from; ``teacher``: those of ``config.teacher``, the
    network whose maps the targets blend in (distillation)."""
    import torch

    from mocapflow.tasks.deepmocap import fcn

    arch = fcn.FcnArchitecture(input_size=config.input_size, stream_width=config.stream_width,
                               fused_width=config.fused_width, stage_width=config.stage_width, stages=config.stages,
                               flow_stream=config.flow_stream, off_branch=config.off_branch)
    if isinstance(samples, xr.Dataset):
        samples = InMemorySamples(samples, IMAGES)
    crop = CropConfig(sample_scale=float(samples.table.attrs.get("sample_scale", 0.5)), margin=config.margin,
                      min_side=config.min_side)
    pool = SamplePool(samples, config)
    torch.manual_seed(config.seed)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    model = fcn.TwoStreamFCN(arch) if init is None else _started_from(init, arch, config.init)
    model = model.to(device).train()
    mixed = config.bfloat16 and _bfloat16_ok(device)
    teach = None if teacher is None else _Teacher(teacher, arch, config, device, mixed)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimizer, max_lr=config.learning_rate,
                                                   total_steps=config.iterations, pct_start=0.1)
    run = TrainingProgress.start(checkpoint.load() if checkpoint is not None else None, {"model": model}, optimizer,
                                 schedule, config.iterations)
    stream = Batches(pool, arch, crop, config, start=run.iteration, rng_state=str(run.saved.get("rng", "")))
    for batch in stream:  # the batches from run.iteration on
        depth, flow, s_target, l_target = (torch.as_tensor(column).to(device) for column in batch)  # uint8 images
        with torch.autocast(device, dtype=torch.bfloat16, enabled=mixed):
            outputs = model(fcn.to_input(depth), fcn.to_input(flow) if arch.flow_stream else None)
        outputs = [(s.float(), None if f is None else f.float()) for s, f in outputs]  # the loss in float32
        l_target = l_target.reshape(len(depth), -1, *l_target.shape[-2:])  # (batch, 52, g, g)
        weight = 1.0 + config.foreground_weight * s_target[:, :fcn.N_REFLECTORS].amax(dim=1, keepdim=True)
        if teach is not None:
            s_target, l_target = teach.blend(depth, flow, s_target, l_target)
        loss = fcn.stage_losses(outputs, s_target, l_target, weight)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
        run.step(loss.item())
        if checkpoint is not None and run.due(config.checkpoint_every):
            checkpoint.save(run.state({"model": model}, optimizer, schedule, rng=stream.rng_state()))
    return weights_dataset(model.cpu(), crop, config, run.losses, n_samples=len(pool),
                           seconds=run.seconds(), device=device + (" bfloat16" if mixed else ""))


def _started_from(init: dict, arch, name: str):
    """The network of ``init`` (fine-tuning), which must be of ``arch``."""
    from mocapflow.tasks.deepmocap import fcn

    model = fcn.unpack(init)
    found, wanted = asdict(model.arch), asdict(arch)
    differ = [f"{k}: {found[k]!r} in the file, {v!r} here" for k, v in sorted(wanted.items()) if found[k] != v]
    if differ:
        raise ValueError(f"init weights {name} are another architecture ({', '.join(differ)}); set those params "
                         "to the file's or train from scratch (init: \"\")")
    return model


class _Teacher:
    """The network a smaller one learns from: its last stage's maps blended into each target (distillation)."""

    def __init__(self, weights: dict, arch, config: TrainConfig, device: str, mixed: bool):
        from mocapflow.tasks.deepmocap import fcn

        model = fcn.unpack(weights)
        if model.arch.input_size != arch.input_size:
            raise ValueError(f"teacher {config.teacher} reads {model.arch.input_size}-pixel crops, this network "
                             f"{arch.input_size}; their maps must share a grid: set input_size to "
                             f"{model.arch.input_size} or choose another teacher")
        self.model, self.share, self.device, self.mixed = model.to(device), config.distill, device, mixed

    def blend(self, depth, flow, s_target, l_target):
        import torch

        from mocapflow.tasks.deepmocap import fcn

        with torch.no_grad(), torch.autocast(self.device, dtype=torch.bfloat16, enabled=self.mixed):
            s, fields = self.model(fcn.to_input(depth), fcn.to_input(flow) if self.model.arch.flow_stream else None)[-1]
        s_target = self.share * s.float() + (1.0 - self.share) * s_target
        if fields is not None:
            l_target = self.share * fields.float() + (1.0 - self.share) * l_target
        return s_target, l_target


class SamplePool:
    """The samples a training draws from: every ``frame_step``-th frame of each view with at least one reflector
    seen; their small variables in memory, their images read when drawn."""

    def __init__(self, samples: Samples, config: TrainConfig):
        table = samples.table
        keep = (table["frame"].values % config.frame_step == 0) & (table["gt_pixels"].values >= config.min_pixels).any(-1)
        if not keep.any():
            raise ValueError("no training sample sees a reflector; check the training dataset")
        self.index = np.nonzero(keep)[0]
        self.small = {k: table[k].values[self.index] for k in TABLE}
        self.samples = samples

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict:
        return {**{k: v[i] for k, v in self.small.items()}, **self.samples.read(int(self.index[i]), IMAGES)}


def _batch(pool: SamplePool, rng: np.random.Generator, *, arch, crop: CropConfig, config: TrainConfig):
    """One iteration's augmented crops, stacked: depth and flow (batch, size, size, 3) uint8,
    S* (batch, 27, g, g) and L* (batch, 26, 2, g, g) float32."""
    crops = [augmented(pool[int(i)], rng, size=arch.input_size, stride=arch.stride, crop=crop, config=config)
             for i in rng.integers(0, len(pool), config.batch)]
    return tuple(np.stack(column) for column in zip(*crops))


class SeededBatches:
    """Batch ``start + i`` drawn from its own generator seeded ``(seed, start + i)``, so any worker process draws it
    alike (a map-style dataset of the batches from ``start`` on, for torch's DataLoader)."""

    def __init__(self, pool: SamplePool, arch, crop: CropConfig, config: TrainConfig, start: int = 0):
        self.pool, self.arch, self.crop, self.config, self.start = pool, arch, crop, config, start

    def __len__(self) -> int:
        return self.config.iterations - self.start

    def __getitem__(self, i: int):
        rng = np.random.default_rng([self.config.seed, self.start + i])
        return _batch(self.pool, rng, arch=self.arch, crop=self.crop, config=self.config)


def _one_thread(_worker: int) -> None:
    """A batch-drawing process uses one core: the parallelism is across processes."""
    import torch

    cv2.setNumThreads(1)
    torch.set_num_threads(1)


class Batches:
    """The training batches in order from iteration ``start``: one seeded stream (its generator's state at
    ``start`` given as ``rng_state``, JSON), or per-batch seeds drawn here or in ``workers`` processes."""

    def __init__(self, pool: SamplePool, arch, crop: CropConfig, config: TrainConfig, start: int = 0,
                 rng_state: str = ""):
        self.pool, self.arch, self.crop, self.config, self.start = pool, arch, crop, config, start
        self.rng = np.random.default_rng(config.seed)
        if rng_state:
            self.rng.bit_generator.state = json.loads(rng_state)
        elif start and not config.per_batch_seeds:
            raise ValueError(f"resuming one seeded stream at batch {start} needs its generator's state")

    def rng_state(self) -> str:
        """The single stream's generator state now (what the next batch is drawn from); '' for per-batch seeds."""
        return "" if self.config.per_batch_seeds else json.dumps(self.rng.bit_generator.state)

    def __iter__(self):
        if not self.config.per_batch_seeds:
            for _ in range(self.start, self.config.iterations):
                yield _batch(self.pool, self.rng, arch=self.arch, crop=self.crop, config=self.config)
            return
        batches = SeededBatches(self.pool, self.arch, self.crop, self.config, self.start)
        if not self.config.workers:
            yield from (batches[i] for i in range(len(batches)))
            return
        from torch.utils.data import DataLoader

        # fork: the workers share the sample pool instead of each unpickling a copy. cv2's thread pool does not
        # survive a fork (a worker's first warp would wait on it forever), so cv2 stays on one thread in this
        # process while the workers run.
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            yield from DataLoader(batches, batch_size=None, shuffle=False, num_workers=self.config.workers,
                                  prefetch_factor=4, worker_init_fn=_one_thread, multiprocessing_context="fork")
        finally:
            cv2.setNumThreads(threads)


def _bfloat16_ok(device: str) -> bool:
    """Whether bfloat16 autocast is native here (a CUDA GPU that has it, or a CPU with AVX-512 BF16 / AMX)."""
    import torch

    if device == "cuda":
        return torch.cuda.is_bf16_supported()
    try:
        return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a build without the query: stay in float32
        return False


def weights_dataset(model, crop: CropConfig, config: TrainConfig, losses, *, n_samples: int, seconds: float,
                    device: str) -> xr.Dataset:
    return pack(model.state_dict(), asdict(model.arch),
                {"config": asdict(config), "crop": asdict(crop), "samples": int(n_samples),
                 "seconds": round(float(seconds), 1), "device": device}, losses)


def weights_from_dataset(ds: xr.Dataset) -> dict:
    """The plain-tensor weights (tasks/deepmocap/fcn.py ``unpack`` format, plus the crop) of a trained artifact."""
    net = unpack(ds)
    return {"architecture": net["architecture"], "crop": dict(net["training"]["crop"]), "state": net["state"]}
