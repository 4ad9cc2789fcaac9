"""The markerless system's compare hook (registry.Comparer): the 20 template joints read off the triangulated
BlazePose landmarks, against the studio's truth of the filmed take. It gives no surface."""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline.registry import Capture, Comparer, Skeleton
from mocapflow.tasks.shared.body import BODY_PARTS, JOINT_NAMES, PARENTS

SKELETON = Skeleton(JOINT_NAMES, tuple(int(p) for p in PARENTS), BODY_PARTS)  # the template's, in its order


def compared_stage(catalog, stages: list[str]) -> str | None:
    """Of ``stages``, the last writing triangulated markerless joints."""
    return next((s for s in reversed(stages) if catalog.stages[s].spec.output == "markerless_joints"), None)


def capture(catalog, plan, store, stage: str, sequence: str) -> Capture:
    joints = plan.open(store, stage, sequence)[["joints"]].load()
    source = next(s for s in catalog.ancestors(stage) if catalog.stages[s].spec.source)
    images = plan.open(store, source, sequence)
    truth = images[["gt_joints"]].load()
    needs = {"cameras": f"{images.sizes['view']} calibrated video cameras",
             "markers": "none (BlazePose's 2D keypoints, triangulated)",
             "prior": "BlazePose's networks, trained on people in real images"}
    return Capture(stage=stage, fps=float(images.attrs["fps"]),
                   joints=joints["joints"].transpose("frame", "joint", "xyz").values.astype(np.float64),
                   truth=truth["gt_joints"].values.astype(np.float64),  # the studio writes them in JOINT_NAMES order
                   needs=needs, skeleton=SKELETON)


COMPARER = Comparer("markerless", compared_stage, capture,
                    requirements="a few calibrated video cameras and a pretrained 2D keypoint network; no markers, "
                                 "no suit")
