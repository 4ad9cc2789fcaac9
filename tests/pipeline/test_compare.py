"""`mocapflow compare`'s engine half (pipeline/compare.py) and the joint take of a catalog (pipeline/catalog.py):
frames matched on the take's clock, one truth for every system, the figures."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.compare import CompareError, matched_frames, score_take
from mocapflow.pipeline.errors import CatalogError, PlanError
from mocapflow.pipeline.registry import Capture, Skeleton

JOINT = """\
data_roots: [.]
joint_take:
  datasets: [markers, suit]
  defaults: {fps: 30.0, frames: 12}
  sequences:
    squat: {motion: classic_squat, seed: 3}
    reach: {motion: side_reaches, seed: 4}
datasets:
  markers: {kind: studio_markers, defaults: {views: 1}}
  suit: {kind: studio_suit, defaults: {fps: 10.0, frames: 4}}
stages:
  raw: {task: ingest_markers, dataset: markers}
  images: {task: ingest_suit, dataset: suit}
"""


def test_a_joint_take_is_a_sequence_of_every_dataset_it_names(tmp_path):
    (tmp_path / "catalog.yaml").write_text(JOINT)
    catalog = load_catalog(tmp_path / "catalog.yaml")
    assert catalog.joint_take.datasets == ("markers", "suit") and catalog.joint_take.takes == ("squat", "reach")
    assert catalog.joint_take.sequence("squat", "suit") == "squat.suit"
    markers, suit = catalog.datasets["markers"].options, catalog.datasets["suit"].options
    assert sorted(markers["sequences"]) == ["reach.markers", "squat.markers"]
    assert suit["sequences"]["squat.suit"] == {"motion": "classic_squat", "seed": 3}
    assert markers["defaults"] == {"fps": 30.0, "frames": 12, "views": 1}
    assert suit["defaults"] == {"fps": 10.0, "frames": 4}  # the dataset's own rate over the take's


@pytest.mark.parametrize("edit, message", [
    (("datasets: [markers, suit]", "datasets: [markers, suits]"), "no dataset 'suits' (did you mean 'suit'?)"),
    (("suit: {kind: studio_suit, ", "suit: {kind: studio_suit, sequences: {x: {motion: jumping_jack}}, "),
     "its sequences are the joint take's"),
    (("datasets: [markers, suit]", "datasets: []"), "expected a list of the datasets"),
    (("  sequences:\n    squat: {motion: classic_squat, seed: 3}\n    reach: {motion: side_reaches, seed: 4}\n", ""),
     "a joint take needs 'sequences"),
])
def test_a_wrong_joint_take_is_refused_naming_the_fix(tmp_path, edit, message):
    (tmp_path / "catalog.yaml").write_text(JOINT.replace(*edit))
    with pytest.raises(CatalogError, match="joint_take|datasets") as err:
        load_catalog(tmp_path / "catalog.yaml")
    assert message in str(err.value)


# Not the template: compare scores whatever joints the systems declare, by the parts they declare
CHAIN = Skeleton(tuple(f"j{k}" for k in range(20)), (-1, *range(19)),
                 {"first": tuple(f"j{k}" for k in range(5)), "rest": tuple(f"j{k}" for k in range(5, 20))})


def _capture(fps: float, truth: np.ndarray, offset: float, missing=(), skeleton: Skeleton = CHAIN) -> Capture:
    joints = truth + offset
    for f, j in missing:
        joints[f, j] = np.nan
    return Capture(stage="s", fps=fps, joints=joints, truth=truth, skeleton=skeleton)


def _truth(times: np.ndarray) -> np.ndarray:
    """20 joints moving along x with time: a frame's truth tells its instant."""
    base = np.random.default_rng(5).normal(size=(20, 3))
    return base[None] + times[:, None, None] * np.array([1.0, 0.0, 0.0])


def test_systems_at_30_and_10_fps_are_scored_on_the_instants_both_filmed():
    fast, slow = np.arange(30) / 30.0, np.arange(10) / 10.0
    captures = {"a": _capture(30.0, _truth(fast), 0.010, missing=[(3, 0)]), "b": _capture(10.0, _truth(slow), 0.002)}
    frames = matched_frames(captures)
    np.testing.assert_array_equal(frames["a"], np.arange(0, 30, 3))
    np.testing.assert_array_equal(frames["b"], np.arange(10))
    take = score_take("t", captures, {"a": 1.5, "b": 4.0})
    np.testing.assert_allclose(take["times"], slow)
    np.testing.assert_allclose(take["truth"], _truth(slow))  # one truth, at those instants
    a, b = take["systems"]["a"], take["systems"]["b"]
    assert a["frames"] == b["frames"] == 10
    np.testing.assert_allclose(a["mpjpe_mm"], 10 * np.sqrt(3), rtol=1e-9)  # an offset of 10 mm on each axis
    np.testing.assert_allclose(b["mpjpe_per_frame_mm"], 2 * np.sqrt(3), rtol=1e-9)
    assert a["completeness"] == pytest.approx(1 - 1 / 200)  # joint 0 missing at the second instant (frame 3)
    assert np.isnan(a["error_mm"][1, 0]) and list(a["parts_mm"]) == ["first", "rest"]
    b_parts = take["systems"]["b"]["parts_mm"]
    np.testing.assert_allclose([b_parts["first"], b_parts["rest"]], 2 * np.sqrt(3), rtol=1e-9)
    assert take["skeleton"] == CHAIN
    assert a["cpu_s_per_s"] == 1.5 and a["surface_mm"] is None


def test_systems_giving_other_joints_are_not_compared_and_a_skeleton_must_be_whole():
    times = np.arange(10) / 10.0
    renamed = Skeleton(tuple(f"k{k}" for k in range(20)), CHAIN.parents, {"all": tuple(f"k{k}" for k in range(20))})
    with pytest.raises(CompareError, match=r"take 't': 'b' gives the joints \['k0'.*compared on one skeleton"):
        score_take("t", {"a": _capture(10.0, _truth(times), 0.0), "b": _capture(10.0, _truth(times), 0.0,
                                                                               skeleton=renamed)}, {"a": 0, "b": 0})
    with pytest.raises(CatalogError, match=r"2 joints has 1 parents and parts naming joints it lacks \(\['c'\]\)"):
        Skeleton(("a", "b"), (-1,), {"p": ("a", "c")})


def test_captures_of_different_performances_are_not_compared():
    times = np.arange(10) / 10.0
    other = _truth(times)
    other[4, 7, 0] += 0.05  # 5 cm off at one instant: another performance
    with pytest.raises(PlanError, match="differs from that of 'a' by 50.0 mm at the same instant: not one performance"):
        score_take("t", {"a": _capture(10.0, _truth(times), 0.0), "b": _capture(10.0, other, 0.0)}, {"a": 0, "b": 0})


def test_rates_that_do_not_divide_one_another_meet_at_their_common_instants_only():
    a = _capture(7.0, _truth(np.arange(8) / 7.0), 0.0)  # 0, 1/7, ... 1 s
    b = _capture(9.0, _truth(np.arange(10) / 9.0), 0.0)  # 0, 1/9, ... 1 s
    matched = matched_frames({"a": a, "b": b})
    np.testing.assert_array_equal(matched["a"], [0, 7])
    np.testing.assert_array_equal(matched["b"], [0, 9])
