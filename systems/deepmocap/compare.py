"""DeepMoCap's compare hook (registry.Comparer): its solved poses as the 20 template joints, against the truth
its IR-depth sequence carries. DeepMoCap gives no surface."""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline.registry import Capture, Comparer, Skeleton
from mocapflow.tasks.shared.body import BODY_PARTS, JOINT_NAMES, PARENTS

SKELETON = Skeleton(JOINT_NAMES, tuple(int(p) for p in PARENTS), BODY_PARTS)  # the template's, in its order


def compared_stage(catalog, stages: list[str]) -> str | None:
    """The last of ``stages`` writing the body fitted to the reflectors, else the last writing template poses."""
    for schema in ("body_poses", "poses"):
        found = next((s for s in reversed(stages) if catalog.stages[s].spec.output == schema), None)
        if found is not None:
            return found
    return None


def source_stage(catalog, stage: str) -> str:
    return next(s for s in catalog.ancestors(stage) if catalog.stages[s].spec.source)


def in_template_order(names, values: np.ndarray) -> np.ndarray:
    """(frame, joint, 3) reordered to JOINT_NAMES from the artifact's ``joint`` names."""
    names = [str(n) for n in names]
    return values[:, [names.index(j) for j in JOINT_NAMES]].astype(np.float64)


def capture(catalog, plan, store, stage: str, sequence: str) -> Capture:
    poses = plan.open(store, stage, sequence)
    raw = plan.open(store, source_stage(catalog, stage), sequence)
    seq = next(s for s in plan.sequences if s.id == sequence)
    needs = {"cameras": f"{len(seq.views)} IR-depth sensors", "markers": "26 retro-reflective straps and patches",
             "prior": "none (the FCN, trained on studio renders)"}
    return Capture(stage=stage, fps=float(raw.attrs["fps"]),
                   joints=in_template_order(poses["joint"].values, poses["position"].values),
                   truth=in_template_order(raw["joint"].values, raw["gt_joints"].values), needs=needs,
                   skeleton=SKELETON)


COMPARER = Comparer("deepmocap", compared_stage, capture,
                    requirements="IR-depth sensors and retro-reflective straps and patches on the skin; no prior")
