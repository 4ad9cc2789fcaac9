"""UUO solver probe: one studio take of a procedural exercise (never a CMU test clip) through every solver stage.

    python benchmarks/uuo_solver.py [--motion side_reaches] [--markers 40] [--part body] [--frames 120]
                                    [--seed 11] [--rotation-deg 8] [--yaws 0,90,180,270]

Prints, per root-yaw hypothesis, its time, its chamfer (Eq. 3) and the MPJPE of the 20 joints after part matching,
the chamfer pose fit and inverse kinematics (raw and after a rigid registration with scale), then the chosen
hypothesis refined: MPJPE, the velocity error per frame and the share of real markers labelled. A tuning
probe on the studio's exercises, not the held-out benchmark.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    from mocapflow.systems.studio import specs as studio_io
    from mocapflow.tasks.deepmocap.film import synth
    from mocapflow.tasks.uuo import takes as uuo
    from mocapflow.tasks.uuo import prior, segmentation, solve

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--motion", default="side_reaches")
    ap.add_argument("--markers", type=int, default=40)
    ap.add_argument("--part", default="body")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--rotation-deg", type=float, default=8.0)
    ap.add_argument("--yaws", default="0,90,180,270")
    args = ap.parse_args()
    spec, _, _ = studio_io.make_spec({"motion": args.motion, "seed": args.seed, "frames": args.frames,
                                      "body": "mesh", "views": 1}, "probe", lambda p: p)
    rig = synth.build_rig(spec, None)
    layout = uuo.layout(rig.body, np.random.default_rng([args.seed, 3]), args.markers, args.part)
    captured = uuo.record(rig.body, layout, rig.take.posed.vertices[:rig.n_frames], uuo.MarkerFaults(dropout=0.002),
                          np.random.default_rng([args.seed, 4]), spec.fps)  # the studio's optical faults, and dropouts
    take = uuo.marker_dataset(rig.body, layout, captured, rig.take, spec.fps, 0, rig.n_frames)
    segments = segmentation.rigid_segments(take, segmentation.SegmentConfig())
    body_prior = prior.simulated_prior(take, prior.SimulatedPriorConfig(rotation_deg=args.rotation_deg,
                                                                        seed=args.seed))
    truth = take["gt_joints"].values
    print(f"{args.motion}, {args.frames} frames, {args.markers} markers on {args.part}: "
          f"{take.sizes['marker']} trajectories, {segments.attrs['segments']} rigid groups; prior "
          f"{body_prior.attrs['registered_mpjpe_mm']:.1f} mm MPJPE after rigid registration with scale")
    hypotheses = []
    for yaw in (float(y) for y in args.yaws.split(",")):
        t0 = time.perf_counter()
        h = solve.solve_hypothesis(take, segments, body_prior, solve.HypothesisConfig(yaw_deg=yaw))
        rows = []
        for stage in ("matching", "pose_fit", "ik"):
            joints = h["stage_joints"].sel(stage=stage).values
            rows.append(f"{stage} {1000 * np.linalg.norm(joints - truth, axis=-1).mean():.0f}"
                        f" ({1000 * prior.registered_mpjpe(joints, truth):.0f} registered)")
        print(f"yaw {yaw:5.0f}: {time.perf_counter() - t0:6.1f} s, chamfer {h.attrs['chamfer']:.2e} m^2, "
              f"{len(h.attrs['parts'])} parts, MPJPE mm: " + ", ".join(rows))
        hypotheses.append(h)
    t0 = time.perf_counter()
    out = solve.best_hypothesis(take, *hypotheses, config=solve.RefineConfig()) if len(hypotheses) == 4 else \
        solve.single_hypothesis(take, hypotheses[0], solve.RefineConfig())
    joints = out["joints"].values
    velocity = np.linalg.norm(np.diff(joints, axis=0) - np.diff(truth, axis=0), axis=-1).mean()
    real = take["gt_source"].values >= 0
    print(f"refined ({time.perf_counter() - t0:.1f} s): MPJPE {1000 * np.linalg.norm(joints - truth, axis=-1).mean():.1f}"
          f" mm, MPJVE {1000 * velocity:.1f} mm/frame, real markers labelled "
          f"{(out['vertex'].values[real] >= 0).mean():.0%}")


if __name__ == "__main__":
    main()
