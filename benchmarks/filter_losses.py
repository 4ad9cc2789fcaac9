"""Where the 2D filtering (§5.1.3) loses right labels: for each watched reflector and every image where it is a
positive (at least 5 visible pixels), whether its best candidate and its filtered estimate lie within the PCK
radius (0.05 of the subject's box), and for a right candidate that filtering dropped, which rule dropped it.
Reads the stored artifacts of the catalog's current stages (run `mocapflow evaluate` on it first):

    python benchmarks/filter_losses.py [--catalog benchmarks/capsule.yaml] [R_HAND R_WRIST ...]
"""

from __future__ import annotations

import argparse
from collections import Counter, defaultdict

import numpy as np

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.schemas import get_schema
from mocapflow.tasks.deepmocap import reflectors2d as r2d
from mocapflow.tasks.deepmocap.evaluation import pck_radius

MIN_PIXELS = 5  # a positive, as in the 2D evaluation


def why_dropped(r: int, cand: np.ndarray, out: np.ndarray, blob_id, blob_area, names, config) -> str:
    """The filtering rule that dropped (or moved) reflector ``r``'s right candidate."""
    region = r2d.reflector_region(cand[r], blob_id, blob_area, snap_px=config.snap_px,
                                  radius_px=config.region_radius_px)
    if region is None:
        return "no reflector region within snap_px"
    if region[1] < config.b_min:
        return "region smaller than b_min"
    if np.isfinite(out[r, 0]):
        return "moved to a wrong centre"
    d = np.linalg.norm(out - region[0], axis=1)
    d[r] = np.inf
    k = int(np.argmin(np.where(np.isfinite(d), d, np.inf)))
    return f"suppressed within {config.min_distance_px:g} px by {names[k]}" \
        if d[k] <= config.min_distance_px + 1e-6 else "dropped otherwise (c_min)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default="benchmarks/capsule.yaml")
    parser.add_argument("reflectors", nargs="*", default=["R_HAND", "R_WRIST", "L_ELBOW", "L_WRIST", "R_ANKLE"])
    args = parser.parse_args()
    catalog = load_catalog(args.catalog, ())
    store = Store(catalog.root)
    items = build_plan(catalog).by_stage()
    counts = defaultdict(Counter)
    for item in items["reflectors2d"]:
        seq, view = item.partition.sequence, item.partition.view
        config = item.stage.params
        est = store.open("reflectors2d", item.key, get_schema("reflectors2d")).load()
        masks_item = next(m for m in items["masks"] if (m.partition.sequence, m.partition.view) == (seq, view))
        masks = store.open("masks", masks_item.key, get_schema("reflector_masks"))[["blob_id", "blob_area"]].load()
        frames_item = next(m for m in items["frames"] if m.partition.sequence == seq)
        gt = store.open("frames", frames_item.key, get_schema("raw_sequence"))
        gt = gt[["gt_reflectors2d", "gt_pixels", "gt_body"]].sel(view=[view]).load()
        names = [str(n) for n in est["reflector"].values]
        for i in range(est.sizes["frame"]):
            radius = pck_radius(gt["gt_body"].values[0, i])
            uv, pixels = gt["gt_reflectors2d"].values[0, i], gt["gt_pixels"].values[0, i]
            cand = np.stack([est["candidate_x"].values[0, i], est["candidate_y"].values[0, i]], 1).astype(float)
            out = np.stack([est["x"].values[0, i], est["y"].values[0, i]], 1).astype(float)
            for name in args.reflectors:
                r = names.index(name)
                if pixels[r] < MIN_PIXELS:
                    continue
                cand_ok = bool(np.linalg.norm(cand[r] - uv[r]) <= radius)  # NaN compares False
                out_ok = bool(np.linalg.norm(out[r] - uv[r]) <= radius)
                counts[name]["positives"] += 1
                counts[name][f"candidate {'right' if cand_ok else 'wrong or none'}, filtered "
                             f"{'right' if out_ok else 'none' if np.isnan(out[r, 0]) else 'wrong'}"] += 1
                if cand_ok and not out_ok:
                    counts[name]["  why: " + why_dropped(r, cand, out, masks["blob_id"].values[0, i],
                                                         masks["blob_area"].values[0, i], names, config)] += 1
    for name in args.reflectors:
        print(name)
        for key, n in sorted(counts[name].items(), key=lambda kv: (kv[0].startswith("  "), -kv[1])):
            print(f"  {n:6d}  {key}")


if __name__ == "__main__":
    main()
