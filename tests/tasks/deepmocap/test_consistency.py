"""Plausibility of each view's labels without truth: three views lift the template's reflectors (its rest pose, the
pelvis 1 m up) with 1 cm of noise each; the body puts them where they are. Clean views agree with each other and the
body; a view that exchanges the legs fails left/right on them, a label planted off the body fails on-body."""

import numpy as np
import pytest

from mocapflow.tasks.deepmocap import consistency as cs
from mocapflow.tasks.deepmocap.poses import N_DOF, forward_kinematics
from mocapflow.tasks.deepmocap.skeleton import template
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES

NAMES = list(REFLECTOR_NAMES)
SIDED = [n for n in NAMES if "L" in n.split("_") or "R" in n.split("_")]  # 22 of the 26 have a mirror
LEGS = [f"{side}_{part}" for side in "LR" for part in ("CALF", "ANKLE", "FOOT")]
CONFIG = cs.ConsistencyConfig()


def _scene(n_frames: int = 20, n_views: int = 3, seed: int = 0):
    """The body's reflectors (frame, R, 3) and three views' lifts of them (frame, R, V, 3), each view missing a
    tenth of its labels."""
    tmpl = template(NAMES)
    params = np.zeros((1, N_DOF))
    params[0, :3] = [0.0, 0.0, 1.0]
    rot, pos = forward_kinematics(params, tmpl.offsets)
    truth = np.einsum("rij,rj->ri", rot[0, tmpl.bones], tmpl.reflector_offsets) + pos[0, tmpl.bones]  # (R, 3)
    body = np.repeat(truth[None], n_frames, 0)
    rng = np.random.default_rng(seed)
    lifted = body[:, :, None] + rng.normal(0.0, 0.01, (n_frames, len(NAMES), n_views, 3))
    lifted[rng.random((n_frames, len(NAMES), n_views)) < 0.1] = np.nan
    return body, lifted


def _shares(lifted, body):
    return cs.summarize(cs.view_counts(lifted, body, NAMES, CONFIG), ["k0", "k1", "k2"], NAMES, CONFIG)


def test_clean_views_agree_with_each_other_and_with_the_body():
    body, lifted = _scene()
    out = _shares(lifted, body)
    for view, f in out["views"].items():
        # 1 cm of noise per axis: two views' lifts differ by 2.3 cm on average, never by the 10 cm of agreement_m
        assert f["agreement"] == 1.0, (view, f)
        assert f["left_right"] == 1.0 and f["on_body"] == 1.0 and f["worst"] == {}, (view, f)
        assert 0.85 * 20 * len(NAMES) < f["on_body_n"] < 0.95 * 20 * len(NAMES)  # a tenth of the labels missing
        assert 0.85 * 20 * len(SIDED) < f["left_right_n"] < 0.95 * 20 * len(SIDED)  # only labels with a mirror
    assert out["all"]["on_body_n"] == sum(f["on_body_n"] for f in out["views"].values())


def test_a_view_that_exchanges_the_legs_fails_left_right_on_them_and_disagrees():
    body, lifted = _scene()
    swapped = lifted.copy()
    for part in ("CALF", "ANKLE", "FOOT"):
        left, right = NAMES.index(f"L_{part}"), NAMES.index(f"R_{part}")
        swapped[:, [left, right], 0] = lifted[:, [right, left], 0]  # view k0 reads each leg under the other's label
    out = _shares(swapped, body)["views"]
    # 6 of the 22 sided labels exchanged: the view's left/right share falls to about 16/22
    assert abs(out["k0"]["left_right"] - 16 / 22) < 0.03, out["k0"]
    assert out["k1"]["left_right"] == 1.0 and out["k2"]["left_right"] == 1.0
    assert abs(out["k0"]["on_body"] - 20 / 26) < 0.03 and set(out["k0"]["worst"]) <= set(LEGS), out["k0"]
    assert abs(out["k0"]["agreement"] - 20 / 26) < 0.03  # its legs agree with neither other view ...
    # ... which still agree with each other, but where the third misses a leg label (a tenth of the time) and k0 is
    # the only other view: about 6/26 x 0.1 = 2.3 % of their labels
    assert out["k1"]["agreement"] > 0.94 and out["k2"]["agreement"] > 0.94


def test_a_label_planted_off_the_body_fails_on_body_and_is_named():
    body, lifted = _scene()
    planted = lifted.copy()
    wrist = NAMES.index("L_WRIST")
    planted[:10, wrist, 1] = body[:10, wrist] + [0.0, 0.4, 0.0]  # view k1: 40 cm in front of the wrist, half the take
    out = _shares(planted, body)["views"]
    seen = np.isfinite(lifted[:10, wrist, 1, 0]).sum()
    assert out["k1"]["on_body"] == pytest.approx(1.0 - seen / out["k1"]["on_body_n"]), out["k1"]
    assert out["k1"]["on_body"] < out["k0"]["on_body"] == 1.0
    assert list(out["k1"]["worst"]) == ["L_WRIST"] and out["k1"]["worst"]["L_WRIST"] > 0.4, out["k1"]
    assert out["k1"]["left_right"] == 1.0  # in front of the left wrist: still nearer it than the right one


def test_checks_count_only_where_there_is_evidence():
    body, lifted = _scene(n_frames=4)
    one_view = lifted.copy()
    one_view[:, :, 1:] = np.nan  # no other view: nothing to agree with
    body[2:] = np.nan  # frames the fit left out: no body checks
    counts = cs.view_counts(one_view, body, NAMES, CONFIG)
    assert counts["agreement"][1].sum() == 0
    assert counts["on_body"][1, 0].sum() == np.isfinite(lifted[:2, :, 0, 0]).sum()
    f = cs.summarize(counts, ["k0", "k1", "k2"], NAMES, CONFIG)
    assert np.isnan(f["views"]["k0"]["agreement"]) and np.isnan(f["views"]["k1"]["on_body"])
    both = cs.add_counts(cs.add_counts(None, counts), counts)
    assert (both["on_body"] == 2 * counts["on_body"]).all()


def test_true_on_reflector_counts_the_lifted_labels_near_the_truth():
    body, lifted = _scene(n_frames=5)
    lifted[0, 0, 0] = body[0, 0] + [0.0, 0.0, 0.5]
    near = cs.true_on_reflector(lifted, body, CONFIG)
    lifted_n = np.isfinite(lifted[..., 0]).sum((0, 1))
    np.testing.assert_array_equal(near[1], lifted_n)
    np.testing.assert_array_equal(near[0], lifted_n - [1, 0, 0])


@pytest.mark.parametrize("options", [{"agreement_m": 0.0}, {"on_body_m": -0.1}, {"worst": -1}])
def test_bad_settings_are_refused_naming_them(options):
    with pytest.raises(cs.ConsistencyError, match=next(iter(options))):
        cs.ConsistencyConfig(**options)


def test_arrays_of_different_reflectors_are_refused():
    body, lifted = _scene(n_frames=2)
    with pytest.raises(cs.ConsistencyError, match="must match the views' lifted labels"):
        cs.view_counts(lifted, body[:, :-1], NAMES, CONFIG)
