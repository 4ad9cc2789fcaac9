"""Speed of the `refine_reflectors` stage (2D reflectors refined from the solved poses): milliseconds per
view-frame on one CPU core, the stage function called on one frame at a time of every held-out view.
It reads the held-out split's artifacts, so run the evaluation first:

    mocapflow evaluate --catalog benchmarks/capsule.yaml --json
    taskset -c 0 python benchmarks/refine2d.py [--figure docs/refined/knee_raise.png]

``--figure`` also draws, for the held-out view-frame of a clip that the stage changed most, the views' own
labels beside the refined ones (white rings: the truth; hollow dots: reflectors the stage added).
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

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from mocapflow.pipeline.catalog import load_catalog  # noqa: E402
from mocapflow.pipeline.plan import build_plan  # noqa: E402
from mocapflow.pipeline.storage import Store  # noqa: E402
from mocapflow.presentation.report import write_png  # noqa: E402
from mocapflow.systems.deepmocap.report import overlay  # noqa: E402
from mocapflow.tasks.deepmocap.refine2d import Refine2DConfig, refine_reflectors  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
INPUTS = {"reflectors": ("reflectors2d", "reflectors2d"), "poses": ("poses", "poses"), "skeleton": ("skeleton", "skeleton"),
          "masks": ("masks", "reflector_masks"), "frames": ("frames", "raw_sequence")}


def timing(plan, store) -> dict:
    """Median ms per view-frame of the stage function, one frame per call, over every held-out view-frame."""
    times = []
    for seq in plan.sequences:
        whole = {role: plan.open(store, stage, seq.id)
                 for role, (stage, schema) in INPUTS.items() if f"{stage}/{seq.id}" in plan.items}
        whole["frames"] = whole["frames"][["depth", "fx", "fy", "cx", "cy", "dist", "cam_to_world"]]
        for view in seq.views:
            view_inputs = dict(whole)
            for role in ("reflectors", "masks"):
                stage, schema = INPUTS[role]
                view_inputs[role] = plan.open(store, stage, seq.id, view)
            view_inputs["frames"] = whole["frames"].sel(view=[view])
            loaded = {role: ds.load() for role, ds in view_inputs.items()}
            for i in range(loaded["reflectors"].sizes["frame"]):
                one = {role: ds.isel(frame=[i]) if "frame" in ds.dims else ds for role, ds in loaded.items()}
                t = time.perf_counter()
                refine_reflectors(**one, config=Refine2DConfig())
                times.append(1000 * (time.perf_counter() - t))
    return {"refine_reflectors_ms": statistics.median(times), "view_frames": len(times)}


def figure(plan, store, path: Path, sequence: str) -> None:
    """The views' own labels beside the refined ones on the view-frame of ``sequence`` the stage changed most."""
    raw = plan.open(store, "frames", sequence)
    open_2d = {stage: {view: plan.open(store, stage, sequence, view)
                       .sel(view=view).load() for view in map(str, raw["view"].values)}
               for stage in ("reflectors2d", "reflectors2d_refined")}
    changed = {view: (ds["exchanged"].values | ds["reprojected"].values).sum(1)
               for view, ds in open_2d["reflectors2d_refined"].items()}
    view = max(changed, key=lambda v: changed[v].max())
    frame = int(np.argmax(changed[view]))
    truth = raw.sel(view=view).isel(frame=frame).load()
    names = [str(n) for n in truth["reflector"].values]
    uv = np.where(truth["gt_visible"].values[:, None], truth["gt_reflectors2d"].values, np.nan)
    panels = []
    for stage, title in (("reflectors2d", "the view alone"), ("reflectors2d_refined", "refined")):
        est = open_2d[stage][view].isel(frame=frame)
        added = est["reprojected"].values if "reprojected" in est else None
        panels.append((overlay(truth["ir"].values, np.stack([est["x"].values, est["y"].values], 1), uv, names, "",
                               added), f"{sequence}, {view}, frame {frame}: {title}"))
    ys, xs = np.nonzero(truth["gt_body"].values)
    box = (slice(max(ys.min() - 20, 0), ys.max() + 20), slice(max(xs.min() - 80, 0), xs.max() + 80))
    cropped = []
    for img, title in panels:
        img = cv2.resize(img[box], None, fx=1.5, fy=1.5, interpolation=cv2.INTER_LINEAR)  # labels legible
        band = np.zeros((32, img.shape[1], 3), np.uint8)
        cv2.putText(band, title, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        cropped.append(np.vstack([band, img]))
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, np.hstack(cropped))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--figure", type=Path, help="also write the comparison PNG here")
    parser.add_argument("--sequence", default="cmu_knee_raise", help="held-out clip of the figure")
    args = parser.parse_args()
    catalog = load_catalog(ROOT / "benchmarks" / "capsule.yaml", ())
    plan, store = build_plan(catalog), Store(catalog.root)
    if args.figure:
        figure(plan, store, args.figure, args.sequence)
    print(json.dumps(timing(plan, store)))


if __name__ == "__main__":
    main()
