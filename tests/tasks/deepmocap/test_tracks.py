"""Label continuity of the mirrored limb reflectors: an exchanged stretch of a walking pair of legs is
put back, legs that cross in space keep their labels, a lone measurement on the other side's track
takes that side's label, one bad frame does not flip the rest of the take, one limb under both labels
loses the impostor label (judged from the frames before and after, limbs that touch keep both), a
label on another reflector's track is dropped (reflectors side by side on the body keep both), and
the Kalman stage smooths the relabelled data."""

import numpy as np
import pytest
import xarray as xr

from mocapflow.tasks.deepmocap import skeleton, smoothing, tracks
from mocapflow.tasks.shared import labels
from mocapflow.tasks.shared.reflectors import REFLECTOR_TABLE

NAMES = [name for name, *_ in REFLECTOR_TABLE]
LEGS = ("CALF", "ANKLE", "FOOT")
HEIGHTS = {"CALF": 0.45, "ANKLE": 0.10, "FOOT": 0.05}


def walking_legs(n=60, fps=30.0) -> np.ndarray:
    """Every reflector's true track (frame, reflector, 3), x forward, y left, z up: a body walking in place, legs
    swinging in antiphase 0.3 m apart, everything else still where the rest-pose template puts it (arms out)."""
    t = np.arange(n) / fps
    rest = skeleton.rest_reflector_positions(NAMES)  # (reflector, 3): x to the right, y forward, z up, hips at 0
    xyz = np.tile(np.stack([rest[:, 1], -rest[:, 0], rest[:, 2] + 1.0], axis=-1), (n, 1, 1))
    for side, phase in (("L", 0.0), ("R", np.pi)):
        for part in LEGS:
            r = NAMES.index(f"{side}_{part}")
            xyz[:, r, 0] = 0.25 * np.sin(2 * np.pi * 1.0 * t + phase)
            xyz[:, r, 1] = 0.15 if side == "L" else -0.15
            xyz[:, r, 2] = HEIGHTS[part]
    return xyz


def exchange(xyz: np.ndarray, frames, parts=LEGS) -> np.ndarray:
    out = xyz.copy()
    left = [NAMES.index(f"L_{p}") for p in parts]
    right = [NAMES.index(f"R_{p}") for p in parts]
    out[np.ix_(frames, left + right)] = xyz[np.ix_(frames, right + left)]
    return out


STAGE = smoothing.KalmanConfig()


def resolve(z, conf=None, *, duplicate_m=STAGE.duplicate_m, shared_m=STAGE.shared_m):
    """``tracks.resolve_swaps`` at the `kalman` stage's defaults.  -> position, confidence, exchanges, dropped"""
    conf = np.ones(z.shape[:2]) if conf is None else conf
    return tracks.resolve_swaps(z, conf, NAMES, penalty_m=STAGE.swap_penalty_m, reach=STAGE.swap_reach,
                                duplicate_m=duplicate_m, duplicate_reach=STAGE.duplicate_reach, shared_m=shared_m)


def test_mirrored_pairs_pair_left_and_right_limb_reflectors_by_name():
    pairs = labels.mirrored_pairs(NAMES)
    assert [(NAMES[a], NAMES[b]) for a, b in pairs] == [
        ("L_ELBOW", "R_ELBOW"), ("L_WRIST", "R_WRIST"), ("L_HAND", "R_HAND"),
        ("L_CALF", "R_CALF"), ("L_ANKLE", "R_ANKLE"), ("L_FOOT", "R_FOOT")]
    assert labels.mirrored_pairs(["L_CALF", "R_CALF", "L_FOOT"]) == [(0, 1)]  # an unpaired reflector is left out


def test_an_exchanged_stretch_of_the_legs_is_put_back():
    truth = walking_legs()
    rng = np.random.default_rng(1)
    noisy = truth + rng.normal(0, 0.004, truth.shape)
    swapped = exchange(noisy, np.arange(20, 31))
    conf = np.tile(np.linspace(0.5, 1.0, len(NAMES)), (len(truth), 1))
    position, confidence, count, _ = resolve(swapped, exchange(conf, np.arange(20, 31)))
    assert count == 3 * 11  # three pairs, eleven frames
    np.testing.assert_array_equal(position, noisy)
    np.testing.assert_array_equal(confidence, conf)  # confidences travel with their positions


def test_legs_that_cross_in_space_keep_their_labels():
    """The left leg sweeps across the right one's side (a crossover step): continuity, not sides, decides."""
    n = 40
    truth = walking_legs(n)
    for part in LEGS:
        truth[:, NAMES.index(f"L_{part}"), 1] = np.linspace(0.15, -0.45, n)  # passes the right leg at y = -0.15
        truth[:, NAMES.index(f"L_{part}"), 0] = 0.12  # 12 cm in front of it
        truth[:, NAMES.index(f"R_{part}"), 0] = 0.0
    _, _, count, dropped = resolve(truth)
    assert count == 0 and dropped == 0


def test_a_lone_measurement_on_the_other_track_takes_its_label_and_missing_data_is_kept_missing():
    truth = walking_legs()
    z = truth.copy()
    ankle_l, ankle_r = NAMES.index("L_ANKLE"), NAMES.index("R_ANKLE")
    z[25, ankle_l] = truth[25, ankle_r]  # the right ankle, labelled left, and nothing labelled right
    z[25, ankle_r] = np.nan
    z[26:28, ankle_l] = np.nan  # and a gap: the last positions are held over it
    position, _, count, _ = resolve(z)
    assert count == 1
    np.testing.assert_array_equal(position[25, ankle_r], truth[25, ankle_r])
    assert np.isnan(position[25, ankle_l]).all() and np.isnan(position[26:28, ankle_l]).all()
    np.testing.assert_array_equal(position[28:], truth[28:])


def test_one_bad_frame_does_not_flip_the_rest_of_the_take():
    """A frame-by-frame tracker that accepts one wrong exchange follows the wrong side from there on."""
    truth = walking_legs()
    z = truth.copy()
    z[19, NAMES.index("L_CALF")] = truth[19, NAMES.index("R_CALF")]  # the left calf on the right one's track
    z[19, NAMES.index("R_CALF")] += [2.8, 0.0, 0.0]  # and the right calf wild
    z[20:, NAMES.index("R_CALF")] = np.nan  # then the right calf is lost for good
    position, _, count, _ = resolve(z)
    assert count <= 1  # frame 19 itself may go either way
    np.testing.assert_array_equal(position[20:], z[20:])


def test_viterbi_on_a_hand_computed_case():
    # frame 2 jumps (switching is cheap there), frame 4 jumps back: exchanging frames 2-3 costs 2 x 0.1
    same = np.array([0.0, 0.1, 1.0, 0.1, 1.0, 0.1])
    exchanged = np.array([0.0, 1.0, 0.1, 1.0, 0.1, 1.0])
    np.testing.assert_array_equal(tracks.viterbi(same, exchanged, np.full(6, 0.1)), [0, 0, 1, 1, 0, 0])
    # when exchanging costs more than the two jumps it removes, the labels stay as given
    np.testing.assert_array_equal(tracks.viterbi(same, exchanged, np.full(6, 1.0)), np.zeros(6, bool))


def test_a_take_that_starts_exchanged_stays_so():
    truth = walking_legs()
    _, _, count, _ = resolve(exchange(truth, np.arange(len(truth))))
    assert count == 0  # documented limit: the first frames are taken as labelled


def test_one_limb_under_both_labels_loses_the_impostor_label():
    """The right ankle's label sits on the left ankle for frames 20-27 (the right ankle unlabelled): the right
    label is dropped there, the left one kept, and the rest of the take is untouched."""
    truth = walking_legs()
    l_ankle, r_ankle = NAMES.index("L_ANKLE"), NAMES.index("R_ANKLE")
    z = truth.copy()
    z[20:28, r_ankle] = truth[20:28, l_ankle] + [0.0, 0.0, 0.01]  # 1 cm apart: another view's guess of it
    position, confidence, count, dropped = resolve(z)
    assert (count, dropped) == (0, 8)
    assert np.isnan(position[20:28, r_ankle]).all() and (confidence[20:28, r_ankle] == 0).all()
    np.testing.assert_array_equal(position[20:28, l_ankle], truth[20:28, l_ankle])
    np.testing.assert_array_equal(np.delete(position, np.s_[20:28], axis=0), np.delete(truth, np.s_[20:28], axis=0))
    assert resolve(z, duplicate_m=0.0, shared_m=0.0)[3] == 0  # both rules off (the later one catches it too)


def test_a_take_that_opens_with_one_limb_under_both_labels_is_judged_from_the_frames_after():
    truth = walking_legs()
    l_calf, r_calf = NAMES.index("L_CALF"), NAMES.index("R_CALF")
    z = truth.copy()
    z[:6, l_calf] = truth[:6, r_calf]  # the left label on the right calf from the first frame
    drop = tracks.drop_impostors(z[:, [l_calf, r_calf]], near_m=0.05, reach=15)  # (frame, side)
    np.testing.assert_array_equal(np.flatnonzero(drop[:, 0]), np.arange(6))
    assert not drop[:, 1].any()
    assert not tracks.impostors(z[:, [l_calf, r_calf]], near_m=0.05, reach=15).any()  # the frames before alone can't tell


def test_where_the_frames_before_and_after_disagree_both_labels_stay():
    """Frames 10-12 put both labels at the right leg's place; before them the left label was on the left leg,
    after them it is on the right leg's track: the frames before call the left label the impostor, the frames
    after the right one, so neither is dropped."""
    z = np.zeros((24, 2, 3))
    z[:, 0, 1], z[:, 1, 1] = 0.15, -0.15
    z[10:13, 0, 1] = -0.14  # both labels on the right leg
    z[13:, 0, 1], z[13:, 1, 1] = -0.15, 0.15  # then the labels trade places
    forward = tracks.impostors(z, near_m=0.05, reach=15)
    backward = tracks.impostors(z[::-1], near_m=0.05, reach=15)[::-1]
    assert forward[10:13, 0].all() and backward[10:13, 1].all()
    assert not tracks.drop_impostors(z, near_m=0.05, reach=15).any()


def test_limbs_that_come_together_keep_both_labels():
    """A foot that steps in quickly (6 cm per frame) to touch the still other foot (2 cm apart) and stays: the
    point lies nearer the still foot's last position, but the feet were already close the frame before."""
    n = 40
    xyz = np.zeros((n, 2, 3))
    xyz[:, 0, 1] = np.maximum(0.50 - 0.06 * np.arange(n), 0.02)  # the left foot closes in, then stays
    assert not tracks.drop_impostors(xyz, near_m=0.05, reach=15).any()


def test_a_calf_label_on_the_ankle_strap_is_dropped_after_the_ankles_are_put_back():
    """A deep squat: the thigh hides the left calf strap and the views call the left ankle strap "calf"
    (frames 20-27), while the ankles' labels are exchanged there. The ankles are put back first; then the
    calf label sits on the left ankle's track, 35 cm from its own, and is dropped. Nothing else changes."""
    truth = walking_legs()
    calf, ankle = NAMES.index("L_CALF"), NAMES.index("L_ANKLE")
    z = exchange(truth, np.arange(20, 28), parts=("ANKLE",))
    z[20:28, calf] = truth[20:28, ankle] + [0.0, 0.01, 0.0]
    position, confidence, count, dropped = resolve(z)
    assert (count, dropped) == (8, 8)
    assert np.isnan(position[20:28, calf]).all() and (confidence[20:28, calf] == 0).all()
    np.testing.assert_array_equal(np.delete(position, calf, axis=1), np.delete(truth, calf, axis=1))
    np.testing.assert_array_equal(np.delete(position[:, calf], np.s_[20:28], axis=0),
                                  np.delete(truth[:, calf], np.s_[20:28], axis=0))
    assert resolve(z, shared_m=0.0)[3] == 0  # off


def test_reflectors_side_by_side_on_the_body_may_share_a_point():
    """The left hand strap's label on the wrist strap's point (11 cm apart at rest; one image region in a
    view) for frames 20-27: both labels stay, as the image rules made them. The same for the calf (35 cm
    from the ankle at rest) loses the label, so the exemption is by the body's layout, not by the data."""
    truth = walking_legs()
    wrist, hand = NAMES.index("L_WRIST"), NAMES.index("L_HAND")
    z = truth.copy()
    z[20:28, hand] = truth[20:28, wrist] + [0.01, 0.0, 0.0]
    assert resolve(z)[3] == 0
    assert tracks.coinciding(z, 0.05, np.ones((len(NAMES), len(NAMES)), bool))  # the pair does come close
    assert (wrist, hand) not in tracks.coinciding(z, 0.05, ~skeleton.neighbours(NAMES, tracks.REST_NEIGHBOURS_M))


def _markers(xyz: np.ndarray) -> xr.Dataset:
    return xr.Dataset(
        {"position": (("frame", "reflector", "xyz"), xyz.astype(np.float32)),
         "confidence": (("frame", "reflector"), np.ones(xyz.shape[:2], np.float32))},
        coords={"frame": np.arange(len(xyz)), "reflector": NAMES, "xyz": ["x", "y", "z"]}, attrs={"fps": 30.0})


def test_the_kalman_stage_smooths_the_relabelled_legs():
    truth = walking_legs()
    markers = _markers(exchange(truth, np.arange(20, 31)))
    fixed = smoothing.kalman(markers, smoothing.KalmanConfig())
    assert fixed.attrs["label_exchanges"] == 3 * 11 and fixed.attrs["label_duplicates_dropped"] == 0
    legs = [NAMES.index(f"{s}_{p}") for s in "LR" for p in LEGS]
    assert np.abs(fixed["position"].values[:, legs] - truth[:, legs]).max() < 0.01
    # without the exchanges undone, one pass follows the exchanged labels onto the other leg...
    kept = smoothing.kalman(markers, smoothing.KalmanConfig(resolve_swaps=False, alternatives=0))
    assert np.nanmax(np.linalg.norm(kept["position"].values[20:31, legs] - truth[20:31, legs], axis=-1)) > 0.2
    # ... and competing tracks leave those frames missing: the labelled leg could not get there and back
    kept = smoothing.kalman(markers, smoothing.KalmanConfig(resolve_swaps=False))
    assert np.isnan(kept["position"].values[20:31, legs]).all()


@pytest.mark.parametrize("bad", [{"swap_penalty_m": 0.0}, {"swap_reach": 0}, {"duplicate_m": -0.01},
                                 {"duplicate_reach": 0}, {"shared_m": -0.01}])
def test_bad_swap_settings_are_refused(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        smoothing.KalmanConfig(**bad)
