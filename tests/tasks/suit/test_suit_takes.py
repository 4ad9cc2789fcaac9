"""Suit takes: each readable corner is rendered as a checkerboard saddle at its true pixel; the truth is
consistent with the cameras; the same seed films the same bytes."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.suit import takes as st
from mocapflow.tasks.deepmocap.film import synth
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.suit import pattern as pt

CLOSE = st.SuitCameras(count=2, width=480, height=640, radius=1.4, heights=(1.2, 1.2), target=(0.0, 0.0, 1.2),
                       view_height_m=0.7)  # about 1 px per mm on the chest


@pytest.fixture(scope="module")
def take():
    ref = mesh_body(Phenotype())
    suit = pt.make_suit(ref, pt.SUITS["small"])
    mesh_rig = synth.build_rig(SequenceSpec(motion="classic_squat", body="mesh", frames=2, views=1, seed=3))
    rig = st.suit_rig(mesh_rig.body, suit, CLOSE, st.SuitLook(), seed=3)
    return rig, mesh_rig, st.film(rig, mesh_rig.take.posed.vertices, range(0, 1))


def test_readable_corners_are_checkerboard_saddles_at_their_true_pixels(take):
    rig, _, shot = take
    image = shot.image[0, 0].astype(float)
    xy = shot.corners2d[0, 0][shot.readable[0, 0]]
    xy = xy[((xy >= 6) & (xy < np.array([CLOSE.width, CLOSE.height]) - 6)).all(axis=1)]
    assert len(xy) > 40
    contrast = []
    for x, y in xy:
        c, r = int(round(x)), int(round(y))
        q = [image[r - 5:r - 1, c - 5:c - 1].mean(), image[r - 5:r - 1, c + 2:c + 6].mean(),
             image[r + 2:r + 6, c + 2:c + 6].mean(), image[r + 2:r + 6, c - 5:c - 1].mean()]  # TL TR BR BL
        contrast.append(abs((q[0] + q[2]) - (q[1] + q[3])) / 2)  # diagonal quadrants alike, neighbours opposite
    assert np.median(contrast) > 40


def test_truth_agrees_with_the_cameras(take):
    rig, mesh_rig, shot = take
    for v, cam in enumerate(rig.cameras):
        xy, z = cam.project(shot.corners[0])
        np.testing.assert_allclose(shot.corners2d[v, 0], xy, atol=1e-6)
        assert (z[shot.visible[v, 0]] > 0).all()
        assert not (shot.readable[v, 0] & ~shot.visible[v, 0]).any()  # readable corners are visible
    inside = (shot.corners2d[..., 0] >= -0.5) & (shot.corners2d[..., 0] < CLOSE.width - 0.5)  # pixel centres at integers
    assert not (shot.visible & ~inside).any()


def test_same_seed_same_bytes(take):
    rig, mesh_rig, shot = take
    again = st.film(st.suit_rig(mesh_rig.body, rig.suit, CLOSE, st.SuitLook(), seed=3), mesh_rig.take.posed.vertices,
                    range(0, 1))
    np.testing.assert_array_equal(again.image, shot.image)


def test_bad_camera_settings_are_refused():
    with pytest.raises(st.SuitTakeError, match="views"):
        st.SuitCameras(count=0)
    with pytest.raises(st.SuitTakeError, match="64 x 64"):
        st.SuitCameras(width=32)
