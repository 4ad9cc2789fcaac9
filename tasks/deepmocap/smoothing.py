"""Temporal filtering of the labelled 3D reflectors (DeepMoCap §3.4.2: "a Kalman filter stabilizes the
tracks"). Three swappable implementations of the `smoothed` stage:

- ``kalman``: first the labels of mirrored limb reflectors are kept continuous (tracks.py: a label
  that sits on the other limb's track while that limb's own label is there too is dropped, a
  reflector that jumps to the other side's track and back takes that side's label, and a label that
  joins another reflector's track, far from its own, is dropped); then per
  reflector, a filterpy Kalman filter with a constant-velocity (order 1) or constant-acceleration
  (order 2) model; measurement noise grows as the fused confidence falls; with ``fast_process_noise`` > 0
  (off by default) an interacting-multiple-model filter (filterpy ``IMMEstimator``) of two such models, a slow and a
  fast process noise, so that the noise follows the motion (a foot in a kick or a sprint) instead of one
  value serving slow and fast limbs alike;
  a track starts only on a measurement that the next ones confirm (reachable at a top speed);
  a measurement a track rejected may start a track of its own, and of the competing tracks the chain that best
  explains the reflector's measurements, never asking it to move faster than the top speed from one piece to
  the next, is kept (a ghost of the reflector that one view keeps seeing loses to the reflector itself);
  Mahalanobis gating rejects outliers (against the IMM's mixed prediction, or either model's right after an
  accepted measurement); gaps of up to ``max_gap`` frames inside a track are bridged, a
  track ends at its last accepted measurement (past it a reflector is reported missing rather than
  extrapolated); optional Rauch-Tung-Striebel smoothing for offline runs (with the IMM, over a process
  noise that is each frame's mix of the models' noises by the forward pass's model probabilities).
- ``butterworth``: zero-phase low-pass (scipy ``filtfilt``) over each run of observed frames.
- ``none``: the fused markers as they are.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from mocapflow.tasks.deepmocap import tracks

if TYPE_CHECKING:
    from filterpy.kalman import IMMEstimator, KalmanFilter


@dataclass(frozen=True)
class KalmanConfig:
    order: int = 1  # 1: constant velocity, 2: constant acceleration
    process_noise: float = 400.0  # variance of the white-noise highest derivative, (m/s^(order+1))^2
    measurement_noise_m: float = 0.01  # measurement std at confidence 1; divided by the confidence
    max_gap: int = 10  # longest gap (frames) bridged inside a track
    gate: float = 16.27  # squared Mahalanobis distance beyond which a measurement is an outlier (chi2, 3 dof, 0.999)
    rts: bool = True  # Rauch-Tung-Striebel smoothing over each track (offline)
    max_speed_m_s: float = 10.0  # top reflector speed (a hand in a fast throw); farther jumps do not confirm a track
    confirm: int = 2  # following measurements that confirm a track's start (0: start on any measurement)
    resolve_swaps: bool = True  # keep mirrored limb reflectors' labels continuous (labels.py) first
    swap_penalty_m: float = 0.03  # cost of an exchanged frame per measurement, against the jumps it removes
    swap_reach: int = 5  # frames a reflector's last position is held over a gap when comparing frames
    duplicate_m: float = 0.05  # > 0: a limb pair this close that was apart has one limb under both labels (labels.py)
    duplicate_reach: int = 15  # frames a side's last position is kept when judging which label is the impostor
    shared_m: float = 0.05  # > 0: two labels the body keeps apart, this close after being apart: one is dropped (labels.py)
    # > 0: an interacting-multiple-model filter of a slow (process_noise) and a fast (this) model; 0: one filter.
    # 8000 (20x) is the value chosen on the training splits; off by default, as it costs two of the three training
    # splits' poses (docs/deepmocap.md, "Motions the training lacks")
    fast_process_noise: float = 0.0
    switch_probability: float = 0.05  # IMM: probability per frame that a reflector changes model (slow <-> fast)
    # measurements a track rejected that may start tracks of their own (per reflector), of which the chain that
    # best explains the measurements is kept (0: one pass, each track from the first confirmed measurement after
    # the last one ends); a bound on the work, which more than 16 did not change on the training splits
    alternatives: int = 16

    def __post_init__(self):
        if not self.process_noise > 0:
            raise ValueError(f"process_noise must be > 0 (e.g. 400.0), got {self.process_noise}")
        if self.fast_process_noise != 0 and not self.fast_process_noise > self.process_noise:
            raise ValueError(f"fast_process_noise must be 0 (off) or > process_noise ({self.process_noise}, "
                             f"e.g. {20 * self.process_noise}), got {self.fast_process_noise}")
        if not 0 < self.switch_probability < 0.5:
            raise ValueError(f"switch_probability must be in (0, 0.5) per frame (e.g. 0.05), got {self.switch_probability}")
        if not self.swap_penalty_m > 0:
            raise ValueError(f"swap_penalty_m must be > 0 metres (e.g. 0.03), got {self.swap_penalty_m}")
        if self.duplicate_m < 0:
            raise ValueError(f"duplicate_m must be >= 0 metres (0: off, e.g. 0.05), got {self.duplicate_m}")
        if self.shared_m < 0:
            raise ValueError(f"shared_m must be >= 0 metres (0: off, e.g. 0.05), got {self.shared_m}")
        if self.duplicate_reach < 1:
            raise ValueError(f"duplicate_reach must be >= 1 frame (e.g. 15), got {self.duplicate_reach}")
        if self.swap_reach < 1:
            raise ValueError(f"swap_reach must be >= 1 frame (e.g. 5), got {self.swap_reach}")
        if not self.max_speed_m_s > 0:
            raise ValueError(f"max_speed_m_s must be > 0 (e.g. 10.0), got {self.max_speed_m_s}")
        if self.alternatives < 0:
            raise ValueError(f"alternatives must be >= 0 tracks (0: one pass, e.g. 16), got {self.alternatives}")
        if self.confirm < 0:
            raise ValueError(f"confirm must be >= 0 measurements (0 starts a track on any), got {self.confirm}")


@dataclass(frozen=True)
class ButterworthConfig:
    cutoff_hz: float = 6.0
    order: int = 4


@dataclass(frozen=True)
class NoSmoothing:
    """`none`: the fused markers unchanged."""


def _filter(order: int, dt: float, process_noise: float) -> KalmanFilter:
    # filterpy (and scipy.signal below) here, not at the top: they import scipy.stats, about 0.3 s of every CLI call
    # and of every worker's start
    from filterpy.common import Q_discrete_white_noise
    from filterpy.kalman import KalmanFilter

    n = order + 1
    kf = KalmanFilter(dim_x=3 * n, dim_z=3)
    step = np.eye(n)
    for k in range(1, n):
        step += np.diag(np.full(n - k, dt**k / np.prod(np.arange(1, k + 1))), k)  # Taylor terms of the motion model
    kf.F = np.kron(np.eye(3), step)  # state ordered (x, x', [x''], y, ..., z, ...)
    kf.H = np.kron(np.eye(3), np.eye(1, n))
    kf.Q = Q_discrete_white_noise(dim=n, dt=dt, var=process_noise, block_size=3)
    return kf


def follows(z: np.ndarray, i: int, j: int, *, dt: float, max_speed_m_s: float, slack_m: float) -> bool:
    """Whether measurement j (> i) is reachable from measurement i at no more than the top speed.  (frame, 3)"""
    return bool(np.linalg.norm(z[j] - z[i]) <= max_speed_m_s * (j - i) * dt + slack_m)


def confirmed(z: np.ndarray, i: int, *, count: int, within: int, **reach) -> bool:
    """Track initiation: measurement i starts a track only when each of the next ``count`` measurements
    (none more than ``within`` frames after the one before) follows from the one before.  (frame, 3)"""
    ahead = z[i + 1:i + 1 + count * within]  # a chain of count links, each within ``within`` frames, ends here
    seen = np.flatnonzero(np.isfinite(ahead).all(axis=1)) + i + 1
    chain = [i, *seen[:count]]
    if len(chain) <= count:
        return False
    return all(b - a <= within and follows(z, a, b, **reach) for a, b in zip(chain, chain[1:]))


def _start(z0: np.ndarray, *, order: int, dt: float, process_noises: tuple[float, ...], switch: float,
           measurement_noise_m: float) -> KalmanFilter | IMMEstimator:
    """A track's filter at its first measurement z0 (3,): one Kalman filter per process noise; two or more are
    mixed by an interacting-multiple-model estimator (Blom & Bar-Shalom 1988, "The interacting multiple model
    algorithm for systems with Markovian switching coefficients", IEEE TAC 33(8)) that changes model with
    probability ``switch`` per frame; the first process noise is the slow model's."""
    filters = []
    for q in process_noises:
        kf = _filter(order, dt, q)
        kf.x = np.zeros(kf.dim_x)
        kf.x[::order + 1] = z0
        kf.P = np.kron(np.eye(3), np.diag([measurement_noise_m**2] + [1.0] * order))
        filters.append(kf)
    if len(filters) == 1:
        return filters[0]
    from filterpy.kalman import IMMEstimator

    m = len(filters)
    M = np.full((m, m), switch / (m - 1))  # (model, model) Markov transition probabilities
    np.fill_diagonal(M, 1.0 - switch)
    mu = np.full(m, switch / (m - 1))  # (model,) a track starts in the slow model until its measurements say otherwise
    mu[0] = 1.0 - switch
    return IMMEstimator(filters, mu=mu, M=M)


def _models(tracker: KalmanFilter | IMMEstimator) -> list[KalmanFilter]:
    """The Kalman filters a track runs: an IMM's models, or the one filter itself."""
    return list(getattr(tracker, "filters", [tracker]))


def _prior(tracker: KalmanFilter | IMMEstimator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The predicted state (dim_x,), its covariance (dim_x, dim_x) and the models' prior probabilities (model,).

    For the IMM, the moment-matched mix of the models' predictions weighted by the prior model probabilities
    (``cbar``; filterpy's own ``x_prior`` weights them by the previous posterior ones).
    """
    models = _models(tracker)
    if len(models) == 1:
        return tracker.x, tracker.P, np.ones(1)
    w = tracker.cbar  # (model,)
    xs = np.array([f.x for f in models])  # (model, dim_x)
    x = w @ xs  # (dim_x,)
    d = xs - x  # (model, dim_x)
    P = np.einsum("m,mij->ij", w, np.array([f.P for f in models]) + d[:, :, None] * d[:, None, :])
    return x, P, w.copy()


def _gated_update(tracker: KalmanFilter | IMMEstimator, z: np.ndarray, confidence: float, *,
                  measurement_noise_m: float, gate: float, union: bool = False) -> bool:
    """Update with z unless its squared Mahalanobis distance to the prediction exceeds the gate; whether it was
    used. An IMM's prediction is its models' mix (``_prior``); with ``union``, z is also kept when any one
    model predicts it (the union of the models' validation regions): against the mix alone, the slow model's
    weight would reject the first frames of a fast move, the very measurements that should switch the models."""
    R = np.eye(3) * (measurement_noise_m / max(confidence, 0.05)) ** 2  # (3, 3)
    models = _models(tracker)
    x, P, _ = _prior(tracker)  # (dim_x,), (dim_x, dim_x)
    H = models[0].H  # (3, dim_x)
    predictions = [(x, P)] + ([(f.x, f.P) for f in models] if union and len(models) > 1 else [])
    for x, P in predictions:
        residual = z - H @ x  # (3,)
        if residual @ np.linalg.solve(H @ P @ H.T + R, residual) <= gate:
            break
    else:
        return False
    if len(models) > 1:
        for f in models:  # IMMEstimator.update takes no R: each model's is set
            f.R = R
        tracker.update(z)
    else:
        tracker.update(z, R=R)
    return True


def _follow(z: np.ndarray, seen: np.ndarray, confidence: np.ndarray, first: int, *, max_gap: int, gate: float,
            order: int, dt: float, process_noises: tuple[float, ...], switch: float,
            measurement_noise_m: float) -> tuple[list, int]:
    """One track from a confirmed measurement until more than ``max_gap`` frames pass without one it accepts.

    Returns its (frame, x, P, accepted, mu) entries up to its last accepted measurement (mu: the model
    probabilities (model,), posterior where a measurement was accepted, prior elsewhere), and the frame where
    the search for the next track resumes. ``seen`` (frame,) marks the frames with a measurement.
    """
    tracker = _start(z[first], order=order, dt=dt, process_noises=process_noises, switch=switch,
                     measurement_noise_m=measurement_noise_m)
    mixed = len(_models(tracker)) > 1
    mu0 = tracker.mu.copy() if mixed else np.ones(1)
    segment, gap = [(first, tracker.x.copy(), tracker.P.copy(), True, mu0)], 0
    for i in range(first + 1, len(z)):
        tracker.predict()
        # a model alone may take a measurement only right after an accepted one: over a gap the fast model's
        # validation region grows with its larger noise and would take another reflector's measurement
        accepted = bool(seen[i]) and _gated_update(tracker, z[i], float(confidence[i]),
                                                   measurement_noise_m=measurement_noise_m, gate=gate,
                                                   union=gap == 0)
        gap = 0 if accepted else gap + 1
        if gap > max_gap:
            return _up_to_last_measurement(segment), i
        if accepted:
            x, P, mu = tracker.x.copy(), tracker.P.copy(), tracker.mu.copy() if mixed else np.ones(1)
        else:
            x, P, mu = (a.copy() for a in _prior(tracker))
        segment.append((i, x, P, accepted, mu))
    return _up_to_last_measurement(segment), len(z)


def _up_to_last_measurement(segment: list) -> list:
    """A track ends at its last accepted measurement: past it, a prediction only drifts."""
    last = max(k for k, (_, _, _, accepted, _) in enumerate(segment) if accepted)
    return segment[:last + 1]


def _candidates(z: np.ndarray, seen: np.ndarray, *, confirmable, follow, alternatives: int) -> list[list]:
    """Candidate tracks of one reflector, in order of their first frame: one from each confirmed measurement
    that no earlier track took, after the earlier tracks end, and, up to ``alternatives`` of them, inside an
    earlier track's frames (a measurement it rejected: where two streams compete for a label, as a reflector
    and a ghost of it that one view keeps, both are followed and ``_select`` chooses).  z (frame, 3), seen (frame,)"""
    covered = np.zeros(len(z), bool)  # (frame,) measurements some track took
    resume, spawned, tracks = 0, 0, []
    for i in np.flatnonzero(seen):
        inside = i < resume
        if covered[i] or (inside and spawned >= alternatives) or not confirmable(i):
            continue
        segment, stop = follow(i)
        tracks.append(segment)
        covered[[f for f, _, _, accepted, _ in segment if accepted]] = True
        resume, spawned = max(resume, stop), spawned + inside
    return tracks


def _pieces(tracks: list[list], n: int) -> list[tuple]:
    """Each track up to its end, and up to its last measurement before each later track's start inside it, with
    its score: the measurements it took less those it rejected within its frames that another track took (a
    stream it ignored; an outlier no track takes costs nothing).  n: frames ->
    [(track, last entry kept, first frame, last frame, score)], by last frame"""
    taken_by = np.zeros((len(tracks), n), bool)  # (track, frame)
    for t, track in enumerate(tracks):
        taken_by[t, [e[0] for e in track if e[3]]] = True
    taken = taken_by.any(axis=0)  # (frame,)
    pieces = []
    for t, track in enumerate(tracks):
        frames = np.array([e[0] for e in track])
        accepted = np.array([e[3] for e in track])
        competing = taken & ~taken_by[t]  # (frame,) taken by another track, not by this one
        starts = {u[0][0] for u in tracks if frames[0] < u[0][0] <= frames[-1]}
        cuts = {len(track) - 1} | {int(np.flatnonzero(accepted & (frames < s))[-1]) for s in starts}
        for k in sorted(cuts):
            score = int(accepted[:k + 1].sum()) - int(competing[frames[0]:frames[k] + 1].sum())
            pieces.append((t, k, int(frames[0]), int(frames[k]), score))
    return sorted(pieces, key=lambda p: p[3])


def _best_chain(pieces: list[tuple], joins: np.ndarray) -> list[int]:
    """Weighted interval scheduling by dynamic programming over ``pieces`` (``_pieces``): the chain of the highest
    total score whose consecutive pieces may follow one another (``joins`` (piece, piece) bool: the first ends
    before the second starts, within the top speed's reach).  -> the chain's piece indices, in order"""
    best, before = np.full(len(pieces), -np.inf), np.full(len(pieces), -1)
    for p, (_, _, _, _, score) in enumerate(pieces):
        earlier = np.flatnonzero(joins[:p, p])  # pieces this one may follow
        q = int(earlier[np.argmax(best[earlier])]) if earlier.size else -1
        before[p] = q if q >= 0 and best[q] > 0 else -1  # a chain worth nothing is not continued
        best[p] = score + (best[q] if before[p] >= 0 else 0.0)
    if not len(pieces) or best.max() <= 0:
        return []
    chain, p = [], int(np.argmax(best))
    while p >= 0:
        chain.append(p)
        p = int(before[p])
    return chain[::-1]


def _select(tracks: list[list], z: np.ndarray, **reach) -> list[list]:
    """The chain of track pieces that best explains a reflector's measurements (``_pieces``, ``_best_chain``):
    consecutive pieces must not overlap and the reflector must be able to move from one to the next at the top
    speed (``follows``).  z (frame, 3); each track a list of (frame, x, P, accepted, mu) -> the
    chosen pieces, in order"""
    pieces = _pieces(tracks, len(z))
    joins = np.array([[a[3] < b[2] and follows(z, a[3], b[2], **reach) for b in pieces] for a in pieces],
                     bool).reshape(len(pieces), len(pieces))  # (piece, piece)
    return [tracks[pieces[p][0]][:pieces[p][1] + 1] for p in _best_chain(pieces, joins)]


def kalman_track(z: np.ndarray, confidence: np.ndarray, dt: float, config: KalmanConfig) -> tuple[np.ndarray, np.ndarray]:
    """Filtered positions of one reflector and which frames are predictions.  (frame, 3), (frame,) -> same, bool

    Tracks start on confirmed measurements (see ``confirmed``): started on a lone outlier, the gate would
    reject the true measurements that follow. With ``alternatives`` > 0, measurements a track rejected start
    tracks of their own and the best-supported chain of pieces, never faster than the top speed between them,
    is kept (``_select``). Gaps inside a track are bridged; RTS smoothing makes the
    bridge an interpolation between the measurements on either side. With ``fast_process_noise`` > 0 each
    track is an IMM of the slow and the fast model, and its RTS pass takes, per frame, the process noise
    mixed by the forward pass's model probabilities.
    """
    n, order, max_gap = len(z), config.order, config.max_gap
    out, predicted = np.full((n, 3), np.nan), np.zeros(n, bool)
    seen = np.isfinite(z).all(axis=1)
    reach = {"dt": dt, "max_speed_m_s": config.max_speed_m_s, "slack_m": 3 * config.measurement_noise_m}
    noises = (config.process_noise,) + ((config.fast_process_noise,) if config.fast_process_noise > 0 else ())
    model = {"order": order, "dt": dt, "process_noises": noises, "switch": config.switch_probability}
    tracks = _candidates(
        z, seen, alternatives=config.alternatives,
        confirmable=lambda i: confirmed(z, i, count=config.confirm, within=max_gap, **reach),
        follow=lambda i: _follow(z, seen, confidence, i, max_gap=max_gap, gate=config.gate,
                                 measurement_noise_m=config.measurement_noise_m, **model))
    if config.alternatives > 0:
        tracks = _select(tracks, z, **reach)
    for segment in tracks:
        frames = [k for k, *_ in segment]
        xs, ps = np.array([e[1] for e in segment]), np.array([e[2] for e in segment])  # (step, dim_x), (step, dim_x, dim_x)
        if config.rts and len(segment) > 1:
            from filterpy.kalman import rts_smoother

            templates = [_filter(order, dt, q) for q in noises]
            Qm = np.array([t.Q for t in templates])  # (model, dim_x, dim_x)
            mu = np.array([e[4] for e in segment])  # (step, model)
            # the step k -> k+1 takes the noise of the models that explain frame k+1 (a single model: its own Q)
            Qs = np.einsum("km,mij->kij", np.vstack([mu[1:], mu[-1:]]), Qm)  # (step, dim_x, dim_x)
            xs, *_ = rts_smoother(xs, ps, Fs=[templates[0].F] * len(segment), Qs=Qs)
        out[frames] = xs[:, ::order + 1]
        predicted[frames] = [not e[3] for e in segment]
    return out, predicted


def butterworth_track(z: np.ndarray, *, fps: float, cutoff_hz: float, order: int) -> np.ndarray:
    """Zero-phase low-pass of each run of observed frames (runs too short to pad are kept).  (frame, 3)"""
    from scipy import signal  # here, not at the top, as filterpy above

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


def kalman(markers: xr.Dataset, config: KalmanConfig) -> xr.Dataset:
    """`kalman` smoothing of a sequence's markers (frame, reflector, xyz), after the limb labels' continuity."""
    xyz, conf = markers["position"].values.astype(np.float64), markers["confidence"].values
    exchanges = dropped = 0
    if config.resolve_swaps:
        names = [str(n) for n in markers["reflector"].values]
        xyz, conf, exchanges, dropped = tracks.resolve_swaps(
            xyz, conf, names, penalty_m=config.swap_penalty_m, reach=config.swap_reach, duplicate_m=config.duplicate_m,
            duplicate_reach=config.duplicate_reach, shared_m=config.shared_m)
    dt = 1.0 / float(markers.attrs["fps"])
    filtered = [kalman_track(xyz[:, r], conf[:, r], dt, config) for r in range(xyz.shape[1])]
    out = _result(markers.assign(confidence=(markers["confidence"].dims, conf)), np.stack([t[0] for t in filtered], 1),
                  np.stack([t[1] for t in filtered], 1), "kalman")
    out.attrs["label_exchanges"] = exchanges
    out.attrs["label_duplicates_dropped"] = dropped
    return out


def butterworth(markers: xr.Dataset, config: ButterworthConfig) -> xr.Dataset:
    xyz = markers["position"].values.astype(np.float64)
    out = np.stack([butterworth_track(xyz[:, r], fps=float(markers.attrs["fps"]), cutoff_hz=config.cutoff_hz,
                                      order=config.order)
                    for r in range(xyz.shape[1])], 1)
    return _result(markers, out, np.zeros(out.shape[:2], bool), "butterworth")


def no_smoothing(markers: xr.Dataset, config: NoSmoothing) -> xr.Dataset:
    xyz = markers["position"].values.astype(np.float64)
    return _result(markers, xyz, np.zeros(xyz.shape[:2], bool), "none")
