"""UUO's solver: part matching, the losses, and a take solved back to its truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import mesh_body as mb
from mocapflow.tasks.uuo import takes as uuo
from mocapflow.tasks.deepmocap.film.synth import build_rig
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.uuo import correspondence, hypotheses, matching, prior, segmentation, solve
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_vertices

FRAMES = 24


@pytest.fixture(scope="module")
def take():
    rig = build_rig(SequenceSpec("side_reaches", frames=FRAMES, seed=41, body="mesh", views=1))
    layout = uuo.layout(rig.body, np.random.default_rng(5), 40)
    rec = uuo.capture(uuo.marker_paths(rig.body, layout, rig.take.posed.vertices[:FRAMES]),
                      uuo.MarkerFaults.clean(ghosts_per_s=1.25), np.random.default_rng(6), fps=30.0)  # one ghost
    return uuo.marker_dataset(rig.body, layout, rec, rig.take, 30.0, 0, FRAMES)


@pytest.fixture(scope="module")
def body():
    b = mb.mesh_body(mb.Phenotype(gender=0.2, height=0.7))
    return b, SolverBody(b)


def test_connected_chains_follow_the_skeleton():
    assert ("left_foot", "left_shank", "left_thigh") in matching.connected_chains(3)
    assert ("left_foot", "left_thigh", "right_thigh") not in matching.connected_chains(3)  # not connected
    assert matching.connected_chains(15) == [matching.PART_NAMES]
    assert len(matching.connected_chains(1)) == 15


def test_closest_point_icp_finds_a_planted_yaw_and_shift(body):
    b, solver = body
    rng = np.random.default_rng(3)
    fit = BodyFit(np.broadcast_to(np.eye(3), (4, len(b.bone_names), 3, 3)).copy(),
                  np.broadcast_to(b.rest_heads[0], (4, 3)).copy(), np.array([0.5] * 6))
    chain = matching.part_vertices(b, matching.PART_NAMES)
    vertices = posed_vertices(solver, fit, chain[::4])  # (4, n, 3)
    turn, shift = np.radians(35.0), np.array([0.4, -0.2, 0.05])
    markers = vertices[:, rng.choice(vertices.shape[1], 40, replace=False)] @ matching.yaw_matrix(turn).T + shift
    yaw, t, chamfer = matching.fit_yaw(markers, vertices, 0.0, 30)
    assert abs(np.degrees(yaw) - 35.0) < 1.0
    np.testing.assert_allclose(t, np.broadcast_to(shift, t.shape), atol=0.01)
    assert chamfer < 1e-5


def test_the_nearest_skin_search_finds_what_brute_force_finds_even_far_off():
    """The k-d tree over every frame's skin (frames set apart) against the brute-force closest points, with points
    near the skin, far beyond the gap between frames (they would land in another frame) and a subset of frames."""
    rng = np.random.default_rng(8)
    vertices = rng.normal(0.0, 0.3, (5, 400, 3))
    points = vertices[:, rng.choice(400, 30)] + rng.normal(0.0, 0.02, (5, 30, 3))
    points[1, :4] += [50.0, 0.0, 0.0]  # a ghost a long way off
    points[3, 2] = [-80.0, 3.0, 1.0]
    skin = matching.NearestSkin(vertices)
    index, d2 = skin.query(points)
    expected, expected_d2 = matching.closest(points, vertices)
    np.testing.assert_array_equal(index, expected)
    np.testing.assert_allclose(d2, expected_d2, rtol=1e-12)
    some = np.array([3, 0])
    np.testing.assert_array_equal(skin.query(points[some], some)[0], expected[some])


def test_the_chamfer_and_the_correspondence_match_hand_computed_values(body):
    b, solver = body
    fit = BodyFit(np.broadcast_to(np.eye(3), (2, len(b.bone_names), 3, 3)).copy(),
                  np.broadcast_to(b.rest_heads[0], (2, 3)).copy(),
                  np.array([getattr(b.phenotype, k) for k in mb.PHENOTYPE_NAMES]))
    chain = matching.part_vertices(b, ("left_thigh",))
    v = posed_vertices(solver, fit, chain)
    picked = [10, 150, 300]
    markers = v[:, picked] + 0.02 * np.array([1.0, 0.0, 0.0])  # markers 2 cm beside three of its vertices ...
    markers[1, 2] = np.nan  # ... one sample missing
    d2 = matching.closest(np.nan_to_num(markers), v)[1]
    expected = d2[np.isfinite(markers).all(-1)]
    assert solve.chamfer(solver, markers, fit, chain, cap_m=1.0, vertices=len(chain)) == pytest.approx(expected.mean())
    assert solve.chamfer(solver, markers, fit, chain, cap_m=0.001, vertices=len(chain)) == pytest.approx(1e-6)
    exact = v[:, picked]  # markers on the vertices themselves: Eq. (6) finds those vertices, at distance 0
    two_frames = correspondence.CorrespondenceConfig(min_frames=2)
    vertex, mean = correspondence.correspond(solver, exact, fit, chain, two_frames)
    np.testing.assert_array_equal(vertex, chain[picked])
    np.testing.assert_allclose(mean, 0.0, atol=1e-12)
    far = exact + 0.5  # half a metre off in each axis: a ghost, left unlabelled; so is a track seen too briefly
    assert (correspondence.correspond(solver, far, fit, chain, two_frames)[0] == -1).all()
    assert (correspondence.correspond(solver, exact, fit, chain, correspondence.CorrespondenceConfig())[0] == -1).all()


FAST = solve.HypothesisConfig(
    matching=matching.MatchConfig(frames=12, vertices=600, iterations=12),
    pose_fit=dataclasses.replace(solve.PoseFitConfig(), rounds=3, iterations=10, vertices=2000),
    ik=dataclasses.replace(solve.IKConfig(), iterations=40))


def _turned_prior(take):
    """The take's exact prior turned half round about the vertical and shifted: what MHT is for."""
    exact = prior.SimulatedPriorConfig(form="mild", rotation_deg=0.0, yaw_deg=0.0, scale_range=(1.0, 1.0),
                                       translation_m=0.4,
                                       lost=0.0, phenotype_noise=0.0, drift_m=0.0, seed=2)
    body_prior = prior.simulated_prior(take, exact)
    turned = body_prior.copy()
    half = Rotation.from_euler("z", 180, degrees=True)
    turned["bone_rotation"].values[:] = (half * Rotation.from_quat(
        body_prior["bone_rotation"].values.reshape(-1, 4))).as_quat().reshape(turned["bone_rotation"].shape)
    turned["root"].values[:] = half.apply(body_prior["root"].values)
    return turned


def _mirrored_prior(body_prior):
    """The prior with its sides swapped (a monocular estimate that took the left limbs for the right)."""
    from mocapflow.tasks.shared.kinematics import world_rotations

    body, _ = solve._bodies(body_prior.attrs["phenotype"])
    fit = hypotheses.mirrored(solve.body_fit(body_prior), hypotheses.mirror_bones(body.bone_names))
    out = body_prior.copy(deep=True)
    out["bone_rotation"].values[:] = Rotation.from_matrix(world_rotations(fit.local, body.bone_parents).reshape(
        -1, 3, 3)).as_quat().reshape(out["bone_rotation"].shape)
    return out


def test_a_take_with_a_turned_mirrored_prior_is_solved_back_from_the_screened_placements(take):
    """The exact prior turned half round and mirrored: the screen's placements (every 30 degrees, mirrored or not)
    hold the way back, the four best solved, the best refined; one hypothesis from the prior as it is fails."""
    turned = _mirrored_prior(_turned_prior(take))
    segments = segmentation.rigid_segments(take, segmentation.SegmentConfig())
    screen = solve.screen_hypotheses(take, segments, turned, hypotheses.ScreenConfig(matching=FAST.matching))
    assert screen.sizes["hypothesis"] == 24 and not screen.attrs["symmetric_prior"]  # 12 yaws, mirrored or not
    assert screen.attrs["distinct"] == 4
    hyps = {f"h{r}": solve.solve_screened(take, segments, turned, screen, solve.ScreenedConfig(rank=r, solve=FAST))
            for r in range(4)}
    best = solve.best_hypothesis(take, **hyps, config=solve.RefineConfig())
    truth = take["gt_joints"].values
    mpjpe = np.linalg.norm(best["joints"].values - truth, axis=-1).mean()
    assert mpjpe < 0.03, mpjpe  # within 3 cm of the true joints
    assert best.attrs["mirror"] and abs(abs(best.attrs["matched_yaw_deg"]) - 180.0) < 10.0  # turned and mirrored
    assert len(best.attrs["hypothesis_chamfer"]) == 4 and sum(best.attrs["hypotheses_mirror"]) >= 1
    with pytest.raises(solve.SolveError, match="rank 24 asks for more placements"):
        solve.solve_screened(take, segments, turned, screen, solve.ScreenedConfig(rank=24, solve=FAST))
    as_is = solve.solve_hypothesis(take, segments, turned, FAST)  # the paper's first hypothesis, not mirrored
    single = np.linalg.norm(solve.single_hypothesis(take, as_is, solve.RefineConfig())["joints"].values
                            - truth, axis=-1).mean()
    assert single > 3 * mpjpe  # Table 3: one hypothesis started the wrong way round stays wrong
    real = take["gt_source"].values >= 0
    labelled = best["vertex"].values >= 0
    assert labelled[real].mean() > 0.9  # the markers labelled (a ghost far off stays out: the test above)
    seen = best["stage_joints"].sel(stage="refined").values
    np.testing.assert_allclose(seen, best["joints"].values)

    # the baseline without a solve (the paper's HMR2.0+RR): the prior placed from the best of the four yaws
    turned = _turned_prior(take)
    placed = solve.rigid_prior(take, segments, turned, solve.RigidPriorConfig(matching=FAST.matching))
    placed_mpjpe = np.linalg.norm(placed["joints"].values - truth, axis=-1).mean()
    assert placed_mpjpe < 0.05, placed_mpjpe  # an exact pose turned and shifted: the placement brings it back
    assert abs(abs(placed.attrs["matched_yaw_deg"]) - 180.0) < 10.0
    stages = placed["stage_joints"]
    np.testing.assert_allclose(stages.sel(stage="matching").values, placed["joints"].values, atol=1e-6)
    assert np.isnan(stages.sel(stage="refined").values).all()  # no solver stage ran
    assert (placed["vertex"].values[real] >= 0).mean() > 0.8
    with pytest.raises(solve.SolveError, match="yaws_deg is empty"):
        solve.rigid_prior(take, segments, turned, solve.RigidPriorConfig(yaws_deg=()))



class GoalShortfall(Exception):
    """The realistic-prior solve misses one of its goals (the xfail below expects this and nothing else)."""


@pytest.mark.xfail(strict=True, raises=GoalShortfall,  # only the goals' check raises it: any assertion is a failure
                   reason="measured shortfall: from the realistic prior this 24-frame take solves to 235 mm MPJPE "
                   "(placed: 288 mm) with one hypothesis and the fast settings (goal: under 60 mm and half the "
                   "placement's), labels 70 % of the markers (goal: 85 %) and puts 2 markers on the wrong side (goal: "
                   "none); the solver does not yet undo held depth flips and the lean (docs/uuo.md, What is left)")
def test_a_take_with_the_realistic_prior_is_solved_far_closer_than_the_prior_placed(take):
    """The default prior (flips held, a lean, every bone off; 165 mm measured after part matching's alignment),
    turned by at most 30 degrees, so one hypothesis suffices (choosing among four: the test above).

    The checks that hold today are plain assertions (they fail the test, not its xfail), at bounds from the values
    measured: a regression breaks them. The goals are checked together last, all of them evaluated, and raise
    GoalShortfall naming every one missed; when all are met the strict xfail fails: make this a plain test."""
    realistic = prior.simulated_prior(take, prior.SimulatedPriorConfig(seed=3, yaw_deg=30.0))
    assert realistic.attrs["aligned_mpjpe_mm"] > 90  # measured 165 mm: a realistic prior, not a mild one
    segments = segmentation.rigid_segments(take, segmentation.SegmentConfig())
    best = solve.single_hypothesis(take, solve.solve_hypothesis(take, segments, realistic, FAST),
                                   solve.RefineConfig())
    truth = take["gt_joints"].values
    mpjpe = 1000 * np.linalg.norm(best["joints"].values - truth, axis=-1).mean()
    placed = 1000 * np.linalg.norm(best["stage_joints"].sel(stage="matching").values - truth, axis=-1).mean()
    real = take["gt_source"].values >= 0
    labelled = (best["vertex"].values[real] >= 0).mean()
    true_body = mb.mesh_body(mb.Phenotype(**take.attrs["phenotype"]))
    true_part = np.array([mb.part_of_bone(true_body.bone_names[true_body.vertex_bone[true_body.faces[f, 0]]])
                          for f in take["gt_face"].values[real]])
    got = best["part"].values[real]
    sided = np.array([("left" in t or "right" in t) and g != "" for t, g in zip(true_part, got)])
    swapped = np.array([("left" in t and "right" in g) or ("right" in t and "left" in g)
                        for t, g in zip(true_part, got)])

    # what holds today (measured: 235 mm solved from 288 mm placed, 28 of 40 markers labelled, 13 markers on
    # sided parts labelled of which 2 on the other side): the solve improves on the placement and most markers
    # keep a side; a bound a regression breaks, not the goal
    assert mpjpe < 0.9 * placed and mpjpe < 270, (mpjpe, placed)  # the solve still improves on the placement
    assert labelled >= 0.6, labelled  # 24 of 40 or more
    assert sided.sum() > 10 and swapped.sum() <= 3, (sided.sum(), swapped.sum())  # the mirroring check

    goals = {"MPJPE under 60 mm": mpjpe < 60,  # the markers pull the wrong limbs back: a fraction of the error
             "MPJPE under half the placement's": mpjpe < 0.5 * placed,
             "85 % of the markers labelled": labelled > 0.85,
             "no marker of one side on the other (not mirrored)": swapped.sum() == 0}
    missed = [goal for goal, met in goals.items() if not met]
    if missed:
        raise GoalShortfall(f"missed: {missed}; MPJPE {mpjpe:.0f} mm (placed {placed:.0f} mm), "
                            f"{labelled:.0%} labelled, {swapped.sum()} of {sided.sum()} sided markers swapped")


def test_close_hypotheses_are_told_apart_by_the_priors_pose_and_one_side_per_rigid_group(body):
    import xarray as xr

    b, _ = body
    parts = np.array(["left_thigh", "left_thigh", "right_thigh", "right_shank", "torso", ""])
    groups = np.array([0, 0, 0, 1, 1, -1])  # group 0: two left, one right; group 1: one sided label only
    assert solve.side_split(parts, groups) == pytest.approx(1 / 3)
    assert solve.side_split(parts[:2], groups[:2]) == 0.0
    local = np.broadcast_to(np.eye(3), (2, len(b.bone_names), 3, 3)).copy()
    bent = local.copy()
    knee = b.bone("lowerleg01.L")
    bent[:, knee] = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    bent[:, 0] = Rotation.from_euler("z", 180, degrees=True).as_matrix()  # the root is placement's: not counted
    count = sum(1 for n in b.bone_names if n in prior.PRIOR_BONES) - 1
    assert solve.pose_disagreement(b, bent, local) == pytest.approx(90.0 / count)

    def hyp(chamfer, pose_deg, split, yaw=0.0, mirror=False, hyper=0.0, backward=0.0):
        return xr.Dataset(attrs={"chamfer": chamfer, "prior_pose_deg": pose_deg, "side_split": split,
                                 "matched_yaw_deg": yaw, "mirror": mirror, "hyperextension_deg": hyper,
                                 "backward_travel": backward})

    config = solve.RefineConfig()
    # the least chamfer wins when no other comes close ...
    assert solve.choose([hyp(1.0, 30, 0.0), hyp(2.0, 5, 0.0)], config).index == 0
    # ... among close ones, the pose like the prior's, and groups kept to one side
    assert solve.choose([hyp(1.0, 30, 0.0), hyp(1.2, 5, 0.0), hyp(5.0, 1, 0.0)], config).index == 1
    assert solve.choose([hyp(1.0, 10, 0.0), hyp(1.1, 5, 0.2)], config).index == 0
    # ... and knees bent backward count against a hypothesis, degree for degree
    assert solve.choose([hyp(1.0, 5, 0.0, hyper=30.0), hyp(1.1, 10, 0.0, yaw=180.0)], config).index == 1
    walked = solve.RefineConfig(travel_deg=50.0)  # walking backward, when weighed
    assert solve.choose([hyp(1.0, 5, 0.0, backward=0.9), hyp(1.1, 10, 0.0, yaw=180.0)], walked).index == 1
    # a runner-up facing otherwise (or mirrored) within call_deg: too close to call
    near = solve.choose([hyp(1.0, 10, 0.0), hyp(1.1, 12, 0.0, yaw=170.0), hyp(1.2, 11, 0.0, yaw=20.0)], config)
    assert (near.index, near.runner_up, near.too_close) == (0, 1, True) and near.margin_deg == pytest.approx(2.0)
    far = solve.choose([hyp(1.0, 10, 0.0), hyp(1.1, 30, 0.0, mirror=True)], config)
    assert (far.runner_up, far.too_close) == (1, False) and far.margin_deg == pytest.approx(20.0)
    alone = solve.choose([hyp(1.0, 10, 0.0), hyp(1.1, 11, 0.0, yaw=30.0)], config)  # the same facing: no rival
    assert alone.runner_up is None and not alone.too_close
    with pytest.raises(solve.SolveError, match="close >= 1"):
        solve.RefineConfig(close=0.5)


def test_a_chosen_body_far_from_every_marker_is_kept_unrefined_and_labels_nothing(take, caplog):
    """A hypothesis no trajectory lies near (a partial layout matched to the wrong place) still gives the take a
    body: stage 4's, every trajectory unlabelled, with a warning; the benchmark keeps the take and scores it."""
    fit = solve.body_fit(prior.simulated_prior(take, prior.SimulatedPriorConfig(form="mild", rotation_deg=0.0,
                                                                                 yaw_deg=0.0, lost=0.0)))
    away = dataclasses.replace(fit, root=fit.root + [3.0, 0.0, 0.0])  # the body 3 m beside the markers
    body = mb.mesh_body(mb.Phenotype(**take.attrs["phenotype"]))
    solver = SolverBody(body)
    heads = {name: np.zeros((FRAMES, 20, 3)) for name in ("matching", "pose_fit", "ik")}
    hypothesis = solve.body_dataset(take, body, solver, away, np.full(take.sizes["marker"], -1),
                                    np.full(take.sizes["marker"], np.inf), heads,
                                    {"yaw_deg": 0.0, "chamfer": 1.0, "parts": list(matching.PART_NAMES)})
    with caplog.at_level("WARNING", logger="mocapflow.tasks.uuo.solve"):
        kept = solve.single_hypothesis(take, hypothesis, solve.RefineConfig())
    assert (kept["vertex"].values == -1).all() and (kept["part"].values == "").all()
    np.testing.assert_allclose(kept["root"].values, away.root)
    np.testing.assert_allclose(kept["joints"].values, hypothesis["joints"].values, atol=1e-6)
    assert "no marker trajectory lies within 0.11 m of the chosen hypothesis' body" in caplog.text


def test_a_take_the_solver_cannot_use_is_refused_naming_its_frames(take):
    """Too few markers on the body, a unit the file misstates, a subject leaving the volume: a clear message,
    before any solve (the engine stores nothing for a failed task)."""
    positions = take["position"].transpose("frame", "marker", "xyz").values.astype(np.float64)
    frames = take["frame"].values + 100
    solve.check_take(positions, 30.0, frames)  # the take itself is fine
    few = positions.copy()
    few[:, 3:] = np.nan
    with pytest.raises(solve.SolveError, match="too few markers on the body to solve: a median of 3 per frame over "
                                               "frames 100-123"):
        solve.check_take(few, 30.0, frames)
    with pytest.raises(solve.SolveError, match="span a median of 0.00.* m on a frame.*unit is likely misstated"):
        solve.check_take(positions / 1000.0, 30.0, frames)  # metres labelled as millimetres
    gone = positions.copy()
    gone[16:, 2:] = np.nan  # from frame 116 on, two samples a frame: 8 frames, 0.8 s at 10 frames/s
    with pytest.raises(solve.SolveError, match=r"frames 116-123 have fewer than 4 markers for more than 0.5 s"):
        solve.check_take(gone, 10.0, frames)
    solve.check_take(gone, 30.0, frames)  # at 30 frames/s the same 8 frames are 0.27 s: a gap the solver bridges
    left = take.assign(position=take["position"].where(take["frame"] < take["frame"].values[16])).assign_attrs(fps=10.0)
    with pytest.raises(solve.SolveError, match="subject left the capture volume"):
        solve.screen_hypotheses(left, segmentation.rigid_segments(take, segmentation.SegmentConfig()),
                                _turned_prior(take), hypotheses.ScreenConfig())
