"""UUO's compare hook (registry.Comparer): the solved body's 20 template joints and its skin against the truth of
the marker take (the true body posed by the studio)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.registry import Capture, Comparer, Skeleton
from mocapflow.tasks.shared.body import BODY_PARTS, JOINT_NAMES, PARENTS
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body, pose_mesh

SURFACE_POINTS = 150  # skin vertices shown in the comparison's 3D view

SKELETON = Skeleton(JOINT_NAMES, tuple(int(p) for p in PARENTS), BODY_PARTS)  # the template's, in its order


def compared_stage(catalog, stages: list[str]) -> str | None:
    """Of ``stages``, the first body chosen among hypotheses (a stage writing uuo_body from uuo_body), else the last
    uuo_body."""
    bodies = [s for s in stages if catalog.stages[s].spec.output == "uuo_body"]
    chosen = [s for s in bodies if "uuo_body" in catalog.stages[s].spec.inputs.values()]
    return (chosen or bodies[-1:] or [None])[0]


def skin(phenotype: dict, quats: np.ndarray, root: np.ndarray) -> np.ndarray:
    """(frame, vertex, 3) m: the body of ``phenotype`` posed by world bone rotations (x y z w) and its root."""
    body = mesh_body(Phenotype(**phenotype))
    rotations = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(quats.shape[:2] + (3, 3))
    return pose_mesh(body, rotations, root).vertices


def in_template_order(names, values: np.ndarray) -> np.ndarray:
    names = [str(n) for n in names]
    return values[:, [names.index(j) for j in JOINT_NAMES]].astype(np.float64)


PRIORS = {"monocular_prior": "BlazePose's estimate from the take's video (its networks, trained on real images)",
          "file_prior": "a monocular body prior per frame, read from a file",
          "combine_priors": "several monocular body priors per frame, combined"}


def _prior_said(catalog, stage: str) -> str:
    """What the solve's prior is, by the task of the prior stage it descends from."""
    tasks = [catalog.stages[s].spec.name for s in catalog.ancestors(stage)]
    found = next((PRIORS[t] for t in tasks if t in PRIORS), None)
    return found or ("a monocular body prior per frame, simulated from the studio's truth"
                     if "simulated_prior" in tasks else "a monocular body prior per frame")


def capture(catalog, plan, store, stage: str, sequence: str) -> Capture:
    solved = plan.open(store, stage, sequence).load()
    source = next(s for s in catalog.ancestors(stage) if catalog.stages[s].spec.source)
    markers = plan.open(store, source, sequence)[["gt_joints", "gt_bone_rotations", "gt_root", "gt_source"]].load()
    vertices = skin(solved.attrs["phenotype"], solved["bone_rotation"].values, solved["root"].values)
    true_vertices = skin(markers.attrs["phenotype"], markers["gt_bone_rotations"].values, markers["gt_root"].values)
    step = max(1, vertices.shape[1] // SURFACE_POINTS)
    real = markers["gt_source"].values >= 0
    part = str(markers.attrs.get("marker_part", "body"))
    needs = {"cameras": "an optical marker system's cameras (markers given as 3D points)",
             "markers": f"{len(np.unique(markers['gt_source'].values[real]))} unlabelled markers on the "
                        f"{part.replace('_', ' ')}",
             "prior": _prior_said(catalog, stage)}
    return Capture(stage=stage, fps=float(markers.attrs["fps"]),
                   joints=in_template_order(solved["joint"].values, solved["joints"].values),
                   truth=in_template_order(markers["joint"].values, markers["gt_joints"].values),
                   surface_error_mm=1000 * np.median(np.linalg.norm(vertices - true_vertices, axis=-1), axis=1),
                   surface=vertices[:, ::step], needs=needs, skeleton=SKELETON)


COMPARER = Comparer("uuo", compared_stage, capture,
                    requirements="unlabelled optical markers anywhere on the body and a monocular body prior")
