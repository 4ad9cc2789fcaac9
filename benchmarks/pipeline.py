"""Whole-pipeline throughput: frames per second of `mocapflow run` from the sensors' frames to poses
(masks, `dis` flow, heatmaps, reflectors2d, markers3d, smoothed, skeleton, template, checked, the body fit `poses`,
refined labels) for 3 views at
512x424 on the machine's cores, as a user runs it (fresh processes, engine and storage included).

The recording itself (the studio render, standing in for the sensors) is made once and not timed;
each repeat deletes every other stage's artifacts and reruns. The stages are the held-out catalog's
(benchmarks/capsule.yaml); held-out motion (CMU walk), held-out subject seed and a random camera layout:

    python benchmarks/pipeline.py [--frames 90] [--repeats 3] [--workers 2] [--weights FILE] [--drop STAGE ...]

``--drop poses`` runs the chain without its body fit (the template's poses then end it), the chain before the
poses were bodies.

The CMU clips give at most about 140 frames at 30 fps; longer takes, where the per-take costs (process start,
skeleton calibration) weigh less, run on a studio exercise: ``--motion jumping_jack --frames 300``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import yaml

from mocapflow.pipeline.storage import Store

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
CLIP = SHARED / "motions" / "cmu_12_01_walk.bvh"


def catalog_text(frames: int, preset: str, motion: str = str(CLIP), weights: Path | None = None,
                 drop: tuple[str, ...] = ()) -> str:
    """The held-out catalog's stage chain (benchmarks/capsule.yaml) on one sequence of ``frames`` frames of
    ``motion`` (a BVH file or a studio exercise), its `dis` flow at DIS ``preset``, the network of ``weights``
    (None: the shipped one), without the stages ``drop``."""
    held_out = yaml.safe_load((ROOT / "benchmarks" / "capsule.yaml").read_text())
    for stage in drop:
        held_out["stages"].pop(stage)
    held_out["stages"]["flow"].setdefault("params", {})["preset"] = preset
    roots = [".", str(SHARED)]
    if weights is not None:
        weights = weights.resolve()
        held_out["stages"]["heatmaps"].setdefault("params", {})["weights"] = str(weights)
        roots.append(str(weights.parent))
    dataset = {"kind": "studio", "defaults": {**held_out["datasets"]["heldout"]["defaults"], "frames": frames},
               "sequences": {"take": {"motion": motion, "seed": 9105}}}
    return yaml.safe_dump({"data_roots": roots, "storage": {"root": "storage/", "region_frames": 16},
                           "datasets": {"heldout": dataset}, "stages": held_out["stages"]}, sort_keys=False)


def mocapflow(folder: Path, *args: str) -> None:
    subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", *args, "--no-progress"], cwd=folder, check=True,
                   stdout=subprocess.DEVNULL)


def clear_stages(storage: Path) -> None:
    """Delete every stage's artifacts but the recorded frames (and the run logs), so that the next run computes
    them all again."""
    for stage_dir in storage.iterdir():
        if stage_dir.name not in ("frames", "logs"):
            shutil.rmtree(stage_dir)


def stage_seconds(storage: Path) -> dict[str, float]:
    """Compute seconds per stage, summed over partitions, from the artifacts' lineage records."""
    store = Store(str(storage))
    return {stage: sum(v.lineage.get("compute_seconds", 0.0) for v in store.versions(stage))
            for stage in store.stages_on_disk()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--preset", default="fast", help="DIS preset of the `dis` flow (the issue's fast variant)")
    parser.add_argument("--motion", default=str(CLIP), help="a BVH file or a studio exercise (default: the CMU walk)")
    parser.add_argument("--weights", type=Path, help="the network's weights file (default: the shipped one)")
    parser.add_argument("--drop", action="append", default=[], help="a stage left out (and nothing reads it)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "catalog.yaml").write_text(catalog_text(args.frames, args.preset, args.motion, args.weights,
                                                                 tuple(args.drop)))
        mocapflow(folder, "run", "--until", "frames")
        walls, per_stage = [], defaultdict(list)
        for _ in range(args.repeats):
            clear_stages(folder / "storage")
            started = time.perf_counter()
            mocapflow(folder, "run", "--workers", str(args.workers))
            walls.append(time.perf_counter() - started)
            for stage, s in stage_seconds(folder / "storage").items():
                if stage != "frames":
                    per_stage[stage].append(s)
    wall = statistics.median(walls)
    print(json.dumps({
        "motion": Path(args.motion).stem, "frames": args.frames, "dropped": args.drop, "views": 3, "preset": args.preset,
        "workers": args.workers, "wall_s_median": round(wall, 2),
        "frames_per_s": round(args.frames / wall, 2),
        "compute_ms_per_frame": {k: round(1000 * statistics.median(v) / args.frames, 1) for k, v in per_stage.items()},
    }, indent=1))


if __name__ == "__main__":
    main()
