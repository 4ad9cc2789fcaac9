"""The DeepMoCap studio's realism switches: tape of its real size, clothing, the Kinect v2's time-of-flight artefacts."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from mocapflow.pipeline.errors import InputError
from mocapflow.systems.studio.specs import fingerprint, make_spec
from mocapflow.tasks.shared.reflectors import TAPE_WIDTH
from mocapflow.tasks.deepmocap.film import cloth, mesh_reflectors, tape, tof
from mocapflow.tasks.shared.cameras import look_at
from mocapflow.tasks.studio.cameras import kinect_v2
from mocapflow.tasks.studio.mesh_render import MeshScene
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.studio.take import RealismError

BASE = dict(motion="jumping_jack", frames=3, seed=7, body="mesh", random_layout=True, ir_bloom_px=3)
ALL = dict(tape=True, cloth_cm=3.0, tof_artefacts=True)
VARIABLES = ("depth", "ir", "gt_reflector_id", "gt_body", "gt_scene_flow", "gt_reflectors", "gt_pixels", "gt_joints")


@pytest.fixture(scope="module")
def renders():
    out = {}
    for name, extra in (("plain", None), ("off", {}), ("tape", {"tape": True}), ("cloth", {"cloth_cm": 3.0}),
                        ("tof", {"tof_artefacts": True}), ("all", ALL)):
        spec = SequenceSpec(**BASE) if extra is None else SequenceSpec(**BASE, **extra)
        rig = build_rig(spec)
        out[name] = rig, synthesize(rig, 1, 2)
    return out


def _same(a, b, names=VARIABLES):
    return {name: np.array_equal(a[name].values, b[name].values) for name in names}


def test_every_switch_off_renders_the_studio_byte_for_byte(renders):
    assert all(_same(renders["plain"][1], renders["off"][1]).values())
    assert fingerprint(SequenceSpec(**BASE), None) == fingerprint(SequenceSpec(**BASE), None)
    assert "realism" not in renders["off"][1].attrs
    for name in ("tape", "cloth", "tof", "all"):
        assert fingerprint(renders[name][0].spec, None) != fingerprint(SequenceSpec(**BASE), None), name


def test_each_switch_changes_only_what_it_renders(renders):
    plain = renders["plain"][1]
    # the sensor's artefacts leave the truth alone
    same = _same(plain, renders["tof"][1])
    assert not same["depth"] and not same["ir"]
    assert all(v for k, v in same.items() if k.startswith("gt_")), same
    # tape changes the reflectors' pixels and the sensor round them, nothing far from them, and not the truth in 3D
    tape_ds = renders["tape"][1]
    same = _same(plain, tape_ds)
    assert not same["gt_reflector_id"] and same["gt_reflectors"] and same["gt_scene_flow"] and same["gt_body"]
    near = np.zeros(plain.depth.shape, bool)
    for v in range(near.shape[0]):
        refl = (plain.gt_reflector_id.values[v, 0] >= 0) | (tape_ds.gt_reflector_id.values[v, 0] >= 0)
        near[v, 0] = ndimage.binary_dilation(refl, iterations=25)
    assert np.array_equal(plain.depth.values[~near], tape_ds.depth.values[~near])
    # cloth moves the surface and the tape on it, not the skeleton
    same = _same(plain, renders["cloth"][1])
    assert same["gt_joints"] and not same["gt_body"] and not same["gt_reflectors"] and not same["depth"]


def test_a_seeded_harsh_render_is_deterministic(renders):
    rig, ds = renders["all"]
    again = synthesize(build_rig(SequenceSpec(**BASE, **ALL)), 1, 2)
    assert all(_same(ds, again).values())
    assert ds.attrs["realism"] == {"tape": True, "cloth_cm": 3.0, "tof": True}
    other = synthesize(build_rig(dataclasses.replace(rig.spec, seed=8)), 1, 2)
    assert not np.array_equal(other.ir.values, ds.ir.values)


def _flat_scene(width_m: float, height_m: float, distance_m: float):
    """A Kinect v2 looking along +Y at a flat wall ``distance_m`` away, its two triangles, and the rays' hits."""
    cam = kinect_v2("k", look_at((0.0, -distance_m, 1.0), (0.0, 0.0, 1.0)))
    w, h = width_m / 2, height_m / 2
    verts = np.array([[-w, 0, 1 - h], [w, 0, 1 - h], [w, 0, 1 + h], [-w, 0, 1 + h]], float)
    scene = MeshScene(verts, np.array([[0, 1, 2], [0, 2, 3]]))
    rays = cam.pixel_rays().reshape(-1, 3) @ cam.cam_to_world[:3, :3].T
    origin = np.broadcast_to(cam.cam_to_world[:3, 3], rays.shape)
    face, _, t = scene.cast(origin, rays)
    points = origin + rays * np.where(face >= 0, t, 0.0)[:, None]
    return cam, face.reshape(cam.height, cam.width), points


def test_tape_is_its_real_size_in_pixels_at_two_metres():
    cam, face, points = _flat_scene(1.0, 1.0, 2.0)
    out = np.array([0.0, -1.0, 0.0])  # the wall faces the camera
    frame = np.stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], out])  # across (x), along (z, the "segment"), out
    layout = tape.TapeLayout(np.array([False, True]), np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]),
                             np.stack([frame, frame]), np.array([[TAPE_WIDTH / 2, tape.PATCH_LENGTH / 2, TAPE_WIDTH / 2],
                                                                 [TAPE_WIDTH / 2, TAPE_WIDTH / 2, TAPE_WIDTH / 2]]),
                             np.ones(2), np.zeros((2, 2)), np.ones(2))
    hit = face.ravel() >= 0
    for r, (across_px, along_px) in enumerate([(cam.fx * TAPE_WIDTH / 2, cam.fy * tape.PATCH_LENGTH / 2),
                                               (None, cam.fy * TAPE_WIDTH / 2)]):
        candidate = np.where(hit, r, -1)
        labels = tape.label(layout, candidate, points).reshape(face.shape) == r
        rows, cols = np.nonzero(labels)
        # a 5.08 cm tape 2 m away: fx 0.0508 / 2 = 9.2 px wide with the studio's intrinsics (fx 361.6, fy 367.2)
        assert abs(np.ptp(rows) + 1 - along_px) <= 1.0, (r, np.ptp(rows) + 1, along_px)
        if across_px is not None:  # the patch: a 5.08 x 7.62 cm rectangle, 9 x 14 px
            assert abs(np.ptp(cols) + 1 - across_px) <= 1.0, (np.ptp(cols) + 1, across_px)
            assert abs(labels.sum() - across_px * along_px) <= 0.15 * across_px * along_px
            assert 8 <= across_px <= 10 and 13 <= along_px <= 15
        else:  # the strap: a band as wide as the tape, as long as the limb is round (here the whole wall)
            assert 9 <= along_px <= 10 and np.ptp(cols) + 1 >= 0.99 * cam.fx * 1.0 / 2  # the 1 m wall


def test_tape_saturates_unevenly_and_flares_per_reflector():
    frame = np.eye(3)
    layout = tape.TapeLayout(np.array([False, False]), np.zeros((2, 3)), np.stack([frame, frame]),
                             np.full((2, 3), 0.05), np.array([1.0, 1.0]), np.array([[0.0, 1.0], [2.0, 3.0]]),
                             np.array([0.5, 1.6]))
    s = np.linspace(-0.04, 0.04, 200)
    rest = np.column_stack([np.zeros_like(s), s, np.zeros_like(s)])  # along the tape
    ir = tape.tape_ir(layout, np.zeros(200, np.int64), rest, np.full(200, 2.5), np.full(200, np.cos(np.radians(50))))
    assert ir.max() / ir.min() > 1.5  # the gain swings along the tape
    assert (ir > 64000).any() and (ir < 64000).any()  # part saturated, part not
    # at 2.5 m facing the sensor the tape overflows it; seen at 80 degrees it does not
    face_on = tape.tape_ir(layout, np.zeros(1, np.int64), np.zeros((1, 3)), np.array([2.5]), np.array([1.0]))
    oblique = tape.tape_ir(layout, np.zeros(1, np.int64), np.zeros((1, 3)), np.array([2.5]),
                           np.array([np.cos(np.radians(80))]))
    assert face_on[0] > 64000 > oblique[0]
    # two equal saturated tapes with different flare factors flare differently
    sat = np.zeros((60, 120), bool)
    sat[25:35, 20:30] = sat[25:35, 80:90] = True
    rid = np.full(sat.shape, -1, np.int8)
    rid[:, :60][sat[:, :60]] = 0
    rid[:, 60:][sat[:, 60:]] = 1
    hot, glow = tape.flare(sat, rid, np.where(sat, 128000.0, 0.0), layout, 3, 64000.0)
    assert hot[sat].all() and 0 < hot[:, :60].sum() < hot[:, 60:].sum()
    assert glow.max() <= 1.0 and glow[sat].min() > 0


def test_cloth_moves_the_tape_out_and_sideways_by_at_most_3_cm(renders):
    plain_rig, plain = renders["plain"]
    rig, ds = renders["cloth"]
    thickness = rig.cloth_layer.thickness
    assert 0.0 <= thickness.min() and thickness.max() <= 0.03 and thickness.max() > 0.015
    part = np.array([b for b in rig.body.bone_names])[rig.body.vertex_bone]
    assert thickness[np.char.startswith(part.astype(str), "head")].max() == 0.0  # the face is bare
    shift = np.linalg.norm(ds.gt_reflectors.values - plain.gt_reflectors.values, axis=-1)[0]
    assert shift.max() <= 0.03 and shift.max() > 0.005 and (shift > 1e-4).sum() >= 10, shift.round(4)
    # the patches on the clothed trunk move out with the cloth: their depth is nearer the sensors
    body_both = plain.gt_body.values & ds.gt_body.values & (plain.depth.values > 0) & (ds.depth.values > 0)
    nearer = plain.depth.values[body_both].astype(float) - ds.depth.values[body_both]
    assert 2 <= np.median(nearer) <= 30  # mm


def test_folds_hide_part_of_some_tapes(renders):
    rig, _ = renders["all"]
    corners = rig.body.vertices[rig.body.faces]
    centroids = corners.mean(axis=1)
    labels = tape.label(rig.tapes, rig.face_tape, centroids)
    on = labels >= 0
    share = cloth.hidden_share(rig.cloth_layer, labels[on].astype(np.int64), centroids[on])
    bare = ~np.isfinite(rig.cloth_layer.cover_threshold)
    assert share[bare].max() == 0.0 and bare.sum() >= 3  # head and hand patches sit on skin
    assert (share > 0.05).sum() >= 3 and share.max() < 0.9, share.round(2)


def test_flying_pixels_appear_only_at_silhouettes():
    z = np.full((60, 80), 4.0)
    z[20:40, 30:50] = 2.0
    out, flying = tof.flying_pixels(z, np.random.default_rng(0))
    ring = ndimage.binary_dilation(z < 3, iterations=1) & ~ndimage.binary_erosion(z < 3, iterations=1)
    changed = out != z
    assert changed.any() and not (changed & ~ring).any()
    assert (flying == ring).all()
    assert ((out[changed] > 2.0) & (out[changed] < 4.0)).all()  # between the foreground and the background


def test_multipath_biases_depth_only_near_the_floor():
    proximity = np.tile(np.linspace(0.0, 1.0, 101), (10, 1))  # metres from the floor (or the floor's corner)
    z = np.full(proximity.shape, 3.0)
    out = tof.multipath(z, np.ones_like(z), proximity, np.random.default_rng(1))
    bias = out - z
    assert (bias[proximity > tof.MULTIPATH_REACH_M] == 0).all()
    assert (bias >= 0).all()  # the indirect path is longer: depth reads too far
    assert 0.015 < bias[:, 0].mean() < 0.035 and bias[:, 20].mean() < 0.4 * bias[:, 0].mean()
    # a floor point is as near the corner as it is to the wall; a body point as high as it is
    world = np.array([[[0.0, 0.0, 0.1], [4.1, 0.0, 0.0], [0.0, 0.0, 1.2]]])
    np.testing.assert_allclose(tof.floor_proximity(world, np.array([[False, True, False]]), 4.2), [[0.1, 0.1, 1.2]])


def test_motion_smears_depth_only_round_fast_surfaces():
    z = np.full((60, 80), 4.0)
    z[20:40, 10:30] = 2.0
    moving = np.zeros(z.shape, bool)
    moving[20:40, 10:30] = True
    shift = np.where(moving[..., None], np.array([6.0, 0.0]), 0.0)
    out, dropped = tof.motion_smear(z, tof.Motion(shift), np.random.default_rng(2))
    touched = (out != z) | dropped
    assert touched.any() and not touched[:, 40:].any() and not touched[:18].any()
    still, _ = tof.motion_smear(z, tof.Motion(np.zeros_like(shift)), np.random.default_rng(2))
    assert np.array_equal(still, z)


def test_other_sensors_add_noise_and_dropouts_where_they_see():
    z = np.full((100, 100), 2.5)
    others = np.zeros(z.shape, np.int16)
    others[:, 50:] = 2
    out, dropped = tof.interference_depth(z, others, 1.0, np.random.default_rng(3))
    assert (out[:, :50] == z[:, :50]).all() and not dropped[:, :50].any()
    assert out[:, 50:].std() > 0.002 and 0.01 < dropped[:, 50:].mean() < 0.08
    ir = np.full(z.shape, 20000, np.uint16)
    hot = np.zeros(z.shape, bool)
    hot[:, 90:] = True
    noisy = tof.interference_ir(ir, others, hot, np.random.default_rng(4))
    assert (noisy[:, :50] == ir[:, :50]).all() and (noisy[:, 90:] == ir[:, 90:]).all() and noisy[:, 50:90].std() > 500


def test_the_switches_are_checked_with_errors_that_say_the_fix(tmp_path):
    with pytest.raises(RealismError, match="mesh body only.*body: mesh"):
        SequenceSpec("jumping_jack", tape=True)
    with pytest.raises(RealismError, match=r"cloth_cm = 5.*between 0 \(bare skin\) and 3"):
        SequenceSpec("jumping_jack", body="mesh", cloth_cm=5)
    with pytest.raises(InputError, match="tof_artefacts: True is filmed on the mesh body only"):
        make_spec({"motion": "jumping_jack", "tof_artefacts": True}, "seq", lambda p: tmp_path / p)
    spec, _, _ = make_spec({"motion": "jumping_jack", "body": "mesh", "tape": True, "cloth_cm": 2},
                           "seq", lambda p: tmp_path / p)
    assert isinstance(spec, SequenceSpec) and spec.tape is True and spec.cloth_cm == 2.0


def test_tape_faces_need_placements_with_tape_frames(renders):
    rig, _ = renders["plain"]
    bare = tuple(dataclasses.replace(p, centre=None) for p in rig.placements)
    with pytest.raises(mesh_reflectors.MeshPlacementError, match="no tape frame"):
        mesh_reflectors.tape_faces(rig.body, bare, np.full((26, 3), 0.03))
