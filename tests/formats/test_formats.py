"""The file formats (formats/), each written here and read back by a reader that is not ours: C3D by the `c3d`
package, BVH by the `bvh` package, PLY by trimesh, TRC by the standard library's csv module."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from mocapflow.formats import bvh, c3d, ply, trc

NAMES = ["LASI", "RASI", "LKNE"]


def points(n_frames: int = 12, seed: int = 0) -> np.ndarray:
    """(frame, marker, 3) mm, one sample missing."""
    xyz = np.random.default_rng(seed).uniform(-900.0, 1800.0, (n_frames, len(NAMES), 3))
    xyz[3, 1] = np.nan
    return xyz


def test_c3d_points_read_the_same_through_the_c3d_package(tmp_path):
    import c3d as independent

    xyz = points()
    residual = np.where(np.isfinite(xyz).all(-1), 2.0, -1.0)
    scale = c3d.c3d_scale(xyz, residual)
    word4 = np.where(residual < 0, -1, np.rint(residual / abs(scale)))
    path = tmp_path / "take.c3d"
    c3d.write_points(path, np.nan_to_num(xyz), NAMES, 100.0, scale, word4)
    with open(path, "rb") as handle:
        reader = independent.Reader(handle)
        assert [label.strip() for label in reader.point_labels] == NAMES
        assert reader.point_rate == pytest.approx(100.0)
        frames = [p for _, p, _ in reader.read_frames()]
    got = np.stack(frames)  # (frame, marker, 5): x y z residual cameras
    seen = np.isfinite(xyz).all(-1)
    np.testing.assert_allclose(got[..., :3][seen], xyz[seen], rtol=1e-6, atol=1e-3)
    assert (got[..., 3][~seen] < 0).all()  # the missing sample is marked missing
    ours, labels, rate, res = c3d.read_points(path)
    np.testing.assert_allclose(ours[seen], xyz[seen], rtol=1e-6, atol=1e-3)
    assert labels == NAMES and rate == pytest.approx(100.0) and (res[~seen] < 0).all()


def test_trc_text_reads_back_through_csv(tmp_path):
    xyz = points()
    frames = np.arange(10, 10 + len(xyz))
    path = tmp_path / "take.trc"
    path.write_text(trc.trc_text(xyz, NAMES, 50.0, frames, "y", path.name))
    rows = list(csv.reader(path.open(), delimiter="\t"))
    header = dict(zip(rows[1], rows[2]))
    assert header["DataRate"] == "50.00" and header["Units"] == "mm" and header["UpAxis"] == "Y"
    assert header["NumFrames"] == str(len(xyz)) and header["NumMarkers"] == str(len(NAMES))
    assert [n for n in rows[3][2:] if n] == NAMES
    data = rows[5:]
    assert [int(r[0]) for r in data] == list(frames + 1)  # 1-based frame numbers
    np.testing.assert_allclose([float(r[1]) for r in data], frames / 50.0, atol=1e-5)
    values = np.array([[float(v) if v else np.nan for v in r[2:]] for r in data]).reshape(xyz.shape)
    np.testing.assert_allclose(values, xyz, atol=5e-4, equal_nan=True)
    np.testing.assert_allclose(trc.read_trc(path)[0], values, equal_nan=True)


def test_bvh_text_reads_back_through_the_bvh_package(tmp_path):
    from bvh import Bvh

    names = ["Hips", "Spine", "Head", "LeftLeg"]
    parents = np.array([-1, 0, 1, 0])
    offsets = np.array([[0, 0, 0], [0, 0, 0.2], [0, 0, 0.3], [0.1, 0, -0.4]])  # m, Z up
    n = 5
    rng = np.random.default_rng(3)
    quat = Rotation.from_euler("xyz", rng.uniform(-40, 40, (n * 4, 3)), degrees=True).as_quat().reshape(n, 4, 4)
    root = rng.uniform(-1, 1, (n, 3)) + [0, 0, 1]
    text = bvh.bvh_text(names, parents, offsets, quat, root, 60.0)
    parsed = Bvh(text)
    assert parsed.get_joints_names() == names
    assert parsed.nframes == n and parsed.frame_time == pytest.approx(1 / 60.0)
    # offsets in centimetres, Y up: z up -> y, y -> z, x -> -x
    np.testing.assert_allclose(parsed.joint_offset("Spine"), (0, 20, 0), atol=1e-4)
    np.testing.assert_allclose(parsed.joint_offset("LeftLeg"), (-10, -40, 0), atol=1e-4)
    assert parsed.joint_channels("Hips")[:3] == ["Xposition", "Yposition", "Zposition"]
    got = np.array(parsed.frames_joint_channels("Hips", ["Xposition", "Yposition", "Zposition"]))
    np.testing.assert_allclose(got, np.stack([-root[:, 0], root[:, 2], root[:, 1]], -1) * 100, atol=1e-4)
    joints, read_names, fps = bvh.read_bvh_joints(_saved(tmp_path, text))
    assert read_names == names and fps == pytest.approx(60.0)
    np.testing.assert_allclose(joints[:, 0], root, atol=1e-6)  # back in metres, Z up


def _saved(tmp_path, text):
    path = tmp_path / "skeleton.bvh"
    path.write_text(text)
    return path


def test_ply_text_reads_back_through_trimesh(tmp_path):
    position = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    observed = np.array([1, 1, 0, 1, 0, 1], bool)
    cells = np.array([[0, 1, 2, 3], [1, 4, 5, 2]])
    path = tmp_path / "suit.ply"
    path.write_text(ply.ply_text(position, observed, cells))
    mesh = trimesh.load(path, file_type="ply", process=False)
    np.testing.assert_allclose(mesh.vertices, position, atol=1e-6)
    assert len(mesh.faces) == 2 * len(cells)  # each square as two triangles
    assert set(map(tuple, mesh.faces[:2])) == {(0, 1, 2), (1, 4, 5)}
    np.testing.assert_allclose(mesh.area, 2.0)  # the two unit squares, nothing lost or doubled
