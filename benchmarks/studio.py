"""Studio benchmark: render time per view-frame at 512x424 on one CPU core, and disk size per view-frame.

    taskset -c 0 python benchmarks/studio.py     # pin to one core

Rendering is timed per view-frame (depth, IR, reflector ids, scene flow, noise) after the
per-camera setup; the disk size comes from `mocapflow synth` output with every ground-truth group.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from mocapflow.tasks.deepmocap.film import render  # noqa: E402
from mocapflow.tasks.deepmocap.film.synth import build_rig  # noqa: E402
from mocapflow.tasks.studio.spec import SequenceSpec


def render_times(motions=("jumping_jack", "kick_box_kicking", "classic_squat"), frames=30) -> list[float]:
    times = []
    for seed, name in enumerate(motions):
        rig = build_rig(SequenceSpec(name, frames=frames, seed=seed))
        for f in range(frames):
            for v, view in enumerate(rig.views):
                rng = np.random.default_rng([seed, v, f])
                t0 = time.perf_counter()
                render.render(view, rig.prims, rig.placements, rig.pose(f), rig.pose(max(f - 1, 0)), rig.pose(f + 1),
                              rng, 1.0)
                times.append(time.perf_counter() - t0)
    return times


def disk_per_view_frame(frames=32, views=3) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", "synth", "--out", tmp, "--motion",
                        "jumping_jack", "--frames", str(frames), "--views", str(views)], check=True, capture_output=True)
        store = Path(tmp) / "jumping_jack.zarr"
        sizes = {}
        for var in store.iterdir():
            if var.is_dir():
                sizes[var.name] = sum(p.stat().st_size for p in var.rglob("*") if p.is_file())
        total = sum(p.stat().st_size for p in store.rglob("*") if p.is_file())
    n = frames * views
    return {"total_kb": total / n / 1024, "raw_kb": (sizes["depth"] + sizes["ir"]) / n / 1024,
            **{f"{k}_kb": v / n / 1024 for k, v in sorted(sizes.items()) if v / n > 1024}}


def main() -> None:
    cv2.setNumThreads(1)
    cores = len(os.sched_getaffinity(0))
    times = render_times()
    disk = disk_per_view_frame()
    print(f"render: median {1000 * statistics.median(times):.1f} ms per view-frame at 512x424 "
          f"(p90 {1000 * np.percentile(times, 90):.1f} ms, {len(times)} view-frames, {cores} core(s))")
    print("disk per view-frame: " + ", ".join(f"{k[:-3]} {v:.0f} KB" for k, v in disk.items()))
    print(json.dumps({"render_ms_median": 1000 * statistics.median(times), "cores": cores, "disk_kb": disk}))


if __name__ == "__main__":
    main()
