"""What the motion capture stages cost on their own: skeleton calibration and pose solving fed the
studio's true 3D reflector positions (every reflector in every frame, confidence 1) instead of the
pipeline's, on the held-out sequences, scored like `mocapflow evaluate` (MAE and 3D PCK on the 12
joints of Table 8). The gap between this floor and the evaluated figures is what the 2D labels, the
depth lifting and fusion cost. Run the held-out evaluation first so the inputs exist
(`mocapflow evaluate --catalog benchmarks/capsule.yaml`):

    python benchmarks/poses_floor.py [--set KEY=VALUE ...]   # catalog overrides, as `mocapflow evaluate --set`
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import xarray as xr

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.deepmocap import poses, skeleton
from mocapflow.tasks.deepmocap.evaluation import TABLE8_JOINTS, joint_errors

ROOT = Path(__file__).resolve().parents[1]


def no_views(markers):
    """Single views' estimates for the pose solve's fallback: none (the truth leaves no reflector without data)."""
    shape = (markers.sizes["frame"], markers.sizes["reflector"], 1)
    return xr.Dataset({"view_position": (("frame", "reflector", "view", "xyz"), np.full(shape + (3,), np.nan, np.float32)),
                       "view_confidence": (("frame", "reflector", "view"), np.zeros(shape, np.float32))},
                      coords={"frame": markers["frame"].values, "reflector": markers["reflector"].values})


def true_markers(smoothed, raw):
    """The smoothed markers' layout (names, frames, attrs) holding the studio's true positions."""
    truth = smoothed.copy(deep=True)
    truth["position"].values[...] = raw["gt_reflectors"].sel(reflector=smoothed["reflector"]).values
    truth["confidence"].values[...] = 1.0
    truth["predicted"].values[...] = False
    return truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    catalog = load_catalog(str(ROOT / "benchmarks" / "capsule.yaml"), tuple(args.overrides))
    store, plan = Store(catalog.root), build_plan(catalog)
    per_clip, errors = {}, []
    for seq in plan.sequences:
        raw = plan.open(store, "frames", seq.id)
        smoothed = plan.open(store, "smoothed", seq.id).load()
        markers = true_markers(smoothed, raw)
        skel = skeleton.calibrate_skeleton(markers, skeleton.SkeletonConfig())
        solved = poses.solve_poses(skel, markers, no_views(markers), poses.PoseConfig())
        e = joint_errors(solved["position"].sel(joint=list(TABLE8_JOINTS)).values,
                         raw["gt_joints"].sel(joint=list(TABLE8_JOINTS)).values)  # (frame, 12) cm
        per_clip[seq.id] = round(float(np.nanmean(e)), 2)
        errors.append(e)
    e = np.concatenate(errors)
    print(json.dumps({"floor_mae3d_cm": round(float(np.nanmean(e)), 3), "floor_pck3d_5cm": round(float(np.mean(e < 5)), 4),
                      "floor_pck3d_20cm": round(float(np.mean(e < 20)), 4), "per_sequence_mae_cm": per_clip}))


if __name__ == "__main__":
    main()
