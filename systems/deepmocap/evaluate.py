"""`mocapflow evaluate` for DeepMoCap's stages, against the studio's ground truth, and without it the labels'
plausibility per view.

Each sequence's artifacts are read view by view and scored by the pure metrics of tasks/deepmocap/evaluation.py:
scene flow (the `flow` stage), the labelled 2D reflectors (a stage writing `reflectors2d`, per view too), the 3D
reflectors (`markers3d`, `smoothed_markers` and the plausibility check that refines them, with the tail of the
error: p95, p99 and the share of marker-frames more than 10 cm from the truth) and the joints of the solved poses
(`poses`). Every take, a recording without ground truth too, gets the plausibility of each view's labels
(tasks/deepmocap/consistency.py: the views against each other and against the fitted body), where the catalog
has a `markers3d` stage and poses; with truth, beside each view's true 2D mAP and the share of its labels lifted
onto their true reflector, to show how well the checks track them.
"""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline.catalog import stage_writing
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.plan import Plan
from mocapflow.pipeline.registry import Evaluator
from mocapflow.pipeline.storage import Store
from mocapflow.presentation.evaluate import format_rows, pct
from mocapflow.tasks.deepmocap.consistency import (CHECKS, ConsistencyConfig, add_counts, summarize,
                                                   true_on_reflector, view_counts)
from mocapflow.tasks.deepmocap.evaluation import (TABLE8_JOINTS, Matches2D, flow_errors, jitter, joint_errors, match_2d,
                                                  pck_radius, summarize_2d, summarize_flow, summarize_joints,
                                                  summarize_markers)
from mocapflow.tasks.deepmocap.refine2d import reflectors_on_poses
from mocapflow.tasks.shared.marker_errors import marker_errors

C_MIN_SWEEP = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
# 3D marker stages scored: (kind, schema, whether the stage refines an artifact of that schema). "checked" is the
# plausibility check after the poses (tasks/deepmocap/plausibility.py): what export writes.
MARKER_KINDS = (("fused", "markers3d", False), ("smoothed", "smoothed_markers", False),
                ("checked", "smoothed_markers", True))
# JSON prefixes of each kind's figures (the smoothed stage's kept bare, as before the tail was reported), and of its tail
MARKER_PREFIX = {"fused": ("marker_fused_", "markers3d_"), "smoothed": ("marker_", "smoothed_"),
                 "checked": ("marker_checked_", "checked_")}


def poses_stage(catalog) -> str | None:
    """The stage whose joints are the take's poses: the body fitted to the reflectors where the catalog has one,
    else the template skeleton's poses."""
    return stage_writing(catalog, "body_poses") or stage_writing(catalog, "poses")


def applies(catalog) -> bool:
    """Whether the catalog has a stage this evaluator scores: the scene flow, 2D reflectors, 3D markers or poses."""
    return "flow" in catalog.stages or any(stage_writing(catalog, schema) for schema in
                                           ("reflectors2d", "markers3d", "smoothed_markers", "poses", "body_poses"))


def evaluate_deepmocap(catalog, plan: Plan, store: Store, per_sequence: dict, thorough: bool = True) -> dict:
    """Figures per sequence (into ``per_sequence``) and overall for every DeepMoCap stage the catalog has
    (``thorough`` False: all but the scene flow, the slowest to score and no figure of the capture itself); the
    plausibility of each view's labels (``plausibility``) where the catalog has the stages it reads, and only that
    where the sequences have no ground truth (recordings)."""
    stage_2d = stage_writing(catalog, "reflectors2d")
    stage_poses = poses_stage(catalog)
    raws = {}
    for seq in plan.sequences:
        raw = plan.open(store, "frames", seq.id)
        raws[seq.id] = raw
        per_sequence.setdefault(seq.id, {})["exercise"] = raw.attrs.get("exercise", "")
    untrue = [s for s, raw in raws.items() if "gt_body" not in raw]
    result: dict = {}
    if untrue:
        if len(untrue) < len(raws):
            true = next(s for s in raws if s not in untrue)
            raise PlanError(f"sequence {untrue[0]!r} has no ground truth (gt_body) but {true!r} has: evaluate the "
                            "recordings and the studio sequences apart (--sequences)")
        if not plausibility_stages(catalog):
            raise PlanError(f"sequence {untrue[0]!r} has no ground truth (gt_body), and the catalog no markers3d and "
                            "poses stages whose plausibility could stand in for it; evaluate on studio sequences, or "
                            "add the stages markers3d and poses (see catalog.yaml)")
        result["plausibility"] = evaluate_plausibility(catalog, plan, store, per_sequence)
        return result
    if "flow" in catalog.stages and thorough:
        result["flow"] = _evaluate_flow(plan, store, raws, per_sequence)
        result["task"] = catalog.stages["flow"].task
    if stage_2d is not None:
        result["reflectors2d"] = _evaluate_2d(plan, store, raws, stage_2d, per_sequence)
    stage_refined = stage_writing(catalog, "reflectors2d", refined=True)
    if stage_refined is not None:
        result["reflectors2d_refined"] = _evaluate_2d(plan, store, raws, stage_refined, per_sequence,
                                                      key="reflectors2d_refined")
    for kind, schema, refined in MARKER_KINDS:
        stage = stage_writing(catalog, schema, refined=refined)
        if stage is not None:
            result[f"markers_{kind}"] = _evaluate_markers(plan, store, raws, stage, schema, kind, per_sequence)
    if stage_poses is not None:
        result["poses"] = _evaluate_poses(plan, store, raws, stage_poses, per_sequence)
    if plausibility_stages(catalog):
        result["plausibility"] = evaluate_plausibility(catalog, plan, store, per_sequence, raws)
    return result


def plausibility_stages(catalog) -> tuple[str, str] | None:
    """The stages the plausibility of the views reads: the markers3d stage (each view's lifted labels) and the
    poses (where the body puts each reflector); None where the catalog lacks either."""
    fused, poses = stage_writing(catalog, "markers3d"), poses_stage(catalog)
    return (fused, poses) if fused is not None and poses is not None else None


def body_reflectors(catalog, plan: Plan, store: Store, stage: str, sequence: str, names: list[str],
                    frames: np.ndarray) -> np.ndarray:
    """Where the poses of ``stage`` put the reflectors ``names`` in ``frames``: a body fit's ``reflector_position``
    (NaN in frames it did not fit, posed from their neighbours), or the template's reflectors carried by its solved
    poses (its skeleton stage's offsets; NaN where unsolved).  -> (frame, R, 3)"""
    poses = plan.open(store, stage, sequence).load().sel(frame=frames)
    if "reflector_position" in poses:
        missing = sorted(set(names) - {str(n) for n in poses["reflector"].values})
        if missing:
            raise PlanError(f"stage {stage!r} places no {missing[0]!r} on the body, which the markers3d stage "
                            "labels; fit the body to the same reflectors")
        out = poses["reflector_position"].sel(reflector=names).transpose("frame", "reflector", "xyz").values
        fitted = poses["fitted"].values.astype(bool) if "fitted" in poses else np.ones(len(frames), bool)
        return np.where(fitted[:, None, None], out.astype(np.float64), np.nan)
    skeleton = catalog.stages[stage].inputs.get("skeleton")
    if skeleton is None:
        raise PlanError(f"stage {stage!r} writes poses without reflectors and reads no skeleton; the plausibility of "
                        "the views needs a body fit (fit_body_poses) or solve_poses with its skeleton input")
    return reflectors_on_poses(poses, plan.open(store, skeleton, sequence).load(), names, frames)[0]


def evaluate_plausibility(catalog, plan: Plan, store: Store, per_sequence: dict, raws: dict | None = None,
                          config: ConsistencyConfig = ConsistencyConfig()) -> dict:
    """Per sequence and over all, per view: the share of its labels agreeing with another view, on their side of
    the fitted body and on the body (tasks/deepmocap/consistency.py). Where ``raws`` carry the truth
    (``gt_reflectors``), per view also the share of its lifted labels within ``on_body_m`` of their true reflector
    (``true_on_reflector``), to show how well the checks track the truth."""
    fused, poses = plausibility_stages(catalog)
    per_view, truth_total, names = {}, {}, None  # a view's counts over the sequences it films, by its name
    for seq in plan.sequences:
        markers = plan.open(store, fused, seq.id).load()
        seq_names = [str(n) for n in markers["reflector"].values]
        if names is not None and seq_names != names:
            raise PlanError(f"sequence {seq.id!r} labels the reflectors {seq_names[:3]}..., another sequence "
                            f"{names[:3]}...; evaluate takes labelled alike together (--sequences)")
        names, views = seq_names, [str(v) for v in markers["view"].values]
        lifted = markers["view_position"].transpose("frame", "reflector", "view", "xyz").values.astype(np.float64)
        body = body_reflectors(catalog, plan, store, poses, seq.id, names, markers["frame"].values)
        counts = view_counts(lifted, body, names, config)
        for v, view in enumerate(views):
            per_view[view] = add_counts(per_view.get(view), {k: c[:, v] for k, c in counts.items()})
        figures = summarize(counts, views, names, config)
        raw = (raws or {}).get(seq.id)
        if raw is not None and "gt_reflectors" in raw:
            truth = raw["gt_reflectors"].sel(reflector=names).values
            near = true_on_reflector(lifted, truth, config)
            for v, view in enumerate(views):
                figures["views"][view]["true_on_reflector"] = _share(*near[:, v])
                truth_total[view] = truth_total.get(view, 0) + near[:, v]
        per_sequence[seq.id]["plausibility"] = figures
    views = list(per_view)
    out = summarize({k: np.stack([per_view[v][k] for v in views], axis=1) for k in CHECKS}, views, names, config)
    for view, near in truth_total.items():
        out["views"][view]["true_on_reflector"] = _share(*near)
    out.update({"stage": fused, "reflectors": catalog.stages[fused].inputs.get("reflectors"), "poses": poses,
                "agreement_m": config.agreement_m, "on_body_m": config.on_body_m})
    return out


def _share(passed, counted) -> float:
    return float(passed / counted) if counted else float("nan")


def _evaluate_poses(plan: Plan, store: Store, raws: dict, stage: str, per_sequence: dict) -> dict:
    """3D joint error of the Table 8 joints: overall, per joint (Table 8 form) and per exercise (Table 7 form)."""
    errors, by_exercise = [], {}
    for seq in plan.sequences:
        raw = raws[seq.id]
        if "gt_joints" not in raw:
            raise PlanError(f"sequence {seq.id!r} has no joint ground truth (gt_joints)")
        est = plan.open(store, stage, seq.id).load()
        est_joints = [str(j) for j in est["joint"].values]
        gt_names = [str(j) for j in raw["joint"].values]
        e = joint_errors(est["position"].values[:, [est_joints.index(j) for j in TABLE8_JOINTS]],
                         raw["gt_joints"].values[:, [gt_names.index(j) for j in TABLE8_JOINTS]])
        per_sequence[seq.id]["poses"] = summarize_joints(e, TABLE8_JOINTS)
        by_exercise.setdefault(per_sequence[seq.id]["exercise"] or seq.id, []).append(e)
        errors.append(e)
    out = summarize_joints(np.concatenate(errors), TABLE8_JOINTS)
    out["per_exercise"] = {k: summarize_joints(np.concatenate(v), TABLE8_JOINTS) for k, v in by_exercise.items()}
    out["stage"] = stage
    return out


def _evaluate_markers(plan: Plan, store: Store, raws: dict, stage: str, schema_name: str, kind: str,
                      per_sequence: dict) -> dict:
    """3D error of each reflector against the studio's ground truth, completeness and jitter."""
    errors, names, jitters, gt_jitters = [], None, [], []
    for seq in plan.sequences:
        raw = raws[seq.id]
        if "gt_reflectors" not in raw:
            raise PlanError(f"sequence {seq.id!r} has no 3D reflector ground truth (gt_reflectors)")
        est = plan.open(store, stage, seq.id).load()
        names = [str(n) for n in est["reflector"].values]
        gt = raw["gt_reflectors"].values
        e = marker_errors(est["position"].values, gt)
        fps = float(raw.attrs["fps"])
        per_sequence[seq.id][f"markers_{kind}"] = summarize_markers(
            e, names, jitter_value=jitter(est["position"].values, fps), gt_jitter=jitter(gt, fps))
        errors.append(e)
        jitters.append(per_sequence[seq.id][f"markers_{kind}"]["jitter_ms2"])
        gt_jitters.append(per_sequence[seq.id][f"markers_{kind}"]["gt_jitter_ms2"])
    out = summarize_markers(np.concatenate(errors), names, jitter_value=float(np.nanmean(jitters)),
                            gt_jitter=float(np.nanmean(gt_jitters)))
    out["stage"] = stage
    return out


def _evaluate_flow(plan: Plan, store: Store, raws: dict, per_sequence: dict) -> dict:
    all_errors, all_eligible = [], 0
    for seq in plan.sequences:
        raw, errors, eligible = raws[seq.id], [], 0
        if "gt_scene_flow_prev" not in raw:
            raise PlanError(f"sequence {seq.id!r} has no scene-flow ground truth (gt_scene_flow_prev)")
        for view in seq.views:
            est = plan.open(store, "flow", seq.id, view).sel(view=view)
            gt = raw.sel(view=view)
            e, n = flow_errors(est["flow"].values, est["valid"].values, gt["gt_scene_flow_prev"].values,
                               gt["gt_body"].values, gt["depth"].values, est["frame"].values == 0)
            errors.append(e)
            eligible += n
        errors = np.concatenate(errors)
        per_sequence[seq.id]["flow"] = summarize_flow(errors, eligible)
        all_errors.append(errors)
        all_eligible += eligible
    return summarize_flow(np.concatenate(all_errors), all_eligible)


def _evaluate_2d(plan: Plan, store: Store, raws: dict, stage: str, per_sequence: dict, key: str = "reflectors2d") -> dict:
    """AP per reflector and mAP at PCK 0.05, before (best candidate) and after filtering, and the c_min sweep."""
    names = None
    n_reflectors = raws[plan.sequences[0].id].sizes["reflector"]
    total = {k: Matches2D(n_reflectors) for k in ("filtered", "unfiltered")}
    per_view: dict[str, Matches2D] = {}  # the filtered estimates of each view, over the sequences
    for seq in plan.sequences:
        raw = raws[seq.id]
        if "gt_reflectors2d" not in raw:
            raise PlanError(f"sequence {seq.id!r} has no 2D reflector ground truth (gt_reflectors2d)")
        seq_matches = {k: Matches2D(n_reflectors) for k in total}
        seq_view = {str(view): Matches2D(n_reflectors) for view in seq.views}
        for view in seq.views:
            est = plan.open(store, stage, seq.id, view)
            est, gt = est.sel(view=view).load(), raw.sel(view=view)
            names = list(est["reflector"].values)
            body, uv, pixels = gt["gt_body"].values, gt["gt_reflectors2d"].values, gt["gt_pixels"].values
            arrays = {kind: (np.stack([est[x].values, est[y].values], axis=-1), est[c].values)  # (frame, reflector, 2)
                      for kind, (x, y, c) in {"filtered": ("x", "y", "confidence"),
                                              "unfiltered": ("candidate_x", "candidate_y",
                                                             "candidate_confidence")}.items()}
            own = (per_view.setdefault(str(view), Matches2D(n_reflectors)), seq_view[str(view)])
            for i in range(est.sizes["frame"]):
                radius = pck_radius(body[i])
                for kind, (xy, confidence) in arrays.items():
                    for matches in (seq_matches[kind], total[kind]) + (own if kind == "filtered" else ()):
                        match_2d(matches, xy[i], confidence[i], uv[i], pixels[i], radius)
        per_sequence[seq.id][key] = {k: summarize_2d(m, names) for k, m in seq_matches.items()}
        per_sequence[seq.id][key]["per_view"] = {view: summarize_2d(m, names) for view, m in seq_view.items()}
    out = {k: summarize_2d(m, names) for k, m in total.items()}
    out["per_view"] = {view: summarize_2d(m, names) for view, m in per_view.items()}
    out["sweep"] = {c: summarize_2d(total["filtered"], names, c_min=c) for c in C_MIN_SWEEP}
    out["stage"] = stage
    return out


def deepmocap_headline(result: dict) -> dict:
    """DeepMoCap's JSON figures of `mocapflow evaluate --json`."""
    out: dict = {}
    if "flow" in result:
        flow = result["flow"]
        out.update({"flow_task": result["task"], "flow_epe_mm": flow["epe_mean_mm"],
                    "flow_epe_median_mm": flow["epe_median_mm"], "flow_coverage": flow["coverage"]})
    if "reflectors2d" in result:
        r = result["reflectors2d"]
        out.update({"map2d": r["filtered"]["map"], "map2d_unfiltered": r["unfiltered"]["map"],
                    "map2d_no_end": r["filtered"]["map_no_end"], "map2d_unfiltered_no_end": r["unfiltered"]["map_no_end"],
                    "precision2d": r["filtered"]["precision"], "recall2d": r["filtered"]["recall"]})
    if "reflectors2d_refined" in result:
        r = result["reflectors2d_refined"]["filtered"]
        out.update({"map2d_refined": r["map"], "map2d_refined_no_end": r["map_no_end"],
                    "precision2d_refined": r["precision"], "recall2d_refined": r["recall"]})
    for kind, (prefix, tail_prefix) in MARKER_PREFIX.items():
        if f"markers_{kind}" in result:
            m = result[f"markers_{kind}"]
            out.update({f"{prefix}err_median_mm": m["median_mm"], f"{prefix}err_mean_mm": m["mean_mm"],
                        f"{prefix}err_p95_mm": m["p95_mm"], f"{prefix}completeness": m["completeness"],
                        f"{prefix}jitter_ms2": m["jitter_ms2"], f"{tail_prefix}p95_mm": m["p95_mm"],
                        f"{tail_prefix}p99_mm": m["p99_mm"], f"{tail_prefix}gross_share": m["gross_share"]})
    if "poses" in result:
        p = result["poses"]
        out.update({"pck3d_20cm": p["pck_20cm"], "pck3d_5cm": p["pck_5cm"], "mae3d_cm": p["mae_cm"],
                    "rmse3d_cm": p["rmse_cm"], "poses_solved": p["solved"]})
    if "plausibility" in result:  # over every view, and the least of any view
        p = result["plausibility"]
        for check in CHECKS:
            shares = [v[check] for v in p["views"].values() if np.isfinite(v[check])]
            out.update({f"plausibility_{check}": p["all"][check],
                        f"plausibility_{check}_worst_view": min(shares) if shares else float("nan")})
    return out


def deepmocap_table(result: dict) -> list[str]:
    """DeepMoCap's tables of `mocapflow evaluate`."""
    lines = []
    if "flow" in result:
        lines += _flow_table(result)
    if "reflectors2d" in result:
        lines += ([""] if lines else []) + _reflectors_table(result)
    if "reflectors2d_refined" in result:
        lines += ([""] if lines else []) + _refined_table(result)
    if any(f"markers_{k}" in result for k in MARKER_PREFIX):
        lines += ([""] if lines else []) + _markers_table(result)
    if "poses" in result:
        lines += ([""] if lines else []) + poses_table(result["poses"])
    if "plausibility" in result:
        lines += ([""] if lines else []) + plausibility_table(result)
    return lines


def plausibility_table(result: dict) -> list[str]:
    """Per sequence and view, the plausibility of its labels; with ground truth, the view's true 2D mAP and the
    share of its lifted labels on their true reflector beside them."""
    p = result["plausibility"]
    truth = any("true_on_reflector" in v for v in p["views"].values())
    lines = [f"plausibility of each view's labels, no ground truth needed ({p['stage']} against {p['poses']}): % of "
             f"its lifted labels within {100 * p['agreement_m']:g} cm of another view's, nearer their own side's "
             f"reflector on the body than the mirrored one, within {100 * p['on_body_m']:g} cm of their reflector on "
             "the body"]
    head = ("sequence", "motion", "view", "labels", "agree %", "left/right %", "on body %")
    head += ("true 2D mAP %", "on true reflector %") if truth else ()
    rows = [head + ("most off the body (% of its labels)",)]
    scored = result.get("reflectors2d", {})
    same = scored.get("stage") == p.get("reflectors")  # the 2D labels scored are those the views lifted
    overall = {"exercise": "", "plausibility": p, "reflectors2d": scored}
    for name, s in list(result["sequences"].items()) + [("all", overall)]:
        if "plausibility" not in s:
            continue
        for view, f in s["plausibility"]["views"].items():
            row = (name, s["exercise"], view, str(f["on_body_n"]), pct(f["agreement"]), pct(f["left_right"]),
                   pct(f["on_body"]))
            if truth:
                true_map = s.get("reflectors2d", {}).get("per_view", {}).get(view, {}).get("map", np.nan) if same \
                    else np.nan
                row += (pct(true_map), pct(f.get("true_on_reflector", np.nan)))
            worst = ", ".join(f"{label} {100 * share:.0f}" for label, share in f["worst"].items())
            rows.append(row + (worst or "-",))
        f = s["plausibility"]["all"]
        true_map = s.get("reflectors2d", {}).get("filtered", {}).get("map", np.nan) if same else np.nan
        rows.append((name, s["exercise"], "all views", str(f["on_body_n"]), pct(f["agreement"]), pct(f["left_right"]),
                     pct(f["on_body"])) + ((pct(true_map), "") if truth else ()) + ("",))
    return lines + format_rows(rows)


def poses_table(p: dict) -> list[str]:
    """Per joint (Table 8 form) and per exercise (Table 7 form) 3D joint accuracy."""
    lines = [f"3D joints ({p['stage']}): MAE / RMSE (cm) and 3D PCK (%) on the 12 joints of Table 8"]
    rows = [("joint", "MAE cm", "PCK@5cm", "PCK@20cm")]
    rows += [(n, f"{j['mae_cm']:.2f}", pct(j["pck_5cm"]), pct(j["pck_20cm"])) for n, j in p["per_joint"].items()]
    rows += [("all", f"{p['mae_cm']:.2f}", pct(p["pck_5cm"]), pct(p["pck_20cm"]))]
    lines += format_rows(rows) + ["", "per exercise"]
    rows = [("exercise", "MAE cm", "RMSE cm", "PCK@5cm", "PCK@20cm", "solved %")]
    rows += [(n, f"{e['mae_cm']:.2f}", f"{e['rmse_cm']:.2f}", pct(e["pck_5cm"]), pct(e["pck_20cm"]), pct(e["solved"]))
             for n, e in p["per_exercise"].items()]
    rows += [("all", f"{p['mae_cm']:.2f}", f"{p['rmse_cm']:.2f}", pct(p["pck_5cm"]), pct(p["pck_20cm"]),
              pct(p["solved"]))]
    return lines + format_rows(rows)


def _markers_table(result: dict) -> list[str]:
    kinds = [k for k in MARKER_PREFIX if f"markers_{k}" in result]
    lines = ["3D reflectors: error against ground truth (mm), share of marker-frames > 10 cm off, completeness, "
             "jitter (mean |acceleration|, m/s^2)"]
    rows = [("sequence", "motion", "markers", "median", "mean", "p95", "p99", "> 10 cm %", "complete %", "jitter",
             "true jitter")]
    for name, s in list(result["sequences"].items()) + [("all", {"exercise": "", **{f"markers_{k}": result[f"markers_{k}"]
                                                                                    for k in kinds}})]:
        for k in kinds:
            m = s[f"markers_{k}"]
            rows.append((name, s["exercise"], f"{k} ({result[f'markers_{k}']['stage']})", f"{m['median_mm']:.1f}",
                         f"{m['mean_mm']:.1f}", f"{m['p95_mm']:.1f}", f"{m['p99_mm']:.1f}",
                         pct(m["gross_share"]), f"{100 * m['completeness']:.2f}",
                         f"{m['jitter_ms2']:.2f}", f"{m['gt_jitter_ms2']:.2f}"))
    lines += format_rows(rows) + ["", "median error per reflector (mm)"]
    rows = [("reflector",) + tuple(kinds)]
    names = result[f"markers_{kinds[0]}"]["per_reflector_median_mm"]
    rows += [(n,) + tuple(f"{result[f'markers_{k}']['per_reflector_median_mm'][n]:.1f}" for k in kinds) for n in names]
    return lines + format_rows(rows)


def _flow_table(result: dict) -> list[str]:
    rows = [("sequence", "motion", "EPE mean mm", "EPE median mm", "EPE p90 mm", "coverage")]
    for name, r in list(result["sequences"].items()) + [("all", {"exercise": "", "flow": result["flow"]})]:
        f = r["flow"]
        rows.append((name, r["exercise"], f"{f['epe_mean_mm']:.2f}", f"{f['epe_median_mm']:.2f}",
                     f"{f['epe_p90_mm']:.2f}", f"{f['coverage']:.3f}"))
    return [f"scene flow ({result['task']}), 3D end-point error on visible body pixels"] + format_rows(rows)


def _reflectors_table(result: dict) -> list[str]:
    r = result["reflectors2d"]
    lines = [f"2D reflectors ({r['stage']}): AP % at PCK 0.05 of the subject's box (Tables 2-5 form)"]
    rows = [("reflector", "AP unfiltered", "AP filtered")]
    rows += [(n, pct(r["unfiltered"]["ap"][n]), pct(r["filtered"]["ap"][n])) for n in r["filtered"]["ap"]]
    rows += [("mAP", pct(r["unfiltered"]["map"]), pct(r["filtered"]["map"])),
             ("mAP without end-reflectors", pct(r["unfiltered"]["map_no_end"]), pct(r["filtered"]["map_no_end"]))]
    lines += format_rows(rows) + ["", "per sequence"]
    rows = [("sequence", "motion", "mAP unfiltered", "mAP filtered", "precision", "recall")]
    for name, s in result["sequences"].items():
        u, f = s["reflectors2d"]["unfiltered"], s["reflectors2d"]["filtered"]
        rows.append((name, s["exercise"], pct(u["map"]), pct(f["map"]), pct(f["precision"]), pct(f["recall"])))
    lines += format_rows(rows) + ["", "c_min sweep of the filtered estimates (Fig. 12 form)"]
    rows = [("c_min", "mAP", "precision", "recall", "estimates")]
    rows += [(f"{c:.1f}", pct(s["map"]), pct(s["precision"]), pct(s["recall"]), str(s["estimates"]))
             for c, s in r["sweep"].items()]
    return lines + format_rows(rows)


def _refined_table(result: dict) -> list[str]:
    """AP of each view's own estimates (after filtering) against the same estimates refined from the poses."""
    refined = result["reflectors2d_refined"]["filtered"]
    own = result["reflectors2d"]["filtered"] if "reflectors2d" in result else {}
    lines = [f"2D reflectors refined from the solved poses ({result['reflectors2d_refined']['stage']}): AP % at PCK 0.05"]
    rows = [("reflector", "AP filtered", "AP refined")]
    rows += [(n, pct(own.get("ap", {}).get(n, np.nan)), pct(ap)) for n, ap in refined["ap"].items()]
    rows += [(label, pct(own.get(k, np.nan)), pct(refined[k])) for label, k in (
        ("mAP", "map"), ("mAP without end-reflectors", "map_no_end"), ("precision", "precision"), ("recall", "recall"))]
    lines += format_rows(rows) + ["", "per sequence"]
    rows = [("sequence", "motion", "mAP filtered", "mAP refined", "precision", "recall")]
    for name, s in result["sequences"].items():
        f = s["reflectors2d_refined"]["filtered"]
        rows.append((name, s["exercise"], pct(s["reflectors2d"]["filtered"]["map"]) if "reflectors2d" in s else "-",
                     pct(f["map"]), pct(f["precision"]), pct(f["recall"])))
    return lines + format_rows(rows)


EVALUATOR = Evaluator("deepmocap", applies, evaluate_deepmocap, deepmocap_headline, deepmocap_table)
