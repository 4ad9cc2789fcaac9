"""UUO's solver on the house's Levenberg-Marquardt body fitter against L-BFGS, on a tuning split, and the choice.

A tuning split of procedural exercises (never the CMU clips of the held-out split, nor their motions: no walk,
jumping jack, squat, jog or knee raise), one subject seed each, 40 markers on the body recorded as the studio
records them by default (occlusion, breaks, ghosts) with the held-out split's dropouts, the realistic simulated
prior; every take through the stages as a catalog runs them (four root-yaw hypotheses, the best refined), once per
solver, one thread:

    python benchmarks/uuo_fitter.py [--frames 48] [--takes 6] [--variants lm,lbfgs,lbfgs+lm,lm5]

A variant names the pose fit's solver and inverse kinematics' (and the refinement's): ``lm`` and ``lbfgs`` both
on one, ``lbfgs+lm`` the pose fit on L-BFGS and the rest on Levenberg-Marquardt, ``lmN`` every fit on
Levenberg-Marquardt with N steps per pose-fit round. Prints per take and variant the MPJPE of the refined joints
against the truth, the facing error and the CPU seconds; then per variant the median and 90th percentile over
takes, the takes turned around, the median CPU time, and the default it chooses: the variant of least median
MPJPE, the fastest of those within ``--tie-mm`` of it.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

TUNING = ("side_reaches", "elbow_flexion", "kick_box_kicking", "side_step_knee_elbow", "single_arm_raise",
          "forward_lunge_left_right", "butt_kicks_left_right", "closing_arms_above_head", "front_kick",
          "dance_swing")


def make_take(motion: str, seed: int, frames: int, part: str = "body"):
    """A tuning take: 40 markers on the whole body, or 20 on a part (the held-out split's partial layouts)."""
    from mocapflow.systems.studio import specs as studio_io
    from mocapflow.tasks.deepmocap.film import synth
    from mocapflow.tasks.uuo import takes as uuo
    from mocapflow.tasks.uuo import prior, segmentation

    spec, _, _ = studio_io.make_spec({"motion": motion, "seed": seed, "frames": frames, "body": "mesh", "views": 1},
                                     "tuning", lambda p: p)
    rig = synth.build_rig(spec, None)
    layout = uuo.layout(rig.body, np.random.default_rng([seed, 3]), 40 if part == "body" else 20, part)
    captured = uuo.record(rig.body, layout, rig.take.posed.vertices[:rig.n_frames], uuo.MarkerFaults(dropout=0.002),
                          np.random.default_rng([seed, 4]), spec.fps)  # the studio's optical faults, and dropouts
    take = uuo.marker_dataset(rig.body, layout, captured, rig.take, spec.fps, 0, rig.n_frames)
    return take, segmentation.rigid_segments(take, segmentation.SegmentConfig()), \
        prior.simulated_prior(take, prior.SimulatedPriorConfig(seed=seed))


def configs(variant: str):
    """The stages' settings of a variant (the module's text).  -> (HypothesisConfig, RefineConfig)"""
    from mocapflow.tasks.uuo import solve

    pose_solver, ik_solver = variant.split("+") if "+" in variant else (variant, variant)
    steps = {}
    if pose_solver.startswith("lm") and pose_solver != "lm":
        pose_solver, ik_solver, steps = "lm", "lm", {"steps": int(pose_solver[2:])}
    base, refine = solve.HypothesisConfig(), solve.RefineConfig()
    return (dataclasses.replace(base, pose_fit=dataclasses.replace(base.pose_fit, solver=pose_solver, **steps),
                                ik=dataclasses.replace(base.ik, solver=ik_solver)),
            dataclasses.replace(refine, ik=dataclasses.replace(refine.ik, solver=ik_solver)))


def solve_take(take, segments, body_prior, variant: str):
    """The catalog's stages: four hypotheses, the best refined, on ``variant``.  -> (joints, CPU s)"""
    from mocapflow.tasks.uuo import solve

    hypothesis, refine = configs(variant)
    start = time.process_time()
    hypotheses = [solve.solve_hypothesis(take, segments, body_prior, dataclasses.replace(hypothesis, yaw_deg=yaw))
                  for yaw in (0.0, 90.0, 180.0, 270.0)]
    out = solve.best_hypothesis(take, *hypotheses, config=refine)
    return out["joints"].values, time.process_time() - start


def main() -> None:
    import torch

    from mocapflow.tasks.shared.body import JOINT_NAMES
    from mocapflow.tasks.uuo import metrics

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--takes", type=int, default=6)
    ap.add_argument("--variants", default="lm,lbfgs,lbfgs+lm,lm5")
    ap.add_argument("--tie-mm", type=float, default=2.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    solvers = args.variants.split(",")
    rows = {s: [] for s in solvers}
    for i, motion in enumerate(TUNING[:args.takes]):
        take, segments, body_prior = make_take(motion, 7300 + i, args.frames)
        truth = take["gt_joints"].values
        for solver in solvers:
            joints, seconds = solve_take(take, segments, body_prior, solver)
            error = 1000 * metrics.mpjpe(joints, truth)
            facing = metrics.facing_error_deg(joints, truth, list(JOINT_NAMES))
            rows[solver].append((error, facing, seconds))
            print(f"{motion:26s} {solver:9s} MPJPE {error:7.1f} mm  facing {facing:5.1f} deg  {seconds:6.1f} s CPU",
                  flush=True)
    summary = {}
    for solver, r in rows.items():
        errors = np.array([x[0] for x in r])
        summary[solver] = (float(np.median(errors)), statistics.median(x[2] for x in r))
        print(f"{solver}: MPJPE median {np.median(errors):.1f} mm, p90 {np.percentile(errors, 90):.1f} mm; turned "
              f"{sum(x[1] > metrics.TURNED_DEG for x in r)} of {len(r)}; CPU median {summary[solver][1]:.1f} s")
    best = min(summary, key=lambda s: summary[s][0])
    near = [s for s in summary if summary[s][0] <= summary[best][0] + args.tie_mm]
    print(f"chosen default: {min(near, key=lambda s: summary[s][1])}")


if __name__ == "__main__":
    main()
