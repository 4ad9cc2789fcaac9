"""`mocapflow export` of UUO solves: a labelled C3D read back through ezc3d, a BVH of the solved rig whose
forward kinematics give the solved bone heads, a report page; and the same through the CLI."""

from __future__ import annotations

import shutil

import ezc3d
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import mocapflow, read_artifacts
from shared_runs import copy_run, shared_run
from studio_catalogs import UUO_CATALOG
from mocapflow.systems.uuo import export as export_uuo
from mocapflow.formats.bvh import parse_bvh, read_bvh_joints
from mocapflow.systems.uuo.marker_files import read_markers
from mocapflow.tasks.shared.kinematics import local_rotations
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES
from mocapflow.tasks.uuo import takes as uuo
from mocapflow.tasks.deepmocap.film.synth import build_rig
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.uuo import solve
from mocapflow.tasks.shared.solver_body import BodyFit


@pytest.fixture(scope="module")
def take():
    rig = build_rig(SequenceSpec("side_reaches", frames=12, seed=35, body="mesh", views=1))
    layout = uuo.layout(rig.body, np.random.default_rng(1), 15)
    rec = uuo.capture(uuo.marker_paths(rig.body, layout, rig.take.posed.vertices[:12]),
                      uuo.MarkerFaults.clean(dropout=0.05, ghosts_per_s=5.0), np.random.default_rng(2),
                      fps=30.0)  # 12 frames, 0.4 s: two ghosts
    markers = uuo.marker_dataset(rig.body, layout, rec, rig.take, 30.0, 0, 12)
    body, solver = solve._bodies(markers.attrs["phenotype"])
    world = Rotation.from_quat(markers.gt_bone_rotations.values.reshape(-1, 4)).as_matrix().reshape(12, -1, 3, 3)
    fit = BodyFit(local_rotations(world, body.bone_parents), markers.gt_root.values,
                  np.array([markers.attrs["phenotype"][k] for k in PHENOTYPE_NAMES]))
    vertex = np.where(markers.gt_face.values >= 0, body.faces[np.maximum(markers.gt_face.values, 0), 0], -1)
    solved = solve.body_dataset(markers, body, solver, fit, vertex, np.full(len(vertex), 0.0095), {},
                                {"yaw_deg": 0.0, "chamfer": 0.0, "parts": ["body"]})
    return markers, solved


def test_the_labelled_c3d_carries_each_trajectorys_part_and_vertex(take, tmp_path):
    markers, solved = take
    export_uuo.write_uuo_c3d(solved, markers, tmp_path / "take.c3d")
    c3d = ezc3d.c3d(str(tmp_path / "take.c3d"))
    labels = [str(n) for n in c3d["parameters"]["POINT"]["LABELS"]["value"]]
    ghosts = markers.gt_source.values < 0
    assert ghosts.any() and all(label == str(m) for label, m in zip(np.array(labels)[ghosts], markers.marker.values[ghosts]))
    real = [label for label, g in zip(labels, ghosts) if not g]
    vertex, part = solved.vertex.values[~ghosts], solved.part.values[~ghosts]
    assert real == [f"{p}_v{v:05d}" for p, v in zip(part, vertex)] and all(p for p in part)
    assert list(c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"]) == list(markers.marker.values)
    back = read_markers(tmp_path / "take.c3d", labels="use")  # the project's own reader: metres, Z up, NaN gaps
    np.testing.assert_allclose(back.position.values, markers.position.values, atol=1e-5, equal_nan=True)
    assert np.isnan(back.position.values).any() and back.attrs["fps"] == 30.0


def test_the_bvh_of_the_solved_rig_parses_and_reproduces_the_bone_heads(take, tmp_path):
    _, solved = take
    export_uuo.write_uuo_bvh(solved, tmp_path / "take.bvh")
    bvh = parse_bvh((tmp_path / "take.bvh").read_text())
    assert len([n for n in bvh.names if not n.endswith("_End")]) == solved.sizes["bone"] and bvh.fps == pytest.approx(30)
    joints, names, _ = read_bvh_joints(tmp_path / "take.bvh")
    assert names[0] == "root" and "upperarm01_L" in names
    np.testing.assert_allclose(joints, solved.bone_heads.values, atol=2e-4)  # 1e-5 cm text, float32 heads


def test_the_report_page_shows_the_mesh_and_the_errors(take, tmp_path):
    import cv2

    markers, solved = take
    truth = markers.gt_joints.values.astype(np.float64)
    page = export_uuo.write_report(tmp_path / "take", "take", "body", solved, markers, truth, "the truth", [])
    text = page.read_text()
    for name in ("markers_on_mesh.png", "joint_errors.png", "error_over_time.png"):
        assert name in text
        img = cv2.imread(str(tmp_path / "take" / name))
        assert img is not None and img.std() > 10  # drawn, not blank
    mesh = cv2.imread(str(tmp_path / "take" / "markers_on_mesh.png"))
    assert mesh.shape == (420, 840, 3) and (mesh[..., 0] > 100).mean() > 0.05  # the body covers part of both views
    import re

    value = re.search(r"MPJPE against the truth \(mm\)</td><td>([^<]+)<", text).group(1)
    assert float(value) < 1e-6  # the truth scored against itself


def test_the_cli_exports_a_uuo_solve_as_c3d_bvh_and_a_report(request, tmp_path):
    # the pytest run's one run of the UUO studio catalog (test_uuo_engine and test_uuo_report read it too)
    shared_run(request, "uuo", UUO_CATALOG)
    project = copy_run(request, "uuo", tmp_path / "project")
    shutil.rmtree(project / "storage" / "solve")  # the solve is missing: the first export computes it again
    out = tmp_path / "out"
    for fmt in ("c3d", "bvh", "report"):
        proc = mocapflow("export", "--format", fmt, "--out", str(out), "--workers", "1", "--threads", cwd=project)
        assert "wrote" in proc.stdout
    c3d = ezc3d.c3d(str(out / "reach.c3d"))
    labels = [str(n) for n in c3d["parameters"]["POINT"]["LABELS"]["value"]]
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(project / "storage").items()}["solve/reach"]
    assert labels == [f"{p}_v{v:05d}" if v >= 0 else f"m{i:03d}"
                      for i, (p, v) in enumerate(zip(stored["part"], stored["vertex"]))]
    assert sum("_v" in label for label in labels) >= 5  # the solve labelled markers
    assert len(parse_bvh((out / "reach.bvh").read_text()).names) > 100
    assert "MPJPE against the studio" in (out / "reach" / "report.html").read_text()  # scored against its truth
    proc = mocapflow("export", "--format", "trc", "--out", str(out), "--stage", "solve", cwd=project, check=False)
    assert proc.returncode != 0 and "trc exports smoothed_markers or markers3d" in proc.stderr
