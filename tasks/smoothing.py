"""Temporal filtering of the labelled 3D reflectors (DeepMoCap §3.4.2: "a Kalman filter stabilizes the
tracks"). Three swappable implementations of the `smoothed` stage:

- ``kalman``: per reflector, a filterpy Kalman filter with a constant-velocity (order 1) or
  constant-acceleration (order 2) model; measurement noise grows as the fused confidence falls;
  Mahalanobis gating rejects outliers; gaps are predicted through up to ``max_gap`` frames, after
  which the reflector is reported missing; optional Rauch-Tung-Striebel smoothing for offline runs.
- ``butterworth``: zero-phase low-pass (scipy ``filtfilt``) over each run of observed frames.
- ``none``: the fused markers as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter, rts_smoother
from scipy import signal


@dataclass(frozen=True)
class KalmanConfig:
    order: int = 1  # 1: constant velocity, 2: constant acceleration
    process_noise: float = 400.0  # variance of the white-noise highest derivative, (m/s^(order+1))^2
    measurement_noise_m: float = 0.01  # measurement std at confidence 1; divided by the confidence
    max_gap: int = 10  # frames predicted through before a reflector is reported missing
    gate: float = 16.27  # squared Mahalanobis distance beyond which a measurement is an outlier (chi2, 3 dof, 0.999)
    rts: bool = True  # Rauch-Tung-Striebel smoothing over each track (offline)


@dataclass(frozen=True)
class ButterworthConfig:
    cutoff_hz: float = 6.0
    order: int = 4


@dataclass(frozen=True)
class NoSmoothing:
    """`none`: the fused markers unchanged."""


def _filter(order: int, dt: float, process_noise: float) -> KalmanFilter:
    n = order + 1
    kf = KalmanFilter(dim_x=3 * n, dim_z=3)
    step = np.eye(n)
    for k in range(1, n):
        step += np.diag(np.full(n - k, dt**k / np.prod(np.arange(1, k + 1))), k)  # Taylor terms of the motion model
    kf.F = np.kron(np.eye(3), step)  # state ordered (x, x', [x''], y, ..., z, ...)
    kf.H = np.kron(np.eye(3), np.eye(1, n))
    kf.Q = Q_discrete_white_noise(dim=n, dt=dt, var=process_noise, block_size=3)
    return kf


def kalman_track(z: np.ndarray, confidence: np.ndarray, *, dt: float, order: int, process_noise: float,
                 measurement_noise_m: float, max_gap: int, gate: float, rts: bool) -> tuple[np.ndarray, np.ndarray]:
    """Filtered positions of one reflector and which frames are predictions.  (frame, 3), (frame,) -> same, bool"""
    n = len(z)
    out, predicted = np.full((n, 3), np.nan), np.zeros(n, bool)
    kf, gap, segment = None, 0, []
    segments = []
    for i in range(n):
        seen = np.isfinite(z[i]).all()
        if kf is None:
            if not seen:
                continue
            kf = _filter(order, dt, process_noise)
            kf.x = np.zeros(kf.dim_x)
            kf.x[::order + 1] = z[i]
            kf.P = np.kron(np.eye(3), np.diag([measurement_noise_m**2] + [1.0] * order))
            segment, gap = [], 0
        else:
            kf.predict()
            accepted = False
            if seen:
                R = np.eye(3) * (measurement_noise_m / max(float(confidence[i]), 0.05)) ** 2
                residual = z[i] - kf.H @ kf.x
                S = kf.H @ kf.P @ kf.H.T + R
                if residual @ np.linalg.solve(S, residual) <= gate:  # Mahalanobis gating
                    kf.update(z[i], R=R)
                    accepted = True
            gap = 0 if accepted else gap + 1
            if gap > max_gap:  # lost: report missing from here, restart on the next measurement
                segments.append(segment)
                kf = None
                continue
            predicted[i] = not accepted
        segment.append((i, kf.x.copy(), kf.P.copy()))
    if kf is not None:
        segments.append(segment)
    for seg in segments:
        frames = [i for i, _, _ in seg]
        xs, ps = np.array([x for _, x, _ in seg]), np.array([p for _, _, p in seg])
        if rts and len(seg) > 1:
            template = _filter(order, dt, process_noise)
            xs, *_ = rts_smoother(xs, ps, Fs=[template.F] * len(seg), Qs=[template.Q] * len(seg))
        out[frames] = xs[:, ::order + 1]
    predicted[np.isnan(out[:, 0])] = False
    return out, predicted


def butterworth_track(z: np.ndarray, *, fps: float, cutoff_hz: float, order: int) -> np.ndarray:
    """Zero-phase low-pass of each run of observed frames (runs too short to pad are kept).  (frame, 3)"""
    b, a = signal.butter(order, cutoff_hz / (fps / 2.0))
    out = z.copy()
    seen = np.isfinite(z).all(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], seen.astype(int), [0]])))
    for start, stop in zip(edges[::2], edges[1::2]):
        if stop - start > 3 * max(len(a), len(b)):
            out[start:stop] = signal.filtfilt(b, a, z[start:stop], axis=0)
    return out


def _result(markers: xr.Dataset, xyz: np.ndarray, predicted: np.ndarray, method: str) -> xr.Dataset:
    conf = np.where(predicted | np.isnan(xyz[..., 0]), 0.0, markers["confidence"].values).astype(np.float32)
    return xr.Dataset(
        {"position": (("frame", "reflector", "xyz"), xyz.astype(np.float32)),
         "confidence": (("frame", "reflector"), conf),
         "predicted": (("frame", "reflector"), predicted)},
        coords={k: markers[k].values for k in ("frame", "reflector", "xyz")},
        attrs={**markers.attrs, "smoothing": method},
    )


def kalman(markers: xr.Dataset, **config) -> xr.Dataset:
    """`kalman` smoothing of a sequence's markers (frame, reflector, xyz)."""
    xyz, conf = markers["position"].values.astype(np.float64), markers["confidence"].values
    dt = 1.0 / float(markers.attrs["fps"])
    tracks = [kalman_track(xyz[:, r], conf[:, r], dt=dt, **config) for r in range(xyz.shape[1])]
    return _result(markers, np.stack([t[0] for t in tracks], 1), np.stack([t[1] for t in tracks], 1), "kalman")


def butterworth(markers: xr.Dataset, *, cutoff_hz: float, order: int) -> xr.Dataset:
    xyz = markers["position"].values.astype(np.float64)
    out = np.stack([butterworth_track(xyz[:, r], fps=float(markers.attrs["fps"]), cutoff_hz=cutoff_hz, order=order)
                    for r in range(xyz.shape[1])], 1)
    return _result(markers, out, np.zeros(out.shape[:2], bool), "butterworth")


def no_smoothing(markers: xr.Dataset) -> xr.Dataset:
    xyz = markers["position"].values.astype(np.float64)
    return _result(markers, xyz, np.zeros(xyz.shape[:2], bool), "none")
