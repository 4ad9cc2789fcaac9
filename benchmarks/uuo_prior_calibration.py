"""Calibration of UUO's simulated prior on the studio's procedural exercises (never a CMU test clip).

    python benchmarks/uuo_prior_calibration.py [--frames 90] [--seeds 2] [--form realistic] [--set flip_per_s=0.3 ...]
    python benchmarks/uuo_prior_calibration.py --form monocular [--models storage/models/blazepose]

For each exercise and subject seed, the prior's error three ways: PA-MPJPE (each frame registered with scale, the
articulated error), MPJPE after one rigid registration with scale of the take (HMR2.0+RR) and MPJPE after what
part matching itself estimates (one rotation for the take, a translation per frame: ``aligned``); then the
median and p90 over takes. The realistic form's defaults were chosen with it (aligned median in 130-150 mm).
``--form monocular`` measures the real estimator instead: each take filmed by the studio's video camera
(tasks/studio/video.py), BlazePose run on it and Anny fitted to its joints (tasks/uuo/monocular.py).
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
    from scipy.spatial.transform import Rotation

    from mocapflow.tasks.studio.synth import SequenceSpec, build_rig
    from mocapflow.tasks.uuo import prior

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--form", default="realistic")
    ap.add_argument("--set", nargs="*", default=[], help="field=value of SimulatedPriorConfig")
    ap.add_argument("--models", default="storage/models/blazepose", help="BlazePose's two .tflite files (monocular)")
    args = ap.parse_args()
    estimate = monocular_estimate(args.models) if args.form == "monocular" else None
    fields = {f.name: f for f in dataclasses.fields(prior.SimulatedPriorConfig)}
    overrides = {}
    for item in args.set:
        key, value = item.split("=")
        overrides[key] = tuple(float(v) for v in value.split(",")) if "," in value else float(value)
        assert key in fields, key
    rows = []
    t0 = time.perf_counter()
    for name in EXERCISES:
        for seed in range(args.seeds):
            rig = build_rig(SequenceSpec(name, frames=args.frames, seed=500 + seed, body="mesh", views=1))
            n = rig.n_frames
            quats = Rotation.from_matrix(rig.take.rotations[:n].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
            truth = rig.take.posed.heads[:n][:, rig.body.joint_bones()]
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


def monocular_estimate(models: str):
    """(rig, frames, truth joints) -> (PA, RR, aligned) mm of the monocular prior on the take's studio video."""
    from pathlib import Path

    from mocapflow.tasks.studio.video import VideoSpec, film
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
