"""Temporal filtering: the Kalman stage fills a short gap, rejects an outlier, gives up after max_gap,
does not extrapolate a track's end, starts tracks only on confirmed measurements (with one filter and with
the two-model IMM), keeps the reflector rather than a ghost of it that competes for its label, keeps a track
among outliers no other track takes, and never joins tracks the reflector cannot move between; the IMM keeps a limb
that accelerates to 12 m/s where the slow filter gates it out, and
is no worse on a slow track; Butterworth keeps a slow motion and removes noise."""

from dataclasses import replace

import numpy as np
import pytest

from mocapflow.tasks.deepmocap import smoothing


# one filter at the slow process noise (the kalman stage's default), and the two-model IMM (fast model 20x)
ONE = {"fast_process_noise": 0.0}
IMM = {"fast_process_noise": 8000.0}
MODES = pytest.mark.parametrize("mode", [ONE, IMM], ids=["one_filter", "imm"])


def _track_config(mode=None, **overrides) -> smoothing.KalmanConfig:
    """The default config with the filter ``mode`` and ``overrides``."""
    return smoothing.KalmanConfig(**{**(mode or {}), **overrides})


def _track(n=90, fps=30.0):
    t = np.arange(n) / fps
    return np.column_stack([0.5 * np.sin(2 * np.pi * 0.5 * t), 0.2 * t, np.full(n, 1.0)])


@MODES
def test_kalman_fills_a_gap_and_rejects_an_outlier(mode):
    truth = _track()
    rng = np.random.default_rng(0)
    z = truth + rng.normal(0, 0.003, truth.shape)
    z[40:45] = np.nan  # a 5-frame gap
    z[60] += [0.5, 0.0, 0.0]  # a 0.5 m outlier
    config = _track_config(mode)
    out, predicted = smoothing.kalman_track(z, np.full(len(z), 0.9), 1 / 30, config)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(np.nonzero(predicted)[0], [40, 41, 42, 43, 44, 60])
    assert np.linalg.norm(out[40:45] - truth[40:45], axis=1).max() < 0.02  # bridged within 2 cm
    assert np.linalg.norm(out[60] - truth[60]) < 0.02  # the outlier left no mark
    assert np.median(np.linalg.norm(out - truth, axis=1)) < np.median(np.linalg.norm(z - truth, axis=1)[np.isfinite(z[:, 0])])


@MODES
def test_kalman_reports_missing_past_max_gap_and_restarts(mode):
    z = _track()
    z[30:60] = np.nan
    config = _track_config(mode, max_gap=10)
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, config)
    # the track ends at its last measurement: nothing is extrapolated into the gap it cannot bridge
    assert np.isfinite(out[:30]).all() and np.isnan(out[30:60]).all()
    assert np.linalg.norm(out[60:] - z[60:], axis=1).max() < 0.01 and not predicted.any()


@MODES
def test_kalman_bridges_a_gap_inside_a_track_but_does_not_extrapolate_its_end(mode):
    truth = _track()
    z = truth.copy()
    z[20:26] = np.nan  # inside the track: bridged
    z[80:] = np.nan  # after its last measurement: missing, not predicted
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, _track_config(mode))
    np.testing.assert_array_equal(np.nonzero(predicted)[0], np.arange(20, 26))
    assert np.linalg.norm(out[20:26] - truth[20:26], axis=1).max() < 0.02
    assert np.isnan(out[80:]).all()


@MODES
def test_kalman_does_not_start_a_track_on_a_lone_outlier(mode):
    """Started on a wrong first measurement, the gate would reject the true ones after it (a lock-in)."""
    truth = _track()
    z = truth.copy()
    z[0] += [1.5, 0.0, 0.0]  # the first measurement is 1.5 m off: no next one can follow it at 10 m/s
    config = _track_config(mode)
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, config)
    assert np.isnan(out[0]).all()
    assert np.linalg.norm(out[1:] - truth[1:], axis=1).max() < 0.01 and not predicted.any()
    # without confirmation the track locks onto the outlier and loses the true measurements for max_gap frames
    locked, _ = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, replace(config, confirm=0, alternatives=0))
    lock = 3 if config.fast_process_noise else 5  # the IMM's fast model walks back to the true track sooner
    assert np.linalg.norm(locked[1:lock] - truth[1:lock], axis=1).min() > 0.5


def _ghosted(truth: np.ndarray) -> np.ndarray:
    """The reflector's measurements as one view's ghost takes its label: the ghost, static 1.2 m away, at frames 2,
    5, 9 and 13 (where the reflector itself is missing), the reflector at frame 1 and from frame 12 on, with gaps
    (measured so in a squat on the training split).  (frame, 3) -> same"""
    z = np.full_like(truth, np.nan)
    z[[1, 12, 16, 18, 19, 21]] = truth[[1, 12, 16, 18, 19, 21]]
    z[23:] = truth[23:]
    z[[2, 5, 9, 13]] = truth[0] + [0.2, -1.1, 0.45]
    return z


@MODES
def test_a_ghost_that_competes_for_the_label_loses_to_the_reflector(mode):
    truth = _track(n=40)
    truth[:, 2] -= np.linspace(0.0, 0.6, 40)  # the head going down in a squat
    z = _ghosted(truth)
    config = _track_config(mode)
    out, _ = smoothing.kalman_track(z, np.full(len(z), 0.85), 1 / 30, config)
    err = np.linalg.norm(out - truth, axis=1)
    assert np.isnan(out[:12]).all()  # the ghost's frames: missing, not written 1.2 m off
    # the reflector from frame 16 (at 12 the ghost's next frame breaks the confirmation), within 2 cm
    assert np.isfinite(out[16:]).all() and np.nanmax(err) < 0.02
    # one pass follows the ghost, which came first, and then bridges to the reflector across it
    one_pass, _ = smoothing.kalman_track(z, np.full(len(z), 0.85), 1 / 30, replace(config, alternatives=0))
    assert np.nanmax(np.linalg.norm(one_pass - truth, axis=1)[:23]) > 1.0


@MODES
def test_tracks_the_reflector_cannot_move_between_are_not_both_kept(mode):
    truth = _track()
    z = truth.copy()
    z[50:62] = np.nan  # 12 frames unseen (more than max_gap): the track ends at frame 49
    z[62:68] = truth[62:68] + [5.0, 0.0, 0.0]  # then six measurements 5 m away (11.5 m/s from frame 49)
    z[68:] = np.nan
    out, _ = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, _track_config(mode))
    assert np.linalg.norm(out[:50] - truth[:50], axis=1).max() < 0.01
    assert np.isnan(out[50:]).all()  # the weaker of the two is dropped
    both, _ = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, _track_config(mode, alternatives=0))
    assert np.isfinite(both[62:68]).all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_track_among_outliers_that_no_track_takes_is_kept(seed):
    """Only a stream another track takes counts against a track: after three frames, two of every three
    measurements scattered 0.6-1 m off (a noisy label; the reflector unseen there) leave its track whole."""
    truth = _track(n=40)
    rng = np.random.default_rng(seed)
    z = truth.copy()
    off = np.array([k for k in range(3, 40) if k % 3])
    direction = rng.normal(size=(len(off), 3))
    z[off] += direction / np.linalg.norm(direction, axis=1, keepdims=True) * rng.uniform(0.6, 1.0, (len(off), 1))
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, _track_config())
    assert np.isfinite(out).all() and np.linalg.norm(out - truth, axis=1).max() < 0.02
    np.testing.assert_array_equal(np.nonzero(predicted)[0], off)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_alternatives_leave_a_clean_track_as_one_pass_makes_it(seed):
    truth = _track()
    z = truth + np.random.default_rng(seed).normal(0, 0.003, truth.shape)
    z[30:34] = np.nan
    z[60] += [0.5, 0.0, 0.0]  # an outlier no measurement after it can follow
    confidence = np.full(len(z), 0.9)
    out, predicted = smoothing.kalman_track(z, confidence, 1 / 30, _track_config())
    one_pass, one_predicted = smoothing.kalman_track(z, confidence, 1 / 30, _track_config(alternatives=0))
    np.testing.assert_array_equal(out, one_pass)
    np.testing.assert_array_equal(predicted, one_predicted)


def _kick(n=90, fps=30.0, peak_m_s=12.0, hz=1.5):
    """A reflector that moves slowly, then from frame 40 swings out and back twice (1 - cos, 1.27 m) at up to
    ``peak_m_s`` (accelerations up to 113 m/s^2, a foot in a front kick).  -> (frame, 3) metres"""
    t = np.arange(n) / fps
    swing = np.clip(t - 40 / fps, 0.0, None)
    x = 0.1 * np.sin(2 * np.pi * 0.3 * t) + peak_m_s / (2 * np.pi * hz) * (1 - np.cos(2 * np.pi * hz * swing))
    return np.column_stack([x, 0.05 * t, np.full(n, 1.0)])


def _jitter(out: np.ndarray, fps=30.0) -> float:
    """RMS of the filtered track's second difference, m/s^2.  (frame, 3) -> scalar"""
    return float(np.sqrt(np.mean(np.sum(np.diff(out, 2, axis=0) ** 2, axis=1))) * fps**2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_imm_keeps_every_measurement_of_a_limb_that_accelerates_to_12_m_s(seed):
    truth = _kick()
    assert 11.9 < np.linalg.norm(np.diff(truth, axis=0), axis=1).max() * 30 < 12.0
    z = truth + np.random.default_rng(seed).normal(0, 0.003, truth.shape)  # 3 mm measurement noise
    confidence = np.full(len(z), 0.9)
    out, predicted = smoothing.kalman_track(z, confidence, 1 / 30, _track_config(IMM))
    err = np.linalg.norm(out - truth, axis=1)
    assert not predicted.any() and np.isfinite(out).all()  # no true measurement gated out
    assert np.mean(err) < 0.005 and err.max() < 0.02
    # the slow filter alone (in one pass; competing tracks do not make it faster) gates the swing out: frames
    # predicted, then the track lost
    slow, slow_predicted = smoothing.kalman_track(z, confidence, 1 / 30, _track_config(ONE, alternatives=0))
    assert slow_predicted.sum() >= 10 and np.isnan(slow[:, 0]).sum() >= 10
    assert np.nanmax(np.linalg.norm(slow - truth, axis=1)) > 0.5


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_imm_on_a_slow_track_is_no_worse_than_the_slow_filter(seed):
    truth = _track()
    z = truth + np.random.default_rng(seed).normal(0, 0.003, truth.shape)
    confidence = np.full(len(z), 0.9)
    fixed, _ = smoothing.kalman_track(z, confidence, 1 / 30, _track_config(ONE))
    imm, predicted = smoothing.kalman_track(z, confidence, 1 / 30, _track_config(IMM))
    fast, _ = smoothing.kalman_track(z, confidence, 1 / 30, _track_config(ONE, process_noise=8000.0))
    assert not predicted.any()
    err = {k: np.mean(np.linalg.norm(v - truth, axis=1)) for k, v in (("fixed", fixed), ("imm", imm), ("fast", fast))}
    assert err["imm"] < 1.05 * err["fixed"] < err["fast"]  # the fast noise alone would cost accuracy...
    assert _jitter(imm) < 1.1 * _jitter(fixed) < _jitter(fast)  # ... and smoothness


def test_imm_without_rts_takes_the_forward_estimate():
    truth = _kick()
    z = truth + np.random.default_rng(0).normal(0, 0.003, truth.shape)
    out, predicted = smoothing.kalman_track(z, np.full(len(z), 0.9), 1 / 30, _track_config(IMM, rts=False))
    assert not predicted.any() and np.linalg.norm(out - truth, axis=1).max() < 0.03


def test_confirmation_needs_each_next_measurement_within_reach():
    z = np.zeros((6, 3))
    z[:, 0] = [0.0, 0.1, 0.2, 1.0, np.nan, 1.1]
    z[4] = np.nan
    reach = {"dt": 1 / 30, "max_speed_m_s": 10.0, "slack_m": 0.03}  # 0.36 m per frame at most
    assert smoothing.confirmed(z, 0, count=2, within=10, **reach)
    assert not smoothing.confirmed(z, 1, count=2, within=10, **reach)  # 0.2 -> 1.0 is 0.8 m in one frame
    assert smoothing.confirmed(z, 3, count=1, within=10, **reach)  # 1.0 -> 1.1 over two frames (one missing)
    assert not smoothing.confirmed(z, 3, count=1, within=1, **reach)  # ... but not within one frame
    assert not smoothing.confirmed(z, 5, count=1, within=10, **reach)  # nothing after the last measurement


def test_butterworth_smooths_noise_and_keeps_gaps():
    truth = _track()
    z = truth + np.random.default_rng(1).normal(0, 0.005, truth.shape)
    z[50:52] = np.nan
    out = smoothing.butterworth_track(z, fps=30.0, cutoff_hz=3.0, order=4)
    assert np.isnan(out[50:52]).all()
    err = np.linalg.norm(out - truth, axis=1)
    assert np.nanmedian(err) < 0.6 * np.nanmedian(np.linalg.norm(z - truth, axis=1))


def test_kalman_config_refuses_a_non_positive_top_speed_and_a_negative_confirmation():
    with pytest.raises(ValueError, match="max_speed_m_s"):
        smoothing.KalmanConfig(max_speed_m_s=0.0)
    with pytest.raises(ValueError, match="confirm"):
        smoothing.KalmanConfig(confirm=-1)
    with pytest.raises(ValueError, match="^alternatives must be >= 0.*got -1"):
        smoothing.KalmanConfig(alternatives=-1)


@pytest.mark.parametrize("bad, field", [
    ({"fast_process_noise": 100.0}, "fast_process_noise"),  # slower than the slow model
    ({"fast_process_noise": -1.0}, "fast_process_noise"),
    ({"switch_probability": 0.0, "fast_process_noise": 4000.0}, "switch_probability"),
    ({"switch_probability": 0.6}, "switch_probability"),
    ({"process_noise": 0.0}, "process_noise"),
])
def test_kalman_config_refuses_bad_imm_values(bad, field):
    with pytest.raises(ValueError, match=rf"^{field} must be .*e\.g\..*got"):
        smoothing.KalmanConfig(**bad)


def test_the_kalman_stage_defaults_to_one_filter():
    """The IMM is an option: it costs two of the three training splits' poses (docs/deepmocap.md)."""
    truth = _kick()
    z = truth + np.random.default_rng(0).normal(0, 0.003, truth.shape)
    default = smoothing.kalman_track(z, np.full(len(z), 0.9), 1 / 30, smoothing.KalmanConfig())
    one = smoothing.kalman_track(z, np.full(len(z), 0.9), 1 / 30, _track_config(ONE))
    np.testing.assert_array_equal(default[0], one[0])
    np.testing.assert_array_equal(default[1], one[1])
