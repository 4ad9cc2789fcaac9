"""Tune the suit's filling of what no camera saw (tasks/suit/fill.py ``fill_suit_detections``, tasks/suit/limbs.py)
on the tuning split of training motions (benchmarks/suit_fill_tune.yaml), never on the held-out splits.

    mocapflow run --catalog benchmarks/suit_fill_tune.yaml
    python benchmarks/suit_fill_tune.py [--catalog benchmarks/suit_fill_tune.yaml] [--quick | --report]

Reads each take's stored images (truth, calibration, the corners' places), corner detections, grown labels and
triangulated corners, fills them with ``fill_suit`` (Eq. 8 alone) and with ``fill_suit_detections`` under each
setting of a small grid, and scores every filled corner (not observed) against the studio's truth: median / p95 / p99
over all takes, and the spread of the per-take p95. The choice is the setting with the lowest pooled p95 (ties: the
lowest p99, then the first of the grid, the cheapest). Prints one JSON line: every setting's figures and the choice.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from dataclasses import replace

import numpy as np
import torch

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.datasets import discover
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.suit.fill import FillDetectionsConfig, FillSuitConfig, fill_suit, fill_suit_detections

GRID = {"match_px": (2.0, 3.0, 5.0), "min_corners": (3, 10), "min_share": (0.0, 0.25)}
QUICK = {"match_px": (3.0,), "min_corners": (3,), "min_share": (0.25,)}


def chains(catalog) -> list[dict[str, str]]:
    """Per triangulation stage of exact cameras: its images, detections, labels and points stages."""
    out = []
    for name, stage in catalog.stages.items():
        if stage.spec.name != "triangulate_corners" or getattr(stage.params, "calibration_error_px", 0.0) > 0:
            continue
        labels, images = stage.inputs["labels"], stage.inputs["images"]
        up = labels
        while "corners" not in catalog.stages[up].inputs:  # labels stages carry their detections' stage
            up = catalog.stages[up].inputs["labels"]
        out.append({"images": images, "corners": catalog.stages[up].inputs["corners"], "labels": labels,
                    "points": name})
    return out


def takes(catalog_path: str, sequences: str | None = None) -> list[dict]:
    """Every take's inputs of the filling (those matching the glob ``sequences``), loaded."""
    catalog = load_catalog(catalog_path, ())
    store, plan = Store(catalog.root), build_plan(catalog, sequences)
    out = []
    for chain in chains(catalog):
        ids = {s.id for s in discover(catalog, catalog.datasets[catalog.stages[chain["images"]].dataset])}
        for seq in plan.sequences:
            if seq.id not in ids:
                continue
            images = plan.open(store, chain["images"], seq.id).drop_vars("image").load()
            out.append({"id": seq.id, "images": images,
                        "points": plan.open(store, chain["points"], seq.id).load(),
                        "corners": _views(plan, store, chain["corners"], seq),
                        "labels": _views(plan, store, chain["labels"], seq)})
    return out


def _views(plan, store, stage, seq):
    import xarray as xr

    return xr.concat([plan.open(store, stage, seq.id, v).sel(view=[v]).load() for v in seq.views], dim="view")


def errors_mm(filled, truth) -> np.ndarray:
    """3D errors of the filled (not observed) corners, mm."""
    observed = filled["observed"].values
    d = np.linalg.norm(filled["position"].values.astype(np.float64) - truth, axis=-1) * 1000.0
    return d[~observed & np.isfinite(truth).all(-1)]


def figures(per_take: dict[str, np.ndarray], seconds: float) -> dict:
    pooled = np.concatenate(list(per_take.values()))
    p95 = {k: round(float(np.percentile(v, 95)), 2) for k, v in per_take.items()}
    return {"median_mm": round(float(np.median(pooled)), 2), "p95_mm": round(float(np.percentile(pooled, 95)), 2),
            "p99_mm": round(float(np.percentile(pooled, 99)), 2), "take_p95_mm": p95,
            "take_p95_range_mm": [min(p95.values()), max(p95.values())], "seconds": round(seconds, 1)}


def run(loaded: list[dict], fill) -> dict:
    start, per_take = time.process_time(), {}
    for take in loaded:
        filled = fill(take)
        per_take[take["id"]] = errors_mm(filled, take["images"]["gt_corners"].values.astype(np.float64))
    return figures(per_take, time.process_time() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--catalog", default="benchmarks/suit_fill_tune.yaml")
    parser.add_argument("--sequences", default=None, help="only takes whose id matches this glob")
    parser.add_argument("--quick", action="store_true", help="one setting only (a smoke test)")
    parser.add_argument("--match-px", type=float, nargs="+", default=GRID["match_px"], help="the grid's match_px")
    parser.add_argument("--min-corners", type=int, nargs="+", default=GRID["min_corners"],
                        help="the grid's min_corners")
    parser.add_argument("--min-share", type=float, nargs="+", default=GRID["min_share"], help="the grid's min_share")
    parser.add_argument("--report", action="store_true",
                        help="no grid: Eq. 8 alone and fill_suit_detections at its defaults (the chosen setting)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    loaded = takes(args.catalog, args.sequences)
    out = {"catalog": args.catalog, "takes": [t["id"] for t in loaded]}
    out["eq8_only"] = run(loaded, lambda t: fill_suit(t["points"], t["images"], FillSuitConfig()))
    if args.report:
        out["defaults"] = run(loaded, lambda t: fill_suit_detections(t["points"], t["images"], t["corners"],
                                                                     t["labels"], FillDetectionsConfig()))
        print(json.dumps(out))
        return
    grid = QUICK if args.quick else {"match_px": tuple(args.match_px), "min_corners": tuple(args.min_corners),
                                     "min_share": tuple(args.min_share)}
    tried = []
    for values in itertools.product(*grid.values()):
        setting = dict(zip(grid, values))
        base = FillDetectionsConfig()
        config = replace(base, limbs=replace(base.limbs, **setting))
        result = run(loaded, lambda t: fill_suit_detections(t["points"], t["images"], t["corners"], t["labels"],
                                                            config))
        tried.append({**setting, **result})
    out["tried"] = tried
    best = min(range(len(tried)), key=lambda k: (tried[k]["p95_mm"], tried[k]["p99_mm"], k))
    out["choice"] = {k: tried[best][k] for k in grid}
    out["choice_figures"] = {k: tried[best][k] for k in ("median_mm", "p95_mm", "p99_mm", "take_p95_range_mm")}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
