"""What the engine costs: the whole pipeline's tasks run in memory, without storage, caching or Dask, on
the same take as benchmarks/pipeline.py (3 views at 512x424, the held-out catalog's stages and
parameters, `dis` at the fast preset). Each view's 2D chain (masks, flow, heatmaps, reflectors2d)
runs in one of ``--workers`` fresh processes; fusion, smoothing, calibration and poses follow in the
main one. The wall time counts from this script's first line (its imports included) to the poses, so
it compares with `python benchmarks/pipeline.py`'s, which counts a fresh `mocapflow run`:

    python benchmarks/compute_floor.py [--frames 90] [--repeats 3] [--workers 2] [--motion jumping_jack] [--weights FILE]
"""

from __future__ import annotations

import time

STARTED = time.perf_counter()

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import xarray as xr  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

SENSOR = ("depth", "ir", "fx", "fy", "cx", "cy", "dist", "width", "height", "cam_to_world")  # what the stages read


def stage_calls(folder: Path) -> dict:
    """Each stage's task function and parameters (keyword arguments) from the take's catalog."""
    from mocapflow.pipeline import registry
    from mocapflow.pipeline.catalog import load_catalog
    from mocapflow.pipeline.models import load_weights
    from mocapflow.pipeline.plan import build_plan

    catalog = load_catalog(str(folder / "catalog.yaml"), ())
    calls = {}
    for item in build_plan(catalog).items.values():
        name = item.partition.stage
        if name != "frames" and name not in calls:
            weights = {p: load_weights(path, sha) for p, (path, sha) in item.weights.items()}
            calls[name] = (registry.get(item.stage.task).fn, item.stage.params, weights)
    return calls


def raw_frames(folder: Path) -> xr.Dataset:
    from mocapflow.pipeline.storage import Store
    from mocapflow.schemas import get_schema

    store = Store(str(folder / "storage"))
    version = store.versions("frames")[0]
    return store.open("frames", version.key, get_schema("raw_sequence"))[list(SENSOR)]


def apply(calls: dict, stage: str, *inputs: xr.Dataset) -> xr.Dataset:
    """``stage``'s task on ``inputs`` with the catalog's parameters (``stage_calls``)."""
    fn, config, weights = calls[stage]
    return fn(*inputs, config, **weights)


def view_chain(folder: Path, view: str) -> tuple[xr.Dataset, xr.Dataset]:
    """One view's reflectors2d and masks, computed in memory from its raw frames."""
    calls = stage_calls(folder)
    frames = raw_frames(folder).sel(view=[view]).load()
    masks = apply(calls, "masks", frames[["depth", "ir"]])
    flow = apply(calls, "flow", frames)
    heatmaps = apply(calls, "heatmaps", masks[["colorized_depth", "blob_id", "blob_area"]], flow[["colorized_flow"]])
    reflectors = apply(calls, "reflectors2d", heatmaps, masks[["blob_id", "blob_area"]])
    return reflectors, masks[["blob_id"]]


def run(folder: Path, workers: int) -> float:
    """Seconds from this process's start to the poses of the take."""
    frames = raw_frames(folder)
    views = [str(v) for v in frames["view"].values]
    with ProcessPoolExecutor(workers) as pool:
        per_view = list(pool.map(view_chain, [folder] * len(views), views))
    calls = stage_calls(folder)
    reflectors = xr.concat([r for r, _ in per_view], dim="view")
    masks = xr.concat([m for _, m in per_view], dim="view")
    markers = apply(calls, "markers3d", reflectors, masks, frames.load())
    smoothed = apply(calls, "smoothed", markers)
    skeleton = apply(calls, "skeleton", smoothed)
    poses = apply(calls, "poses", skeleton, smoothed, markers[["view_position", "view_confidence"]])
    assert poses.sizes["frame"] == frames.sizes["frame"]
    return time.perf_counter() - STARTED


def timed_run(folder: Path, workers: int) -> float:
    """Seconds of one run of the take in ``folder`` in a fresh process, its imports included (``run``)."""
    out = subprocess.run([sys.executable, __file__, "--folder", str(folder), "--workers", str(workers)], check=True,
                         capture_output=True, text=True)
    return float(out.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--motion", help="a BVH file or a studio exercise (default: the CMU walk)")
    parser.add_argument("--weights", type=Path, help="the network's weights file (default: the shipped one)")
    parser.add_argument("--folder", help=argparse.SUPPRESS)  # one timed repeat in a fresh process
    args = parser.parse_args()
    if args.folder:
        print(run(Path(args.folder), args.workers))
        return
    import pipeline

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        motion = args.motion or str(pipeline.CLIP)
        (folder / "catalog.yaml").write_text(pipeline.catalog_text(args.frames, "fast", motion, args.weights))
        pipeline.mocapflow(folder, "run", "--until", "frames")
        walls = [timed_run(folder, args.workers) for _ in range(args.repeats)]
    wall = statistics.median(walls)
    print(json.dumps({"motion": Path(args.motion or pipeline.CLIP).stem, "frames": args.frames, "views": 3,
                      "preset": "fast", "workers": args.workers, "wall_s_median": round(wall, 2),
                      "frames_per_s": round(args.frames / wall, 2)}, indent=1))


if __name__ == "__main__":
    main()
