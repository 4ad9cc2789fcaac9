"""Calibration of UUO's simulated prior on the studio's procedural exercises (never a CMU test clip).

    python benchmarks/uuo_prior_calibration.py [--frames 90] [--seeds 2] [--form realistic] [--set flip_per_s=0.3 ...]
    python benchmarks/uuo_prior_calibration.py --form monocular [--models storage/models/blazepose]
    python benchmarks/uuo_prior_calibration.py --draws 3 [--form realistic|monocular] [--exercises 4]

For each exercise and subject seed, the prior's error three ways: PA-MPJPE (each frame registered with scale, the
articulated error), MPJPE after one rigid registration with scale of the take (HMR2.0+RR) and MPJPE after what
part matching itself estimates (one rotation for the take, a translation per frame: ``aligned``); then the
median and p90 over takes. The realistic form's defaults were chosen with it (aligned median in 130-150 mm).
``--form monocular`` measures the real estimator instead: each take filmed by the studio's video camera
(tasks/uuo/video.py), BlazePose run on it and Anny fitted to its joints (tasks/uuo/monocular.py).

``--draws 3`` makes three priors per take and combines them (tasks/uuo/combine.py), each rotation average in
turn, and prints the single draws' and the combinations' error after part matching's alignment, median and p90
over takes. Simulated draws come from seeds ``seed + 100 * exercise + 1000 * draw``: the prior's seed is mixed
with a key of the take's subject and start (prior.take_key), which the exercises of one subject share, so with
one seed per subject the ten exercises would be degraded by the same draws. Monocular draws are the video as
filmed, moved (``--shift-px``) and mirrored (``flip``). Simulated draws err independently of each other, a real
estimator's reruns in correlated ways.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
import xarray as xr

EXERCISES = ("walking_on_the_spot", "side_reaches", "jumping_jack", "classic_squat", "kick_box_kicking",
             "forward_lunge_left_right", "side_steps", "dance_swing", "front_kick", "elbow_flexion")


def main() -> None:
    from mocapflow.tasks.uuo import prior

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--form", default="realistic")
    ap.add_argument("--set", nargs="*", default=[], help="field=value of SimulatedPriorConfig")
    ap.add_argument("--models", default="storage/models/blazepose", help="BlazePose's two .tflite files (monocular)")
    ap.add_argument("--draws", type=int, default=1, choices=(1, 3), help="3: three priors per take, combined")
    ap.add_argument("--exercises", type=int, default=len(EXERCISES), help="the first N exercises only")
    ap.add_argument("--shift-px", type=float, default=12.0, help="monocular draws: the second video's shift (px)")
    args = ap.parse_args()
    if args.draws == 3:
        return combined_calibration(args)
    estimate = monocular_estimate(args.models) if args.form == "monocular" else None
    fields = {f.name: f for f in dataclasses.fields(prior.SimulatedPriorConfig)}
    overrides = {}
    for item in args.set:
        key, value = item.split("=")
        overrides[key] = tuple(float(v) for v in value.split(",")) if "," in value else float(value)
        assert key in fields, key
    rows = []
    t0 = time.perf_counter()
    for name in EXERCISES[:args.exercises]:
        for seed in range(args.seeds):
            rig, n, quats, truth = calibration_take(name, seed, args.frames)
            if estimate is not None:
                rows.append(estimate(rig, n, truth))
            else:
                config = prior.SimulatedPriorConfig(form=args.form, seed=seed, **overrides)
                out = prior.degraded_body(np.arange(n), dataclasses.asdict(rig.body.phenotype), quats,
                                          rig.take.root[:n], truth, 30.0, config, "simulated")
                rows.append((out.attrs["pa_mpjpe_mm"], out.attrs["registered_mpjpe_mm"], out.attrs["aligned_mpjpe_mm"]))
            print(f"{name:26s} seed {seed}: PA {rows[-1][0]:6.1f}  RR {rows[-1][1]:6.1f}  aligned {rows[-1][2]:6.1f} mm")
    a = np.array(rows)
    for label, col in (("PA-MPJPE", 0), ("registered (RR)", 1), ("aligned (part matching)", 2)):
        print(f"{label:24s} median {np.median(a[:, col]):6.1f}  p90 {np.percentile(a[:, col], 90):6.1f}  "
              f"min {a[:, col].min():6.1f}  max {a[:, col].max():6.1f} mm")
    print(f"{len(rows)} takes, form {args.form} {overrides or ''}, {time.perf_counter() - t0:.0f} s")


def calibration_take(name: str, seed: int, frames: int):
    """One calibration take of a procedural exercise: (rig, frames, true world rotations as quaternions (frame,
    bone, 4), the true template joints (frame, joint, 3))."""
    from scipy.spatial.transform import Rotation

    from mocapflow.tasks.deepmocap.film.synth import build_rig

    from mocapflow.tasks.studio.spec import SequenceSpec

    rig = build_rig(SequenceSpec(name, frames=frames, seed=500 + seed, body="mesh", views=1))
    n = rig.n_frames
    quats = Rotation.from_matrix(rig.take.rotations[:n].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    return rig, n, quats, rig.take.posed.heads[:n][:, rig.body.joint_bones()]


def combined_calibration(args) -> None:
    """``--draws 3``: per take three priors, each alone and the three combined by each rotation average; the error
    after part matching's alignment (aligned_mpjpe) on the frames each prior keeps."""
    from mocapflow.tasks.uuo import combine, prior

    overrides = {}
    for item in args.set:
        key, value = item.split("=")
        overrides[key] = tuple(float(v) for v in value.split(",")) if "," in value else float(value)
    draw_priors = monocular_draws(args.models, args.shift_px) if args.form == "monocular" else None

    def aligned_mm(ds: xr.Dataset, truth: np.ndarray) -> float:
        valid = ds["valid"].values.astype(bool)
        return 1000.0 * prior.aligned_mpjpe(ds["joints"].values.astype(np.float64)[valid], truth[valid])

    singles, combined, spreads = [], {m: [] for m in combine.ROTATION_AVERAGES}, []
    t0 = time.perf_counter()
    for i, name in enumerate(EXERCISES[:args.exercises]):
        for seed in range(args.seeds):
            rig, n, quats, truth = calibration_take(name, seed, args.frames)
            if draw_priors is not None:
                draws = draw_priors(rig, n)
            else:
                draws = [prior.degraded_body(np.arange(n), dataclasses.asdict(rig.body.phenotype), quats,
                                             rig.take.root[:n], truth, 30.0,
                                             prior.SimulatedPriorConfig(form=args.form, seed=seed + 100 * i + 1000 * d,
                                                                        **overrides), "simulated")
                         for d in range(3)]
            singles.append([aligned_mm(d, truth) for d in draws])
            line = "  ".join(f"{v:6.1f}" for v in singles[-1])
            for method in combine.ROTATION_AVERAGES:
                out = combine.combine_priors(*draws, combine.CombinePriorsConfig(rotation=method))
                combined[method].append(aligned_mm(out, truth))
                line += f"  {method} {combined[method][-1]:6.1f}"
            spreads.append(out.attrs["spread_deg"])
            print(f"{name:26s} seed {seed}: draws {line} mm  (spread {spreads[-1]:4.1f} deg)", flush=True)
    s = np.array(singles)

    def row(label: str, values) -> None:
        v = np.asarray(values)
        print(f"{label:34s} median {np.median(v):6.1f}  p90 {np.percentile(v, 90):6.1f}  min {v.min():6.1f}  "
              f"max {v.max():6.1f} mm")

    print("after part matching's alignment (aligned_mpjpe), over takes:")
    row("one draw (draw 0)", s[:, 0])
    row("one draw (each take's median draw)", np.median(s, axis=1))
    row("one draw (all draws pooled)", s.ravel())
    for method, values in combined.items():
        row(f"three combined ({method})", values)
    default = combine.CombinePriorsConfig().rotation
    better = (np.asarray(combined[default]) < np.median(s, axis=1)).mean()
    print(f"combined ({default}) under the take's median draw on {100 * better:.0f} % of takes; draws' spread "
          f"{np.median(spreads):.1f} deg (median angle between two draws' rotations of an articulated joint)")
    print(f"{len(s)} takes, form {args.form} {overrides or ''}, three draws, {time.perf_counter() - t0:.0f} s")


def monocular_draws(models: str, shift_px: float):
    """(rig, frames) -> three monocular priors of the take's studio video: as filmed, moved by ``shift_px`` to
    the right and down, and mirrored (tasks/uuo/monocular.py perturb_frames)."""
    from pathlib import Path

    from mocapflow.tasks.uuo.video import VideoSpec, film
    from mocapflow.tasks.uuo import monocular

    folder = Path(models)
    detector, landmarker = ((folder / f).read_bytes() for f in ("pose_detection.tflite", "pose_landmark_full.tflite"))
    configs = (monocular.MonocularPriorConfig(), monocular.MonocularPriorConfig(shift_px=(shift_px, shift_px)),
               monocular.MonocularPriorConfig(flip=True))

    def draws(rig, n):
        video = film(rig.take.posed.vertices[:n], rig.body.faces, rig.body.uv, VideoSpec(), np.random.default_rng(0))
        frames = xr.Dataset({"video": (("frame", "y", "x", "rgb"), video)}, coords={"frame": np.arange(n)},
                            attrs={"fps": 30.0})
        return [monocular.monocular_prior(frames, c, detector, landmarker) for c in configs]

    return draws


def monocular_estimate(models: str):
    """(rig, frames, truth joints) -> (PA, RR, aligned) mm of the monocular prior on the take's studio video."""
    from pathlib import Path

    from mocapflow.tasks.uuo.video import VideoSpec, film
    from mocapflow.tasks.uuo import monocular, prior

    folder = Path(models)
    detector, landmarker = ((folder / f).read_bytes() for f in ("pose_detection.tflite", "pose_landmark_full.tflite"))

    def measure(rig, n, truth):
        video = film(rig.take.posed.vertices[:n], rig.body.faces, rig.body.uv, VideoSpec(), np.random.default_rng(0))
        frames = xr.Dataset({"video": (("frame", "y", "x", "rgb"), video)}, coords={"frame": np.arange(n)},
                            attrs={"fps": 30.0})
        out = monocular.monocular_prior(frames, monocular.MonocularPriorConfig(), detector, landmarker)
        valid = out["valid"].values
        joints = out["joints"].values.astype(np.float64)[valid]
        return tuple(1000.0 * f(joints, truth[valid]) for f in (prior.procrustes_mpjpe, prior.registered_mpjpe,
                                                                 prior.aligned_mpjpe))

    return measure


if __name__ == "__main__":
    main()
