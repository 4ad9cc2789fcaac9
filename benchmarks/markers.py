"""3D stages benchmark: time per frame of `markers3d` (2D->3D + fusion) and of each `smoothed`
implementation (and of `kalman` in one pass, without competing tracks) on a 3-view held-out sequence, one CPU
core. Run the held-out evaluation first so the
inputs exist (`mocapflow evaluate --catalog benchmarks/capsule.yaml`):

    taskset -c 0 python benchmarks/markers.py
"""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import xarray as xr  # noqa: E402

from mocapflow.pipeline.catalog import load_catalog  # noqa: E402
from mocapflow.pipeline.plan import build_plan  # noqa: E402
from mocapflow.pipeline.storage import Store  # noqa: E402
from mocapflow.schemas import get_schema  # noqa: E402
from mocapflow.tasks.deepmocap import markers3d, smoothing  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEQUENCE = "cmu_jumping_jacks"


def _inputs():
    catalog = load_catalog(ROOT / "benchmarks" / "capsule.yaml", ())
    plan, store = build_plan(catalog, SEQUENCE), Store(catalog.root)

    def load(stage, schema, variables):
        parts = [store.open(stage, i.key, get_schema(schema))[list(variables)] for i in plan.for_stages([stage])]
        return xr.concat(parts, dim="view", data_vars="minimal", coords="minimal", compat="override").load()

    frames = plan.open(store, "frames", SEQUENCE)
    frames = frames[["depth", "fx", "fy", "cx", "cy", "dist", "cam_to_world", "width", "height"]].load()
    return (load("reflectors2d", "reflectors2d", ("x", "y", "confidence")), load("masks", "reflector_masks", ("blob_id",)),
            frames)


def main(repeats: int = 3) -> None:
    reflectors, masks, frames = _inputs()
    n = reflectors.sizes["frame"]
    fuse_s, smooth_s = [], {"kalman": [], "kalman_one_pass": [], "butterworth": [], "none": []}
    for _ in range(repeats):
        t = time.perf_counter()
        markers = markers3d.markers3d(reflectors, masks, frames, markers3d.Markers3DConfig())
        fuse_s.append(time.perf_counter() - t)
        for name, fn, config in (("kalman", smoothing.kalman, smoothing.KalmanConfig()),
                                 ("kalman_one_pass", smoothing.kalman, smoothing.KalmanConfig(alternatives=0)),
                                 ("butterworth", smoothing.butterworth, smoothing.ButterworthConfig()),
                                 ("none", smoothing.no_smoothing, smoothing.NoSmoothing())):
            t = time.perf_counter()
            fn(markers, config)
            smooth_s[name].append(time.perf_counter() - t)
    figures = {"sequence": SEQUENCE, "views": reflectors.sizes["view"], "frames": n,
               "markers3d_ms_per_frame": 1000 * statistics.median(fuse_s) / n,
               **{f"{k}_ms_per_frame": 1000 * statistics.median(v) / n for k, v in smooth_s.items()}}
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
