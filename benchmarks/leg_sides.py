"""Could one view tell its legs apart by itself? A per-view side test, simulated on stored artifacts.

Each view's own estimates are lifted with that view's depth and calibration alone (markers3d's
``view_position``: one view's region depth, no other view). The view's trunk gives a left-right axis
(the mean direction of its mirrored trunk pairs, left minus right, made horizontal; pairs closer than
5 cm horizontally are skipped), and the leg labels are exchanged, left chain for right chain (calf,
ankle, foot), when the left chain's mean lies right of the right chain's by more than ``--margin``
metres. The script prints the 2D mAP before and after (the filtered estimates, as `mocapflow
evaluate` scores them), how many exchanges were right and wrong, and, from the true 3D reflectors, how
far apart the chains really are along the true pelvis axis in every sequence. Run `mocapflow evaluate`
on the catalog first:

    python benchmarks/leg_sides.py [--catalog training/validation.yaml] [--margin 0.10]
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.schemas import get_schema
from mocapflow.tasks.deepmocap.evaluation import Matches2D, match_2d, pck_radius, summarize_2d

TRUNK_PAIRS = [("F_L_SHOULDER", "F_R_SHOULDER"), ("B_L_SHOULDER", "B_R_SHOULDER"), ("L_PELVIS", "R_PELVIS"),
               ("F_L_CHEST", "F_R_CHEST"), ("F_L_HEAD", "F_R_HEAD")]
LEG = ("CALF", "ANKLE", "FOOT")
MIN_APART_M = 0.05


def left_axis(points: np.ndarray, ix: dict) -> np.ndarray | None:
    """Horizontal unit left direction from the trunk pairs one view has lifted; None where none is usable.
    points (reflector, 3) world m, NaN where not lifted."""
    found = [points[ix[a]] - points[ix[b]] for a, b in TRUNK_PAIRS]
    found = [d * (1, 1, 0) for d in found if np.isfinite(d).all() and np.linalg.norm(d[:2]) > MIN_APART_M]
    if not found:
        return None
    axis = np.mean([d / np.linalg.norm(d) for d in found], axis=0)
    return axis / np.linalg.norm(axis)


def exchanged_legs(points: np.ndarray, axis: np.ndarray | None, ix: dict, margin: float) -> bool:
    """Whether the view's left leg chain lies right of its right chain, along its trunk's left ``axis``
    (``left_axis``), by more than ``margin`` m."""
    if axis is None:
        return False
    side = [points[[ix[f"{s}_{p}"] for p in LEG]] @ axis for s in "LR"]
    if not all(np.isfinite(s).any() for s in side):
        return False
    return bool(np.nanmean(side[0]) - np.nanmean(side[1]) < -margin)


def truth_apart(gt: np.ndarray, ix: dict) -> float:
    """Smallest left-minus-right chain distance (m) along the true pelvis axis over a sequence's frames."""
    axis = gt[:, ix["L_PELVIS"]] - gt[:, ix["R_PELVIS"]]
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)  # (frame, 3)
    apart = [np.einsum("fk,fk->f", gt[:, ix[f"L_{p}"]] - gt[:, ix[f"R_{p}"]], axis) for p in LEG]
    return float(np.min(np.mean(apart, axis=0)))


def leg_hits(xy: np.ndarray, uv: np.ndarray, radius: float, ix: dict) -> int:
    """How many of the view's leg estimates lie within the PCK radius of their own reflector."""
    rows = [ix[f"{s}_{p}"] for s in "LR" for p in LEG]
    return int(np.sum(np.linalg.norm(xy[rows] - uv[rows], axis=1) <= radius))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default="training/validation.yaml")
    parser.add_argument("--margin", type=float, default=0.0, help="metres")
    args = parser.parse_args()
    catalog = load_catalog(args.catalog, ())
    store = Store(catalog.root)
    items = build_plan(catalog).by_stage()
    before = after = names = None
    verdicts = Counter()
    for frames_item in items["frames"]:
        seq = frames_item.partition.sequence
        frames = store.open("frames", frames_item.key, get_schema("raw_sequence")).load()
        m3_item = next(m for m in items["markers3d"] if m.partition.sequence == seq)
        own = store.open("markers3d", m3_item.key, get_schema("markers3d"))["view_position"].load()
        names = [str(n) for n in frames["reflector"].values]
        ix = {n: i for i, n in enumerate(names)}
        apart = truth_apart(frames["gt_reflectors"].values, ix)
        print(f"{seq}: true chains apart along the pelvis axis, at least {apart:+.2f} m")
        if before is None:
            before, after = Matches2D(len(names)), Matches2D(len(names))
        swap = np.arange(len(names))
        for p in LEG:
            swap[[ix[f"L_{p}"], ix[f"R_{p}"]]] = ix[f"R_{p}"], ix[f"L_{p}"]
        for item in (i for i in items["reflectors2d"] if i.partition.sequence == seq):
            view = item.partition.view
            est = store.open("reflectors2d", item.key, get_schema("reflectors2d")).load().sel(view=view)
            cam, points = frames.sel(view=view), own.sel(view=view).values  # (frame, reflector, 3)
            for f in range(est.sizes["frame"]):
                xy = np.stack([est["x"].values[f], est["y"].values[f]], axis=1).astype(float)  # (reflector, 2)
                conf = est["confidence"].values[f].astype(float)
                uv, pix = cam["gt_reflectors2d"].values[f], cam["gt_pixels"].values[f]
                radius = pck_radius(cam["gt_body"].values[f])
                match_2d(before, xy, conf, uv, pix, radius)
                axis = left_axis(points[f], ix)
                on_other = leg_hits(xy[swap], uv, radius, ix)  # leg labels on the other leg's reflector
                verdicts["view-frames without a trunk axis"] += axis is None
                verdicts["view-frames with swapped leg labels"] += on_other > 0
                verdicts["of those, without a trunk axis"] += on_other > 0 and axis is None
                if exchanged_legs(points[f], axis, ix, args.margin):
                    gain = on_other - leg_hits(xy, uv, radius, ix)
                    verdicts["right" if gain > 0 else "wrong" if gain < 0 else "neither"] += 1
                    xy, conf = xy[swap], conf[swap]
                match_2d(after, xy, conf, uv, pix, radius)
    b, a = summarize_2d(before, names, 0.1), summarize_2d(after, names, 0.1)
    print(f"margin {args.margin:g} m: mAP {b['map']:.4f} -> {a['map']:.4f}; exchanges {dict(verdicts)}")


if __name__ == "__main__":
    main()
