"""The monocular prior's estimator: BlazePose's geometry rebuilt as array functions, and the real networks on
the studio's video of a body whose joints are known."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import xarray as xr

from blazepose_models import blazepose_files
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.kinematics import rigid_fit
from mocapflow.tasks.uuo import monocular
from mocapflow.tasks.shared.blazepose import EstimatorError, Region, body_region, decode_detection, ssd_anchors
from mocapflow.tasks.uuo.monocular import (BlazePose, MonocularPriorConfig, monocular_prior, perturb_frames,
                                           template_joints, to_z_up, unmirror_landmarks)
from mocapflow.tasks.uuo.prior import PriorError, aligned_mpjpe, procrustes_mpjpe


def test_the_detector_anchors_are_its_2254_cells_in_output_order():
    a = ssd_anchors()
    assert a.shape == (2254, 2)
    np.testing.assert_allclose(a[0], [0.5 / 28, 0.5 / 28])  # stride 8: 28 x 28 cells, two anchors each
    np.testing.assert_allclose(a[1], a[0])
    np.testing.assert_allclose(a[2], [1.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(a[1568], [0.5 / 14, 0.5 / 14])  # stride 16 starts after 28 * 28 * 2
    np.testing.assert_allclose(a[-1], [6.5 / 7, 6.5 / 7])  # the three stride-32 layers: 7 x 7 cells, six anchors


def test_a_detection_is_decoded_to_image_pixels_through_the_letterbox():
    boxes = np.zeros((2254, 12), np.float32)
    logits = np.full(2254, -10.0, np.float32)
    best = 1568 + 2 * (14 * 7 + 7)  # a stride-16 cell in the middle of the grid
    logits[best] = 3.0
    boxes[best, 4:12] = [0, 0, 0, -40, 10, -20, 0, -50]  # hips' centre on the anchor, the circle 40 px above
    side, offset = 640.0, np.array([0.0, 80.0])  # a 640 x 480 frame padded to 640 x 640
    points = decode_detection(boxes, logits, side, offset, 0.5)
    centre = ssd_anchors()[best] * side - offset
    np.testing.assert_allclose(points[0], centre, atol=1e-4)
    np.testing.assert_allclose(points[1], centre + [0, -40 * side / 224], atol=1e-3)
    assert decode_detection(boxes, logits - 10.0, side, offset, 0.5) is None  # every score under the threshold


def test_the_region_stands_the_body_upright_and_crops_what_it_maps_back():
    up = body_region(np.array([300.0, 250.0]), np.array([300.0, 150.0]))
    assert up.rotation == pytest.approx(0.0) and up.side == pytest.approx(250.0)
    lying = body_region(np.array([300.0, 250.0]), np.array([400.0, 250.0]))  # head to the right
    assert abs(lying.rotation) == pytest.approx(np.pi / 2)
    image = np.zeros((480, 640, 3), np.uint8)
    cv2.circle(image, (330, 210), 3, (255, 255, 255), -1)
    for region in (up, lying, Region(np.array([320.0, 240.0]), 300.0, 0.6)):
        crop = cv2.warpAffine(image, region.crop_transform(256), (256, 256),
                              flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR)
        ys, xs = np.nonzero(crop[..., 0] > 100)
        found = region.to_image(np.array([[xs.mean(), ys.mean()]]), 256)[0]
        np.testing.assert_allclose(found, [330, 210], atol=1.0)


def test_world_landmarks_turn_onto_z_up_right_handed():
    turn = to_z_up(np.eye(3))  # rows: x, y, z of BlazePose's frame
    assert np.linalg.det(turn) == pytest.approx(1.0)
    np.testing.assert_allclose(to_z_up(np.array([0.0, -1.0, 0.0])), [0, 0, 1])  # image up (y down) is up
    np.testing.assert_allclose(to_z_up(np.array([0.0, 0.0, 1.0])), [0, 1, 0])  # away from the camera


def test_the_template_joints_are_read_off_the_landmarks_by_side():
    rng = np.random.default_rng(0)
    lm = rng.normal(size=(33, 3))
    joints = template_joints(lm)
    assert joints.shape == (20, 3)
    j = dict(zip(JOINT_NAMES, joints))
    np.testing.assert_allclose(j["LeftShoulder"], lm[monocular.LEFT_SHOULDER])
    np.testing.assert_allclose(j["RightKnee"], lm[monocular.RIGHT_KNEE])
    np.testing.assert_allclose(j["Hips"], (lm[23] + lm[24]) / 2)
    np.testing.assert_allclose(j["LeftHand"], (lm[17] + lm[19]) / 2)
    np.testing.assert_allclose(j["Neck"] - j["Hips"], 1.21 * ((lm[11] + lm[12]) / 2 - j["Hips"]))
    assert template_joints(np.stack([lm, lm + 1])).shape == (2, 20, 3)


def test_the_estimator_refuses_missing_networks_and_markers_without_video():
    with pytest.raises(EstimatorError, match="detector network is missing"):
        BlazePose(b"", b"x")
    with pytest.raises(EstimatorError, match="not a TensorFlow Lite model"):
        BlazePose(b"not a model at all", b"x")
    markers = xr.Dataset({"position": (("frame", "marker", "xyz"), np.zeros((2, 1, 3), np.float32))},
                         coords={"frame": [0, 1]})
    with pytest.raises(PriorError, match="needs the take's video"):
        monocular_prior(markers, MonocularPriorConfig(), b"", b"")
    with pytest.raises(PriorError, match="thresholds"):
        MonocularPriorConfig(min_presence=1.5)


@pytest.fixture(scope="module")
def filmed():
    """A procedural exercise on the mesh body, 12 frames, filmed by the studio's video camera."""
    from mocapflow.tasks.deepmocap.film.synth import build_rig
    from mocapflow.tasks.studio.spec import SequenceSpec
    from mocapflow.tasks.uuo.video import VideoSpec, film

    rig = build_rig(SequenceSpec("side_reaches", frames=12, seed=3, body="mesh", views=1))
    n = rig.n_frames
    video = film(rig.take.posed.vertices[:n], rig.body.faces, rig.body.uv, VideoSpec(), np.random.default_rng(1))
    return video, rig.take.posed.heads[:n][:, rig.body.joint_bones()]


def test_blazepose_finds_the_studio_body_and_its_joints_by_side(filmed):
    detector, landmarker = blazepose_files()
    video, truth = filmed
    landmarks, presence = BlazePose(detector.read_bytes(), landmarker.read_bytes()).track(video)
    joints = template_joints(landmarks)
    assert np.isfinite(joints).all() and (presence > 0.9).all()  # a body on every frame
    assert procrustes_mpjpe(joints, truth) < 0.12  # measured 74-95 mm on 48-frame exercises
    assert aligned_mpjpe(joints, truth) < 0.16
    # left is left: after the alignment each wrist lies nearer its own true wrist than the other's
    lw, rw = JOINT_NAMES.index("LeftWrist"), JOINT_NAMES.index("RightWrist")
    a = joints - joints.mean(axis=1, keepdims=True)
    b = truth - truth.mean(axis=1, keepdims=True)
    rot, _ = rigid_fit(a.reshape(-1, 3), b.reshape(-1, 3))
    placed = a @ rot.T
    own = np.linalg.norm(placed[:, lw] - b[:, lw], axis=-1) + np.linalg.norm(placed[:, rw] - b[:, rw], axis=-1)
    swapped = np.linalg.norm(placed[:, lw] - b[:, rw], axis=-1) + np.linalg.norm(placed[:, rw] - b[:, lw], axis=-1)
    assert (own < swapped).mean() > 0.9


def test_the_monocular_prior_fits_anny_to_the_estimate(filmed):
    detector, landmarker = blazepose_files()
    video, truth = filmed
    n = len(video)
    black = video.copy()
    black[5] = 0  # a frame with nobody in it is lost, held from its neighbour
    markers = xr.Dataset({"position": (("frame", "marker", "xyz"), np.zeros((n, 1, 3), np.float32)),
                          "video": (("frame", "y", "x", "rgb"), black)},
                         coords={"frame": np.arange(n)}, attrs={"fps": 30.0})
    out = monocular_prior(markers, MonocularPriorConfig(), detector.read_bytes(), landmarker.read_bytes())
    valid = out["valid"].values
    assert out.attrs["source"] == "monocular" and out.attrs["found_frames"] == n - 1
    assert not valid[5] and valid.sum() == n - 1
    joints = out["joints"].values.astype(float)
    np.testing.assert_allclose(joints[5], joints[4], atol=1e-6)
    assert aligned_mpjpe(joints[valid], truth[valid]) < 0.16
    assert out.attrs["fit_error_mm"] < 40.0


def test_the_estimators_input_is_moved_zoomed_and_mirrored_as_asked():
    image = np.zeros((48, 64, 3), np.uint8)
    image[19:22, 29:32] = 255  # a 3 x 3 spot centred on x 30, y 20
    frames = image[None]

    def spot(frames):
        ys, xs = np.nonzero(frames[0, ..., 0] > 0)
        weight = frames[0, ys, xs, 0].astype(float)
        return np.array([(xs * weight).sum(), (ys * weight).sum()]) / weight.sum()

    assert perturb_frames(frames) is frames  # nothing asked: the frames themselves, today's estimate unchanged
    np.testing.assert_allclose(spot(perturb_frames(frames, (5.0, -3.0))), [35, 17], atol=1e-6)
    np.testing.assert_allclose(spot(perturb_frames(frames, flip=True)), [63 - 30, 20], atol=1e-6)
    np.testing.assert_allclose(spot(perturb_frames(frames, scale=2.0)), [31.5 + 2 * (30 - 31.5), 23.5 + 2 * (20 - 23.5)],
                               atol=0.05)  # zoomed about the frame's centre
    rng = np.random.default_rng(0)
    real = rng.normal(size=(2, 33, 3))
    seen = real[:, monocular.MIRRORED_LANDMARKS] * [-1.0, 1.0, 1.0]  # the mirrored body, its sides read swapped
    np.testing.assert_allclose(unmirror_landmarks(seen), real)
    assert monocular.MIRRORED_LANDMARKS[monocular.LEFT_WRIST] == monocular.RIGHT_WRIST
    with pytest.raises(PriorError, match="perturbation out of range"):
        MonocularPriorConfig(scale=3.0)


def test_a_moved_or_mirrored_video_changes_the_estimate_a_little(filmed):
    """A second and third estimate of one take for combine.py: the same networks on the video moved by a few
    pixels, or mirrored and read back, differ from the first by centimetres, not by a different body."""
    detector, landmarker = blazepose_files()
    video, truth = filmed
    estimator = BlazePose(detector.read_bytes(), landmarker.read_bytes())

    def gap(a, b):  # mean joint distance, each frame hips-centred, in the camera's axes (no alignment)
        return np.linalg.norm((a - a.mean(axis=1, keepdims=True)) - (b - b.mean(axis=1, keepdims=True)), axis=-1).mean()

    first = template_joints(estimator.track(video)[0])
    moved = template_joints(estimator.track(perturb_frames(video, (9.0, 6.0)))[0])
    seen = estimator.track(perturb_frames(video, flip=True))[0]
    mirrored = template_joints(unmirror_landmarks(seen))
    assert 0.001 < gap(moved, first) < 0.012, gap(moved, first)  # measured 5.9 mm; twice that: unstable
    assert gap(mirrored, first) < 0.05, gap(mirrored, first)  # measured 36.8 mm
    wrong = seen.copy()
    wrong[..., 0] *= -1.0  # mirrored back without the sides swapped: a body of the other handedness
    assert gap(template_joints(wrong), first) > 0.2  # measured 305 mm
    for joints in (moved, mirrored):  # measured 97 and 102 mm
        assert aligned_mpjpe(joints, truth) < 0.13, aligned_mpjpe(joints, truth)
    n = len(video)
    markers = xr.Dataset({"position": (("frame", "marker", "xyz"), np.zeros((n, 1, 3), np.float32)),
                          "video": (("frame", "y", "x", "rgb"), video)}, coords={"frame": np.arange(n)},
                         attrs={"fps": 30.0})
    out = monocular_prior(markers, MonocularPriorConfig(flip=True), detector.read_bytes(), landmarker.read_bytes())
    assert out.attrs["input_perturbed"] == {"shift_px": [0.0, 0.0], "scale": 1.0, "flip": True}
    assert aligned_mpjpe(out["joints"].values.astype(float), truth) < 0.16
