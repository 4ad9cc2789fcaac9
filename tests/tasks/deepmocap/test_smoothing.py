"""Temporal filtering: the Kalman stage fills a short gap, rejects an outlier, gives up after max_gap,
does not extrapolate a track's end, starts tracks only on confirmed measurements;
Butterworth keeps a slow motion and removes noise."""

from dataclasses import replace

import numpy as np
import pytest

from mocapflow.tasks.deepmocap import smoothing


def _track_config(**overrides) -> smoothing.KalmanConfig:
    """The default config with ``overrides``."""
    return smoothing.KalmanConfig(**overrides)


def _track(n=90, fps=30.0):
    t = np.arange(n) / fps
    return np.column_stack([0.5 * np.sin(2 * np.pi * 0.5 * t), 0.2 * t, np.full(n, 1.0)])


def test_kalman_fills_a_gap_and_rejects_an_outlier():
    truth = _track()
    rng = np.random.default_rng(0)
    z = truth + rng.normal(0, 0.003, truth.shape)
    z[40:45] = np.nan  # a 5-frame gap
    z[60] += [0.5, 0.0, 0.0]  # a 0.5 m outlier
    config = _track_config()
    out, predicted = smoothing.kalman_track(z, np.full(len(z), 0.9), 1 / 30, config)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(np.nonzero(predicted)[0], [40, 41, 42, 43, 44, 60])
    assert np.linalg.norm(out[40:45] - truth[40:45], axis=1).max() < 0.02  # bridged within 2 cm
    assert np.linalg.norm(out[60] - truth[60]) < 0.02  # the outlier left no mark
    assert np.median(np.linalg.norm(out - truth, axis=1)) < np.median(np.linalg.norm(z - truth, axis=1)[np.isfinite(z[:, 0])])


def test_kalman_reports_missing_past_max_gap_and_restarts():
    z = _track()
    z[30:60] = np.nan
    config = _track_config(max_gap=10)
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, config)
    # the track ends at its last measurement: nothing is extrapolated into the gap it cannot bridge
    assert np.isfinite(out[:30]).all() and np.isnan(out[30:60]).all()
    assert np.linalg.norm(out[60:] - z[60:], axis=1).max() < 0.01 and not predicted.any()


def test_kalman_bridges_a_gap_inside_a_track_but_does_not_extrapolate_its_end():
    truth = _track()
    z = truth.copy()
    z[20:26] = np.nan  # inside the track: bridged
    z[80:] = np.nan  # after its last measurement: missing, not predicted
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, _track_config())
    np.testing.assert_array_equal(np.nonzero(predicted)[0], np.arange(20, 26))
    assert np.linalg.norm(out[20:26] - truth[20:26], axis=1).max() < 0.02
    assert np.isnan(out[80:]).all()


def test_kalman_does_not_start_a_track_on_a_lone_outlier():
    """Started on a wrong first measurement, the gate would reject the true ones after it (a lock-in)."""
    truth = _track()
    z = truth.copy()
    z[0] += [1.5, 0.0, 0.0]  # the first measurement is 1.5 m off: no next one can follow it at 10 m/s
    config = _track_config()
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, config)
    assert np.isnan(out[0]).all()
    assert np.linalg.norm(out[1:] - truth[1:], axis=1).max() < 0.01 and not predicted.any()
    # without confirmation the track locks onto the outlier and loses the true measurements for max_gap frames
    locked, _ = smoothing.kalman_track(z, np.ones(len(z)), 1 / 30, replace(config, confirm=0))
    assert np.linalg.norm(locked[1:5] - truth[1:5], axis=1).min() > 0.5


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
