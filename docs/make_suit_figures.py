"""Figures of the suit system from the held-out benchmark's store (run it first:
`mocapflow run --catalog benchmarks/suit.yaml`).

    python docs/make_suit_figures.py     # writes docs/suit/labels.png, filled.png, reprojection.png
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.systems.suit.report import histogram, overlay_labels, view_3d
from mocapflow.pipeline.storage import Store

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "suit"
PNG = [cv2.IMWRITE_PNG_COMPRESSION, 9]


def main() -> None:
    catalog = load_catalog(str(ROOT / "benchmarks" / "suit.yaml"), ())
    plan, store = build_plan(catalog, "jacks"), Store(catalog.root)
    images = plan.open(store, "images", "jacks")
    frame, view = 3, "cam00"
    image = images["image"].sel(view=view).isel(frame=frame).values
    labels = plan.open(store, "grown", "jacks", view).sel(view=view).isel(frame=frame)
    xy = np.stack([labels["x"].values, labels["y"].values], axis=1).astype(np.float64)
    truth = images["gt_corners2d"].sel(view=view).isel(frame=frame).values.astype(np.float64)
    truth[~images["gt_visible"].sel(view=view).isel(frame=frame).values] = np.nan
    ys, xs = np.nonzero(image > 60)
    cy, cx = int(np.median(ys)), int(np.median(xs))
    box = (cy - 350, cy + 50, cx - 200, cx + 200)
    OUT.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(OUT / "labels.png"), overlay_labels(image, xy, images["square_corners"].values,
                                                        images["code"].values, truth, box), PNG)
    filled = plan.open(store, "filled_check", "jacks").isel(frame=frame)
    cv2.imwrite(str(OUT / "filled.png"), view_3d(filled["position"].values.astype(np.float64),
                                                 filled["observed"].values, images["cells"].values), PNG)
    errors = [plan.open(store, "points", seq.id) for seq in plan.sequences]
    values = np.concatenate([e["error"].values[e["kept"].values] for e in errors])
    cv2.imwrite(str(OUT / "reprojection.png"), histogram(values[np.isfinite(values)], 1.0,
                                                        "reprojection error of triangulated corners (px)"), PNG)


if __name__ == "__main__":
    main()
