"""The DeepMoCap dataset's own files (`kind: dmc`): a studio take written in the DeepMoCap layout, mirrored and
with the Kinect's x-left, y-up camera axes, reads back as the take itself; bad recordings are refused at the door."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
import yaml

from conftest import mocapflow, read_artifacts
from mocapflow.systems.deepmocap import dmc_files
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.datasets import discover
from mocapflow.pipeline.registry import dataset_kinds
from mocapflow.pipeline.errors import CatalogError, InputError
from mocapflow.cli.scaffold import DEFAULT_STAGES
from mocapflow.tasks.deepmocap.masks import MaskConfig, masks
from mocapflow.tasks.shared.cameras import calibrated_camera
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec

FIRST = 5433  # the dataset's numbers do not start at 0
PREFIX = "03-18-11-27-03_3V_completed_{view}_"


@pytest.fixture(scope="module")
def take():
    """Three frames of a studio jumping jack from two sensors, with its ground truth."""
    return synthesize(build_rig(SequenceSpec(motion="jumping_jack", frames=3, views=2, seed=1)), 0, 3)


def write_dmc(folder, ds, *, flow=True, extrinsics_inside=False):
    """``ds`` as the DeepMoCap dataset stores it: images mirrored, 16-bit PGM depth, JET depth with the reflectors
    black, the extrinsics in the Kinect's camera axes (x left, y up) and millimetres. Returns the catalog's
    intrinsics (in the mirrored images' pixels)."""
    intrinsics = {}
    for view in ds["view"].values:
        v = ds.sel(view=view)
        width = int(v["width"])
        pose = v["cam_to_world"].values
        rot = pose[:3, :3] @ np.diag([-1.0, -1.0, 1.0])  # OpenCV axes -> x left, y up
        ext = folder / view / f"{view}.extrinsics" if extrinsics_inside else folder / f"{view}.extrinsics"
        (folder / view).mkdir(parents=True)
        ext.write_text("".join(" ".join(f"{x:.9f}" for x in row) + " \n" for row in rot)
                       + " ".join(f"{x:.6f}" for x in pose[:3, 3] * 1000.0) + " \n")
        dist = v["dist"].values.tolist()
        intrinsics[str(view)] = {"fx": float(v["fx"]), "fy": float(v["fy"]), "cx": width - 1 - float(v["cx"]),
                                 "cy": float(v["cy"]), "dist": dist[:3] + [-dist[3]] + dist[4:]}
        for f in range(ds.sizes["frame"]):
            stem = folder / view / f"{PREFIX.format(view=view)}{FIRST + f:05d}"
            depth = v["depth"].values[f]
            jet = cv2.applyColorMap(np.clip(depth / 4000.0 * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)
            jet[v["gt_reflector_id"].values[f] >= 0] = 0
            assert cv2.imwrite(f"{stem}depth.pgm", np.ascontiguousarray(depth[:, ::-1]))
            assert cv2.imwrite(f"{stem}mc_blob.png", np.ascontiguousarray(jet[:, ::-1]))
            if flow:
                assert cv2.imwrite(f"{stem}flow.png", np.full(jet.shape, 128, np.uint8))
    return intrinsics


def catalog_for(tmp_path, intrinsics, **options):
    body = {"data_roots": ["."], "storage": {"root": "storage/"},
            "datasets": {"dmc": {"kind": "dmc", "path": "recs", "intrinsics": intrinsics, **options}},
            "stages": {"frames": {"task": "ingest", "dataset": "dmc"},
                       "masks": {"task": "reflector_mask", "inputs": ["frames"]}}}
    (tmp_path / "catalog.yaml").write_text(yaml.safe_dump(body, sort_keys=False))
    return tmp_path / "catalog.yaml"


def discover_dmc(tmp_path):
    catalog = load_catalog(tmp_path / "catalog.yaml")
    return discover(catalog, catalog.datasets["dmc"]), catalog.datasets["dmc"]


def test_a_deepmocap_recording_reads_back_as_the_take_it_was_written_from_and_is_reported(tmp_path, take):
    """Written in the DeepMoCap layout, the take reads back as itself (depth, reflector mask, calibration), runs
    through the 2D and 3D stages with the shipped weights, and `mocapflow report` describes it without ground
    truth (the files have none)."""
    intrinsics = write_dmc(tmp_path / "recs" / "take1", take)
    stages = DEFAULT_STAGES[:DEFAULT_STAGES.index("  skeleton:")].replace("dataset: recordings", "dataset: dmc")
    (tmp_path / "catalog.yaml").write_text(
        yaml.safe_dump({"data_roots": ["."], "storage": {"root": "storage/"},
                        "datasets": {"dmc": {"kind": "dmc", "path": "recs", "intrinsics": intrinsics}}},
                       sort_keys=False) + stages)
    proc = mocapflow("report", "--catalog", "catalog.yaml", "--out", "rep", cwd=tmp_path, timeout=600)
    assert "wrote rep/report.html" in proc.stdout
    artifacts = {pid: a for (pid, _), a in read_artifacts(tmp_path / "storage").items()}
    arrays = artifacts["frames/take1"]
    np.testing.assert_array_equal(arrays["depth"], take["depth"].values)  # unmirrored, exactly
    reflectors = take["gt_reflector_id"].values >= 0
    assert reflectors.sum() > 1000
    np.testing.assert_array_equal(arrays["ir"] >= MaskConfig().ir_threshold, reflectors)
    studio_masks = masks(take, MaskConfig())["mask"].values  # the masks stage on the studio's own IR ...
    for v, view in enumerate(take["view"].values):  # ... and on the stand-in IR of the black pixels: the same
        np.testing.assert_array_equal(artifacts[f"masks/take1/{view}"]["mask"][0], studio_masks[v])
    for key in ("fx", "fy", "cx", "cy", "dist", "width", "height"):
        np.testing.assert_allclose(arrays[key], take[key].values, atol=1e-12, err_msg=key)
    np.testing.assert_allclose(arrays["cam_to_world"], take["cam_to_world"].values, atol=1e-8)
    np.testing.assert_allclose(arrays["timestamp"], np.arange(3) / 30.0)
    # every visible reflector's known 3D centre lands at its known pixel through the ingested calibration
    for v, view in enumerate(take["view"].values):
        cam = calibrated_camera(str(view), **{k: arrays[k][v] for k in ("fx", "fy", "cx", "cy", "dist",
                                                                         "cam_to_world", "width", "height")})
        seen = take["gt_visible"].values[v]
        uv, _ = cam.project(take["gt_reflectors"].values.reshape(-1, 3).astype(np.float64))
        np.testing.assert_allclose(uv.reshape(3, -1, 2)[seen], take["gt_reflectors2d"].values[v][seen], atol=2e-3)

    page = (tmp_path / "rep" / "report.html").read_text()
    assert "No ground truth in these recordings" in page and "from stage <code>smoothed</code>" in page
    labels = cv2.imread(str(tmp_path / "rep" / "labels_take1.png"))  # each view with its labels drawn, to judge
    assert '<img src="labels_take1.png">' in page and labels.shape[1] == 2 * arrays["ir"].shape[-1]
    coloured = (labels.max(-1).astype(int) - labels.min(-1)) > 60  # the label dots and names; the image is grey
    assert 200 < coloured.sum() < 0.05 * coloured.size
    rows = {cells[0]: cells[1:] for cells in (re.findall(r"<td>([^<]*)</td>", row)
                                              for row in re.findall(r"<tr>(<td>.*?)</tr>", page)) if len(cells) == 7}
    assert len(rows) == 26  # every reflector, with its views and residual
    tracked = [float(r[0]) for r in rows.values()]
    assert np.mean(tracked) > 60, rows  # the reflectors of a studio take are found in DeepMoCap's files
    assert any(r[5] not in ("0", "-") and float(r[5]) >= 2 for r in rows.values()), rows  # seen from both sensors
    # both sensors' estimates of an ankle agree within 2 cm: the mirroring and the axes undone alike in each view
    assert float(rows["L_ANKLE"][4]) < 20 and float(rows["R_ANKLE"][4]) < 20, rows


def test_extrinsics_in_the_view_folder_a_y_up_world_and_ir_frames(tmp_path, take):
    one = take.isel(frame=[0])
    intrinsics = write_dmc(tmp_path / "recs" / "take1", one, flow=False, extrinsics_inside=True)
    for view in one["view"].values:  # IR given: it is read as it is, not made up from the black pixels
        ir = one.sel(view=view)["ir"].values[0]
        assert cv2.imwrite(str(tmp_path / "recs" / "take1" / view / f"{PREFIX.format(view=view)}{FIRST}ir.pgm"),
                           np.ascontiguousarray(ir[:, ::-1]))
    for view in one["view"].values:  # the extrinsics rewritten in a Y-up world: (x, y, z) -> (x, z, -y)
        ext = tmp_path / "recs" / "take1" / view / f"{view}.extrinsics"
        values = np.array([r.split() for r in ext.read_text().splitlines()], float)
        values = np.vstack([Y_UP_TO_Z_UP.T @ values[:3], values[3] @ Y_UP_TO_Z_UP])  # Z-up world -> Y-up world
        ext.write_text("".join(" ".join(f"{x:.9f}" for x in r) + "\n" for r in values))
    catalog_for(tmp_path, intrinsics, up="y")
    [seq], dataset = discover_dmc(tmp_path)
    frames = dataset_kinds()["dmc"].read(dataset, seq, 0, 1)
    np.testing.assert_array_equal(frames["ir"].values, one["ir"].values)
    np.testing.assert_array_equal(frames["depth"].values, one["depth"].values)
    np.testing.assert_allclose(frames["cam_to_world"].values, one["cam_to_world"].values, atol=1e-8)


def _break(tmp_path, take, change):
    seq = tmp_path / "recs" / "take1"
    intrinsics = write_dmc(seq, take.isel(frame=[0, 1]), flow=True)
    options = change(seq, intrinsics) or {}
    catalog_for(tmp_path, options.pop("intrinsics", intrinsics), **options)
    return seq


def _rm(path):
    path.unlink()


def _pgm8(seq, _):
    [path] = (seq / "kinect1").glob("*05434depth.pgm")
    assert cv2.imwrite(str(path), np.zeros((424, 512), np.uint8))


def _opencv_axes(seq, _):
    rows = (seq / "kinect0.extrinsics").read_text().splitlines()
    rot = np.array([r.split() for r in rows[:3]], float) @ np.diag([-1.0, -1.0, 1.0])
    (seq / "kinect0.extrinsics").write_text("".join(" ".join(f"{x:.9f}" for x in r) + "\n" for r in rot) + rows[3])


BAD = [
    (lambda seq, _: __import__("shutil").rmtree(seq / "kinect1"),
     InputError, "kinect1.extrinsics: view 'kinect1' has no image folder"),
    (lambda seq, _: _rm(next((seq / "kinect0").glob("*05434mc_blob.png"))),
     InputError, "2 depth frames (5433-5434) but 1 *mc_blob.png frames (5433-5433; missing [5434], extra [])"),
    (lambda seq, _: _rm(next((seq / "kinect0").glob("*05434flow.png"))),  # all flow, or all but the first
     InputError, "2 depth frames (5433-5434) but 1 *flow.png frames (5433-5433; missing [5434]"),
    (lambda seq, _: [_rm(p) for p in (seq / "kinect1").glob("*05434*")] and None,
     InputError, "views have different numbers of frames {'kinect0': 2, 'kinect1': 1}"),
    (_pgm8, InputError, "05434depth.pgm is an 8-bit PGM (maxval 255); depth frames must be 16-bit PGMs"),
    (lambda seq, _: _rm(seq / "kinect0.extrinsics"), InputError, "view 'kinect0' has no extrinsics; expected"),
    (lambda seq, _: (seq / "kinect0.extrinsics").write_text("1 0 0\n0 1 0\n0 0 1\n") and None, InputError,
     "kinect0.extrinsics: expected 4 lines of 3 finite numbers"),
    (_opencv_axes, InputError, "the camera's y axis points down in the world (z component -0.999)"),
    (lambda seq, intr: {"intrinsics": {"kinect0": intr["kinect0"]}}, CatalogError,
     "intrinsics: no entry for view 'kinect1'"),
    (lambda seq, intr: {"intrinsics": {"fx": 365.0, "fy": 365.0, "cx": 255.5}}, CatalogError, "missing ['cy']"),
    (lambda seq, intr: {"mirrored": "yes"}, CatalogError, "mirrored: 'yes' is not one of [True, False]"),
]


@pytest.mark.parametrize("change, error, message", BAD, ids=[
    "missing-folder", "colour-count", "flow-count", "view-counts", "pgm-8-bit", "no-extrinsics", "short-extrinsics",
    "opencv-axes", "intrinsics-view", "intrinsics-key", "mirrored-value"])
def test_bad_deepmocap_recordings_are_refused_at_discovery(tmp_path, take, change, error, message):
    _break(tmp_path, take, change)
    with pytest.raises(error) as err:
        discover_dmc(tmp_path)
    assert message in str(err.value)


def test_a_path_pointing_at_one_take_is_refused_naming_its_parent(tmp_path, take):
    intrinsics = write_dmc(tmp_path / "recs", take.isel(frame=[0]))
    catalog_for(tmp_path, intrinsics)
    with pytest.raises(CatalogError) as err:
        discover_dmc(tmp_path)
    assert f"holds extrinsics files, so it is one take, not a folder of takes; point 'path' at the folder that holds " \
           f"it ({tmp_path})" in str(err.value)


def test_the_opencv_axes_option_and_a_black_background_at_the_door(tmp_path, take):
    _break(tmp_path, take, _opencv_axes)
    text = (tmp_path / "catalog.yaml").read_text()
    (tmp_path / "catalog.yaml").write_text(text.replace("kind: dmc", "kind: dmc\n    camera_axes: opencv"))
    [seq], _ = discover_dmc(tmp_path)
    np.testing.assert_allclose(seq.spec["views"]["kinect0"]["cam_to_world"], take["cam_to_world"].values[0], atol=1e-8)
    [path] = (tmp_path / "recs" / "take1" / "kinect1").glob("*05433mc_blob.png")
    assert cv2.imwrite(str(path), np.zeros((424, 512, 3), np.uint8))
    proc = mocapflow("run", "--dry-run", "--catalog", tmp_path / "catalog.yaml", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"{path}: 100% of the pixels are black" in proc.stderr and "give the IR frames" in proc.stderr


def test_mirroring_flips_the_principal_point_and_the_sign_of_p2():
    """A camera with tangential distortion seeing a point, and the same camera's mirror image (x -> -x, column
    u -> width - 1 - u): the mirrored image's intrinsics turned back are the camera's own."""
    width = 512
    K = np.array([[365.0, 0, 250.0], [0, 366.0, 210.0], [0, 0, 1]])
    dist = np.array([0.09, -0.27, 0.004, 0.006, 0.09])
    points = np.array([[0.3, -0.2, 2.0], [-0.5, 0.4, 2.5], [0.1, 0.6, 1.5]])
    uv = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, dist)[0][:, 0]
    files = {"fx": 365.0, "fy": 366.0, "cx": width - 1 - 250.0, "cy": 210.0, "dist": [0.09, -0.27, 0.004, -0.006, 0.09]}
    Km = np.array([[365.0, 0, files["cx"]], [0, 366.0, 210.0], [0, 0, 1]])
    uv_m = cv2.projectPoints(points * [-1, 1, 1], np.zeros(3), np.zeros(3), Km, np.array(files["dist"]))[0][:, 0]
    np.testing.assert_allclose(uv_m, np.stack([width - 1 - uv[:, 0], uv[:, 1]], 1), atol=1e-9)  # the mirror image
    back = dmc_files.mirrored_intrinsics(files, width)
    assert back["cx"] == 250.0 and back["dist"] == dist.tolist()
