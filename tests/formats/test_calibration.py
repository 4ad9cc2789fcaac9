"""Calibration import from Qualisys (.qca), anipose/Pose2Sim (Calib.toml) and OpenCV (cv2.FileStorage): the real
Qualisys file checked geometrically, each format round-tripped from known cameras through projections, the CLI,
and bad files refused naming the file, the key and the value."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from mocapflow.cli import commands as cli
from mocapflow.formats.calibration import cameras_of, read_calibration, read_opencv, read_qca, read_toml
from mocapflow.systems.deepmocap.readers import read_calibration_yaml
from mocapflow.pipeline.errors import InputError
from mocapflow.tasks.shared.cameras import calibrated_camera, extrinsics_of, look_at
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP
from shared_data import CALIBRATION

QCA = CALIBRATION / "pose2sim_demo_Calib.qca.txt"
# World points (metres, Z up) inside the ring's volume.
POINTS = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 1.0], [-0.4, 0.5, 1.7], [0.1, 0.6, 0.4], [-0.5, -0.5, 1.2]])


def ring():
    """Three known cameras around the origin, each with its own intrinsics and distortion."""
    specs = [((3.0, 0.2, 2.0), 1000.0, 1010.0, 640.5, 360.2, [-0.12, 0.05, 0.001, -0.0005, 0.01], 1280, 720),
             ((-1.5, 2.6, 1.8), 1500.0, 1500.0, 960.0, 540.0, [0.02, -0.01, 0.0, 0.0, 0.0], 1920, 1080),
             ((-1.2, -2.8, 2.5), 800.0, 805.0, 330.0, 250.0, [-0.2, 0.1, -0.002, 0.003, -0.02], 640, 480)]
    return {f"cam{i}": calibrated_camera(f"cam{i}", fx=fx, fy=fy, cx=cx, cy=cy, dist=dist, cam_to_world=look_at(np.array(p), (0.0, 0.0, 1.0)),
                                         width=w, height=h)
            for i, (p, fx, fy, cx, cy, dist, w, h) in enumerate(specs)}


def in_file_frame(camera, up: str) -> np.ndarray:
    """A camera's pose in a file's world (Z up, or Y up)."""
    return camera.cam_to_world if up == "z" else np.block([[Y_UP_TO_Z_UP.T, np.zeros((3, 1))],
                                                           [np.zeros((1, 3)), 1.0]]) @ camera.cam_to_world


def assert_same_cameras(views, expected):
    assert list(views) == list(expected)
    for name, camera in cameras_of(views).items():
        want = expected[name]
        assert (camera.width, camera.height) == (want.width, want.height)
        np.testing.assert_allclose([camera.fx, camera.fy, camera.cx, camera.cy], [want.fx, want.fy, want.cx, want.cy])
        np.testing.assert_allclose(camera.dist, want.dist, atol=1e-12)
        np.testing.assert_allclose(camera.cam_to_world, want.cam_to_world, atol=1e-9)
        got, depth = camera.project(POINTS)
        ref, ref_depth = want.project(POINTS)
        assert np.isfinite(got).all()
        np.testing.assert_allclose(got, ref, atol=1e-6)  # pixels
        np.testing.assert_allclose(depth, ref_depth, atol=1e-9)


# ---- Qualisys .qca ------------------------------------------------------------------------------
@pytest.mark.needs_shared
def test_the_real_qca_file_reads_in_metres_pixels_and_z_up():
    views = read_qca(QCA)
    assert list(views) == ["cam01", "cam02", "cam03", "cam04"]
    cam01 = views["cam01"]
    # the file's numbers: position in mm, intrinsics in 1/64 pixel, the video window 0..1087 x 0..1919 inclusive
    np.testing.assert_allclose(np.array(cam01["cam_to_world"])[:3, 3],
                               np.array([1460.2323709212087, -1909.1590482454608, 1896.5058524092062]) / 1000)
    np.testing.assert_allclose([cam01["fx"], cam01["fy"], cam01["cx"], cam01["cy"]],
                               np.array([107599.671875, 107588.828125, 34110.316406, 60680.792969]) / 64)
    assert (cam01["width"], cam01["height"]) == (1088, 1920)
    assert cam01["dist"] == [-0.046183, 0.139983, 0.000608, 0.00069, 0.0]
    np.testing.assert_allclose(np.array(views["cam04"]["cam_to_world"])[:3, 3], [-3.758720480260634, -1.4156654017496533,
                                                                                 1.8817941041388026])
    # the extrinsics Pose2Sim's converter writes for this file (its Calib_qualisys.toml, cam_01)
    rvec, tvec = extrinsics_of(np.array(cam01["cam_to_world"]))
    np.testing.assert_allclose(rvec, [1.68827548, 1.04832205, -0.41955852], atol=1e-7)
    np.testing.assert_allclose(tvec, [0.32110489, 0.95633206, 2.89071305], atol=1e-7)


@pytest.mark.needs_shared
def test_every_real_qualisys_camera_looks_at_the_volume_and_sees_it_upright():
    cameras = cameras_of(read_qca(QCA))
    centres = np.array([c.cam_to_world[:3, 3] for c in cameras.values()])
    assert (centres[:, 2] > 1.5).all()  # mounted high, Z up
    for camera in cameras.values():
        pose = camera.cam_to_world
        towards = -pose[:3, 3] / np.linalg.norm(pose[:3, 3])  # to the volume's centre, the origin
        assert np.degrees(np.arccos(pose[:3, 2] @ towards)) < 25, camera.name  # the optical axis
        assert pose[2, 1] < -0.8, camera.name  # image y (down) points down the world
        uv, depth = camera.project(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
        assert ((uv >= 0) & (uv < [camera.width, camera.height])).all(), (camera.name, uv)
        assert (depth > 2.5).all() and (depth < 6).all()
        assert uv[1, 1] < uv[0, 1] - 300  # a point 1 m above the origin is higher in the image


@pytest.mark.needs_shared
def test_the_other_reading_of_the_qca_rotation_looks_away_from_the_volume():
    """The check above tells the conventions apart: taking r11..r33 row by row as the camera-to-world rotation
    (without the transpose) points the cameras away from the volume."""
    import xml.etree.ElementTree as ET

    angles = []
    for transform in ET.parse(QCA).getroot().iter("transform"):
        rot = np.array([[float(transform.get(f"r{i}{j}")) for j in (1, 2, 3)] for i in (1, 2, 3)])
        position = np.array([float(transform.get(a)) for a in "xyz"]) / 1000
        axis = -rot[:, 2]  # the Qualisys camera looks along its -z
        angles.append(np.degrees(np.arccos(axis @ -position / np.linalg.norm(position))))
    assert max(angles) > 60


def qca_text(cameras, *, up="z", extra="", viewrotation="0") -> str:
    """A .qca file of known cameras: Qualisys camera axes, mm, 1/64-pixel intrinsics."""
    rows = []
    for name, cam in cameras.items():
        pose = in_file_frame(cam, up)
        rot = np.diag([1.0, -1.0, -1.0]) @ pose[:3, :3].T  # rij: rows are the Qualisys camera's axes
        r = " ".join(f'r{i + 1}{j + 1}="{float(rot[i, j])!r}"' for i in range(3) for j in range(3))
        x, y, z = (float(v) for v in pose[:3, 3] * 1000)
        k1, k2, p1, p2, k3 = cam.dist
        rows.append(f'''<camera active="1" serial="{name}" viewrotation="{viewrotation}" model="Miqus Video">
  <fov_video left="0" top="0" right="{cam.width - 1}" bottom="{cam.height - 1}"/>
  <transform x="{x!r}" y="{y!r}" z="{z!r}" {r}/>
  <intrinsic focalLengthU="{cam.fx * 64!r}" focalLengthV="{cam.fy * 64!r}" centerPointU="{cam.cx * 64!r}"
    centerPointV="{cam.cy * 64!r}" radialDistortion1="{k1!r}" radialDistortion2="{k2!r}" radialDistortion3="{k3!r}"
    tangentalDistortion1="{p1!r}" tangentalDistortion2="{p2!r}"/>
</camera>''')
    return f'<?xml version="1.0"?>\n<calibration><cameras>{"".join(rows)}{extra}</cameras></calibration>\n'


@pytest.mark.parametrize("up", ["z", "y"])
def test_a_qca_of_known_cameras_reads_back_as_them(tmp_path, up):
    inactive = '<camera active="0" serial="spare"><transform/></camera>'
    (tmp_path / "c.qca.txt").write_text(qca_text(ring(), up=up, extra=inactive))
    assert_same_cameras(read_qca(tmp_path / "c.qca.txt", up=up), ring())  # the inactive camera is skipped


# ---- anipose / Pose2Sim Calib.toml -----------------------------------------------------------------
def toml_text(cameras, *, unit="m", up="z", fisheye="false") -> str:
    scale = {"m": 1.0, "mm": 1000.0}[unit]
    out = []
    for i, (name, cam) in enumerate(cameras.items()):
        rvec, tvec = extrinsics_of(in_file_frame(cam, up))
        K = cam.K.tolist()
        out.append(f'[cam_{i + 1}]\nname = "{name}"\nsize = [ {cam.width}.0, {cam.height}.0,]\nmatrix = {K}\n'
                   f"distortions = {list(cam.dist[:4])}\nrotation = {rvec.tolist()}\ntranslation = {(tvec * scale).tolist()}\n"
                   f"fisheye = {fisheye}\n\n")
    return "".join(out) + "[metadata]\nadjusted = false\nerror = 0.0\n"


@pytest.mark.parametrize("unit, up", [("m", "z"), ("mm", "z"), ("m", "y")])
def test_a_toml_of_known_cameras_reads_back_as_them(tmp_path, unit, up):
    cameras = {name: calibrated_camera(name, **{**cam.as_dict(), "dist": [*cam.dist[:4], 0.0]})  # Pose2Sim: 4 coefficients
               for name, cam in ring().items()}
    (tmp_path / "Calib.toml").write_text(toml_text(cameras, unit=unit, up=up))
    views = read_toml(tmp_path / "Calib.toml", unit=None if unit == "m" else unit, up=up)  # metres by default
    assert_same_cameras(views, cameras)


# ---- OpenCV FileStorage ---------------------------------------------------------------------------
def write_opencv(path, cam, *, unit="m", rotation="matrix", keys=("camera_matrix", "distortion_coefficients"),
                 **override):
    rvec, tvec = extrinsics_of(cam.cam_to_world)
    values = {keys[0]: cam.K, keys[1]: np.array(cam.dist).reshape(1, 5),
              "R" if rotation == "matrix" else "rvec": cv2.Rodrigues(rvec)[0] if rotation == "matrix" else rvec.reshape(3, 1),
              "T" if rotation == "matrix" else "tvec": tvec.reshape(3, 1) * {"m": 1.0, "mm": 1000.0}[unit],
              "image_width": cam.width, "image_height": cam.height, **override}
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in values.items():
        if value is not None:
            storage.write(key, value)
    storage.release()


@pytest.mark.parametrize("suffix, unit, rotation, keys", [(".yml", "m", "matrix", ("camera_matrix", "distortion_coefficients")),
                                                          (".xml", "mm", "rvec", ("K", "dist"))])
def test_an_opencv_file_of_a_known_camera_reads_back_as_it(tmp_path, suffix, unit, rotation, keys):
    for name, cam in ring().items():
        write_opencv(tmp_path / f"{name}{suffix}", cam, unit=unit, rotation=rotation, keys=keys)
        views = read_opencv(tmp_path / f"{name}{suffix}", unit=unit)
        assert_same_cameras(views, {name: cam})  # named by the file


# ---- the command line --------------------------------------------------------------------------
def test_the_cli_writes_a_calibration_yaml_the_image_reader_accepts(tmp_path):
    (tmp_path / "lab.qca.txt").write_text(qca_text(ring()))
    args = ["calibration", "import", str(tmp_path / "lab.qca.txt"), "--format", "qca", "--fps", "30",
            "--out", str(tmp_path / "seq" / "calibration.yaml")]
    result = CliRunner().invoke(cli.main, args)
    assert result.exit_code == 0, result.output
    assert "3 view(s) cam0, cam1, cam2" in result.output
    calib = read_calibration_yaml(tmp_path / "seq")  # what an `images` dataset reads
    assert calib["fps"] == 30.0
    for name, cam in ring().items():
        np.testing.assert_allclose(calib["cameras"][name].project(POINTS)[0], cam.project(POINTS)[0], atol=1e-6)
    text = (tmp_path / "seq" / "calibration.yaml").read_text()
    assert yaml.safe_load(text)["views"]["cam0"]["width"] == 1280

    (tmp_path / "other.qca.txt").write_text(qca_text({"cam0": ring()["cam1"]}))
    refused = CliRunner().invoke(cli.main, [*args[:2], str(tmp_path / "other.qca.txt"), *args[3:]])
    assert refused.exit_code == 2 and "exists; pass --force" in refused.output
    assert (tmp_path / "seq" / "calibration.yaml").read_text() == text  # kept
    forced = CliRunner().invoke(cli.main, [*args[:2], str(tmp_path / "other.qca.txt"), *args[3:], "--force"])
    assert forced.exit_code == 0, forced.output
    assert list(read_calibration_yaml(tmp_path / "seq")["cameras"]) == ["cam0"]
    assert read_calibration_yaml(tmp_path / "seq")["cameras"]["cam0"].width == 1920


def test_the_cli_merges_opencv_files_and_needs_their_unit(tmp_path):
    files = []
    for name, cam in ring().items():
        write_opencv(tmp_path / f"{name}.yml", cam, unit="mm")
        files.append(str(tmp_path / f"{name}.yml"))
    out = tmp_path / "calibration.yaml"
    base = ["calibration", "import", *files, "--format", "opencv", "--fps", "60", "--out", str(out)]
    no_unit = CliRunner().invoke(cli.main, base)
    assert no_unit.exit_code == 2 and "does not say the unit" in no_unit.output and "--unit mm" in no_unit.output
    assert not out.exists()
    result = CliRunner().invoke(cli.main, [*base, "--unit", "mm"])
    assert result.exit_code == 0, result.output
    calib = read_calibration_yaml(tmp_path)
    assert calib["fps"] == 60.0 and list(calib["cameras"]) == ["cam0", "cam1", "cam2"]
    np.testing.assert_allclose(calib["cameras"]["cam2"].cam_to_world, ring()["cam2"].cam_to_world, atol=1e-9)
    unknown = CliRunner().invoke(cli.main, [*base[:-4], "--format", "vicon", "--fps", "60", "--out", str(out)])
    assert unknown.exit_code == 2 and "'vicon' is not one of 'qca', 'toml', 'opencv'" in unknown.output


# ---- bad files ---------------------------------------------------------------------------------------
def good_toml():
    return toml_text({name: calibrated_camera(name, **{**cam.as_dict(), "dist": [*cam.dist[:4], 0.0]})
                      for name, cam in ring().items()})


TOML_CASES = [
    ("missing key", lambda t: t.replace("matrix = ", "matrixx = ", 1), r"\[cam_1\] has no 'matrix'"),
    ("non-numeric", lambda t: t.replace("size = [ 1280.0,", 'size = [ "wide",', 1),
     r"\[cam_1\]: 'size' must be \[width, height\] in pixels, got \['wide', 720.0\] \(not numbers"),
    ("3x4 matrix", lambda t: t.replace("matrix = [[1000.0, 0.0, 640.5]", "matrix = [[1000.0, 0.0, 640.5, 0.0]", 1)
     .replace("[0.0, 1010.0, 360.2]", "[0.0, 1010.0, 360.2, 0.0]").replace("[0.0, 0.0, 1.0]]", "[0.0, 0.0, 1.0, 0.0]]", 1),
     r"\[cam_1\]: 'matrix' must be a 3x3 intrinsic matrix .*, got 3x4"),
    ("fisheye", lambda t: t.replace("fisheye = false", "fisheye = true", 1), r"\[cam_1\]: fisheye = True; fisheye "),
    ("empty", lambda t: "\n", r"Calib.toml is empty"),
    ("not toml", lambda t: t.replace("[metadata]", "[metadata"), r"not valid TOML"),
    ("skew", lambda t: t.replace("[[1000.0, 0.0, 640.5]", "[[1000.0, 2.5, 640.5]", 1), r"skew of 2.5"),
    ("same name", lambda t: t.replace('name = "cam1"', 'name = "cam0"'), r"two cameras are named 'cam0'"),
    ("bad name", lambda t: t.replace('name = "cam1"', 'name = "cam 1/left"'),
     r"camera name 'cam 1/left' is not a valid view name"),
]


@pytest.mark.parametrize("case, edit, message", TOML_CASES, ids=[c[0] for c in TOML_CASES])
def test_a_bad_toml_is_refused_naming_the_key_and_value(tmp_path, case, edit, message):
    path = tmp_path / "Calib.toml"
    text = good_toml()
    edited = edit(text)
    assert edited != text
    path.write_text(edited)
    with pytest.raises(InputError, match=message) as caught:
        read_toml(path)
    assert str(path) in str(caught.value)
    if case in ("non-numeric", "not toml"):
        assert caught.value.__cause__ is not None  # the parser's error is chained


QCA_CASES = [
    ("missing key", lambda t: t.replace('focalLengthU="', 'focalLengthX="', 1),
     r"camera 'cam0': <intrinsic> has no 'focalLengthU' attribute"),
    ("non-numeric", lambda t: t.replace('<transform x="', '<transform x="east', 1),
     r"camera 'cam0': <transform> x='east.*' is not a number"),
    ("viewrotation", lambda t: t.replace('viewrotation="0"', 'viewrotation="90"', 1),
     r"camera 'cam0': viewrotation is '90'; only unrotated images"),
    ("empty", lambda t: "", r"c.qca.txt is empty"),
    ("not xml", lambda t: t.replace("</calibration>", ""), r"not a readable .qca XML file"),
    ("no transform", lambda t: t.replace("<transform ", "<transformed ", 1), r"camera 'cam0': has no <transform>"),
    ("not a rotation", lambda t: re.sub('r11="[^"]*"', 'r11="2.5"', t, count=1), r"transform r11..r33 is not a rotation"),
]


@pytest.mark.parametrize("case, edit, message", QCA_CASES, ids=[c[0] for c in QCA_CASES])
def test_a_bad_qca_is_refused_naming_the_camera_key_and_value(tmp_path, case, edit, message):
    path = tmp_path / "c.qca.txt"
    text = qca_text(ring())
    edited = edit(text)
    assert edited != text or case == "empty"
    path.write_text(edited)
    with pytest.raises(InputError, match=message) as caught:
        read_qca(path)
    assert str(path) in str(caught.value)
    if case == "non-numeric":
        assert isinstance(caught.value.__cause__, ValueError)


OPENCV_CASES = [
    ("missing key", {"T": None}, r"has no 'T' or 'tvec'; an OpenCV camera file needs .*keys found: camera_matrix"),
    ("non-numeric", {"image_width": "wide"}, r"'image_width' must be a number or a matrix of numbers, got 'wide'"),
    ("3x4 matrix", {"camera_matrix": np.zeros((3, 4))}, r"'camera_matrix' must be a 3x3 intrinsic matrix .*got 3x4"),
    ("rational model", {"distortion_coefficients": np.array([[0.1, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0]])},
     r"must be 4 or 5 distortion coefficients .*got 8"),
    ("fractional size", {"image_height": 720.5}, r"height must be a whole number of pixels, got 720.5"),
]


@pytest.mark.parametrize("case, override, message", OPENCV_CASES, ids=[c[0] for c in OPENCV_CASES])
def test_a_bad_opencv_file_is_refused_naming_the_key_and_value(tmp_path, case, override, message):
    path = tmp_path / "cam0.yml"
    write_opencv(path, ring()["cam0"], **override)
    with pytest.raises(InputError, match=message) as caught:
        read_opencv(path, unit="m")
    assert str(path) in str(caught.value)


def test_empty_files_unknown_formats_and_unit_mistakes_are_refused(tmp_path):
    (tmp_path / "cam0.yml").write_text("")
    with pytest.raises(InputError, match=r"cam0.yml is empty"):
        read_opencv(tmp_path / "cam0.yml", unit="m")
    with pytest.raises(InputError, match=r"unknown calibration format 'vicon'; use one of qca, toml, opencv"):
        read_calibration(tmp_path / "cam0.yml", "vicon")
    with pytest.raises(InputError, match=r"missing.qca does not exist"):
        read_qca(tmp_path / "missing.qca")
    (tmp_path / "Calib.toml").write_text(good_toml())
    with pytest.raises(InputError, match=r"up axis 'x' is not one of z, y"):
        read_toml(tmp_path / "Calib.toml", up="x")
    with pytest.raises(InputError, match=r"unit 'cm' is not one of mm, m"):
        read_toml(tmp_path / "Calib.toml", unit="cm")
    # metres read as millimetres: the 3 m ring shrinks to 3 mm
    with pytest.raises(InputError, match=r"within 5.\d\d mm of each other \(read with unit 'mm'\); .* pass --unit m"):
        read_toml(tmp_path / "Calib.toml", unit="mm")
    # millimetres read as metres: a camera 3.6 km away
    (tmp_path / "mm.toml").write_text(toml_text(ring(), unit="mm"))
    with pytest.raises(InputError, match=r"camera 'cam\d' would be 3\d\d\d.\d m from the origin .* pass --unit mm"):
        read_toml(tmp_path / "mm.toml")
