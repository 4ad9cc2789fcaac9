"""Training targets (Eq. 4-6) on hand-computed cases, crops and label-swapping flips."""

import numpy as np
import pytest

from mocapflow.tasks.deepmocap import targets
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES


def test_confidence_map_is_the_gaussian_of_eq4():
    maps = targets.confidence_maps(np.array([[2.0, 3.0], [1.0, 1.0]]), np.array([True, False]), (6, 5), sigma=1.0)
    assert maps.shape == (3, 6, 5)
    assert maps[0, 3, 2] == pytest.approx(1.0)
    assert maps[0, 3, 3] == pytest.approx(np.exp(-1.0))  # one cell away: exp(-1 / sigma^2)
    assert maps[0, 4, 4] == pytest.approx(np.exp(-5.0))  # (2, 1) away: exp(-5)
    assert not maps[1].any()  # not seen: no target
    np.testing.assert_allclose(maps[2], 1.0 - maps[0])  # background


def test_flow_field_follows_the_segment_of_eq5_6():
    start, end = np.array([[1.0, 1.0]]), np.array([[4.0, 1.0]])
    field = targets.flow_fields(start, end, np.array([True]), (5, 7), width=1.0)  # (1, 2, hy, hx)
    assert field.shape == (1, 2, 5, 7)
    np.testing.assert_allclose(field[0, :, 1, 2], [1.0, 0.0])  # on the segment: the unit direction
    np.testing.assert_allclose(field[0, :, 2, 3], [1.0, 0.0])  # one cell across: inside width 1
    np.testing.assert_allclose(field[0, :, 3, 3], [0.0, 0.0])  # two cells across: outside
    np.testing.assert_allclose(field[0, :, 1, 0], [0.0, 0.0])  # before the start
    np.testing.assert_allclose(field[0, :, 1, 5], [0.0, 0.0])  # past the end
    diagonal = targets.flow_fields(np.array([[0.0, 0.0]]), np.array([[3.0, 4.0]]), np.array([True]), (6, 6), 0.5)
    np.testing.assert_allclose(diagonal[0, :, 4, 3], [0.6, 0.8])
    still = targets.flow_fields(start, start, np.array([True]), (5, 7), width=1.0)
    assert not still.any()


def test_crop_centres_the_box_and_flips_swap_sides():
    box = np.array([100.0, 50.0, 140.0, 170.0])
    m = targets.crop_affine(box, size=160, margin=1.25, min_side=10.0)
    np.testing.assert_allclose(targets.apply_affine(m, np.array([[120.0, 110.0]])), [[79.5, 79.5]])
    top = targets.apply_affine(m, np.array([[120.0, 50.0]]))[0]
    assert top[1] == pytest.approx(79.5 - 160 / 1.25 / 2)  # the long side spans size / margin pixels
    flipped = targets.crop_affine(box, size=160, margin=1.25, min_side=10.0, jitter=targets.CropJitter(flip=True))
    left = targets.apply_affine(flipped, np.array([[100.0, 110.0]]))[0]
    assert left[0] > 79.5  # the image's left lands on the crop's right
    back = targets.apply_affine(targets.invert_affine(m), targets.apply_affine(m, box.reshape(2, 2)))
    np.testing.assert_allclose(back, box.reshape(2, 2), atol=1e-9)


def test_flip_order_swaps_left_and_right_labels():
    order = targets.FLIP_ORDER
    assert REFLECTOR_NAMES[order[REFLECTOR_NAMES.index("R_HAND")]] == "L_HAND"
    assert REFLECTOR_NAMES[order[REFLECTOR_NAMES.index("B_L_SHOULDER")]] == "B_R_SHOULDER"
    assert REFLECTOR_NAMES[order[REFLECTOR_NAMES.index("B_HEAD")]] == "B_HEAD"  # central: unchanged
    np.testing.assert_array_equal(order[order], np.arange(len(order)))


def test_warped_flow_image_turns_its_motion_with_the_crop():
    image = np.full((40, 40, 3), 128, np.uint8)
    image[..., 0] = 128 + 100  # everything moves +x
    box = np.array([10.0, 10.0, 30.0, 30.0])
    flipped = targets.warp_flow(image, targets.crop_affine(box, size=32, margin=1.0, min_side=1.0,
                                                           jitter=targets.CropJitter(flip=True)), 32)
    assert flipped[16, 16, 0] == 28 and flipped[16, 16, 1] == 128  # mirrored: moves -x
    turned = targets.warp_flow(image, targets.crop_affine(box, size=32, margin=1.0, min_side=1.0,
                                                          jitter=targets.CropJitter(rotation_deg=90.0)), 32)
    assert turned[16, 16, 0] == 128 and turned[16, 16, 1] == 228  # a quarter turn: x motion becomes y


def test_subject_box_spans_the_reflector_regions():
    blob_id = np.zeros((50, 60), np.uint16)
    blob_id[5:8, 10:13] = 1
    blob_id[40:44, 50:52] = 2
    blob_id[20, 2] = 3  # a 1-pixel speck is not a reflector
    box = targets.subject_box(blob_id, np.array([9, 8, 1]), targets.BoxRule(min_area=3))
    np.testing.assert_array_equal(box, [10, 5, 51, 43])


def test_a_speck_far_from_the_subject_stays_out_of_its_box():
    blob_id = np.zeros((424, 512), np.uint16)
    blob_id[200:210, 250:260] = 1  # the subject: two reflectors 40 px apart
    blob_id[240:250, 250:260] = 2
    blob_id[228:230, 300:302] = 3  # a small reflector beside them (a hand): 45 px from the nearest
    blob_id[10:12, 10:12] = 4  # a speck in a corner of the room, 4 px
    blob_id[400:420, 480:500] = 5  # a large region far off: a reflector, not a speck
    areas = np.array([100, 100, 4, 4, 400])
    rule = targets.BoxRule(min_area=3, speck_area=20, link_px=120.0)
    np.testing.assert_array_equal(targets.subject_box(blob_id, areas, rule), [250, 200, 499, 419])
    no_speck_rule = targets.BoxRule(min_area=3)
    np.testing.assert_array_equal(targets.subject_box(blob_id, areas, no_speck_rule), [10, 10, 499, 419])
    areas[4] = 0  # without the large one: the subject and its hand
    np.testing.assert_array_equal(targets.subject_box(blob_id, areas, rule), [250, 200, 301, 249])
    only = np.where(blob_id == 4, 4, 0).astype(np.uint16)
    np.testing.assert_array_equal(targets.subject_box(only, areas, rule), [10, 10, 11, 11])  # alone: kept
