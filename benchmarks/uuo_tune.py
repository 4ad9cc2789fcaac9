"""UUO's choice settings decided on a tuning split, and printed: the rule among hypotheses and the floor term.

The tuning split is procedural exercises (never the CMU clips of the held-out split, nor their motions: no walk,
jumping jack, squat, jog or knee raise; the motions of benchmarks/uuo_fitter.py), one subject seed each, recorded
as the studio records by default (occlusion, breaks, ghosts, the held-out split's dropouts) with the realistic
simulated prior: whole-body layouts of 40 markers and partial ones (a leg, an arm). Every take goes through the
stages a catalog runs (the screen, its four best placements solved), once per floor weight; then every setting of
the rule among hypotheses (``close``, ``split_deg``, ``hinge_weight``, ``travel_deg``) is applied to the solved
hypotheses and scored against the truth:

    python benchmarks/uuo_tune.py [--frames 48] [--takes 8] [--floor-weights 10,0] [--jobs 2]

The rule kept: fewest takes turned or mirrored, then the least median MPJPE of the chosen hypothesis (stage 4),
then the nearest to today's defaults. Then the floor weight: the same order with the rule kept. ``call_deg`` (when
the report says a take is too close to call) is printed as the share of wrong takes it flags and of right takes it
flags needlessly, for a few values; the one chosen flags every wrong take it can at the least cost. Each line of the
choice is printed with the figures it rests on.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import os
from concurrent.futures import ProcessPoolExecutor

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

from uuo_fitter import TUNING, make_take  # noqa: E402  (the tuning motions and their takes)

LAYOUTS = ("body", "body", "body", "body", "body", "body", "left_leg", "right_arm", "left_shoulder", "body")
GRID = {"close": (1.25, 1.5, 2.0, 3.0), "split_deg": (0.0, 50.0, 100.0, 200.0),
        "hinge_weight": (0.0, 0.5, 1.0, 2.0), "travel_deg": (0.0, 50.0)}
CALLS = (2.0, 5.0, 10.0, 20.0)


def solve_hypotheses(job: tuple) -> dict:
    """One take (motion, seed, frames, layout) solved from the screen's four placements with a floor weight.
    -> per hypothesis its attrs and figures against the truth"""
    import torch

    from mocapflow.systems.uuo.evaluate import score_take, take_truth
    from mocapflow.tasks.uuo import hypotheses, solve

    torch.set_num_threads(1)
    motion, seed, frames, layout, floor_weight = job
    take, segments, body_prior = make_take(motion, seed, frames, layout)
    base = solve.HypothesisConfig()
    config = dataclasses.replace(base, floor=floor_weight > 0,
                                 pose_fit=dataclasses.replace(base.pose_fit, floor_weight=floor_weight or 1.0),
                                 ik=dataclasses.replace(base.ik, floor_weight=floor_weight or 1.0))
    screen = solve.screen_hypotheses(take, segments, body_prior, hypotheses.ScreenConfig())
    truth = take_truth(take)
    out = []
    for rank in range(4):
        h = solve.solve_screened(take, segments, body_prior, screen, solve.ScreenedConfig(rank=rank, solve=config))
        score = score_take(truth, h)
        out.append({"attrs": {k: h.attrs[k] for k in ("chamfer", "prior_pose_deg", "side_split", "mirror",
                                                     "matched_yaw_deg", "hyperextension_deg", "backward_travel")},
                    "mpjpe_mm": score["mpjpe_mm"], "wrong": bool(score["turned"] or score["mirrored"])})
    return {"take": f"{motion}/{layout}", "floor_weight": floor_weight, "hypotheses": out}


def apply_rule(takes: list[dict], config) -> tuple[int, float, list[bool], list[float]]:
    """The rule applied to every take's solved hypotheses.  -> (wrong takes, median MPJPE, wrong per take, margin
    per take)"""
    import xarray as xr

    from mocapflow.tasks.uuo import solve

    wrong, errors, margins = [], [], []
    for t in takes:
        choice = solve.choose([xr.Dataset(attrs=h["attrs"]) for h in t["hypotheses"]], config)
        wrong.append(t["hypotheses"][choice.index]["wrong"])
        errors.append(t["hypotheses"][choice.index]["mpjpe_mm"])
        margins.append(choice.margin_deg)
    return sum(wrong), float(np.median(errors)), wrong, margins


def main() -> None:
    from mocapflow.tasks.uuo import solve

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--takes", type=int, default=8)
    ap.add_argument("--floor-weights", default="10,0")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    floors = [float(w) for w in args.floor_weights.split(",")]
    jobs = [(motion, 7300 + i, args.frames, LAYOUTS[i % len(LAYOUTS)], w)
            for i, motion in enumerate(TUNING[:args.takes]) for w in floors]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(solve_hypotheses, jobs))
    by_floor = {w: [r for r in results if r["floor_weight"] == w] for w in floors}
    for r in results:
        print(f"{r['take']:40s} floor {r['floor_weight']:4.1f}  " + "  ".join(
            f"[{h['attrs']['matched_yaw_deg']:6.1f}{'m' if h['attrs']['mirror'] else ' '} ch "
            f"{1e4 * h['attrs']['chamfer']:5.2f} hx {h['attrs']['hyperextension_deg']:5.1f} "
            f"{h['mpjpe_mm']:6.1f} mm{' WRONG' if h['wrong'] else ''}]" for h in r["hypotheses"]), flush=True)

    default = solve.RefineConfig()
    today = {k: getattr(default, k) for k in GRID}

    def rank(values: dict, takes: list[dict]):
        config = dataclasses.replace(default, **values)
        wrong, median, _, _ = apply_rule(takes, config)
        distance = sum(abs(np.log((values[k] + 1) / (today[k] + 1))) for k in GRID)
        return (wrong, round(median, 1), distance)

    tuning = by_floor[floors[0]]
    settings = [dict(zip(GRID, combo)) for combo in itertools.product(*GRID.values())]
    scored = sorted(((rank(s, tuning), s) for s in settings), key=lambda x: x[0])
    (wrong, median, _), rule = scored[0]
    print(f"rule today {today}: {rank(today, tuning)[:2]} (takes turned or mirrored, median MPJPE mm)")
    print(f"chosen rule: {rule}: {wrong} takes turned or mirrored of {len(tuning)}, median {median} mm")
    for w in floors:
        print(f"floor weight {w}: {rank(rule, by_floor[w])[:2]} with the chosen rule")
    floor = min(floors, key=lambda w: rank(rule, by_floor[w])[:2])
    print(f"chosen floor weight: {floor}")
    takes = by_floor[floor]
    _, _, wrong_takes, margins = apply_rule(takes, dataclasses.replace(default, **rule))
    best_call, best_cost = default.call_deg, None
    for call in CALLS:
        flagged = [m <= call for m in margins]
        caught = sum(f and w for f, w in zip(flagged, wrong_takes))
        needless = sum(f and not w for f, w in zip(flagged, wrong_takes))
        print(f"call_deg {call}: flags {caught} of {sum(wrong_takes)} wrong takes, {needless} of "
              f"{len(takes) - sum(wrong_takes)} right ones")
        cost = (-caught, needless)
        if best_cost is None or cost < best_cost:
            best_call, best_cost = call, cost
    print(f"chosen call_deg: {best_call}")


if __name__ == "__main__":
    main()
