"""UUO in `mocapflow report`: the take's markers as recorded with the headline solve's joints (and the studio's true
joints where the take has them) in the 3D view, and per take the solve's figures (export.py ``report_figures``):
the markers on the solved mesh from the front and the side, and, against the truth or the catalog's labelled
reference where there is one, the error per joint and over time. The headline solve is `mocapflow evaluate`'s
(export.py ``default_stage``); a catalog without one shows the markers alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapflow.pipeline.catalog import final_stage, stage_writing
from mocapflow.pipeline.registry import ReportSection
from mocapflow.presentation.report import Take, base_takes
from mocapflow.systems.uuo.export import default_stage, report_figures, solve_markers, solve_truth
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS


def applies(catalog) -> bool:
    return final_stage(catalog, "raw_markers") is not None


def takes(catalog, plan, store) -> list[Take]:
    """Every sequence's markers as recorded (the last stage writing raw_markers: a labelled take's merged ones),
    with the headline solve's joints and the recording's true joints, where the catalog has them."""
    out = base_takes(catalog, plan, store, final_stage(catalog, "raw_markers"))
    solve, source = default_stage(catalog), stage_writing(catalog, "raw_markers")
    for take in out:
        if solve is not None:
            solved = plan.open(store, solve, take.id)
            _add_joints(take, solved)
            take.note = f"joints in the 3D view: the solve of stage {solve}" + _doubt(solved.attrs)
        raw = plan.open(store, source, take.id) if source else None
        if take.joints is not None and raw is not None and "gt_joints" in raw:
            take.gt_joints = raw["gt_joints"].values.astype(np.float64)
    return out


def _doubt(attrs) -> str:
    """What the solver says of its facing when two hypotheses were too close to call (solve.choose)."""
    if not attrs.get("too_close"):
        return ""
    return (f"; facing too close to call: the hypothesis kept (yaw {float(attrs['matched_yaw_deg']):.0f} deg"
            f"{', mirrored' if attrs.get('mirror') else ''}) beat one facing or sided otherwise by only "
            f"{float(attrs['call_margin_deg']):.1f} deg of plausibility; check the facing before using this take")


def _add_joints(take: Take, solved) -> None:
    """The solve's template joints and their tree (the body's, where the joints are its 20)."""
    take.joints = solved["joints"].values.astype(np.float64)
    take.joint_names = [str(j) for j in solved["joint"].values]
    take.parents = [int(i) for i in PARENTS] if take.joint_names == list(JOINT_NAMES) else []


def figures(folder: Path, catalog, plan, store, result: dict) -> list[Path]:
    """Per sequence the headline solve's figures, ``markers_on_mesh_<seq>.png`` and, against a truth,
    ``joint_errors_<seq>.png`` and ``error_over_time_<seq>.png``."""
    solve = default_stage(catalog)
    if solve is None:
        return []
    out = []
    for seq in plan.sequences:
        truth, against = solve_truth(catalog, plan, store, solve, seq.id)
        out += report_figures(folder, plan.open(store, solve, seq.id).load(),
                              solve_markers(catalog, plan, store, solve, seq.id), truth, against, tag=f"_{seq.id}")
    return out


# The evaluation's JSON keys, named for a reader: (label, scale, unit)
NAMED_FIGURES = {
    "uuo_mpjpe_mm": ("UUO joint error (MPJPE)", 1, "mm"),
    "uuo_mpjve_mm": ("UUO joint velocity error (MPJVE)", 1, "mm"), "uuo_v2v_mm": ("UUO vertex error (V2V)", 1, "mm"),
    "uuo_m2s_mm": ("UUO marker to skin (m2s)", 1, "mm"),
}


# The studio's takes carry the true joints (``gt_joints``); a recording does not.
SECTION = ReportSection("uuo", applies, takes, figures, NAMED_FIGURES,
                        truth="gt_joints")
