"""Flow benchmark: time per frame pair per view on one CPU core at 512x424 for both variants, and the
EPE table of each on the held-out split (benchmarks/capsule.yaml).

    taskset -c 0 python benchmarks/flow.py
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import torch  # noqa: E402

from mocapflow.tasks.deepmocap.flow import DisConfig, PrimalDualConfig, dis  # noqa: E402
from mocapflow.tasks.deepmocap.pdflow import primal_dual  # noqa: E402
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize  # noqa: E402
from mocapflow.tasks.studio.spec import SequenceSpec

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {"dis": lambda ds: dis(ds, DisConfig()),  # around the subject (the default)
            "primal_dual": lambda ds: primal_dual(ds, PrimalDualConfig(device="cpu"))}
TIMED_ONLY = {"dis_whole_image": lambda ds: dis(ds, DisConfig(roi_ir=0.0))}


def time_per_pair(pairs: int = 12) -> dict[str, float]:
    """Median seconds per (view, frame pair), the whole stage function included (lifting, colorizing)."""
    ds = synthesize(build_rig(SequenceSpec("jumping_jack", frames=pairs + 1, seed=9100, random_layout=True)),
                    0, pairs + 1)
    out = {}
    for name, run in {**VARIANTS, **TIMED_ONLY}.items():
        run(ds.isel(view=[0], frame=[0, 1]))  # warm-up: rays, torch kernels
        samples = []
        for v in range(ds.sizes["view"]):
            t0 = time.perf_counter()
            run(ds.isel(view=[v]))
            samples.append((time.perf_counter() - t0) / pairs)
        out[name] = statistics.median(samples)
    return out


def epe(task: str) -> dict:
    proc = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", "evaluate", "--catalog",
                           str(ROOT / "benchmarks" / "capsule.yaml"), "--json", "--set", f"stages.flow.task={task}"],
                          capture_output=True, text=True, check=True)
    lines = proc.stdout.strip().splitlines()
    return {"table": "\n".join(lines[:-1]), "figures": json.loads(lines[-1])}


def main() -> None:
    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    times = time_per_pair()
    for name, seconds in times.items():
        print(f"{name}: {1000 * seconds:.1f} ms per frame pair per view ({1 / seconds:.1f} pairs/s, one core)")
    print(f"primal_dual / dis time ratio: {times['primal_dual'] / times['dis']:.1f}; "
          f"dis around the subject / whole image: {times['dis'] / times['dis_whole_image']:.2f}")
    results = {name: epe(name) for name in VARIANTS}
    for r in results.values():
        print(r["table"])
    print(json.dumps({"seconds_per_pair": times, "epe": {k: r["figures"] for k, r in results.items()}}))


if __name__ == "__main__":
    main()
