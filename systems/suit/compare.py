"""The suit's compare hook (registry.Comparer): the filled suit as its surface, and the 20 template joints carried
by the corners round each joint (tasks/suit/joints.py) on the body the filling fitted."""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline.registry import Capture, Comparer, Skeleton
from mocapflow.tasks.shared.body import BODY_PARTS, JOINT_NAMES, PARENTS
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.suit import joints as suit_joints

SURFACE_POINTS = 150  # corners shown in the comparison's 3D view

SKELETON = Skeleton(JOINT_NAMES, tuple(int(p) for p in PARENTS), BODY_PARTS)  # the template's, in its order


def compared_stage(catalog, stages: list[str]) -> str | None:
    """Of ``stages``, the last filling of the triangulated corners themselves (not of a hold-out of them)."""
    def filled_from_points(s: str) -> bool:
        spec = catalog.stages[s].spec
        return spec.output == "suit_filled" and \
            "suit_points" not in catalog.stages[catalog.stages[s].inputs["points"]].spec.inputs.values()

    return next((s for s in reversed(stages) if filled_from_points(s)), None)


def capture(catalog, plan, store, stage: str, sequence: str) -> Capture:
    filled = plan.open(store, stage, sequence).load()
    source = next(s for s in catalog.ancestors(stage) if catalog.stages[s].spec.source)
    images = plan.open(store, source, sequence)
    truth = images[["gt_joints", "gt_corners", "corner_face", "corner_bary"]].load()
    body = mesh_body(Phenotype(**filled.attrs["phenotype"]))  # the subject as the filling fitted it
    rest = suit_joints.rest_corners(body.vertices, body.faces, truth["corner_face"].values, truth["corner_bary"].values)
    rest_joints = body.rest_heads[body.joint_bones()]
    position = filled["position"].transpose("frame", "corner", "xyz").values.astype(np.float64)
    joints = suit_joints.joints_from_corners(position, rest, rest_joints,
                                             suit_joints.joint_neighbourhoods(rest, rest_joints))
    error = np.linalg.norm(position - truth["gt_corners"].values, axis=-1)  # (frame, corner) m
    step = max(1, position.shape[1] // SURFACE_POINTS)
    needs = {"cameras": f"{images.sizes['view']} grey cameras", "markers": f"a printed suit of "
             f"{position.shape[1]} coded corners", "prior": "none (the corner networks, trained on studio renders)"}
    return Capture(stage=stage, fps=float(images.attrs["fps"]), joints=joints,
                   truth=truth["gt_joints"].values.astype(np.float64),  # the studio writes them in JOINT_NAMES order
                   surface_error_mm=1000 * np.nanmedian(error, axis=1), surface=position[:, ::step], needs=needs,
                   skeleton=SKELETON)


COMPARER = Comparer("suit", compared_stage, capture,
                    requirements="grey machine-vision cameras and a suit printed with coded squares; no prior")
