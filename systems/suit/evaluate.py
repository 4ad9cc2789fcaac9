"""`mocapflow evaluate` for the checkerboard-suit stages against the studio's truth (tasks/suit/metrics.py).

Per catalog stage that the suit chain has: CornerdetNet's detections (share of visible corners found within
1.5 px, false detections), RejectorNet's and RecogNet's accuracy over the candidate quads, the labelled corners
(share of readable and of visible corners labelled right, wrong labels, localisation error), the triangulated
corners (3D error, reprojection error percentiles) and the filled suit (3D error of observed and of filled
corners: the studio knows where every hidden corner is).
"""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline.catalog import final_stage, stage_writing
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.registry import Evaluator
from mocapflow.presentation.evaluate import format_rows
from mocapflow.tasks.suit import metrics
from mocapflow.tasks.suit.pattern import ALPHABET

TRUTH = ("gt_corners2d", "gt_visible", "gt_readable", "gt_corners", "square_corners", "code")


def suit_stages(catalog) -> dict[str, str]:
    """What to score: per schema of the suit chain the catalog's last stage writing it (for ``suit_labels`` the
    last refining them, as grow_labels does, and ``suit_labels_read`` the labels it refined); ``suit_points`` the last
    triangulation with the exact cameras and ``suit_points_perturbed`` the last with a calibration error (not a
    hold-out either); ``suit_filled_hidden`` a filling whose points had single observations hidden and
    ``suit_filled_occluded`` one whose points had patches hidden (tasks/suit/holdout.py); ``suit_filled`` the last
    filling of exactly triangulated points themselves."""
    schemas = ("suit_images", "suit_corners", "suit_quads", "suit_codes")
    out = {s: stage_writing(catalog, s) for s in schemas if stage_writing(catalog, s) is not None}
    if final_stage(catalog, "suit_labels") is not None:  # the labels handed on (grown, where a stage grows them)
        out["suit_labels"] = final_stage(catalog, "suit_labels")
        if stage_writing(catalog, "suit_labels") not in (None, out["suit_labels"]):
            out["suit_labels_read"] = stage_writing(catalog, "suit_labels")  # as the quads' codes named them
    for s in catalog.stages.values():
        if s.spec.output == "suit_points" and "suit_points" not in s.spec.inputs.values():
            out["suit_points_perturbed" if _perturbed(s) else "suit_points"] = s.name
    for s in catalog.stages.values():
        if s.spec.output != "suit_filled":
            continue
        source = catalog.stages[s.inputs["points"]]
        if "suit_points" in source.spec.inputs.values():  # a hold-out
            out["suit_filled_occluded" if getattr(source.params, "shape", "") == "patch" else
                "suit_filled_hidden"] = s.name
        elif not _perturbed(source):
            out["suit_filled"] = s.name
    return out


def _perturbed(stage) -> bool:
    return getattr(stage.params, "calibration_error_px", 0.0) > 0


def plan_input(plan, stage: str, role: str = "points") -> str:
    """The upstream stage feeding ``role`` of ``stage``."""
    item = next(i for i in plan.items.values() if i.partition.stage == stage)
    return item.upstream[role].stage


def applies(catalog) -> bool:
    """A suit stage besides the images."""
    return len(suit_stages(catalog)) >= 2


def evaluate(catalog, plan, store, per_sequence: dict, thorough: bool = True) -> dict:
    """The suit figures of `mocapflow evaluate` (``result["suit"]``)."""
    return {"suit": evaluate_suit(plan, store, suit_stages(catalog), per_sequence)}


def evaluate_suit(plan, store, stages: dict[str, str], per_sequence: dict) -> dict:
    if "suit_images" not in stages:
        raise PlanError("the catalog has suit stages but no stage writing suit_images to score them against")
    sums: dict = {k: [] for k in ("detect", "quads", "labels", "labels_read", "points", "points_perturbed", "reproj", "filled",
                                  "observed", "hidden", "occluded", "wrong_3d")}
    for seq in plan.sequences:
        images = plan.open(store, stages["suit_images"], seq.id)
        missing = [v for v in TRUTH if v not in images]
        if missing:
            raise PlanError(f"sequence {seq.id!r} has no suit ground truth ({', '.join(missing)}); evaluate on studio "
                            "suit takes")
        truth = images[list(TRUTH)].load()
        seq_sums = {k: [] for k in sums}
        seq_sums["wrong_masks"] = {}
        for v, view in enumerate(seq.views):
            _score_view(plan, store, stages, seq.id, view, truth.isel(view=v), seq_sums)
        _score_3d(plan, store, stages, seq.id, truth, seq_sums)
        per_sequence.setdefault(seq.id, {})["suit"] = _figures(seq_sums)
        for k in sums:
            sums[k] += seq_sums[k]
    out = _figures(sums)
    out["stages"] = stages
    return out


def _score_view(plan, store, stages, seq_id, view, truth, sums) -> None:
    gt_xy, visible = truth["gt_corners2d"].values, truth["gt_visible"].values  # (frame, corner, 2), (frame, corner)
    for key in ("labels_read", "labels"):
        if f"suit_{key}" in stages:
            lab = plan.open(store, stages[f"suit_{key}"], seq_id, view).sel(view=view).load()
            xy = np.stack([lab["x"].values, lab["y"].values], axis=-1)
            sums[key].append(metrics.label_counts(xy, gt_xy, visible, truth["gt_readable"].values))
    if "suit_labels" in stages:
        sums["wrong_masks"][view] = metrics.wrong_labels(xy, gt_xy, visible)  # (frame, corner), the final labels
    if "suit_corners" in stages:
        det = plan.open(store, stages["suit_corners"], seq_id, view).sel(view=view).load()
        dxy = np.stack([det["x"].values, det["y"].values], axis=-1)  # (frame, detection, 2)
        sums["detect"] += [metrics.detection_counts(dxy[f], gt_xy[f], visible[f]) for f in range(len(dxy))]
        if "suit_quads" in stages and "suit_codes" in stages:
            quads = plan.open(store, stages["suit_quads"], seq_id, view).sel(view=view)["detections"].values
            codes = plan.open(store, stages["suit_codes"], seq_id, view).sel(view=view).load()
            for f in range(len(dxy)):
                square, rotation = metrics.quad_truth(dxy[f], quads[f], gt_xy[f], visible[f],
                                                      truth["square_corners"].values)
                real = quads[f][:, 0] >= 0
                sums["quads"].append(_quad_counts(square[real], rotation[real], codes.isel(frame=f), real,
                                                  code_numbers(truth["code"].values)))


def code_numbers(codes) -> np.ndarray:
    """Two-letter codes as RecogNet's numbers: first * 25 + second character's place in the alphabet."""
    return np.array([ALPHABET.index(c[0]) * len(ALPHABET) + ALPHABET.index(c[1]) for c in codes])


def _quad_counts(square, rotation, codes, real, numbers) -> dict:
    """RejectorNet: accepted vs a true coded square in its upright order; RecogNet: the code of accepted true ones."""
    accepted, turned = codes["accepted"].values[real], codes["rotation"].values[real]
    code = codes["code"].values[real]
    upright = (square >= 0) & (turned == rotation)
    read = accepted & upright
    return {"quads": int(real.sum()), "true": int((square >= 0).sum()), "accepted": int(accepted.sum()),
            "true_accepted": int(read.sum()), "false_accepted": int((accepted & ~upright).sum()),
            "read_right": int((code[read] == numbers[square[read]]).sum())}


def _score_3d(plan, store, stages, seq_id, truth, sums) -> None:
    gt = truth["gt_corners"].values.astype(np.float64)  # (frame, corner, 3)
    if "suit_points" in stages:
        pts = plan.open(store, stages["suit_points"], seq_id).load()
        sums["points"].append(metrics.errors_mm(pts["position"].values, gt))
        err, kept = pts["error"].values, pts["kept"].values
        sums["reproj"].append(err[kept & np.isfinite(err)])
        if sums["wrong_masks"]:  # wrong labels a triangulated corner was solved from: they reached 3D
            views = [str(v) for v in pts["view"].values]
            wrong = np.stack([sums["wrong_masks"].get(v, np.zeros(kept[:, 0].shape, bool)) for v in views], axis=1)
            sums["wrong_3d"].append(np.array([int((kept & wrong).sum())]))
    if "suit_filled" in stages:
        filled = plan.open(store, stages["suit_filled"], seq_id).load()
        observed = filled["observed"].values
        sums["filled"].append(metrics.errors_mm(filled["position"].values, gt, ~observed))
        sums["observed"].append(metrics.errors_mm(filled["position"].values, gt, observed))
    if "suit_points_perturbed" in stages:
        pts = plan.open(store, stages["suit_points_perturbed"], seq_id).load()
        sums["points_perturbed"].append(metrics.errors_mm(pts["position"].values, gt))
    for key, stage in (("hidden", "suit_filled_hidden"), ("occluded", "suit_filled_occluded")):
        if stage in stages:
            filled = plan.open(store, stages[stage], seq_id).load()
            hidden = plan.open(store, plan_input(plan, stages[stage]), seq_id)["hidden"].values
            sums[key].append(metrics.errors_mm(filled["position"].values, gt, hidden & ~filled["observed"].values))


def _figures(sums: dict) -> dict:
    out: dict = {}
    if sums["detect"]:
        d = sums["detect"]
        visible = sum(c.visible for c in d)
        out["corners"] = {"found": sum(c.found for c in d) / max(visible, 1), "visible": visible,
                          "false_per_image": sum(c.false for c in d) / len(d)}
    if sums["quads"]:
        out["quads"] = _network_figures(sums["quads"])
    for key in ("labels", "labels_read"):
        if sums[key]:
            out[key] = _label_figures(sums[key])
    if sums["wrong_3d"]:
        out["wrong_labels_in_3d"] = int(np.sum(sums["wrong_3d"]))
    for key in ("points", "points_perturbed", "reproj", "filled", "observed", "hidden", "occluded"):
        if sums[key]:
            out[key] = metrics.summary(np.concatenate(sums[key]))
    if sums["points"]:  # a corner put somewhere else: what a wrong label that reached 3D would do
        out["points"]["over_5mm"] = int((np.concatenate(sums["points"]) > 5.0).sum())
    return out


def _label_figures(lab: list) -> dict:
    loc = np.concatenate([c.loc_error_px for c in lab])
    return {"readable_found": sum(c.readable_found for c in lab) / max(sum(c.readable for c in lab), 1),
            "visible_found": sum(c.visible_found for c in lab) / max(sum(c.visible for c in lab), 1),
            "labelled": sum(c.labelled for c in lab), "wrong": sum(c.wrong for c in lab),
            "per_image": sum(c.labelled for c in lab) / max(len(lab), 1),
            "loc_error_px": metrics.summary(loc),
            "loc_error_all_px": metrics.summary(np.concatenate([c.loc_error_all_px for c in lab]))}


def _network_figures(rows: list[dict]) -> dict:
    keys = ("quads", "true", "accepted", "true_accepted", "false_accepted", "read_right")
    total = {k: sum(r[k] for r in rows) for k in keys}
    return {**total, "rejector_recall": total["true_accepted"] / max(total["true"], 1),
            "rejector_precision": total["true_accepted"] / max(total["accepted"], 1),
            "recog_accuracy": total["read_right"] / max(total["true_accepted"], 1)}


def suit_headline(result: dict) -> dict:
    """`--json` figures of the suit chain."""
    out = {}
    result = result.get("suit", {})
    if "labels" in result:
        lab = result["labels"]
        out.update({"suit_detect_rate": lab["readable_found"], "suit_visible_rate": lab["visible_found"],
                    "suit_wrong_labels": lab["wrong"], "suit_wrong_label_rate": lab["wrong"] / max(lab["labelled"], 1),
                    "suit_loc_err_px": lab["loc_error_px"]["mean"],
                    "suit_loc_err_all_median_px": lab["loc_error_all_px"]["median"],
                    "suit_loc_err_all_p99_px": lab["loc_error_all_px"]["p99"]})
    if "labels_read" in result:  # the labels as read, before a stage grew them
        lab = result["labels_read"]
        out.update({"suit_detect_rate_read": lab["readable_found"], "suit_visible_rate_read": lab["visible_found"],
                    "suit_wrong_label_rate_read": lab["wrong"] / max(lab["labelled"], 1)})
    if "points" in result:
        out["suit_err3d_median_mm"] = result["points"]["median"]
        out["suit_err3d_over_5mm"] = result["points"]["over_5mm"]
    if "wrong_labels_in_3d" in result:
        out["suit_wrong_labels_in_3d"] = result["wrong_labels_in_3d"]
    if "points_perturbed" in result:
        out["suit_err3d_perturbed_median_mm"] = result["points_perturbed"]["median"]
    if "hidden" in result:
        out["suit_fill_err_median_mm"] = result["hidden"]["median"]
    if "occluded" in result:
        out["suit_fill_occluded_median_mm"] = result["occluded"]["median"]
    if "filled" in result:
        out["suit_fill_all_err_median_mm"] = result["filled"]["median"]
    return out


def suit_table(result: dict) -> list[str]:
    if "suit" not in result:
        return []
    result = result["suit"]
    rows = [("suit", "figure", "value")]
    if "corners" in result:
        c = result["corners"]
        rows += [("corners", "visible corners found (1.5 px)", f"{c['found']:.1%}"),
                 ("corners", "false detections per image", f"{c['false_per_image']:.1f}")]
    if "quads" in result:
        q = result["quads"]
        rows += [("quads", "candidates / true coded squares", f"{q['quads']} / {q['true']}"),
                 ("quads", "RejectorNet recall / precision",
                  f"{q['rejector_recall']:.1%} / {q['rejector_precision']:.1%}"),
                 ("quads", "RecogNet codes read right", f"{q['recog_accuracy']:.2%} of {q['true_accepted']}")]
    if "labels" in result:
        lab = result["labels"]
        rows += [("labels", "readable corners labelled right", f"{lab['readable_found']:.1%}"),
                 ("labels", "visible corners labelled right", f"{lab['visible_found']:.1%}"),
                 ("labels", "wrong labels / labels", f"{lab['wrong']} / {lab['labelled']}"),
                 ("labels", "localisation error mean / p99 px (right labels)",
                  f"{lab['loc_error_px']['mean']:.3f} / {lab['loc_error_px']['p99']:.3f}"),
                 ("labels", "localisation error median / p99 px (every label)",
                  f"{lab['loc_error_all_px']['median']:.3f} / {lab['loc_error_all_px']['p99']:.3f}")]
    if "labels_read" in result:
        lab = result["labels_read"]
        rows += [("labels read", "readable / visible corners labelled right, before growing",
                  f"{lab['readable_found']:.1%} / {lab['visible_found']:.1%}"),
                 ("labels read", "wrong labels / labels, before growing", f"{lab['wrong']} / {lab['labelled']}")]
    if "wrong_labels_in_3d" in result:
        rows.append(("points", "wrong labels (over 2 px off) a corner was triangulated from",
                     str(result["wrong_labels_in_3d"])))
    if "points" in result:
        rows.append(("points", "corners triangulated over 5 mm from the truth", str(result["points"]["over_5mm"])))
    for key, what, unit in (("points", "3D error of observed corners", "mm"),
                            ("points_perturbed", "3D error of observed corners, calibration perturbed", "mm"),
                            ("reproj", "reprojection error", "px"), ("observed", "filled suit: observed corners", "mm"),
                            ("filled", "filled suit: filled corners", "mm"),
                            ("hidden", "filled suit: hidden observations", "mm"),
                            ("occluded", "filled suit: occluded patches", "mm")):
        if key in result:
            s = result[key]
            rows.append((key, f"{what} median / p95 / p99 {unit}",
                         f"{s['median']:.2f} / {s['p95']:.2f} / {s['p99']:.2f} (n={s['n']})"))
    return format_rows(rows)


EVALUATOR = Evaluator("suit", applies, evaluate, suit_headline, suit_table)
