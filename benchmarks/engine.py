"""Engine benchmark: cold run vs no-op rerun of the repository catalog, and per-partition overhead.

    python benchmarks/engine.py            # prints a table and one JSON line

Each figure is the median of several runs of the real CLI in fresh processes; storage goes to a
temporary folder so the repository's storage/ is untouched.
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def cli(*args, cwd, env=None) -> tuple[float, dict]:
    started = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", *map(str, args), "--json", "--no-progress"],
                          cwd=cwd, env=env, capture_output=True, text=True, check=True)
    return time.perf_counter() - started, json.loads(proc.stdout.strip().splitlines()[-1])


def repository_catalog(repeats: int) -> dict:
    cold, noop = [], []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            seconds, summary = cli("run", "--catalog", ROOT / "catalog.yaml", "--set", f"storage.root={tmp}", cwd=ROOT)
            cold.append(seconds)
            for _ in range(3):
                noop.append(cli("run", "--catalog", ROOT / "catalog.yaml", "--set", f"storage.root={tmp}", cwd=ROOT)[0])
    return {"partitions": len(summary["executed"]), "cold_s": statistics.median(cold),
            "noop_s": statistics.median(noop)}


def overhead(n_sequences: int, repeats: int) -> dict:
    """Per-partition overhead: 1 cheap source + 3 trivial per-view partitions per tiny sequence."""
    from mocapflow.schemas.raw import make_raw_sequence

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "benchmarks" / "plugins"),
                                                         os.environ.get("PYTHONPATH", "")]))
    per_part = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cams = {f"k{i}": dict(fx=100.0, fy=100.0, cx=8.0, cy=6.0, dist=[0.0] * 5, cam_to_world=np.eye(4),
                              width=16, height=12) for i in range(3)}
        depth = np.ones((3, 8, 12, 16), np.uint16)
        for s in range(n_sequences):
            make_raw_sequence(depth, depth, cams, 30.0, 0).to_zarr(tmp / "data" / f"s{s:03d}.zarr", zarr_format=3,
                                                                   consolidated=False, mode="w")
        (tmp / "catalog.yaml").write_text(
            "plugins: [bench_tasks]\nstorage: {root: storage/}\ndatasets: {d: {kind: zarr, path: data}}\n"
            "stages:\n  frames: {task: ingest}\n  mean: {task: bench_mean_depth, inputs: [frames]}\n")
        for r in range(repeats):
            root = f"storage{r}"
            cold, summary = cli("run", "--set", f"storage.root={root}", cwd=tmp, env=env)
            noop, _ = cli("run", "--set", f"storage.root={root}", cwd=tmp, env=env)
            per_part.append((cold - noop) / len(summary["executed"]))
    return {"partitions": n_sequences * 4, "per_partition_ms": 1000 * statistics.median(per_part)}


def main() -> None:
    repo = repository_catalog(repeats=3)
    over = overhead(n_sequences=32, repeats=3)
    print(f"repository catalog: {repo['partitions']} partitions, cold {repo['cold_s']:.1f} s, "
          f"no-op rerun {repo['noop_s']:.2f} s (median)")
    print(f"engine overhead: {over['per_partition_ms']:.1f} ms per partition "
          f"({over['partitions']} trivial partitions, median of 3)")
    print(json.dumps({"repository": repo, "overhead": over}))


if __name__ == "__main__":
    main()
