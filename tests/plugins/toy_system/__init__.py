"""A toy fourth capture system, registered through the public path only (registry.System, found through the
``mocapflow.systems`` entry point group): the test of docs/adding-a-system.md.

One marker walks along x at a constant speed, recorded with seeded noise (the dataset kind ``toy_walk``, with its
truth); ``toy_record`` is its source stage, ``toy_smooth`` a moving average; the evaluator scores the smoothed
positions against the truth (``toy_rmse_mm``); the exporter writes ``<sequence>.csv``; its command
``mocapflow toy-walk`` prints the true walk (cli.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from mocapflow.pipeline.catalog import stage_writing
from mocapflow.pipeline.datasets import SequenceInfo
from mocapflow.pipeline.errors import CatalogError
from mocapflow.pipeline.export import target, write_atomically
from mocapflow.pipeline.hashing import digest
from mocapflow.pipeline.registry import Command, Evaluator, ExportJob, Exporter, NoParams, System, TaskSpec
from mocapflow.schemas import ArtifactSchema, VarSpec

COORDS = {"frame": VarSpec(("frame",), "int64"), "marker": VarSpec(("marker",), "str")}
TOY_WALK = ArtifactSchema(
    name="toy_walk", version=1, frame_chunk=8, coords=COORDS, required_attrs={"fps": float},
    variables={"position": VarSpec(("frame", "marker", "xyz"), "float32", "m"),
               "gt_position": VarSpec(("frame", "marker", "xyz"), "float32", "m")})
TOY_SMOOTHED = ArtifactSchema(
    name="toy_smoothed", version=1, frame_chunk=8, coords=COORDS,
    variables={"position": VarSpec(("frame", "marker", "xyz"), "float32", "m")})


class ToyWalkReader:
    """``sequences: {id: {frames, speed, noise_mm, seed}}``."""

    options = ("sequences",)
    has_views = False

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        sequences = dataset.options.get("sequences") or {}
        if not sequences:
            raise CatalogError(f"{dataset.where}: a toy_walk dataset needs 'sequences: {{id: {{frames: N}}}}'")
        return [SequenceInfo(str(name), (), int(spec["frames"]), digest(dict(spec)), dict(spec))
                for name, spec in sequences.items()]

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        fps, frames = 30.0, np.arange(seq.n_frames)
        truth = np.zeros((seq.n_frames, 1, 3), np.float32)
        truth[:, 0, 0] = frames / fps * float(seq.spec.get("speed", 1.0))
        truth[:, 0, 2] = 1.0
        noise = np.random.default_rng(int(seq.spec.get("seed", 0))).normal(0.0, 1e-3 * float(seq.spec.get("noise_mm", 5)),
                                                                              truth.shape)
        window = slice(start, stop)
        return xr.Dataset({"position": (("frame", "marker", "xyz"), (truth + noise).astype(np.float32)[window]),
                           "gt_position": (("frame", "marker", "xyz"), truth[window])},
                          coords={"frame": frames[window].astype(np.int64), "marker": np.array(["m0"], dtype=object)},
                          attrs={"fps": fps})


@dataclass(frozen=True)
class SmoothConfig:
    window: int = 5  # frames averaged, centred


def smooth(walk: xr.Dataset, config: SmoothConfig) -> xr.Dataset:
    """A centred moving average along frames, its window shrunk symmetrically at the ends (a straight walk passes
    through unchanged)."""
    if config.window < 1:
        raise ValueError(f"window must be >= 1 frame, got {config.window}")
    pos = walk["position"].values.astype(np.float64)
    n = pos.shape[0]
    frames = np.arange(n)
    half = np.minimum(config.window // 2, np.minimum(frames, n - 1 - frames))
    sums = np.concatenate([np.zeros((1,) + pos.shape[1:]), np.cumsum(pos, axis=0)])
    mean = (sums[frames + half + 1] - sums[frames - half]) / (2 * half + 1)[:, None, None]
    return xr.Dataset({"position": (("frame", "marker", "xyz"), mean.astype(np.float32))},
                      coords={"frame": walk["frame"].values, "marker": walk["marker"].values})


def applies(catalog) -> bool:
    return stage_writing(catalog, "toy_smoothed") is not None


def evaluate(catalog, plan, store, per_sequence: dict, thorough: bool = True) -> dict:
    """RMSE (mm) of the smoothed marker against the truth, per sequence and over all."""
    stage, source = stage_writing(catalog, "toy_smoothed"), stage_writing(catalog, "toy_walk")
    errors = []
    for seq in plan.sequences:
        est = plan.open(store, stage, seq.id)["position"].values
        gt = plan.open(store, source, seq.id)["gt_position"].values
        e = 1000.0 * np.linalg.norm(est - gt, axis=-1).ravel()
        per_sequence.setdefault(seq.id, {})["toy_rmse_mm"] = float(np.sqrt(np.mean(e ** 2)))
        errors.append(e)
    return {"toy": {"rmse_mm": float(np.sqrt(np.mean(np.concatenate(errors) ** 2))), "stage": stage}}


def headline(result: dict) -> dict:
    return {"toy_rmse_mm": result["toy"]["rmse_mm"]} if "toy" in result else {}


def table(result: dict) -> list[str]:
    if "toy" not in result:
        return []
    return [f"toy walk ({result['toy']['stage']}): RMSE {result['toy']['rmse_mm']:.2f} mm"] + \
        [f"  {name}: {s['toy_rmse_mm']:.2f} mm" for name, s in result["sequences"].items() if "toy_rmse_mm" in s]


def write_csv(job: ExportJob) -> list[Path]:
    path = target(job.out_dir, f"{job.sequence}.csv")
    rows = ["frame,x,y,z"] + [f"{f},{x:.6f},{y:.6f},{z:.6f}" for f, (x, y, z) in
                              zip(job.data["frame"].values, job.data["position"].values[:, 0])]
    write_atomically(path, lambda p: p.write_text("\n".join(rows) + "\n"), ".csv")
    return [path]


SYSTEM = System(
    name="toy",
    description="one marker walking along x, smoothed",
    tasks=(TaskSpec(name="toy_record", fn=None, version="1", params=NoParams, output="toy_walk", partition="sequence",
                    source=True, description="the toy_walk dataset's sequences"),
           TaskSpec(name="toy_smooth", fn=smooth, version="1", params=SmoothConfig, output="toy_smoothed",
                    partition="sequence", inputs={"walk": "toy_walk"}, whole_sequence=True,
                    description="a centred moving average")),
    dataset_kinds={"toy_walk": ToyWalkReader},
    schemas=(TOY_WALK, TOY_SMOOTHED),
    evaluators=(Evaluator("toy", applies, evaluate, headline, table),),
    exporters=(Exporter("csv", ("toy_smoothed",), write_csv),),
    commands={"toy-walk": Command("toy_system.cli", "toy_walk")},
)
