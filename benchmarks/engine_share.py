"""The engine's share of the whole DeepMoCap pipeline's time, on a noisy host: `mocapflow run --until poses` on
benchmarks/pipeline.py's take (storage, caching and Dask included) and the in-memory compute floor
(benchmarks/compute_floor.py: the same tasks without the engine), their runs alternated so that both see the same
spells of load. Prints each one's median wall time and frames/s and the median ratio floor / pipeline (1.0: the
engine costs nothing):

    python benchmarks/engine_share.py [--frames 300] [--repeats 5] [--workers 2] [--motion jumping_jack] [--weights FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import compute_floor  # benchmarks/compute_floor.py: one in-memory run of the take in a fresh process
import pipeline  # benchmarks/pipeline.py: the take's catalog and a fresh `mocapflow run`

def engine_run(folder: Path, workers: int) -> float:
    """Seconds of one fresh `mocapflow run` from the recorded frames to the poses: the stages the floor computes
    (the held-out catalog's later stages, the refined labels and their check, are left out of both)."""
    pipeline.clear_stages(folder / "storage")
    started = time.perf_counter()
    pipeline.mocapflow(folder, "run", "--until", "poses", "--workers", str(workers))
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--motion", default="jumping_jack", help="a BVH file or a studio exercise")
    parser.add_argument("--weights", type=Path, help="the network's weights file (default: the shipped one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "catalog.yaml").write_text(pipeline.catalog_text(args.frames, "fast", args.motion, args.weights))
        pipeline.mocapflow(folder, "run", "--until", "frames")
        engine, floor = [], []
        for i in range(args.repeats):  # alternated, and which goes first alternates too
            pair = (engine_run, compute_floor.timed_run) if i % 2 == 0 else (compute_floor.timed_run, engine_run)
            for fn in pair:
                (engine if fn is engine_run else floor).append(fn(folder, args.workers))
    ratios = [f / e for e, f in zip(engine, floor)]
    print(json.dumps({
        "motion": Path(args.motion).stem, "frames": args.frames, "views": 3, "workers": args.workers,
        "repeats": args.repeats,
        "pipeline_wall_s": [round(s, 2) for s in engine], "floor_wall_s": [round(s, 2) for s in floor],
        "pipeline_frames_per_s": round(args.frames / statistics.median(engine), 2),
        "floor_frames_per_s": round(args.frames / statistics.median(floor), 2),
        "ratio_median": round(statistics.median(ratios), 3),
        "ratio_range": [round(min(ratios), 3), round(max(ratios), 3)],
    }, indent=1))


if __name__ == "__main__":
    main()
