"""Exports read back by independent readers: C3D through ezc3d and the `c3d` package, TRC parsed by hand, BVH through
a small reader written here (its own hierarchy parsing and forward kinematics)."""

import warnings

import numpy as np
import pytest
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.errors import InputError
from mocapflow.formats.c3d import read_points as read_c3d
from mocapflow.formats.trc import read_trc
from mocapflow.systems.deepmocap.export import write_bvh, write_c3d, write_trc


def _markers(n_frames=7):
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-1, 2, (n_frames, 3, 3)).astype(np.float32)
    xyz[2, 1] = np.nan
    residual = rng.uniform(0, 0.01, (n_frames, 3, 2)).astype(np.float32)
    residual[2, 1] = np.nan
    residual[4, 0, 1] = np.nan  # seen by one view only
    return xr.Dataset({"position": (("frame", "reflector", "xyz"), xyz),
                       "residual": (("frame", "reflector", "view"), residual)},
                      coords={"frame": np.arange(n_frames), "reflector": ["R_HAND", "L_HAND", "B_HEAD"],
                              "xyz": ["x", "y", "z"], "view": ["a", "b"]},
                      attrs={"fps": 30.0, "length_unit": "m", "up_axis": "Z"})


def _smoothed(n_frames=7):
    markers = _markers(n_frames)
    return xr.Dataset({"position": markers["position"],
                       "confidence": (("frame", "reflector"), np.ones((n_frames, 3), np.float32)),
                       "predicted": (("frame", "reflector"), np.zeros((n_frames, 3), bool))},
                      attrs={**markers.attrs, "smoothing": "kalman"})


def _read_with_c3d_package(path):
    """xyz (frame, marker, 3), residuals (frame, marker), camera bytes, labels, rate, POINT:SCALE; no warning
    but the one for a file without analog data."""
    import c3d

    with warnings.catch_warnings(record=True) as caught, open(path, "rb") as handle:
        warnings.simplefilter("always")
        reader = c3d.Reader(handle)
        frames = [points for _, points, _ in reader.read_frames(copy=True, check_nan=True)]
        labels = [str(n).strip() for n in reader.point_labels]
        rate, scale = reader.point_rate, reader.point_scale
    assert [str(w.message) for w in caught if "analog" not in str(w.message)] == []
    data = np.stack(frames)
    return data[..., :3], data[..., 3], data[..., 4], labels, rate, scale


@pytest.mark.parametrize("make", [_markers, _smoothed])
def test_c3d_reads_the_same_through_ezc3d_and_the_c3d_package(tmp_path, make):
    import ezc3d

    markers = make()
    write_c3d(markers, tmp_path / "take.c3d")
    truth = markers["position"].values * 1000.0
    missing = np.isnan(truth[..., 0])

    xyz, residual, cameras, labels, rate, scale = _read_with_c3d_package(tmp_path / "take.c3d")
    assert labels == ["R_HAND", "L_HAND", "B_HEAD"] and rate == 30.0
    # float data: POINT:SCALE negative, its magnitude a real scale (max coordinate / 32000 at least), not -1
    assert scale < 0 and abs(scale) >= np.nanmax(np.abs(truth)) / 32000 and scale != -1.0
    np.testing.assert_allclose(xyz[~missing], truth[~missing], atol=0.01)
    assert (residual[missing] == -1).all()
    if "residual" in markers:  # the fusion residual (mean over the fused views), mm, to |SCALE|
        expected = np.nanmean(markers["residual"].values[~missing], axis=-1) * 1000.0
        np.testing.assert_allclose(residual[~missing], expected, atol=abs(scale) / 2 + 1e-4)
        assert (residual[~missing] > 0).all()
        assert cameras[4, 0] == 1 and cameras[0, 0] == 3  # bit per fused view
    else:  # filtered data: residual 0 (processed, not a measurement), no camera bits
        assert (residual[~missing] == 0).all() and (cameras[~missing] == 0).all()

    c3d = ezc3d.c3d(str(tmp_path / "take.c3d"))
    points = c3d["data"]["points"][:3].transpose(2, 1, 0)
    np.testing.assert_allclose(points[~missing], truth[~missing], atol=0.01)
    assert np.isnan(points[missing]).all()
    assert list(c3d["parameters"]["POINT"]["LABELS"]["value"]) == labels
    assert c3d["parameters"]["POINT"]["UNITS"]["value"] == ["mm"]
    assert c3d["parameters"]["POINT"]["SCALE"]["value"][0] == pytest.approx(scale)

    mm, names, fps, ours = read_c3d(tmp_path / "take.c3d")
    assert names == labels and fps == 30.0
    np.testing.assert_allclose(mm[~missing], truth[~missing], atol=0.01)
    np.testing.assert_allclose(ours, residual, atol=1e-4)


def _trc(path):
    """Header fields and (frame, marker, 3) values of a TRC file, parsed here."""
    rows = path.read_text().splitlines()
    assert rows[0].startswith("PathFileType\t4\t(X/Y/Z)")
    header = dict(zip(rows[1].split("\t"), rows[2].split("\t")))
    names = [n for n in rows[3].split("\t")[2:] if n]
    assert rows[4].split("\t")[2:5] == ["X1", "Y1", "Z1"]
    values = [[float(v) if v else np.nan for v in row.split("\t")[2:]] for row in rows[5:]]
    return header, names, np.array(values).reshape(len(values), len(names), 3)


def test_trc_is_y_up_by_default(tmp_path):
    markers = _markers()
    write_trc(markers, tmp_path / "take.trc")
    header, names, xyz = _trc(tmp_path / "take.trc")
    assert names == ["R_HAND", "L_HAND", "B_HEAD"] and header["DataRate"] == "30.00" and header["Units"] == "mm"
    assert header["UpAxis"] == "Y"
    world = markers["position"].values * 1000.0
    np.testing.assert_allclose(xyz[..., 0], world[..., 0], atol=1e-3)  # x stays
    np.testing.assert_allclose(xyz[..., 1], world[..., 2], atol=1e-3)  # height on y
    np.testing.assert_allclose(xyz[..., 2], -world[..., 1], atol=1e-3)  # z = -y: a rotation, handedness kept
    assert np.isnan(xyz[2, 1]).all()
    np.testing.assert_allclose(read_trc(tmp_path / "take.trc")[0], xyz, atol=1e-9)


def test_trc_keeps_z_up_on_request(tmp_path):
    markers = _markers()
    write_trc(markers, tmp_path / "take.trc", up="z")
    header, _, xyz = _trc(tmp_path / "take.trc")
    assert header["UpAxis"] == "Z"
    np.testing.assert_allclose(xyz, markers["position"].values * 1000.0, atol=1e-3)
    with pytest.raises(InputError, match="TRC up axis 'x'.*--up y"):
        write_trc(markers, tmp_path / "other.trc", up="x")


def _bvh_world(text):
    """Joint world positions (frame, joint, 3) and names of BVH text: OFFSET plus any position channels, then the
    rotation channels in their listed order, composed down the hierarchy."""
    tokens = text.split()
    i, joints, stack = 0, [], []  # joint: name, parent, offset, channels
    while tokens[i] != "MOTION":
        tok = tokens[i]
        if tok in ("ROOT", "JOINT"):
            joints.append([tokens[i + 1], stack[-1] if stack else -1, None, []])
            i += 2
        elif tok == "End":
            joints.append(["End", stack[-1], None, []])
            i += 2
        elif tok == "{":
            stack.append(len(joints) - 1)
            i += 1
        elif tok == "}":
            stack.pop()
            i += 1
        elif tok == "OFFSET":
            joints[stack[-1]][2] = np.array([float(v) for v in tokens[i + 1:i + 4]])
            i += 4
        elif tok == "CHANNELS":
            n = int(tokens[i + 1])
            joints[stack[-1]][3] = tokens[i + 2:i + 2 + n]
            i += 2 + n
        else:
            i += 1
    n_frames = int(tokens[tokens.index("Frames:") + 1])
    start = tokens.index("Time:") + 2
    motion = np.array([float(v) for v in tokens[start:]]).reshape(n_frames, -1)
    out = np.zeros((n_frames, len(joints), 3))
    for f in range(n_frames):
        col, rot = 0, {}
        for j, (_, parent, offset, chans) in enumerate(joints):
            local_t, local_r = offset.copy(), np.eye(3)
            for chan in chans:
                value = motion[f, col]
                col += 1
                if chan.endswith("position"):
                    local_t["XYZ".index(chan[0])] += value
                else:
                    local_r = local_r @ Rotation.from_euler(chan[0].lower(), value, degrees=True).as_matrix()
            if parent < 0:
                out[f, j], rot[j] = local_t, local_r
            else:
                out[f, j], rot[j] = out[f, parent] + rot[parent] @ local_t, rot[parent] @ local_r
    keep = [j for j, joint in enumerate(joints) if joint[0] != "End"]
    return out[:, keep], [joints[j][0] for j in keep]


def _poses(n_frames=4):
    from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS, random_subject, rest_offsets

    rng = np.random.default_rng(1)
    offsets = rest_offsets(random_subject(rng, height=1.8))
    local = Rotation.from_rotvec(rng.normal(0, 0.25, (n_frames, len(JOINT_NAMES), 3)))
    root = np.array([0.3, -0.2, 0.95]) + rng.normal(0, 0.05, (n_frames, 3))
    world_r = np.zeros((n_frames, len(JOINT_NAMES), 3, 3))
    pos = np.zeros((n_frames, len(JOINT_NAMES), 3))
    matrices = local.as_matrix()
    for j, parent in enumerate(PARENTS):  # parents come before their children
        if parent < 0:
            world_r[:, j], pos[:, j] = matrices[:, j], root
        else:
            world_r[:, j] = world_r[:, parent] @ matrices[:, j]
            pos[:, j] = pos[:, parent] + np.einsum("fij,j->fi", world_r[:, parent], offsets[j])
    return xr.Dataset(
        {"position": (("frame", "joint", "xyz"), pos.astype(np.float32)),
         "rotation": (("frame", "joint", "quat"), local.as_quat().astype(np.float32)),
         "offset": (("joint", "xyz"), offsets.astype(np.float32))},
        coords={"frame": np.arange(n_frames), "joint": list(JOINT_NAMES), "xyz": ["x", "y", "z"],
                "quat": ["x", "y", "z", "w"]},
        attrs={"length_unit": "m", "up_axis": "Z", "fps": 30.0}), pos


def test_bvh_puts_the_root_and_the_feet_at_their_true_heights(tmp_path):
    poses, world = _poses()
    write_bvh(poses, tmp_path / "take.bvh")
    text = (tmp_path / "take.bvh").read_text()
    root_offset = text.split("OFFSET", 1)[1].split("\n", 1)[0].split()
    assert [float(v) for v in root_offset] == [0.0, 0.0, 0.0]
    joints, names = _bvh_world(text)
    assert names == list(poses["joint"].values)
    height_cm = world[..., 2] * 100.0  # Z-up world -> BVH Y up, centimetres
    for name in ("Hips", "LeftFoot", "RightFoot", "Head"):
        j = names.index(name)
        np.testing.assert_allclose(joints[:, j, 1], height_cm[:, j], atol=0.05)
    # and the whole body: x -> -X, y (forward) -> Z, as the BVH convention of the module says
    np.testing.assert_allclose(joints, np.stack([-world[..., 0], world[..., 2], world[..., 1]], -1) * 100.0,
                               atol=0.05)


def test_unknown_extension_is_refused(tmp_path):
    with pytest.raises(InputError, match="must end in .trc"):
        write_trc(_markers(), tmp_path / "take.csv")
    assert not list(tmp_path.iterdir())


def test_an_export_file_name_may_not_leave_the_out_folder(tmp_path):
    from mocapflow.pipeline.errors import PlanError
    from mocapflow.pipeline.export import target as _inside

    assert _inside(tmp_path / "out", "take1.trc") == tmp_path / "out" / "take1.trc"
    for name in ("../../x.trc", "sub/x.trc", "/etc/x.trc"):
        with pytest.raises(PlanError, match="would be written outside --out"):
            _inside(tmp_path / "out", name)


def test_up_is_refused_for_formats_with_a_fixed_up_axis(tmp_path):
    from mocapflow.pipeline.export import export_files

    with pytest.raises(InputError, match="--up z applies to TRC only.*drop --up"):
        export_files(None, None, "c3d", None, tmp_path, workers=1, up="z")
