"""What the pose stage costs on its own on the mesh body: the poses fed the studio's true 3D reflector positions
(every reflector in every frame, confidence 1) instead of the pipeline's, scored like `mocapflow evaluate` (MAE and
3D PCK on the 12 joints of Table 8), for the body fit (``fit_body_poses``, the default) and the template skeleton
(``calibrate_skeleton`` + ``solve_poses``); with the body fit's time per frame on one thread. Needs the catalog's
frames (`mocapflow run --catalog benchmarks/catalog.yaml --until frames`):

    taskset -c 0 python benchmarks/body_floor.py [--catalog benchmarks/catalog.yaml] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.deepmocap import body_poses, poses, skeleton
from mocapflow.tasks.deepmocap.evaluation import TABLE8_JOINTS, joint_errors

ROOT = Path(__file__).resolve().parents[1]


def true_markers(raw: xr.Dataset) -> xr.Dataset:
    """The studio's true reflector positions as a smoothed-markers dataset (confidence 1, nothing predicted)."""
    position = raw["gt_reflectors"].transpose("frame", "reflector", "xyz").values.astype(np.float32)
    shape = position.shape[:2]
    return xr.Dataset({"position": (("frame", "reflector", "xyz"), position),
                       "confidence": (("frame", "reflector"), np.ones(shape, np.float32)),
                       "predicted": (("frame", "reflector"), np.zeros(shape, bool))},
                      coords={"frame": raw["frame"].values, "reflector": raw["reflector"].values,
                              "xyz": ["x", "y", "z"]}, attrs={"fps": float(raw.attrs["fps"])})


def no_views(markers: xr.Dataset) -> xr.Dataset:
    shape = (markers.sizes["frame"], markers.sizes["reflector"], 1)
    return xr.Dataset({"view_position": (("frame", "reflector", "view", "xyz"), np.full(shape + (3,), np.nan, np.float32)),
                       "view_confidence": (("frame", "reflector", "view"), np.zeros(shape, np.float32))},
                      coords={"frame": markers["frame"].values, "reflector": markers["reflector"].values})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default=str(ROOT / "benchmarks" / "catalog.yaml"))
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--sequences", default=None, help="a glob of the catalog's sequences [all]")
    args = parser.parse_args()
    torch.set_num_threads(1)
    catalog = load_catalog(args.catalog, tuple(args.overrides))
    store, plan = Store(catalog.root), build_plan(catalog, args.sequences)
    out = {"body": {}, "template": {}}
    errors = {"body": [], "template": []}
    seconds, frames = 0.0, 0
    for seq in plan.sequences:
        raw = plan.open(store, "frames", seq.id).load()
        markers = true_markers(raw)
        truth = raw["gt_joints"].sel(joint=list(TABLE8_JOINTS)).values
        started = time.perf_counter()
        body = body_poses.fit_body_poses(markers, body_poses.BodyPoseConfig())
        seconds += time.perf_counter() - started
        frames += markers.sizes["frame"]
        skel = skeleton.calibrate_skeleton(markers, skeleton.SkeletonConfig())
        template = poses.solve_poses(skel, markers, no_views(markers), poses.PoseConfig())
        for kind, solved in (("body", body), ("template", template)):
            e = joint_errors(solved["position"].sel(joint=list(TABLE8_JOINTS)).values, truth)  # (frame, 12) cm
            out[kind][seq.id] = round(float(np.nanmean(e)), 2)
            errors[kind].append(e)
    summary = {kind: {"mae3d_cm": round(float(np.nanmean(np.concatenate(e))), 3),
                      "pck3d_5cm": round(float(np.mean(np.concatenate(e) < 5)), 4),
                      "per_sequence_mae_cm": out[kind]} for kind, e in errors.items()}
    summary["body"]["ms_per_frame"] = round(1000 * seconds / frames, 2)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
