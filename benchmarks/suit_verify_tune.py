"""Decide the print check's thresholds (tasks/suit/verify.py: ``VerifyCodesConfig``, ``VerifyLabelsConfig``) on the
tuning split of training takes (benchmarks/suit_verify_tuning.yaml), never on the held-out splits.

    mocapflow run --catalog benchmarks/suit_verify_tuning.yaml
    python benchmarks/suit_verify_tune.py [--catalog benchmarks/suit_verify_tuning.yaml] [--quick]

Reads each take's stored images (with the studio's truth), corner detections, quads and the codes as RecogNet read
them; scores every accepted quad against the print once (the NCC of the reading, of the best (code, rotation) and the
best's margin), and under each codes setting of the grid re-decides the codes, labels the corners
(``label_corners``), grows the labels (``grow_labels``) and scores every grown label against the print once (the
four squares' NCC, the corner's NCC, its offset), so that every labels setting is a threshold on those scores. The
catalog's own settings of label_corners and grow_labels are used, and its verify stages' canvas. Each point is
scored on the final labels over all takes: readable corners labelled right, wrong labels / labels (a label more
than 2 px from its corner's true pixel, or at a corner the truth does not show).

The rule, fixed before any figure was seen: wrong labels come first (the goal: at most 0.02 % of labels), readable
corners labelled right second (the goal: at least 95 %). Of the points that keep readable corners labelled right
within ``LOSS_POINTS`` (5) percentage points of the chain without the check (codes as read, grown labels kept) on
the same takes, the one with the lowest share of wrong labels; ties by more readable corners labelled right, then
the first in grid order. Where no point keeps that much, the one labelling the most readable corners right.

Prints one JSON line: the chain without the check, every point's figures, and the choice.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from dataclasses import replace

import cv2
import numpy as np
import xarray as xr

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.suit import metrics
from mocapflow.tasks.suit.codes import code_index
from mocapflow.tasks.suit.grow import grow_corner_labels
from mocapflow.tasks.suit.labels import label_corners
from mocapflow.tasks.suit.verify import (VerifyCodesConfig, VerifyLabelsConfig, check_codes, check_labels,
                                         code_templates, print_texels, rectify_quads, suit_grid)

LOSS_POINTS = 5.0  # readable corners labelled right the check may cost, percentage points
CODES_GRID = {"agree_ncc": (0.65, 0.75, 0.85), "correct_margin": (0.05, 0.1)}
LABELS_GRID = {"min_ncc": (0.1, 0.2, 0.3), "min_centre_ncc": (0.65, 0.75, 0.85), "max_offset_px": (2.0, 4.0)}
QUICK_CODES = {"agree_ncc": (0.75,), "correct_margin": (0.05,)}
QUICK_LABELS = {"min_ncc": (0.2,), "min_centre_ncc": (0.65, 0.75), "max_offset_px": (4.0,)}
TRUTH = ("gt_corners2d", "gt_visible", "gt_readable")


def grid(axes: dict) -> list[dict]:
    return [dict(zip(axes, values)) for values in itertools.product(*axes.values())]


def stage_of(catalog, task: str) -> str:
    """The catalog's (first) stage running ``task``."""
    return next(name for name, s in catalog.stages.items() if s.spec.name == task)


def _views(plan, store, stage, seq) -> xr.Dataset:
    return xr.concat([plan.open(store, stage, seq.id, v).sel(view=[v]).load() for v in seq.views], dim="view")


def takes(catalog, sequences: str | None = None) -> list[dict]:
    """Every take's stored inputs of the check, loaded (views in the take's order)."""
    store, plan = Store(catalog.root), build_plan(catalog, sequences)
    names = {k: stage_of(catalog, k) for k in ("ingest_suit", "find_corners", "find_quads", "read_codes")}
    out = []
    for seq in plan.sequences:
        images = plan.open(store, names["ingest_suit"], seq.id).sel(view=list(seq.views)).load()
        out.append({"id": seq.id, "images": images, "corners": _views(plan, store, names["find_corners"], seq),
                    "quads": _views(plan, store, names["find_quads"], seq),
                    "codes": _views(plan, store, names["read_codes"], seq)})
    return out


def code_scores(take: dict, config: VerifyCodesConfig) -> dict:
    """The print's scores of every accepted quad, from one permissive pass (every threshold off): then the reading
    is the print's best exactly where the verdict is 1, and the pick is always the best."""
    images, codes = take["images"], take["codes"]
    printed = tuple(str(c) for c in images["code"].values)
    square_of = np.full(625, -1, np.int64)
    square_of[[code_index(c) for c in printed]] = np.arange(len(printed))
    canvas = config.canvas
    templates = code_templates(printed, print_texels(str(images.attrs.get("suit", "")), canvas), canvas.square_px,
                               float(canvas.blur))
    loose = replace(config, agree_ncc=-1.0, agree_margin=0.0, correct=True, correct_ncc=-1.0, correct_margin=0.0)
    accepted = codes["accepted"].values
    out = {}
    for v in range(accepted.shape[0]):
        for f in range(accepted.shape[1]):
            idx = np.flatnonzero(accepted[v, f])
            if not len(idx):
                continue
            det = take["quads"]["detections"].values[v, f][idx]
            xy = np.column_stack([take["corners"]["x"].values[v, f], take["corners"]["y"].values[v, f]])
            read = codes["code"].values[v, f, idx].astype(np.int64)
            got = check_codes(rectify_quads(images["image"].values[v, f], xy[det], canvas),
                              np.where(read >= 0, square_of[np.clip(read, 0, 624)], -1),
                              codes["rotation"].values[v, f, idx], templates, loose)
            out[v, f] = (idx, got)
    return out


def decide_codes(take: dict, scores: dict, config: VerifyCodesConfig) -> xr.Dataset:
    """The codes verify_codes hands on under ``config``, from the permissive pass's scores."""
    codes = take["codes"]
    numbers = np.array([code_index(str(c)) for c in take["images"]["code"].values], np.int16)
    accepted, rotation = codes["accepted"].values.copy(), codes["rotation"].values.copy()
    code = codes["code"].values.copy()
    for (v, f), (idx, got) in scores.items():
        read_best = got.verdict == 1
        agree = read_best & (got.read_ncc >= config.agree_ncc) & (got.margin >= config.agree_margin)
        correct = config.correct & (got.best_ncc >= config.correct_ncc) & (got.margin >= config.correct_margin)
        ok = agree | correct
        accepted[v, f, idx] = ok
        rotation[v, f, idx] = np.where(ok, got.rotation, -1)
        code[v, f, idx] = np.where(ok, numbers[np.maximum(got.code, 0)], -1)
    dims = ("view", "frame", "quad")
    return xr.Dataset({"accepted": (dims, accepted), "rotation": (dims, rotation), "code": (dims, code),
                       "confidence": (dims, codes["confidence"].values)},
                      coords={"view": codes["view"].values, "frame": codes["frame"].values})


def label_scores(take: dict, grown: xr.Dataset, config: VerifyLabelsConfig) -> np.ndarray:
    """Every grown label's scores against the print (NaN where not checked).  -> (view, frame, corner, 3)"""
    images = take["images"]
    printed = tuple(str(c) for c in images["code"].values)
    grid_ = suit_grid(images["cells"].values, images["square_corners"].values, grown.sizes["corner"])
    texels = print_texels(str(images.attrs.get("suit", "")), config.canvas)
    x, y, named = grown["x"].values, grown["y"].values, grown["quads"].values
    out = np.full((*x.shape, 3), np.nan, np.float32)
    for v in range(x.shape[0]):
        for f in range(x.shape[1]):
            xy = np.column_stack([x[v, f], y[v, f]]).astype(np.float64)
            check = np.ones(len(xy), bool) if config.check_read else named[v, f] == 0
            _, out[v, f] = check_labels(images["image"].values[v, f], xy, check, grid_, printed, texels, config)
    return out


def figures(parts: list[tuple[np.ndarray, xr.Dataset]]) -> dict:
    """Readable corners labelled right and wrong labels over all takes.  parts: (xy (view, frame, corner, 2), truth)"""
    counts = [metrics.label_counts(xy, t["gt_corners2d"].values, t["gt_visible"].values, t["gt_readable"].values)
              for xy, t in parts]
    readable, labelled = sum(c.readable for c in counts), sum(c.labelled for c in counts)
    wrong = sum(c.wrong for c in counts)
    return {"readable": round(100.0 * sum(c.readable_found for c in counts) / max(readable, 1), 2),
            "visible": round(100.0 * sum(c.visible_found for c in counts) / max(sum(c.visible for c in counts), 1), 2),
            "labelled": labelled, "wrong": wrong, "wrong_pct": round(100.0 * wrong / max(labelled, 1), 3)}


def kept_xy(grown: xr.Dataset, scores: np.ndarray | None, labels: dict) -> np.ndarray:
    """The labels left after the check (all of them with ``scores`` None).  -> (view, frame, corner, 2)"""
    xy = np.stack([grown["x"].values, grown["y"].values], axis=-1).astype(np.float64)
    if scores is None:
        return xy
    checked = np.isfinite(scores[..., 0])
    keep = (scores[..., 0] >= labels["min_ncc"]) & (scores[..., 1] >= labels["min_centre_ncc"]) \
        & (scores[..., 2] <= labels["max_offset_px"])
    return np.where((checked & ~keep)[..., None], np.nan, xy)


def choose(base: dict, points: list[dict]) -> dict:
    """The rule of the module's docstring."""
    floor = base["readable"] - LOSS_POINTS
    feasible = [p for p in points if p["readable"] >= floor]
    if not feasible:
        return max(points, key=lambda p: p["readable"])
    return min(feasible, key=lambda p: (p["wrong"] / max(p["labelled"], 1), -p["readable"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default="benchmarks/suit_verify_tuning.yaml")
    parser.add_argument("--sequences", default=None, help="only the takes whose id matches this glob")
    parser.add_argument("--quick", action="store_true", help="a grid of two points (a smoke test)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    catalog = load_catalog(args.catalog, ())
    codes_base = catalog.stages[stage_of(catalog, "verify_codes")].params
    labels_base = catalog.stages[stage_of(catalog, "verify_labels")].params
    label_config = catalog.stages[stage_of(catalog, "label_corners")].params
    grow_config = catalog.stages[stage_of(catalog, "grow_labels")].params
    start = time.process_time()
    data = takes(catalog, args.sequences)
    truth = [t["images"][list(TRUTH)] for t in data]

    def chain(codes_of) -> list[xr.Dataset]:
        return [grow_corner_labels(t["images"], t["corners"],
                                   label_corners(t["images"], t["corners"], t["quads"], codes_of(t), label_config),
                                   grow_config) for t in data]

    base = figures([(kept_xy(g, None, {}), tr) for g, tr in zip(chain(lambda t: t["codes"]), truth)])
    scores = [code_scores(t, codes_base) for t in data]
    points = []
    for codes in grid(QUICK_CODES if args.quick else CODES_GRID):
        config = replace(codes_base, **codes)
        grown = chain(lambda t: decide_codes(t, scores[data.index(t)], config))
        checks = [label_scores(t, g, labels_base) for t, g in zip(data, grown)]
        for labels in grid(QUICK_LABELS if args.quick else LABELS_GRID):
            points.append({**codes, **labels, **figures([(kept_xy(g, s, labels), tr)
                                                         for g, s, tr in zip(grown, checks, truth)])})
    best = choose(base, points)
    print(json.dumps({"catalog": args.catalog, "takes": [t["id"] for t in data],
                      "images": int(sum(t["codes"].sizes["view"] * t["codes"].sizes["frame"] for t in data)),
                      "rule": f"min wrong / labels s.t. readable >= unchecked - {LOSS_POINTS} points",
                      "unchecked": base, "points": points, "choice": best,
                      "cpu_s": round(time.process_time() - start, 1)}))


if __name__ == "__main__":
    main()
