"""Temporal filtering: the Kalman stage fills a short gap, rejects an outlier, gives up after max_gap;
Butterworth keeps a slow motion and removes noise."""

from dataclasses import asdict

import numpy as np

from mocapflow.tasks import smoothing


def _track(n=90, fps=30.0):
    t = np.arange(n) / fps
    return np.column_stack([0.5 * np.sin(2 * np.pi * 0.5 * t), 0.2 * t, np.full(n, 1.0)])


def test_kalman_fills_a_gap_and_rejects_an_outlier():
    truth = _track()
    rng = np.random.default_rng(0)
    z = truth + rng.normal(0, 0.003, truth.shape)
    z[40:45] = np.nan  # a 5-frame gap
    z[60] += [0.5, 0.0, 0.0]  # a 0.5 m outlier
    config = asdict(smoothing.KalmanConfig())
    out, predicted = smoothing.kalman_track(z, np.full(len(z), 0.9), dt=1 / 30, **config)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(np.nonzero(predicted)[0], [40, 41, 42, 43, 44, 60])
    assert np.linalg.norm(out[40:45] - truth[40:45], axis=1).max() < 0.02  # bridged within 2 cm
    assert np.linalg.norm(out[60] - truth[60]) < 0.02  # the outlier left no mark
    assert np.median(np.linalg.norm(out - truth, axis=1)) < np.median(np.linalg.norm(z - truth, axis=1)[np.isfinite(z[:, 0])])


def test_kalman_reports_missing_past_max_gap_and_restarts():
    z = _track()
    z[30:60] = np.nan
    config = {**asdict(smoothing.KalmanConfig()), "max_gap": 10}
    out, predicted = smoothing.kalman_track(z, np.ones(len(z)), dt=1 / 30, **config)
    assert np.isfinite(out[30:40]).all() and np.isnan(out[40:60]).all()  # 10 frames predicted, then missing
    assert np.isfinite(out[60:]).all() and not predicted[40:].any()


def test_butterworth_smooths_noise_and_keeps_gaps():
    truth = _track()
    z = truth + np.random.default_rng(1).normal(0, 0.005, truth.shape)
    z[50:52] = np.nan
    out = smoothing.butterworth_track(z, fps=30.0, cutoff_hz=3.0, order=4)
    assert np.isnan(out[50:52]).all()
    err = np.linalg.norm(out - truth, axis=1)
    assert np.nanmedian(err) < 0.6 * np.nanmedian(np.linalg.norm(z - truth, axis=1))
