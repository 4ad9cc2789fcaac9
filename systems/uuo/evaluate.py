"""`mocapflow evaluate` for the UUO stages: the solved bodies of every stage writing `uuo_body` (the best or the
single hypothesis, refined) against the studio's truth of its marker take (tasks/uuo/metrics.py).

Per stage: MPJPE, MPJVE, V2V and m2s over the evaluation split (median, 90th percentile and worst over takes),
the prior's own error (its stage's ``aligned_mpjpe_mm`` and the others), per layout (a whole-body layout is named by its
marker count, ``body40``; a partial one by its part, also scored on the part's joints), the joints after each
solver stage (the paper's Table 4), and the labelling: the share of real markers given a vertex, of those
the share on the right body part, and the share of ghosts given a vertex (each a false label).

Recorded takes have no truth: with ``evaluation: {uuo_reference: STAGE}`` every other UUO stage is scored
against that stage's body, the same solver on the labelled markers (the paper's "labelled markers" row): MPJPE,
MPJVE and V2V against it, m2s of the labelled markers on both bodies, and the labelling's consistency: for each
true label, the share of the frames it is seen whose trajectory got the label's majority part (an unlabelled
trajectory counting against), and the share that got the reference's part for that label.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.catalog import stage_writing
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.registry import Evaluator
from mocapflow.presentation.evaluate import format_rows
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body, part_of_bone, pose_mesh
from mocapflow.tasks.uuo import metrics
from mocapflow.tasks.uuo.labelled import base_label
from mocapflow.tasks.uuo.prior import aligned_mpjpe, procrustes_mpjpe, registered_mpjpe


def _mesh(phenotype: dict, quats: np.ndarray, root: np.ndarray):
    body = mesh_body(Phenotype(**phenotype))
    rotations = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(quats.shape[:2] + (3, 3))
    return body, pose_mesh(body, rotations, root).vertices


def _layout(markers) -> str:
    """The take's marker layout: ``body40``, ``left_leg``, ... (the layout's count, seen or not)."""
    part = str(markers.attrs.get("marker_part", "body"))
    count = int(markers.attrs["marker_count"]) if "marker_count" in markers.attrs else \
        len(np.unique(markers["gt_source"].values[markers["gt_source"].values >= 0]))
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
    ghost = ~real  # a ghost given a vertex is a false label
    out["ghost_label_rate"] = float((vertex[ghost] >= 0).mean()) if ghost.any() else float("nan")
    out["part_right"] = float((solved["part"].values[labelled] == true_part[labelled]).mean()) if labelled.any() \
        else float("nan")
    out["hypothesis_yaw_deg"] = float(solved.attrs.get("yaw_deg", np.nan))
    out["facing_error_deg"] = metrics.facing_error_deg(joints, truth, names)
    swapped, sided = metrics.side_swaps(true_part[labelled], solved["part"].values[labelled])
    out["side_swap_rate"] = swapped / sided if sided else float("nan")
    out["turned"] = float(out["facing_error_deg"] > metrics.TURNED_DEG)  # counted over takes by over_takes
    out["mirrored"] = float(sided > 0 and swapped > metrics.MIRRORED_SHARE * sided)
    out["too_close"] = float(bool(solved.attrs.get("too_close", False)))  # the solver's own doubt (solve.choose)
    return out


def uuo_stages(catalog) -> list[str]:
    """The bodies a UUO catalog ends with: those choosing among hypotheses, and baselines no stage reads on."""
    read = {up for s in catalog.stages.values() for up in s.inputs.values()}
    return [s.name for s in catalog.stages.values() if s.spec.output == "uuo_body"
            and ("uuo_body" in s.spec.inputs.values() or s.name not in read)]


def applies(catalog) -> bool:
    return bool(uuo_stages(catalog))


def evaluate(catalog, plan, store, per_sequence: dict, thorough: bool = True) -> dict:
    """The UUO figures of `mocapflow evaluate` (``result["uuo"]``)."""
    return {"uuo": evaluate_uuo(catalog, plan, store, uuo_stages(catalog), per_sequence)}


def evaluate_uuo(catalog, plan, store, stages: list[str], per_sequence: dict) -> dict:
    """Figures per UUO stage: overall (median and p90 over takes), per layout and per take."""
    reference = catalog.evaluation.get("uuo_reference")
    if reference is not None:  # recorded takes: no truth, a labelled reference
        return evaluate_against_reference(catalog, plan, store, stages, str(reference), per_sequence)
    markers_stage = stage_writing(catalog, "raw_markers")
    if markers_stage is None:
        raise PlanError("the catalog solves UUO bodies but has no stage writing raw_markers to score them against")
    truths, priors = {}, {}
    for seq in plan.sequences:
        markers = plan.open(store, markers_stage, seq.id).load()
        if "gt_joints" not in markers:
            raise PlanError(f"sequence {seq.id!r} has no ground truth (gt_joints); evaluate UUO on studio takes")
        truths[seq.id] = take_truth(markers)
    out = {}
    for stage in stages:
        prior_stage = prior_of(catalog, stage)  # the prior this solve started from (a catalog may hold several)
        takes = {}
        for seq in plan.sequences:
            if (prior_stage, seq.id) not in priors:
                priors[prior_stage, seq.id] = prior_figures(plan.open(store, prior_stage, seq.id).load(),
                                                            truths[seq.id]["joints"]) if prior_stage else {}
            takes[seq.id] = {**score_take(truths[seq.id], plan.open(store, stage, seq.id).load()),
                             **priors[prior_stage, seq.id]}
            per_sequence.setdefault(seq.id, {})[f"uuo_{stage}"] = takes[seq.id]
        out[stage] = {"overall": _summary(list(takes.values())), "takes": takes,
                      "layouts": {layout: _summary([t for t in takes.values() if t["layout"] == layout])
                                  for layout in sorted({t["layout"] for t in takes.values()})}}
    return out


def prior_of(catalog, stage: str) -> str | None:
    """The stage writing the body_prior that ``stage`` was solved from: the first found upstream, breadth first."""
    queue, seen = [stage], {stage}
    while queue:
        for upstream in catalog.stages[queue.pop(0)].inputs.values():
            if catalog.stages[upstream].spec.output == "body_prior":
                return upstream
            if upstream not in seen:
                seen.add(upstream)
                queue.append(upstream)
    return None


# The prior's error (tasks/uuo/prior.py): after part matching's alignment, after one rigid registration with scale
# (HMR2.0+RR), per frame (PA).
PRIOR_FIGURES = ("aligned_mpjpe_mm", "registered_mpjpe_mm", "pa_mpjpe_mm")
_PRIOR_MEASURES = {"aligned_mpjpe_mm": aligned_mpjpe, "registered_mpjpe_mm": registered_mpjpe,
                   "pa_mpjpe_mm": procrustes_mpjpe}


def prior_figures(prior: xr.Dataset, truth_joints: np.ndarray) -> dict:
    """The prior's error on its estimated frames: as its stage stored it (a simulated prior measures itself), else
    measured here against the truth (a monocular or file prior never sees the truth)."""
    if all(k in prior.attrs for k in PRIOR_FIGURES):
        return {f"prior_{k}": float(prior.attrs[k]) for k in PRIOR_FIGURES}
    valid = prior["valid"].values.astype(bool)
    if not valid.any():
        return {}
    joints, truth = prior["joints"].values[valid].astype(np.float64), truth_joints[valid].astype(np.float64)
    return {f"prior_{k}": 1000.0 * measure(joints, truth) for k, measure in _PRIOR_MEASURES.items()}


COUNTED = ("turned", "mirrored", "too_close")  # per take 0 or 1: counted over takes, never a median


def over_takes(rows: list[dict]) -> dict:
    """Over takes: each figure's median (``key``), its 90th percentile (``key_p90``) and worst (``key_max``); the
    takes solved turned around or mirrored, and those whose facing was too close to call, counted."""
    keys = [k for k, v in rows[0].items() if isinstance(v, float) and k not in COUNTED] if rows else []
    out = {}
    for k in keys:
        values = np.array([r.get(k, np.nan) for r in rows], float)
        finite = values[np.isfinite(values)]
        out[k] = float(np.median(finite)) if len(finite) else float("nan")
        out[f"{k}_p90"] = float(np.percentile(finite, 90)) if len(finite) else float("nan")
        out[f"{k}_max"] = float(finite.max()) if len(finite) else float("nan")
    out["takes"] = len(rows)
    for failure in COUNTED:
        out[f"{failure}_takes"] = int(sum(r.get(failure, 0.0) for r in rows))
    return out


def _summary(rows: list[dict]) -> dict:
    """over_takes, with the median MPJPE after each solver stage (Table 4)."""
    out = over_takes(rows)
    stage_names = {s for r in rows for s in r["stages_mpjpe_mm"]}
    out["stages_mpjpe_mm"] = {s: float(np.nanmedian([r["stages_mpjpe_mm"].get(s, np.nan) for r in rows]))
                              for s in sorted(stage_names)}
    return out


def uuo_headline(result: dict) -> dict:
    """`--json` figures: the first UUO stage's as uuo_*, per layout as uuo_<layout>_mpjpe_mm; other stages
    (ablations, baselines) as uuo_<stage>_mpjpe_mm."""
    out = {}
    for i, (stage, r) in enumerate(result.get("uuo", {}).items()):
        o = r["overall"]
        if "reference" in r:  # recorded takes against their labelled reference
            out.update({f"uuo_real_{stage}_{k}": o[k] for k in ("mpjpe_mm", "mpjpe_mm_p90", "m2s_mm", "consistency",
                                                                 "agreement", "turned_takes", "mirrored_takes",
                                                                 "too_close_takes", "takes")})
            continue
        if i == 0:
            out.update({"uuo_stage": stage, "uuo_mpjpe_mm": o["mpjpe_mm"], "uuo_mpjve_mm": o["mpjve_mm"],
                        "uuo_v2v_mm": o["v2v_mm"], "uuo_m2s_mm": o["m2s_mm"],
                        "uuo_ghost_label_rate": o["ghost_label_rate"], "uuo_turned_takes": o["turned_takes"],
                        "uuo_mirrored_takes": o["mirrored_takes"], "uuo_too_close_takes": o["too_close_takes"]})
            if "prior_aligned_mpjpe_mm" in o:
                out["uuo_prior_aligned_mpjpe_mm"] = o["prior_aligned_mpjpe_mm"]
            for layout, lr in r["layouts"].items():
                key = "part_mpjpe_mm" if "part_mpjpe_mm" in lr else "mpjpe_mm"
                out[f"uuo_{layout}_mpjpe_mm"] = lr[key]  # the median over the layout's takes ...
                out[f"uuo_{layout}_mpjpe_p90_mm"] = lr[f"{key}_p90"]  # ... and its 90th percentile
        else:
            out[f"uuo_{stage}_mpjpe_mm"] = o["mpjpe_mm"]
    return out


def uuo_table(result: dict) -> list[str]:
    if "uuo" not in result:
        return []
    result = result["uuo"]
    if any("reference" in r for r in result.values()):
        return reference_table(result)
    rows = [("UUO stage", "layout", "takes", "MPJPE mm (p90)", "part MPJPE (p90)", "MPJVE mm/frame", "V2V mm",
             "m2s mm (truth)", "labelled", "right part", "ghosts labelled", "prior aligned mm",
             "turned / mirrored / too close")]
    for stage, r in result.items():
        for layout, lr in [("all", r["overall"])] + list(r["layouts"].items()):
            part = lr.get("part_mpjpe_mm", float("nan"))
            prior = lr.get("prior_aligned_mpjpe_mm", float("nan"))
            rows.append((stage, layout, str(lr["takes"]), f"{lr['mpjpe_mm']:.1f} ({lr['mpjpe_mm_p90']:.1f})",
                         "-" if np.isnan(part) else f"{part:.1f} ({lr['part_mpjpe_mm_p90']:.1f})",
                         f"{lr['mpjve_mm']:.2f}", f"{lr['v2v_mm']:.1f}",
                         f"{lr['m2s_mm']:.1f} ({lr['m2s_truth_mm']:.1f})", f"{lr['labelled']:.0%}",
                         f"{lr['part_right']:.0%}",
                         "-" if np.isnan(lr["ghost_label_rate"]) else f"{lr['ghost_label_rate']:.0%}",
                         "-" if np.isnan(prior) else f"{prior:.1f}",
                         f"{lr['turned_takes']} / {lr['mirrored_takes']} / {lr['too_close_takes']}"))
    lines = ["median over takes (90th percentile); turned / mirrored: takes solved turned around (facing off by "
             f"more than {metrics.TURNED_DEG:.0f} degrees) or mirrored (most sided labels on the other side); too "
             "close: takes whose facing or handedness the solver found too close to call"] \
        + format_rows(rows)
    stage_rows = [("UUO stage", "after matching", "pose fit", "IK", "refined")]
    for stage, r in result.items():
        s = r["overall"]["stages_mpjpe_mm"]
        stage_rows.append((stage, *(f"{s[k]:.1f}" if k in s and np.isfinite(s[k]) else "-"
                                    for k in ("matching", "pose_fit", "ik", "refined"))))
    return lines + ["", "MPJPE (mm) after each solver stage (Table 4)"] + format_rows(stage_rows)


# ---- recorded takes: the unlabelled solves against the labelled reference (the paper's "labelled markers" row) ----

def label_consistency(labels: list[str], parts: np.ndarray, positions: np.ndarray,
                      reference_part: dict[str, str]) -> dict[str, dict]:
    """Per true label: over the frames a trajectory of that label is seen, the share whose trajectory got the
    label's majority part (``consistent``; an unlabelled trajectory counts against it), and the share whose part
    is the reference's part of the label (``agrees``).  labels, parts (trajectory,), positions (frame, trajectory, 3)"""
    seen = np.isfinite(positions).all(-1)  # (frame, trajectory)
    out = {}
    for label in dict.fromkeys(labels):
        index = [i for i, name in enumerate(labels) if name == label]
        frame_parts = np.concatenate([np.repeat(parts[i], seen[:, i].sum()) for i in index]).astype(str)
        if not len(frame_parts):
            continue
        named = frame_parts[frame_parts != ""]
        majority = max(set(named), key=lambda p: (named == p).sum()) if len(named) else ""
        out[label] = {"frames": int(len(frame_parts)), "majority": majority, "fragments": len(index),
                      "consistent": float((frame_parts == majority).mean()) if majority else 0.0,
                      "agrees": float((frame_parts == reference_part.get(label, "")).mean())}
    return out


def score_against_reference(solved, reference, raw_labels: list[str], raw_positions: np.ndarray,
                            real_positions: np.ndarray) -> dict:
    """One recorded take's unlabelled solve against its labelled reference (mm, shares). ``raw_labels`` and
    ``raw_positions`` (frame, trajectory, 3): the file's trajectories in the solver's order; ``real_positions``:
    the labelled markers (fragments joined, no ghosts), over which m2s is taken for both bodies."""
    joints = solved["joints"].values.astype(np.float64)
    ref_joints = reference["joints"].values.astype(np.float64)
    body, vertices = _mesh(solved.attrs["phenotype"], solved["bone_rotation"].values, solved["root"].values)
    ref_body, ref_vertices = _mesh(reference.attrs["phenotype"], reference["bone_rotation"].values,
                                   reference["root"].values)
    reference_part = dict(zip((str(m) for m in reference["marker"].values), (str(p) for p in reference["part"].values)))
    per_label = label_consistency(raw_labels, solved["part"].values, raw_positions, reference_part)
    weights = np.array([r["frames"] for r in per_label.values()], float)
    got = solved["part"].values
    expected = np.array([reference_part.get(label, "") for label in raw_labels])
    labelled = (got != "") & (expected != "")
    swapped, sided = metrics.side_swaps(expected[labelled], got[labelled])
    facing = metrics.facing_error_deg(joints, ref_joints, [str(j) for j in solved["joint"].values])
    return {"frames": len(joints), "labels": len(per_label), "trajectories": len(raw_labels),
            "facing_error_deg": facing, "turned": float(facing > metrics.TURNED_DEG),
            "mirrored": float(sided > 0 and swapped > metrics.MIRRORED_SHARE * sided),
            "too_close": float(bool(solved.attrs.get("too_close", False))),
            "mpjpe_mm": 1000 * metrics.mpjpe(joints, ref_joints), "mpjve_mm": 1000 * metrics.mpjve(joints, ref_joints),
            "v2v_mm": 1000 * metrics.v2v(vertices, ref_vertices),
            "m2s_mm": 1000 * metrics.m2s(real_positions, vertices, body.faces),
            "m2s_reference_mm": 1000 * metrics.m2s(real_positions, ref_vertices, ref_body.faces),
            "consistency": float(np.mean([r["consistent"] for r in per_label.values()])),
            "consistency_frames": float(np.average([r["consistent"] for r in per_label.values()], weights=weights)),
            "agreement": float(np.mean([r["agrees"] for r in per_label.values()])),
            "hypothesis_yaw_deg": float(solved.attrs.get("yaw_deg", np.nan)), "per_label": per_label}


def evaluate_against_reference(catalog, plan, store, stages: list[str], reference: str, per_sequence: dict) -> dict:
    """Figures per UUO stage on recorded takes, against the ``reference`` stage's body (evaluation.uuo_reference)."""
    if reference not in catalog.stages or catalog.stages[reference].spec.output != "uuo_body":
        raise PlanError(f"evaluation.uuo_reference names {reference!r}, not a stage writing uuo_body; name the "
                        "labelled solve's stage")
    raw_stage = stage_writing(catalog, "raw_markers")
    labelled_stage = catalog.stages[reference].inputs["markers"]
    params = catalog.stages[labelled_stage].params
    drop_prefix = getattr(params, "drop_prefix", True)
    out = {}
    for stage in [s for s in stages if s != reference]:
        takes = {}
        for seq in plan.sequences:
            raw = plan.open(store, raw_stage, seq.id).load()
            if "label" not in raw:
                raise PlanError(f"sequence {seq.id!r}: the markers carry no labels; read them with labels: use to "
                                "score against the labelled reference")
            labels = [base_label(label, drop_prefix) for label in raw["label"].values]
            solved = plan.open(store, stage, seq.id).load()
            if solved.sizes["marker"] != len(labels):
                raise PlanError(f"stage {stage!r} solved {solved.sizes['marker']} trajectories of {seq.id!r}, the "
                                f"file has {len(labels)}; solve the file's trajectories (drop_labels)")
            real = plan.open(store, labelled_stage, seq.id)["position"].transpose("frame", "marker", "xyz").values
            takes[seq.id] = score_against_reference(
                solved, plan.open(store, reference, seq.id).load(), labels,
                raw["position"].transpose("frame", "marker", "xyz").values, real.astype(np.float64))
            per_sequence.setdefault(seq.id, {})[f"uuo_{stage}"] = {k: v for k, v in takes[seq.id].items()
                                                                   if k != "per_label"}
        out[stage] = {"reference": reference, "takes": takes, "overall": over_takes(list(takes.values()))}
    return out


def reference_table(result: dict) -> list[str]:
    rows = [("UUO stage", "take", "MPJPE mm", "MPJVE mm/frame", "V2V mm", "m2s mm (reference)", "labels",
             "consistency", "agrees with reference", "turned / mirrored / too close")]
    for stage, r in result.items():
        for take, t in r["takes"].items():
            rows.append((stage, take, f"{t['mpjpe_mm']:.1f}", f"{t['mpjve_mm']:.2f}", f"{t['v2v_mm']:.1f}",
                         f"{t['m2s_mm']:.1f} ({t['m2s_reference_mm']:.1f})", str(t["labels"]),
                         f"{t['consistency']:.0%}", f"{t['agreement']:.0%}",
                         " / ".join("yes" if t[k] else "-" for k in COUNTED)))
        o = r["overall"]
        rows.append((stage, f"median (p90) of {o['takes']}", f"{o['mpjpe_mm']:.1f} ({o['mpjpe_mm_p90']:.1f})",
                     f"{o['mpjve_mm']:.2f}", f"{o['v2v_mm']:.1f}",
                     f"{o['m2s_mm']:.1f} ({o['m2s_reference_mm']:.1f})", "-", f"{o['consistency']:.0%}",
                     f"{o['agreement']:.0%}", " / ".join(str(o[f"{k}_takes"]) for k in COUNTED)))
    return [f"against the labelled reference ({next(iter(result.values()))['reference']}); the last row of a stage: "
            "medians over takes (90th percentile), takes turned, mirrored or too close to call counted"] \
        + format_rows(rows)


EVALUATOR = Evaluator("uuo", applies, evaluate, uuo_headline, uuo_table)
