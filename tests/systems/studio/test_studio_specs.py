"""The studio through the engine (catalog dataset kind) and through `mocapflow synth`."""

from __future__ import annotations

import dataclasses
import hashlib
import warnings

import numpy as np
import pytest
import xarray as xr

from conftest import SHARED, last_json, mocapflow, read_artifacts
from mocapflow.formats.bvh import parse_bvh
from mocapflow.pipeline.errors import CatalogError, InputError, InputWarning
from mocapflow.pipeline.hashing import digest
from mocapflow.systems.uuo.film import marker_options
from mocapflow.systems.studio.specs import LATER_FIELDS, check_in_view, fingerprint, load_motion, make_spec
from mocapflow.tasks.studio.cameras import layout as camera_layout
from mocapflow.tasks.shared.body import JOINT_INDEX, Subject
from mocapflow.tasks.studio import retarget
from mocapflow.tasks.uuo.takes import MarkerFaults
from motion_files import USER_MAP, mixamo_text
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize

# 3 frames in regions of 2: a sequence still spans more than one region (and the clip's own frames count is kept)
from mocapflow.tasks.studio.spec import STUDIO_VERSION, SequenceSpec
CATALOG = """\
data_roots: [., {shared}]
storage: {{root: storage/, region_frames: 2}}
datasets:
  studio:
    kind: studio
    defaults: {{frames: 3, noise: 0.5}}
    sequences:
      squat: {{motion: classic_squat, seed: 3, subject_height: 1.62}}
      jacks: {{motion: {shared}/motions/cmu_14_14_jumping_jacks.bvh, seed: 4, frames: 2}}
stages:
  frames: {{task: ingest}}
"""


def tree_digest(folder):
    h = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(path.relative_to(folder).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


@pytest.mark.needs_shared
def test_studio_dataset_runs_through_the_engine_and_equals_the_task(tmp_path):
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(shared=SHARED))
    summary = last_json(mocapflow("run", "--json", cwd=tmp_path))
    assert sorted(summary["executed"]) == ["frames/jacks", "frames/squat"]
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(tmp_path / "storage").items()}
    direct = synthesize(build_rig(SequenceSpec("classic_squat", frames=3, seed=3, subject_height=1.62, noise=0.5)), 0, 3)
    for var in ("depth", "ir", "gt_reflectors2d", "gt_joints", "gt_scene_flow"):
        np.testing.assert_array_equal(stored["frames/squat"][var], direct[var].values)
    assert stored["frames/jacks"]["depth"].shape == (3, 2, 424, 512)
    assert last_json(mocapflow("run", "--json", cwd=tmp_path))["executed"] == []


@pytest.mark.needs_shared
def test_bvh_outside_data_roots_is_refused(tmp_path):
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(shared=SHARED).replace(f"[., {SHARED}]", "[.]"))
    proc = mocapflow("run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "outside the declared data_roots" in proc.stderr


@pytest.mark.needs_shared
def test_studio_catalog_errors(tmp_path):
    text = CATALOG.format(shared=SHARED)
    for old, new, message in [("classic_squat", "clasic_squat", "did you mean 'classic_squat'"),
                              ("seed: 3", "sed: 3", "unknown studio field 'sed' (did you mean 'seed'?)"),
                              ("frames: 3", "frames: 0", "frames must be positive, got 0"),
                              ("seed: 4", "seed: 4, variation: 0.5", "a BVH clip is played as recorded"),
                              ("seed: 3", "seed: 3, variation: -1", "variation must be >= 0")]:
        (tmp_path / "catalog.yaml").write_text(text.replace(old, new))
        proc = mocapflow("run", cwd=tmp_path, check=False)
        assert proc.returncode == 2 and message in proc.stderr, proc.stderr


@pytest.mark.needs_shared
def test_synth_is_deterministic_per_seed_and_writes_the_raw_schema(tmp_path):
    args = ["--motion", "kick_box_kicking", "--motion", SHARED / "motions" / "cmu_12_01_walk.bvh",
            "--frames", "2", "--views", "2", "--seed", "11", "--subject-height", "1.9"]
    mocapflow("synth", "--out", tmp_path / "a", *args, cwd=tmp_path)
    mocapflow("synth", "--out", tmp_path / "b", *args, cwd=tmp_path)
    assert tree_digest(tmp_path / "a") == tree_digest(tmp_path / "b")
    mocapflow("synth", "--out", tmp_path / "c", *args[:-4], "--seed", "12", cwd=tmp_path)
    assert tree_digest(tmp_path / "a") != tree_digest(tmp_path / "c")
    ds = xr.open_zarr(tmp_path / "a" / "cmu_12_01_walk.zarr", consolidated=False)
    assert ds.sizes["view"] == 2 and ds.sizes["frame"] == 2
    assert ds.attrs["subject"]["height"] == 1.9 and ds.attrs["exercise"] == "cmu_12_01_walk"
    assert list(ds.reflector.values[:3]) == ["F_SPINEMID", "F_R_CHEST", "F_L_CHEST"]


def test_synth_refuses_to_overwrite_and_reports_bad_inputs(tmp_path):
    mocapflow("synth", "--out", tmp_path, "--motion", "side_jumps", "--frames", "1", "--views", "1", cwd=tmp_path)
    before = tree_digest(tmp_path)
    proc = mocapflow("synth", "--out", tmp_path, "--motion", "side_jumps", "--frames", "3", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "exists; pass --force" in proc.stderr
    assert tree_digest(tmp_path) == before
    (tmp_path / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    proc = mocapflow("synth", "--out", tmp_path / "x", "--motion", tmp_path / "broken.bvh", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "is not a valid BVH file" in proc.stderr
    (tmp_path / "away.yaml").write_text("sensors:\n  - {name: a, position: [0, 2.5, 0.8], target: [0, 6, 0.8]}\n")
    proc = mocapflow("synth", "--out", tmp_path / "y", "--motion", "side_jumps", "--layout", tmp_path / "away.yaml",
                     cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "does not see the capture centre" in proc.stderr
    proc = mocapflow("synth", "--out", tmp_path / "z", "--motion", "side_jumps", "--frames", "0", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "frames must be positive" in proc.stderr


def test_later_fields_enter_the_fingerprint_only_when_set():
    plain = SequenceSpec("classic_squat", seed=3)
    before_the_fields = {k: v for k, v in dataclasses.asdict(plain).items()
                         if k not in ("variation", "body", "motion_map", "camera_roll_deg", "ir_bloom_px", "tape",
                                      "cloth_cm", "tof_artefacts", "time_base_fps")}  # every field added after the
    # studio's version
    assert fingerprint(plain, None) == digest({"spec": before_the_fields, "bvh": None, "studio": STUDIO_VERSION})
    assert fingerprint(SequenceSpec("classic_squat", seed=3, variation=0.5), None) != fingerprint(plain, None)
    assert fingerprint(SequenceSpec("classic_squat", seed=3, body="mesh"), None) != fingerprint(plain, None)
    assert fingerprint(SequenceSpec("classic_squat", seed=3, random_layout=True, camera_roll_deg=2.0), None) != \
        fingerprint(SequenceSpec("classic_squat", seed=3, random_layout=True), None)
    assert fingerprint(SequenceSpec("classic_squat", seed=3, ir_bloom_px=3), None) != fingerprint(plain, None)
    assert fingerprint(SequenceSpec("classic_squat", seed=3, body="mesh", tape=True), None) != \
        fingerprint(SequenceSpec("classic_squat", seed=3, body="mesh"), None)
    assert fingerprint(SequenceSpec("classic_squat", seed=3, time_base_fps=120.0), None) != fingerprint(plain, None)


def test_a_clip_cut_to_a_window_is_fingerprinted_as_centred_on_it(tmp_path):
    (tmp_path / "take.bvh").write_text(mixamo_text())
    _, clip, _ = make_spec({"motion": "take.bvh"}, "seq", lambda p: tmp_path / p)
    bvh_hash = hashlib.sha256(mixamo_text().encode()).hexdigest()  # a BVH clip's digest is its text's: caches stand
    assert clip.digest == bvh_hash
    whole = SequenceSpec("bvh", frames=None)
    fields = {k: v for k, v in dataclasses.asdict(whole).items() if k not in LATER_FIELDS}
    assert fingerprint(whole, clip) == digest({"spec": fields, "bvh": bvh_hash, "studio": STUDIO_VERSION})
    for cut in (SequenceSpec("bvh", frames=40), SequenceSpec("bvh", frames=None, start_s=1.0)):
        fields = {k: v for k, v in dataclasses.asdict(cut).items() if k not in LATER_FIELDS}
        assert fingerprint(cut, clip) == digest({"spec": fields, "bvh": bvh_hash, "studio": STUDIO_VERSION,
                                                 "centred_on": "window"})


@pytest.mark.needs_shared
def test_a_mesh_body_sequence_runs_through_the_engine_and_through_synth(tmp_path):
    # seed 0's subject: its mesh stands the asked height to 1e-9 m (seed 3's stands 0.15 mm short of it)
    text = CATALOG.format(shared=SHARED).replace("defaults: {frames: 3, noise: 0.5}",
                                                 "defaults: {frames: 3, noise: 0.5, body: mesh, views: 2}")
    text = text.replace("seed: 3, subject_height: 1.62", "seed: 0, subject_height: 1.58")
    (tmp_path / "catalog.yaml").write_text(text)
    summary = last_json(mocapflow("run", "--json", "--sequences", "squat", cwd=tmp_path))
    assert summary["executed"] == ["frames/squat"]
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(tmp_path / "storage").items()}["frames/squat"]
    # the same take through `mocapflow synth` (build_rig and synthesize, in regions of its own): what the engine
    # stored, frame for frame; the capsule body's engine run is checked against synthesize in this process
    # (test_studio_dataset_runs_through_the_engine_and_equals_the_task)
    mocapflow("synth", "--out", tmp_path / "m", "--motion", "classic_squat", "--frames", "3", "--views", "2",
              "--seed", "0", "--noise", "0.5", "--body", "mesh", "--subject-height", "1.58", cwd=tmp_path)
    ds = xr.open_zarr(tmp_path / "m" / "classic_squat.zarr", consolidated=False)
    for var in ("depth", "ir", "gt_reflector_id", "gt_joints", "gt_bone_rotations"):
        np.testing.assert_array_equal(stored[var], ds[var].values)
    assert ds.attrs["body"] == "mesh" and ds.sizes["bone"] == 104
    assert ds.attrs["subject"]["height"] == pytest.approx(1.58, abs=1e-9)
    (tmp_path / "catalog.yaml").write_text(text.replace("body: mesh", "body: mess"))
    proc = mocapflow("run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "body must be one of capsule, mesh, got 'mess'" in proc.stderr


def test_a_varied_sequence_is_rerendered_when_the_variation_ranges_change(monkeypatch):
    from mocapflow.tasks.studio import motion

    plain, varied = SequenceSpec("classic_squat", seed=3), SequenceSpec("classic_squat", seed=3, variation=0.5)
    before = fingerprint(plain, None), fingerprint(varied, None)
    wider = tuple((joint, how, 2 * deg, one_sided) for joint, how, deg, one_sided in motion.VARIATION)
    monkeypatch.setattr(motion, "VARIATION", wider)
    assert fingerprint(plain, None) == before[0]
    assert fingerprint(varied, None) != before[1]


MARKER_CATALOG = """\
data_roots: [., {shared}]
storage: {{root: storage/, region_frames: 8}}
datasets:
  uuo:
    kind: studio_markers
    defaults: {{frames: 12, views: 1}}
    markers: {{count: 30, dropout: 0.02, ghosts_per_s: 5.0}}   # occluded, broken, 2 ghosts in 0.4 s
    sequences:
      walk: {{motion: {shared}/motions/cmu_12_01_walk.bvh, seed: 8}}
      arm: {{motion: elbow_flexion, seed: 9, markers: {{count: 12, part: right_arm, dropout: 0.0, occlusion: false,
                                                      break_per_s: 0.0, ghosts_per_s: 0.0}}}}
stages:
  markers: {{task: ingest_markers, dataset: uuo}}
  segments: {{task: rigid_segments, inputs: [markers]}}
  prior: {{task: simulated_prior, inputs: [markers]}}
"""


@pytest.mark.needs_shared
def test_unlabelled_marker_takes_on_the_mesh_body_run_through_the_engine(tmp_path):
    (tmp_path / "catalog.yaml").write_text(MARKER_CATALOG.format(shared=SHARED))
    # one worker: each worker process loads the mesh body's model for itself (most of the run's CPU time)
    summary = last_json(mocapflow("run", "--json", "--workers", "1", cwd=tmp_path))
    assert sorted(summary["executed"]) == ["markers/arm", "markers/walk", "prior/arm", "prior/walk",
                                           "segments/arm", "segments/walk"]
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(tmp_path / "storage").items()}
    walk, arm = stored["markers/walk"], stored["markers/arm"]
    assert stored["segments/walk"]["segment"].shape == walk["gt_source"].shape  # a group for every trajectory
    assert 2 <= stored["segments/arm"]["segment"].max() + 1 <= 12  # an arm's 12 markers: a few bones
    assert stored["prior/walk"]["joints"].shape == (12, 20, 3)  # a rough body for every frame
    assert walk["position"].shape[0] == 12 and walk["position"].shape[1] > 30  # fragments and ghosts
    real = walk["gt_source"] >= 0
    assert (~real).sum() == 2 and sorted(set(walk["gt_source"][real])) == list(range(30))
    seen = ~np.isnan(walk["position"][..., 0])
    error = np.linalg.norm(walk["position"] - walk["gt_path"], axis=2)[seen & real[None]]
    assert error.max() < 0.006 and np.isnan(walk["gt_path"][:, ~real]).all()
    assert arm["position"].shape == (12, 12, 3) and not np.isnan(arm["position"]).any()
    assert walk["gt_joints"].shape == (12, 20, 3) and walk["gt_bone_rotations"].shape == (12, 104, 4)
    assert last_json(mocapflow("run", "--json", cwd=tmp_path))["executed"] == []
    (tmp_path / "catalog.yaml").write_text(MARKER_CATALOG.format(shared=SHARED).replace("ghosts_per_s", "ghost_per_s"))
    proc = mocapflow("run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "unknown markers field 'ghost_per_s' (did you mean 'ghosts_per_s'?)" in proc.stderr


def test_marker_options_default_to_an_optical_systems_faults_and_keep_the_all_visible_take():
    count, part, faults = marker_options(None, "uuo.markers")
    assert (count, part) == (40, "body") and faults == MarkerFaults()
    assert faults.occlusion and (faults.ghosts_per_s, faults.break_per_s, faults.fragment) == (2.0, 0.1, True)
    _, _, visible = marker_options({"count": 12, "occlusion": False, "break_per_s": 0, "ghosts_per_s": 0}, "seq")
    assert visible == MarkerFaults.clean() and isinstance(visible.ghosts_per_s, float)
    _, _, rated = marker_options({"ghosts_per_s": 3.5, "break_per_s": 0.25, "ghost_frames": [2, 6]}, "seq")
    assert (rated.ghosts_per_s, rated.break_per_s, rated.ghost_frames, rated.occlusion) == (3.5, 0.25, (2, 6), True)
    with pytest.raises(CatalogError, match=r"seq: markers field 'ghosts' is now ghosts_per_s, a rate"):
        marker_options({"ghosts": 3}, "seq")
    with pytest.raises(CatalogError, match=r"seq: ghosts_per_s \(-1.0\) and break_per_s \(0.1\) are rates"):
        marker_options({"ghosts_per_s": -1}, "seq")


def test_a_joint_map_file_is_read_into_the_spec_and_drives_the_retargeting(tmp_path):
    (tmp_path / "take.bvh").write_text(mixamo_text("rig_"))
    (tmp_path / "rig.yaml").write_text("".join(f"{k}: rig_{v}\n" for k, v in USER_MAP.items()))
    spec, clip, path = make_spec({"motion": "take.bvh", "motion_map": "rig.yaml"}, "seq", lambda p: tmp_path / p)
    assert spec.motion == "bvh" and spec.motion_map == {k: f"rig_{v}" for k, v in USER_MAP.items()}
    motion = retarget.retarget(clip.clip, Subject(1.7), user_map=spec.motion_map)
    known = retarget.retarget(parse_bvh(mixamo_text()), Subject(1.7))
    np.testing.assert_allclose(motion.local_rot, known.local_rot, atol=1e-12)
    assert fingerprint(spec, clip) != fingerprint(dataclasses.replace(spec, motion_map=None), clip)
    (tmp_path / "bad.yaml").write_text("- Hips\n- Spine\n")
    with pytest.raises(InputError, match="seq.motion_map: the joint map .*bad.yaml must be a YAML mapping"):
        make_spec({"motion": "take.bvh", "motion_map": "bad.yaml"}, "seq", lambda p: tmp_path / p)
    with pytest.raises(InputError, match="seq: motion_map maps a BVH clip's joints"):
        make_spec({"motion": "side_jumps", "motion_map": "rig.yaml"}, "seq", lambda p: tmp_path / p)


DOOR_CATALOG = """\
data_roots: [.]
storage: {root: storage/}
datasets:
  studio:
    kind: studio
    defaults: {frames: 2, views: 1}
    sequences:
      take: {motion: take.bvh, seed: 1}
stages:
  frames: {task: ingest}
"""


def test_a_skeleton_no_map_fits_is_refused_at_planning_with_the_fix(tmp_path):
    (tmp_path / "take.bvh").write_text(mixamo_text().replace("LeftUpLeg", "LeftThigh"))
    (tmp_path / "catalog.yaml").write_text(DOOR_CATALOG)
    proc = mocapflow("run", "--dry-run", cwd=tmp_path, check=False)
    assert proc.returncode == 2, proc.stderr
    assert f"the skeleton of {tmp_path / 'take.bvh'} cannot be retargeted" in proc.stderr
    assert "the closest, Mixamo, lacks joints ['LeftUpLeg']" in proc.stderr
    assert "motion_map: my_map.yaml" in proc.stderr and "Traceback" not in proc.stderr
    (tmp_path / "my_map.yaml").write_text("".join(f"{k}: mixamorig:{v}\n" for k, v in USER_MAP.items())
                                          .replace("LeftUpLeg", "LeftThigh"))
    (tmp_path / "catalog.yaml").write_text(DOOR_CATALOG.replace("seed: 1", "seed: 1, motion_map: my_map.yaml"))
    assert mocapflow("run", "--dry-run", cwd=tmp_path).stdout.splitlines()[-1] == "1 to run, 0 cached"
    with pytest.raises(InputError, match=r"take.bvh holds 3 frames at 30 fps from start_s 0 .*asked for 9: lower"):
        make_spec({"motion": "take.bvh", "motion_map": "my_map.yaml", "frames": 9}, "seq", lambda p: tmp_path / p)
    with pytest.raises(InputError, match=r"holds 0 frames at 30 fps from start_s 1 \(the clip lasts 0.13 s\)"):
        make_spec({"motion": "take.bvh", "motion_map": "my_map.yaml", "start_s": 1}, "seq", lambda p: tmp_path / p)


def test_an_amc_take_with_its_asf_skeleton_is_a_studio_motion(tmp_path):
    from mocapflow.pipeline.errors import CatalogError
    from motion_files import cmu_amc_text, cmu_asf_text

    (tmp_path / "subject.asf").write_text(cmu_asf_text())
    (tmp_path / "take.amc").write_text(cmu_amc_text())
    resolve = lambda p: tmp_path / p  # noqa: E731
    spec, motion_file, source = make_spec({"motion": "take.amc", "skeleton": "subject.asf", "amc_fps": 30,
                                           "views": 1}, "seq", resolve)
    assert spec.motion == "bvh" and spec.label == "take" and source.amc_fps == 30.0
    again = load_motion(source, "seq")  # what a worker reads is what the fingerprint hashed
    assert again.digest == motion_file.digest and np.array_equal(again.clip.data, motion_file.clip.data)
    faster = make_spec({"motion": "take.amc", "skeleton": "subject.asf", "amc_fps": 60, "views": 1}, "seq", resolve)
    assert faster[1].digest != motion_file.digest  # the rate is the take's too: it enters the fingerprint
    clip = motion_file.clip  # read straight from the ASF and AMC: no BVH text in between
    assert clip.fps == pytest.approx(30.0) and clip.data.shape[0] == 5
    assert retarget.joint_map(clip)["LeftKnee"] == ("ltibia", "ltibia", "lfoot")
    rig = build_rig(dataclasses.replace(spec, frames=2), clip)
    knee, ankle = JOINT_INDEX["LeftKnee"], JOINT_INDEX["LeftAnkle"]
    shin = rig.joint_pos[1, ankle] - rig.joint_pos[1, knee]  # the left knee bent in the take's 3rd frame: backward
    np.testing.assert_allclose(shin / np.linalg.norm(shin), [0, -1, 0], atol=1e-9)
    for raw, error, message in [
        ({"motion": "subject.asf"}, CatalogError, "subject.asf is a skeleton; .* motion: take.amc, skeleton: subject"),
        ({"motion": "take.amc"}, CatalogError, "the AMC take take.amc needs its ASF skeleton: add skeleton"),
        ({"motion": "side_jumps", "skeleton": "subject.asf"}, CatalogError, r"\['skeleton'\] belong to an AMC take"),
        ({"motion": "take.amc", "skeleton": "subject.asf", "amc_fps": 0}, CatalogError, "amc_fps must be positive"),
        ({"motion": "take.amc", "skeleton": "take.amc"}, InputError,
         r"take.amc \(skeleton .*take.amc\) cannot be read: the ASF has no ':root' section"),
    ]:
        with pytest.raises(error, match=message):
            make_spec(raw, "seq", resolve)


CLOSE_SENSOR = """\
storage: {{root: storage/}}
datasets:
  studio:
    kind: studio
    layout: close.yaml
    {check}
    defaults: {{frames: 2, noise: 0.5}}
    sequences:
      squat: {{motion: classic_squat, seed: 3, subject_height: 1.80}}
stages:
  frames: {{task: ingest}}
"""


@pytest.mark.parametrize("check", ["", "out_of_view: refuse"])
def test_a_subject_leaving_a_sensors_view_is_reported_or_refused(tmp_path, check):
    # one sensor 1.1 m in front of a 1.8 m subject sees the chest, not the head and feet
    (tmp_path / "close.yaml").write_text("sensors:\n  - {name: near, position: [0, 1.1, 1.0], target: [0, 0, 1.0]}\n")
    (tmp_path / "catalog.yaml").write_text(CLOSE_SENSOR.format(check=check))
    proc = mocapflow("run", cwd=tmp_path, check=False)
    said = "sequence 'squat': the subject leaves the view of 1 camera(s) (joint-frames outside: near"
    if check:
        assert proc.returncode == 1 and said in proc.stdout + proc.stderr
    else:
        assert proc.returncode == 0 and said in proc.stderr  # the worker's warning, said by the driver
        assert "set the dataset's out_of_view: off" in proc.stderr


def test_the_view_check_warns_refuses_or_keeps_quiet():
    cams = camera_layout({"sensors": [{"name": "near", "position": [0, 1.1, 1.0], "target": [0, 0, 1.0]},
                                      {"name": "far", "position": [0, 3.5, 1.0], "target": [0, 0, 1.0]}]})
    standing = np.zeros((3, 2, 3))
    standing[:, 1, 2] = 1.8  # feet and head of a 1.8 m subject at the centre
    with pytest.warns(InputWarning, match=r"leaves the view of 1 camera\(s\) \(joint-frames outside: near 100 %"):
        check_in_view("s", cams, standing, "warn")
    with pytest.raises(InputError, match="leaves the view of 1 camera"):
        check_in_view("s", cams, standing, "refuse")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_in_view("s", cams, standing, "off")
        check_in_view("s", cams[1:], standing, "warn")  # the far sensor sees head and feet: nothing to say
        waist = np.full((3, 1, 3), [0.0, 0.0, 1.0])
        check_in_view("s", cams, waist, "warn")  # both see the waist


def test_an_unknown_view_check_is_refused_at_load(tmp_path):
    (tmp_path / "close.yaml").write_text("sensors:\n  - {name: near, position: [0, 1.1, 1.0], target: [0, 0, 1.0]}\n")
    (tmp_path / "catalog.yaml").write_text(CLOSE_SENSOR.format(check="out_of_view: maybe"))
    proc = mocapflow("run", "--dry-run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "out_of_view: 'maybe' is not one of ['warn', 'refuse', 'off']" in proc.stderr
