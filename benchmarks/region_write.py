"""Region-write benchmark: storage.write_zarr_region (zarr's internal sync, one loop pass) against zarr's public
per-array API, on a studio-sized region and on a small one, alone and with a thread computing beside it.

    python benchmarks/region_write.py [repeats]        # prints a table and one JSON line

A region is 16 frames of a 3-view raw sequence (424x512 uint16 depth and IR, float16 scene flow, bool body mask,
float32 2D and 3D ground truth); the small region keeps 2x2 pixels of it. Each figure is the median over every
region written (3 per store, ``repeats`` stores per way, the ways interleaved); both ways must store the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zarr

from mocapflow.pipeline import storage
from mocapflow.schemas import get_schema
from mocapflow.schemas.raw import make_raw_sequence

VIEWS, REGION, HEIGHT, WIDTH = 3, 16, 424, 512
FRAMES = 3 * REGION


def sequence(frames: int):
    rng = np.random.default_rng(0)
    depth = rng.integers(500, 4000, (VIEWS, frames, HEIGHT, WIDTH)).astype(np.uint16)
    depth[:, :, :100] = 0
    cams = {f"kinect{i}": dict(fx=365.0, fy=365.0, cx=WIDTH / 2, cy=HEIGHT / 2, dist=[0.0] * 5,
                               cam_to_world=np.eye(4), width=WIDTH, height=HEIGHT) for i in range(VIEWS)}
    extra = {
        "gt_reflectors2d": (("view", "frame", "reflector", "uv"), rng.random((VIEWS, frames, 40, 2), np.float32)),
        "gt_joints": (("frame", "joint", "xyz"), rng.random((frames, 25, 3), np.float32)),
        "gt_scene_flow": (("view", "frame", "y", "x", "xyz"),
                          rng.random((VIEWS, frames, HEIGHT, WIDTH, 3), np.float32).astype(np.float16)),
        "gt_body": (("view", "frame", "y", "x"), rng.random((VIEWS, frames, HEIGHT, WIDTH)) > 0.5),
    }
    return make_raw_sequence(depth, (depth // 3).astype(np.uint16), cams, 30.0, 0, extra)


def internal(target: str, ds, start: int, stop: int) -> None:
    storage.write_zarr_region(target, ds, start, stop)


def public(target: str, ds, start: int, stop: int) -> None:
    group = zarr.open_group(target, mode="r+", zarr_format=3)
    for name, var in ds.variables.items():
        if "frame" in var.dims:
            array = group[name].with_config({"write_empty_chunks": True})
            array[tuple(slice(start, stop) if d == "frame" else slice(None) for d in var.dims)] = var.values


WAYS = {"internal sync": internal, "public per array": public}


def tree_digest(path: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(path.rglob("*")):
        if p.is_file():
            h.update(p.relative_to(path).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def compute(stop: threading.Event) -> None:
    """A worker thread computing in Python: it holds the GIL whenever the writer lets go of it."""
    x = 0
    while not stop.is_set():
        for i in range(10_000):
            x += i


def measure(whole, repeats: int, load: int) -> dict:
    schema = get_schema("raw_sequence")
    seconds: dict[str, list[float]] = {way: [] for way in WAYS}
    digests: dict[str, set[str]] = {way: set() for way in WAYS}
    stop = threading.Event()
    threads = [threading.Thread(target=compute, args=(stop,), daemon=True) for _ in range(load)]
    for t in threads:
        t.start()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(repeats):
                for way, write in WAYS.items():
                    target = Path(tmp) / f"{r}-{way.replace(' ', '_')}.zarr"
                    storage.init_zarr(str(target), schema, whole.isel(frame=slice(0, REGION)), FRAMES)
                    for start in range(0, FRAMES, REGION):
                        region = whole.isel(frame=slice(start, start + REGION))
                        t0 = time.perf_counter()
                        write(str(target), region, start, start + REGION)
                        seconds[way].append(time.perf_counter() - t0)
                    digests[way].add(tree_digest(target))
                    shutil.rmtree(target)
    finally:
        stop.set()
        for t in threads:
            t.join()
    if len(set().union(*digests.values())) != 1:
        raise SystemExit(f"the ways stored different bytes: {digests}")
    return {way: {"median_ms": 1000 * statistics.median(s), "min_ms": 1000 * min(s), "regions": len(s)}
            for way, s in seconds.items()}


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    whole = sequence(FRAMES)
    small = whole.isel(y=slice(0, 2), x=slice(0, 2))
    out = {}
    for size, ds in (("studio", whole), ("small", small)):
        for load in (0, 1):
            case = f"{size} region, {load} computing thread(s)"
            out[case] = measure(ds, repeats, load)
            for way, fig in out[case].items():
                print(f"{case:36s} {way:18s} median {fig['median_ms']:8.1f} ms  min {fig['min_ms']:8.1f} ms  "
                      f"({fig['regions']} regions)")
    print(json.dumps({"zarr": zarr.__version__, "cases": out}))


if __name__ == "__main__":
    main()
