"""`mocapflow evaluate` for the UUO stages: the solved bodies of every stage writing `uuo_body` (the best or the
single hypothesis, refined) against the studio's truth of its marker take (tasks/uuo/metrics.py).

Per stage: MPJPE, MPJVE, V2V and m2s over the evaluation split, per layout (a whole-body layout is named by its
marker count, ``body40``; a partial one by its part, also scored on the part's joints), the joints after each
solver stage (the paper's Table 4), and the labelling: the share of real markers given a vertex, and of those
the share on the right body part.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.errors import PlanError
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body, part_of_bone, pose_mesh
from mocapflow.tasks.uuo import metrics


def _mesh(phenotype: dict, quats: np.ndarray, root: np.ndarray):
    body = mesh_body(Phenotype(**phenotype))
    rotations = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(quats.shape[:2] + (3, 3))
    return body, pose_mesh(body, rotations, root).vertices


def _layout(markers) -> str:
    part = str(markers.attrs.get("marker_part", "body"))
    count = len(np.unique(markers["gt_source"].values[markers["gt_source"].values >= 0]))
    return f"body{count}" if part == "body" else part


def take_truth(markers) -> dict:
    """What every stage of one take is scored against: joints, the true mesh, the real markers, their parts."""
    true_body, true_vertices = _mesh(markers.attrs["phenotype"], markers["gt_bone_rotations"].values,
                                     markers["gt_root"].values)
    real = markers["gt_source"].values >= 0
    positions = markers["position"].transpose("frame", "marker", "xyz").values.astype(np.float64)[:, real]
    parts = np.array([part_of_bone(true_body.bone_names[true_body.vertex_bone[true_body.faces[f, 0]]])
                      if f >= 0 else "" for f in markers["gt_face"].values])
    return {"joints": markers["gt_joints"].values.astype(np.float64), "body": true_body, "vertices": true_vertices,
            "real": real, "positions": positions, "parts": parts, "layout": _layout(markers),
            "part": str(markers.attrs.get("marker_part", "body")),
            "m2s_truth_mm": 1000 * metrics.m2s(positions, true_vertices, true_body.faces)}


def score_take(truth_of: dict, solved) -> dict:
    """Every figure of one take (mm, shares) against its ``take_truth``."""
    truth = truth_of["joints"]
    joints = solved["joints"].values.astype(np.float64)
    names = [str(j) for j in solved["joint"].values]
    _, vertices = _mesh(solved.attrs["phenotype"], solved["bone_rotation"].values, solved["root"].values)
    real = truth_of["real"]
    out = {"layout": truth_of["layout"], "frames": len(truth),
           "mpjpe_mm": 1000 * metrics.mpjpe(joints, truth), "mpjve_mm": 1000 * metrics.mpjve(joints, truth),
           "v2v_mm": 1000 * metrics.v2v(vertices, truth_of["vertices"]),
           "m2s_mm": 1000 * metrics.m2s(truth_of["positions"], vertices, truth_of["body"].faces),
           "m2s_truth_mm": truth_of["m2s_truth_mm"]}
    part = truth_of["part"]
    if part in metrics.PART_JOINTS:
        chosen = [names.index(j) for j in metrics.PART_JOINTS[part]]
        out["part_mpjpe_mm"] = 1000 * metrics.mpjpe(joints[:, chosen], truth[:, chosen])
    out["stages_mpjpe_mm"] = {str(s): 1000 * metrics.mpjpe(solved["stage_joints"].sel(stage=s).values, truth)
                              for s in solved["stage"].values
                              if np.isfinite(solved["stage_joints"].sel(stage=s).values).all()}
    vertex = solved["vertex"].values
    true_part = truth_of["parts"]
    labelled = real & (vertex >= 0)
    out["labelled"] = float(labelled[real].mean()) if real.any() else float("nan")
    out["part_right"] = float((solved["part"].values[labelled] == true_part[labelled]).mean()) if labelled.any() \
        else float("nan")
    out["hypothesis_yaw_deg"] = float(solved.attrs.get("yaw_deg", np.nan))
    return out


def evaluate_uuo(catalog, plan, store, stages: list[str], per_sequence: dict) -> dict:
    """Figures per UUO stage: overall (mean over takes), per layout and per take."""
    from mocapflow.pipeline.evaluate import stage_writing

    markers_stage = stage_writing(catalog, "raw_markers")
    if markers_stage is None:
        raise PlanError("the catalog solves UUO bodies but has no stage writing raw_markers to score them against")
    truths = {}
    for seq in plan.sequences:
        markers = plan.open(store, markers_stage, seq.id).load()
        if "gt_joints" not in markers:
            raise PlanError(f"sequence {seq.id!r} has no ground truth (gt_joints); evaluate UUO on studio takes")
        truths[seq.id] = take_truth(markers)
    out = {}
    for stage in stages:
        takes = {}
        for seq in plan.sequences:
            takes[seq.id] = score_take(truths[seq.id], plan.open(store, stage, seq.id).load())
            per_sequence.setdefault(seq.id, {})[f"uuo_{stage}"] = takes[seq.id]
        out[stage] = {"overall": _mean(list(takes.values())), "takes": takes,
                      "layouts": {layout: _mean([t for t in takes.values() if t["layout"] == layout])
                                  for layout in sorted({t["layout"] for t in takes.values()})}}
    return out


def _mean(rows: list[dict]) -> dict:
    keys = [k for k, v in rows[0].items() if isinstance(v, float)] if rows else []
    out = {k: float(np.nanmean([r.get(k, np.nan) for r in rows])) for k in keys}
    stage_names = {s for r in rows for s in r["stages_mpjpe_mm"]}
    out["stages_mpjpe_mm"] = {s: float(np.nanmean([r["stages_mpjpe_mm"].get(s, np.nan) for r in rows]))
                              for s in sorted(stage_names)}
    out["takes"] = len(rows)
    return out


def uuo_headline(result: dict) -> dict:
    """`--json` figures: the first UUO stage's as uuo_*, per layout as uuo_<layout>_mpjpe_mm; other stages
    (ablations, baselines) as uuo_<stage>_mpjpe_mm."""
    out = {}
    for i, (stage, r) in enumerate(result.items()):
        o = r["overall"]
        if i == 0:
            out.update({"uuo_stage": stage, "uuo_mpjpe_mm": o["mpjpe_mm"], "uuo_mpjve_mm": o["mpjve_mm"],
                        "uuo_v2v_mm": o["v2v_mm"], "uuo_m2s_mm": o["m2s_mm"]})
            for layout, lr in r["layouts"].items():
                out[f"uuo_{layout}_mpjpe_mm"] = lr.get("part_mpjpe_mm", lr["mpjpe_mm"])
        else:
            out[f"uuo_{stage}_mpjpe_mm"] = o["mpjpe_mm"]
    return out


def uuo_table(result: dict) -> list[str]:
    from mocapflow.pipeline.evaluate import _format

    rows = [("UUO stage", "layout", "takes", "MPJPE mm", "part MPJPE", "MPJVE mm/frame", "V2V mm", "m2s mm (truth)",
             "labelled", "right part")]
    for stage, r in result.items():
        for layout, lr in [("all", r["overall"])] + list(r["layouts"].items()):
            part = lr.get("part_mpjpe_mm", float("nan"))
            rows.append((stage, layout, str(lr["takes"]), f"{lr['mpjpe_mm']:.1f}",
                         "-" if np.isnan(part) else f"{part:.1f}", f"{lr['mpjve_mm']:.2f}", f"{lr['v2v_mm']:.1f}",
                         f"{lr['m2s_mm']:.1f} ({lr['m2s_truth_mm']:.1f})", f"{lr['labelled']:.0%}",
                         f"{lr['part_right']:.0%}"))
    lines = _format(rows)
    stage_rows = [("UUO stage", "after matching", "pose fit", "IK", "refined")]
    for stage, r in result.items():
        s = r["overall"]["stages_mpjpe_mm"]
        stage_rows.append((stage, *(f"{s[k]:.1f}" if k in s and np.isfinite(s[k]) else "-"
                                    for k in ("matching", "pose_fit", "ik", "refined"))))
    return lines + ["", "MPJPE (mm) after each solver stage (Table 4)"] + _format(stage_rows)
