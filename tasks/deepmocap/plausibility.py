"""Plausibility of the labelled 3D reflectors: no gross error is written as data.

DeepMoCap's fusion (§3.4.2) and Kalman filter trust every label the FCN gives; a mislabelled or
misdepthed reflector then becomes a marker metres from the subject. Beyond the paper, each smoothed
marker is checked against

- the capture volume: it must lie between the floor and the ceiling heights and inside the view
  frustum of at least ``min_views`` sensors, between their nearest and farthest usable depths
  (a Kinect v2 measures 0.5-4.5 m; the pinhole projection of the calibration decides the frustum);
- the body: it must lie within ``body_tolerance_m`` of where the solved pose puts that reflector
  (the calibrated template's reflector offset carried by its bone, §3.5), in frames whose pose was
  solved; a frame without a pose is checked against the volume only.

A marker failing either check is removed (NaN, confidence 0) and the reason kept per marker-frame in
``rejected`` (0 kept, 1 outside the capture volume, 2 off the body); the counts are attributes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from mocapflow.tasks.deepmocap.refine2d import reflectors_on_poses
from mocapflow.tasks.shared.cameras import camera_of

KEPT, OUTSIDE_VOLUME, OFF_BODY = 0, 1, 2


@dataclass(frozen=True)
class PlausibilityConfig:
    floor_m: float = -0.10  # lowest plausible marker height (world z; the floor is z = 0)
    ceiling_m: float = 2.80  # highest plausible marker height (hands raised in a jump)
    near_m: float = 0.5  # nearest depth a sensor measures (Kinect v2)
    far_m: float = 4.5  # farthest depth a sensor measures (Kinect v2)
    min_views: int = 1  # frusta a marker must lie in
    body_tolerance_m: float = 0.10  # farthest a marker may lie from its reflector on the solved pose; 0: no body check

    def __post_init__(self):
        if not self.ceiling_m > self.floor_m:
            raise ValueError(f"ceiling_m must exceed floor_m (e.g. 2.8 > -0.1), got {self.ceiling_m} <= {self.floor_m}")
        if not 0 <= self.near_m < self.far_m:
            raise ValueError(f"need 0 <= near_m < far_m metres (e.g. 0.5, 4.5), got {self.near_m}, {self.far_m}")
        if self.min_views < 1:
            raise ValueError(f"min_views must be >= 1 sensor, got {self.min_views}")
        if self.body_tolerance_m < 0:
            raise ValueError(f"body_tolerance_m must be >= 0 metres (0: off, e.g. 0.10), got {self.body_tolerance_m}")


def in_frustum(points: np.ndarray, world_to_cam: np.ndarray, K: np.ndarray, size: tuple[int, int], *,
               near_m: float, far_m: float) -> np.ndarray:
    """Whether world points lie in a pinhole camera's view frustum between ``near_m`` and ``far_m`` of depth;
    an image ``size`` (width, height) of 0 leaves the image bounds unchecked.  (n, 3), (4, 4), (3, 3) -> (n,) bool"""
    cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]  # (n, 3)
    z = cam[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        inside = (z >= near_m) & (z <= far_m)
        u = K[0, 0] * cam[:, 0] / z + K[0, 2]  # undistorted pinhole: distortion polynomials fold back far outside
        v = K[1, 1] * cam[:, 1] / z + K[1, 2]
    width, height = size
    if width > 0 and height > 0:
        inside &= (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    return inside


def check(position: np.ndarray, expected: np.ndarray, frusta: list[tuple[np.ndarray, np.ndarray, tuple[int, int]]],
          config: PlausibilityConfig) -> np.ndarray:
    """Reason code of every marker-frame: KEPT, OUTSIDE_VOLUME or OFF_BODY; KEPT where there is no marker.

    position, expected (frame, R, 3) m (expected NaN where the pose is unsolved); frusta: (world_to_cam, K,
    (width, height)) per sensor.  -> (frame, R) int8"""
    n_frames, n_refl = position.shape[:2]
    flat = position.reshape(-1, 3)
    seen = np.isfinite(flat).all(axis=1)
    views = sum(in_frustum(flat, w2c, K, size, near_m=config.near_m, far_m=config.far_m).astype(int)
                for w2c, K, size in frusta)
    inside = (flat[:, 2] >= config.floor_m) & (flat[:, 2] <= config.ceiling_m) & (views >= config.min_views)
    reason = np.where(seen & ~inside, OUTSIDE_VOLUME, KEPT).astype(np.int8)
    if config.body_tolerance_m > 0:
        off = np.linalg.norm(flat - expected.reshape(-1, 3), axis=1)  # NaN where unsolved: the comparison is False
        with np.errstate(invalid="ignore"):
            reason[seen & inside & (off > config.body_tolerance_m)] = OFF_BODY
    return reason.reshape(n_frames, n_refl)


def check_markers(markers: xr.Dataset, poses: xr.Dataset, skeleton: xr.Dataset, frames: xr.Dataset,
                  config: PlausibilityConfig) -> xr.Dataset:
    """`check_plausibility` stage: the smoothed markers with every implausible one removed (see the module)."""
    names = [str(n) for n in markers["reflector"].values]
    expected, _ = reflectors_on_poses(poses, skeleton, names, markers["frame"].values)  # (frame, R, 3)
    cameras = [camera_of(frames, view) for view in frames["view"].values]
    frusta = [(c.world_to_cam, c.K, (c.width, c.height)) for c in cameras]
    position = markers["position"].transpose("frame", "reflector", "xyz").values.astype(np.float64)
    reason = check(position, expected, frusta, config)
    removed = reason != KEPT
    out = markers.copy()
    out["position"] = (("frame", "reflector", "xyz"), np.where(removed[..., None], np.nan, position).astype(np.float32))
    out["confidence"] = (("frame", "reflector"), np.where(removed, 0.0, markers["confidence"].values).astype(np.float32))
    out["rejected"] = (("frame", "reflector"), reason)
    out.attrs.update({"rejected_volume": int((reason == OUTSIDE_VOLUME).sum()),
                      "rejected_body": int((reason == OFF_BODY).sum()),
                      "unposed_frames": int((~np.isfinite(expected).all(axis=(1, 2))).sum())})
    return out
