"""2D reflector estimation benchmark: inference time per view-frame on one CPU core at the default input
size (the `heatmaps` stage function whole: resize, crop, network, in float32 and in bfloat16; and the
greedy `reflectors2d` step),
the training wall time and the weight file's size. Accuracy comes from the held-out split:

    taskset -c 0 python benchmarks/fcn.py [--weights FILE]   # default: the committed weights
    mocapflow evaluate --catalog benchmarks/capsule.yaml --json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import torch  # noqa: E402

from mocapflow.pipeline.catalog import load_catalog  # noqa: E402
from mocapflow.pipeline.plan import build_plan  # noqa: E402
from mocapflow.pipeline.storage import Store  # noqa: E402
from mocapflow.schemas import get_schema  # noqa: E402
from mocapflow.tasks.deepmocap.flow import DisConfig, dis  # noqa: E402
from mocapflow.tasks.deepmocap.heatmaps import HeatmapConfig, fcn_heatmaps  # noqa: E402
from mocapflow.tasks.deepmocap.masks import MaskConfig, masks  # noqa: E402
from mocapflow.tasks.deepmocap.reflectors2d import GreedyConfig, greedy_reflectors  # noqa: E402
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize  # noqa: E402
from mocapflow.tasks.studio.spec import SequenceSpec

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "models" / "deepmocap_fcn.pt"


def time_per_view_frame(weights_file: Path, frames: int = 16) -> dict[str, float]:
    """Median milliseconds per view-frame of the heatmaps stage function (batch of one) in each precision, the two
    interleaved, and of greedy inference."""
    torch.set_num_threads(1)
    raw = synthesize(build_rig(SequenceSpec("jumping_jack", frames=frames, seed=9100, random_layout=True)), 0, frames)
    m = masks(raw[["depth", "ir"]], MaskConfig())
    f = dis(raw, DisConfig())
    weights = torch.load(weights_file, weights_only=True)
    heat_ms, greedy_ms = {"float32": [], "bfloat16": []}, []
    for view in raw["view"].values[:1]:
        for i in range(frames):
            one_m, one_f = m.sel(view=[view]).isel(frame=[i]), f.sel(view=[view]).isel(frame=[i])
            for precision, times in heat_ms.items():
                t = time.perf_counter()
                h = fcn_heatmaps(one_m, one_f, HeatmapConfig(batch=1, precision=precision), weights)
                times.append(1000 * (time.perf_counter() - t))
            t = time.perf_counter()
            greedy_reflectors(h, one_m, GreedyConfig())
            greedy_ms.append(1000 * (time.perf_counter() - t))
    return {"heatmaps_ms": statistics.median(heat_ms["float32"][2:]),
            "heatmaps_bfloat16_ms": statistics.median(heat_ms["bfloat16"][2:]),
            "reflectors2d_ms": statistics.median(greedy_ms[2:])}


def training_figures() -> dict:
    """Wall time and samples of the training run that made the committed weights (from its artifact)."""
    catalog = load_catalog(ROOT / "training" / "catalog.yaml", ())
    item = build_plan(catalog).items["weights/train"]
    store = Store(catalog.root)
    if not store.is_complete("weights", item.key):
        return {"training": "not in storage; run `mocapflow train`"}
    attrs = store.open("weights", item.key, get_schema("fcn_weights")).attrs["training"]
    return {"training_seconds": attrs["seconds"], "training_samples": attrs["samples"], "device": attrs["device"],
            "iterations": attrs["config"]["iterations"], "batch": attrs["config"]["batch"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", type=Path, default=WEIGHTS,
                        help="weights file to time (default: the committed one; training figures are the committed one's)")
    weights = parser.parse_args().weights
    arch = torch.load(weights, weights_only=True)["architecture"]
    figures = {"input_size": arch["input_size"], "widths": [arch["stream_width"], arch["fused_width"], arch["stage_width"]],
               "weights_mb": round(weights.stat().st_size / 1e6, 2), **time_per_view_frame(weights)}
    if weights == WEIGHTS:
        figures.update(training_figures())
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
