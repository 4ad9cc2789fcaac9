"""`mocapflow evaluate`: accuracy of the catalog's stages on its evaluation split, against studio ground truth.

Missing partitions are computed first (through the same engine as `mocapflow run`); then each
sequence's artifacts are read view by view and scored by the pure metrics of tasks/evaluation.py.
"""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.plan import Plan, build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.schemas import get_schema
from mocapflow.tasks.evaluation import flow_errors, summarize_flow


def evaluation_plan(catalog, sequences: str | None) -> Plan:
    pattern = sequences or catalog.evaluation.get("sequences")
    return build_plan(catalog, pattern)


def evaluate(catalog, plan: Plan, store: Store) -> dict:
    """Figures per sequence and overall for every stage the catalog has and the studio can score."""
    if "flow" not in catalog.stages:
        raise PlanError("the catalog has no `flow` stage to evaluate; add one (see catalog.yaml)")
    if not plan.sequences:
        raise PlanError("the evaluation split selects no sequence; check evaluation.sequences or --sequences")
    per_sequence, all_errors, all_eligible = {}, [], 0
    for seq in plan.sequences:
        frames_item = plan.items[f"frames/{seq.id}"]
        raw = store.open("frames", frames_item.key, get_schema("raw_sequence"))
        if "gt_scene_flow_prev" not in raw or "gt_body" not in raw:
            raise PlanError(f"sequence {seq.id!r} has no scene-flow ground truth (gt_scene_flow_prev, gt_body); "
                            "evaluate on studio sequences")
        errors, eligible = [], 0
        for view in seq.views:
            item = plan.items[f"flow/{seq.id}/{view}"]
            est = store.open("flow", item.key, get_schema("scene_flow")).sel(view=view)
            gt = raw.sel(view=view)
            e, n = flow_errors(est["flow"].values, est["valid"].values, gt["gt_scene_flow_prev"].values,
                               gt["gt_body"].values, gt["depth"].values, est["frame"].values == 0)
            errors.append(e)
            eligible += n
        errors = np.concatenate(errors)
        per_sequence[seq.id] = {"flow": summarize_flow(errors, eligible), "exercise": raw.attrs.get("exercise", "")}
        all_errors.append(errors)
        all_eligible += eligible
    overall = summarize_flow(np.concatenate(all_errors), all_eligible)
    return {"task": catalog.stages["flow"].task, "sequences": per_sequence, "flow": overall}


def headline(result: dict) -> dict:
    """The JSON figures `mocapflow evaluate --json` prints."""
    flow = result["flow"]
    return {"flow_task": result["task"], "flow_epe_mm": flow["epe_mean_mm"], "flow_epe_median_mm": flow["epe_median_mm"],
            "flow_coverage": flow["coverage"], "sequences": len(result["sequences"])}


def table(result: dict) -> str:
    rows = [("sequence", "motion", "EPE mean mm", "EPE median mm", "EPE p90 mm", "coverage")]
    for name, r in result["sequences"].items():
        f = r["flow"]
        rows.append((name, r["exercise"], f"{f['epe_mean_mm']:.2f}", f"{f['epe_median_mm']:.2f}",
                     f"{f['epe_p90_mm']:.2f}", f"{f['coverage']:.3f}"))
    f = result["flow"]
    rows.append(("all", "", f"{f['epe_mean_mm']:.2f}", f"{f['epe_median_mm']:.2f}", f"{f['epe_p90_mm']:.2f}",
                 f"{f['coverage']:.3f}"))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = [f"scene flow ({result['task']}), 3D end-point error on visible body pixels"]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    return "\n".join(lines)
