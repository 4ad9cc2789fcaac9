"""Hiding observations to score the filling: single corners at random, or patches shaped like an occluder's
shadow that follow the body for a run of frames."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.suit.holdout import HoldoutConfig, HoldoutError, hidden_patches, hidden_runs


def sheet(frames=20, n=30, spacing=0.03, drop=0.1, seed=0):
    """A 30 x 30 grid of corners 3 cm apart, sliding 1 cm a frame along x; ``drop`` of the observations missing."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    grid = np.column_stack([i.ravel() * spacing, j.ravel() * spacing, np.zeros(n * n)])
    position = np.stack([grid + [0.01 * f, 0.0, 0.0] for f in range(frames)])
    position[rng.random(position.shape[:2]) < drop] = np.nan
    return position


def test_patches_hide_the_asked_share_in_compact_holes_that_follow_the_body():
    position = sheet()
    observed = np.isfinite(position).all(axis=-1)
    config = HoldoutConfig(share=0.1, run_frames=(3, 6), seed=4, shape="patch", radius_m=(0.06, 0.12))
    hide = hidden_patches(position, config)
    assert not (hide & ~observed).any()
    assert 0.1 <= hide.sum() / observed.sum() < 0.2
    # In the body's own frame (the slide undone), a hidden corner's hidden neighbours lie within a patch's diameter
    rest = position - np.array([0.01, 0, 0]) * np.arange(len(position))[:, None, None]
    for f in np.flatnonzero(hide.any(axis=1))[:5]:
        pts = rest[f][hide[f]]
        near = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
        assert (np.sort(near, axis=1)[:, 1] <= 0.061).all()  # no hidden corner alone (unobserved ones aside): holes
    # runs: a hidden corner stays hidden on a following frame more often than not
    both = (hide[1:] & hide[:-1]).sum()
    assert both > 0.5 * hide[1:].sum()


def test_random_holes_hide_single_corners_for_one_run_each():
    observed = np.isfinite(sheet()).all(axis=-1)
    hide = hidden_runs(observed, HoldoutConfig(share=0.05, run_frames=(2, 4), seed=1))
    per_corner = hide.any(axis=0)
    assert per_corner.sum() <= round(0.05 * observed.shape[1])
    frames = np.flatnonzero(hide[:, np.flatnonzero(per_corner)[0]])
    assert frames.max() - frames.min() <= 3


def test_bad_hole_settings_are_refused():
    with pytest.raises(HoldoutError, match="shapes: random, patch"):
        HoldoutConfig(shape="limbs")
    with pytest.raises(HoldoutError, match="radius_m"):
        HoldoutConfig(shape="patch", radius_m=(0.2, 0.1))
