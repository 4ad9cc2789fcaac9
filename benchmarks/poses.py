"""Motion capture benchmark: pose solve time per frame and skeleton calibration time per sequence,
on the held-out sequences' smoothed markers, one CPU core. Run the held-out evaluation first so the
inputs exist (`mocapflow evaluate --catalog benchmarks/capsule.yaml`):

    taskset -c 0 python benchmarks/poses.py
"""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

from mocapflow.pipeline.catalog import load_catalog  # noqa: E402
from mocapflow.pipeline.plan import build_plan  # noqa: E402
from mocapflow.pipeline.storage import Store  # noqa: E402
from mocapflow.tasks.deepmocap import poses  # noqa: E402
from mocapflow.tasks.deepmocap import skeleton  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    catalog = load_catalog(str(ROOT / "benchmarks" / "capsule.yaml"), ())
    store, plan = Store(catalog.root), build_plan(catalog)
    solve_ms, calib_s = [], []
    for seq in plan.sequences:
        markers = plan.open(store, "smoothed", seq.id).load()
        views = plan.open(store, "markers3d", seq.id).load()
        started = time.perf_counter()
        skel = skeleton.calibrate_skeleton(markers, skeleton.SkeletonConfig())
        calib_s.append(time.perf_counter() - started)
        started = time.perf_counter()
        poses.solve_poses(skel, markers, views, poses.PoseConfig())
        solve_ms.append(1000 * (time.perf_counter() - started) / markers.sizes["frame"])
    print(json.dumps({"pose_solve_ms_per_frame_median": round(statistics.median(solve_ms), 2),
                      "skeleton_calibration_s_median": round(statistics.median(calib_s), 2),
                      "sequences": len(solve_ms), "per_sequence_ms": [round(v, 2) for v in solve_ms]}))


if __name__ == "__main__":
    main()
