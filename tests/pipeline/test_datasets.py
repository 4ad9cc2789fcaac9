"""Dataset readers (zarr, 16-bit PNG folders), `mocapflow init`, and bad raw inputs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import xarray as xr
import yaml

from conftest import ROOT, last_json, mocapflow, read_artifacts, write_raw_zarr
from shared_data import catalog_param, reads_shared, skip_unless_beside_checkout
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.datasets import discover
from mocapflow.pipeline.registry import dataset_kinds
from mocapflow.pipeline.errors import CatalogError, InputError


def write_png_sequence(folder, views=("k0", "k1"), frames=6, size=(10, 14)):
    rng = np.random.default_rng(3)
    calib = {"fps": 30.0, "views": {}}
    data = {}
    for view in views:
        calib["views"][view] = {"fx": 365.0, "fy": 365.0, "cx": 7.0, "cy": 5.0, "dist": [0.01, 0, 0, 0, 0],
                                "cam_to_world": np.eye(4).tolist(), "width": size[1], "height": size[0]}
        for kind in ("depth", "ir"):
            (folder / view / kind).mkdir(parents=True)
            stack = rng.integers(0, 65535, (frames, *size)).astype(np.uint16)
            data[view, kind] = stack
            for f, img in enumerate(stack):
                cv2.imwrite(str(folder / view / kind / f"{f:06d}.png"), img)
    (folder / "calibration.yaml").write_text(yaml.safe_dump(calib))
    return data


def test_image_folder_is_imported_exactly(tmp_path):
    data = write_png_sequence(tmp_path / "recs" / "take1")
    mocapflow("init", tmp_path / "recs", cwd=tmp_path)
    summary = last_json(mocapflow("run", "--json", "--catalog", tmp_path / "recs" / "catalog.yaml", cwd=tmp_path))
    per_view = ("masks", "flow", "heatmaps", "reflectors2d", "reflectors2d_refined")  # the whole chain runs, even on noise
    assert sorted(summary["executed"]) == sorted([f"{s}/take1/{v}" for s in per_view for v in ("k0", "k1")]
                                                 + ["frames/take1", "markers3d/take1", "smoothed/take1", "skeleton/take1",
                                                    "template/take1", "checked/take1", "poses/take1"])
    [arrays] = [a for (pid, _), a in read_artifacts(tmp_path / "recs" / "storage").items() if pid == "frames/take1"]
    np.testing.assert_array_equal(arrays["depth"][1], data["k1", "depth"])
    np.testing.assert_array_equal(arrays["ir"][0], data["k0", "ir"])
    np.testing.assert_allclose(arrays["dist"][0], [0.01, 0, 0, 0, 0])


def test_init_detects_zarr_recordings_and_refuses_to_overwrite(tmp_path):
    write_raw_zarr(tmp_path / "recs" / "a.zarr")
    mocapflow("init", tmp_path / "recs", cwd=tmp_path)
    catalog = yaml.safe_load((tmp_path / "recs" / "catalog.yaml").read_text())
    assert catalog["datasets"]["recordings"]["kind"] == "zarr"
    proc = mocapflow("init", tmp_path / "recs", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "exists; pass --force" in proc.stderr
    proc = mocapflow("init", tmp_path / "nothing", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "is not a folder" in proc.stderr


def test_raw_input_violating_the_schema_is_a_clear_error_and_keeps_artifacts(toy_project):
    project = toy_project()
    mocapflow("run", "--json", cwd=project)
    before = read_artifacts(project / "storage")
    broken = xr.open_zarr(project / "data" / "seqA.zarr", consolidated=False).load()
    broken["depth"] = broken["depth"].astype(np.float32)
    broken.to_zarr(project / "data" / "seqC.zarr", zarr_format=3, consolidated=False, mode="w")
    proc = mocapflow("run", "--json", cwd=project, check=False)
    assert proc.returncode == 2
    assert "seqC.zarr does not match its schema" in proc.stderr and "'depth' has dtype float32, expected uint16" in proc.stderr
    after = read_artifacts(project / "storage")
    assert before.keys() == after.keys()


def test_missing_dataset_folder(toy_project):
    project = toy_project()
    (project / "catalog.yaml").write_text((project / "catalog.yaml").read_text().replace("path: data", "path: nowhere"))
    proc = mocapflow("run", cwd=project, check=False)
    assert proc.returncode == 2 and "nowhere is not a folder" in proc.stderr


DATASET_ONLY = "data_roots: [.]\ndatasets:\n  rec:\n    kind: {kind}\n{options}"


@pytest.mark.parametrize("kind,options,typo,right,line", [
    ("zarr", "    path: data\n    patern: '*.zarr'\n", "patern", "pattern", 6),
    ("zarr", "    pth: data\n", "pth", "path", 5),
    ("images", "    path: recs\n    pattrn: 'take*'\n", "pattrn", "pattern", 6),
    ("images", "    paths: recs\n", "paths", "path", 5),
    ("studio", "    defaults: {frames: 30}\n    sequnces: {a: {motion: jumping_jack}}\n", "sequnces", "sequences", 6),
    ("studio", "    default: {frames: 30}\n    sequences: {a: {motion: jumping_jack}}\n", "default", "defaults", 5),
    ("studio", "    layuot: layout.yaml\n    sequences: {a: {motion: jumping_jack}}\n", "layuot", "layout", 5),
])
def test_a_misspelt_dataset_option_is_refused_at_load_naming_key_line_and_the_right_one(tmp_path, kind, options, typo,
                                                                                        right, line):
    path = tmp_path / "catalog.yaml"
    path.write_text(DATASET_ONLY.format(kind=kind, options=options))
    with pytest.raises(CatalogError) as err:
        load_catalog(path)
    allowed = ["kind", *dataset_kinds()[kind].options]
    assert str(err.value) == (f"catalog.yaml (line {line}): datasets.rec.{typo}: unknown option {typo!r} for a {kind!r} "
                              f"dataset (did you mean {right!r}?); its options are {allowed}")
    path.write_text(DATASET_ONLY.format(kind=kind, options=options.replace(f"{typo}:", f"{right}:")))
    dataset = load_catalog(path).datasets["rec"]  # spelt right, the same catalog loads with its options
    assert dataset.kind == kind and right in dataset.options and typo not in dataset.options


def test_a_misspelt_dataset_option_stops_the_run_before_any_stage(toy_project):
    project = toy_project()
    catalog = project / "catalog.yaml"
    catalog.write_text(catalog.read_text().replace("path: data}", "path: data, patern: '*.zarr'}"))
    proc = mocapflow("run", "--json", cwd=project, check=False)
    assert proc.returncode == 2
    assert "datasets.rec.patern: unknown option 'patern' for a 'zarr' dataset (did you mean 'pattern'?)" in proc.stderr
    assert not (project / "storage").exists()


SHIPPED_CATALOGS = ("catalog.yaml", "benchmarks/catalog.yaml", "benchmarks/capsule.yaml", "benchmarks/athletic.yaml",
                    "benchmarks/real_rig.yaml", "benchmarks/real_appearance.yaml", "benchmarks/uuo_c3d_example.yaml",
                    "training/catalog.yaml", "training/catalog_athletic.yaml", "training/validation.yaml",
                    "training/validation_athletic.yaml",
                    "training/catalog_mesh.yaml", "training/validation_mesh.yaml",
                    "training/tracker.yaml", "demo")


# A catalog naming the CMU clips in ../shared (the held-out split) skips in a plain clone (needs_shared).
@pytest.mark.parametrize("name", [catalog_param(ROOT, name) for name in SHIPPED_CATALOGS])
def test_the_shipped_catalogs_still_load_and_discover_their_sequences(tmp_path, name):
    if name == "demo":
        from mocapflow.cli.demo import DemoOptions, prepare

        catalog = prepare(tmp_path, DemoOptions())
    else:
        if reads_shared(ROOT / name):
            skip_unless_beside_checkout(name)
        catalog = load_catalog(ROOT / name)
    assert catalog.datasets
    for dataset in catalog.datasets.values():
        assert set(dataset.options) <= set(dataset_kinds()[dataset.kind].options)
        found = discover(catalog, dataset)
        views = getattr(dataset_kinds()[dataset.kind], "has_views", True)  # a markers take: one partition, no views
        assert found and all(s.n_frames > 0 and (bool(s.views) or not views) for s in found)
    if name == "demo":
        assert sorted(s.id for s in found) == ["jumping_jack_s1"]  # the DeepMoCap demo: one take of the mesh body


# ---- raw input checked at the door: names, numbering, sizes, calibration, timing ------------------------------
IMAGES_CATALOG = "data_roots: [.]\ndatasets:\n  rec:\n    kind: images\n    path: recs\n"


def discover_images(tmp_path):
    (tmp_path / "catalog.yaml").write_text(IMAGES_CATALOG)
    catalog = load_catalog(tmp_path / "catalog.yaml")
    return discover(catalog, catalog.datasets["rec"])


def edit_calibration(seq_dir, change):
    calib = yaml.safe_load((seq_dir / "calibration.yaml").read_text())
    change(calib)
    (seq_dir / "calibration.yaml").write_text(yaml.safe_dump(calib))


def test_png_frames_are_read_in_numeric_order(tmp_path):
    seq_dir = tmp_path / "recs" / "take1"
    data = write_png_sequence(seq_dir, views=("k0",), frames=12)
    for kind in ("depth", "ir"):  # unpadded numbers: by name, 10.png and 11.png would come before 2.png
        for f in range(12):
            (seq_dir / "k0" / kind / f"{f:06d}.png").rename(seq_dir / "k0" / kind / f"{f}.png")
    [seq] = discover_images(tmp_path)
    frames = dataset_kinds()["images"].read(None, seq, 0, 12)
    np.testing.assert_array_equal(frames["depth"].values[0], data["k0", "depth"])
    np.testing.assert_array_equal(frames["ir"].sel(frame=[2, 10]).values[0], data["k0", "ir"][[2, 10]])


def test_a_gap_in_png_frame_numbers_is_refused_not_reordered(tmp_path):
    seq_dir = tmp_path / "recs" / "take1"
    write_png_sequence(seq_dir, frames=16)
    (seq_dir / "k0" / "depth" / "000004.png").rename(seq_dir / "k0" / "depth" / "000099.png")
    with pytest.raises(InputError) as err:
        discover_images(tmp_path)
    assert str(err.value) == (f"{seq_dir / 'k0' / 'depth'}: frame 000004.png is missing (frames jump from 3 to 5); "
                              "frames must be numbered consecutively: renumber them or fill the gap")


def _png(path, shape, dtype=np.uint16):
    cv2.imwrite(str(path), np.full(shape, 7, dtype))


@pytest.mark.parametrize("breaks,message", [
    (lambda d: _png(d / "k1" / "ir" / "000002.png", (12, 14)),
     "k1/ir/000002.png is 14x12 px but view 'k1' is calibrated for 14x10; fix the calibration's width/height or the image"),
    (lambda d: _png(d / "k0" / "depth" / "000001.png", (10, 14), np.uint8),
     "k0/depth/000001.png is a 8-bit grayscale PNG; frames must be 16-bit grayscale"),
    (lambda d: (d / "k0" / "ir" / "000005.png").unlink(),
     "k0: 6 depth frames 0-5 but 5 IR frames 0-4; every frame needs both a depth and an IR PNG of the same number"),
    (lambda d: (d / "k1" / "depth" / "frame_3.png").write_bytes(b""),
     "k1/depth/frame_3.png: a frame's name must be its number, e.g. 000000.png; rename it"),
    (lambda d: edit_calibration(d, lambda c: c["views"]["k0"].update(dist=[0.0, 0.0, 0.0, 0.0])),
     "view 'k0': dist must be five distortion coefficients [k1, k2, p1, p2, k3], got shape (4,)"),
    (lambda d: edit_calibration(d, lambda c: c["views"]["k1"].update(cam_to_world=np.eye(3).tolist())),
     "view 'k1': cam_to_world must be a 4x4 camera-to-world transform (4 rows of 4), got shape (3, 3)"),
    (lambda d: edit_calibration(d, lambda c: c["views"]["k0"].update(fx="abc")),
     "view 'k0': fx must be a number, got 'abc'"),
    (lambda d: edit_calibration(d, lambda c: c["views"]["k0"].update(cy=float("nan"))),
     "view 'k0' has a non-finite calibration: cy = nan"),
    (lambda d: edit_calibration(d, lambda c: c["views"]["k1"].update(width=15)),
     "k1/depth/000000.png is 14x10 px but view 'k1' is calibrated for 15x10"),
    (lambda d: edit_calibration(d, lambda c: c.update(fps=0)),
     "calibration.yaml: fps is 0; the frame rate must be a positive number of frames per second"),
    (lambda d: edit_calibration(d, lambda c: c.pop("fps")),
     "calibration.yaml: expected 'fps' (frames per second, > 0) and 'views:"),
    (lambda d: (d / "calibration.yaml").write_text((d / "calibration.yaml").read_text() + "  k0: {fx: 1}\n"),
     "key 'k0' appears twice"),
    (lambda d: edit_calibration(d, lambda c: c["views"].update({"../k2": c["views"]["k0"]})),
     "view name '../k2' is not a valid name: view names become partition names, so they must match "
     "[A-Za-z0-9_-][A-Za-z0-9_.-]*; rename the view"),
])
def test_bad_png_sequences_are_refused_at_discovery_naming_file_key_and_fix(tmp_path, breaks, message):
    seq_dir = tmp_path / "recs" / "take1"
    write_png_sequence(seq_dir)
    breaks(seq_dir)
    with pytest.raises((InputError, CatalogError)) as err:
        discover_images(tmp_path)
    assert message in str(err.value)


def _zarr_variant(tmp_path, change, **kwargs):
    """data/seqA.zarr, a tiny raw sequence changed by ``change`` (an xarray Dataset -> Dataset)."""
    write_raw_zarr(tmp_path / "orig.zarr", **kwargs)
    ds = change(xr.open_zarr(tmp_path / "orig.zarr", consolidated=False).load())
    (tmp_path / "data").mkdir(exist_ok=True)
    ds.to_zarr(tmp_path / "data" / "seqA.zarr", zarr_format=3, consolidated=False, mode="w")
    (tmp_path / "catalog.yaml").write_text("data_roots: [.]\ndatasets:\n  rec:\n    kind: zarr\n    path: data\n")
    catalog = load_catalog(tmp_path / "catalog.yaml")
    return lambda: discover(catalog, catalog.datasets["rec"])


def _set(ds, name, index, value):
    values = ds[name].values.copy()
    values[index] = value
    return ds.assign({name: (ds[name].dims, values)})


@pytest.mark.parametrize("change,kwargs,message", [
    (lambda ds: ds.assign_attrs(fps=0.0), {}, "seqA.zarr: attribute 'fps' is 0.0; the frame rate must be a positive"),
    (lambda ds: _set(ds, "fx", 1, np.nan), {}, "seqA.zarr: view 'cam1' has a non-finite calibration: fx = nan"),
    (lambda ds: _set(ds, "cam_to_world", (0, 0, 3), np.inf), {}, "view 'cam0' has a non-finite calibration: cam_to_world"),
    (lambda ds: _set(ds, "timestamp", 5, 4 / 30), {},
     "seqA.zarr: timestamps must increase strictly, but frame 5 is at 0.1333"),
    (lambda ds: _set(ds, "width", 0, 20), {},
     "seqA.zarr: view 'cam0' is calibrated for 20x12 px but its images are 16x12; fix 'width'/'height' or the images"),
    (lambda ds: ds, {"frames": 0}, "sequence 'seqA' ("),
    (lambda ds: ds.assign_coords(view=np.array(["cam0", "cam0"], object)), {},
     "view name(s) ['cam0'] appear more than once in ['cam0', 'cam0']; give every sensor its own name"),
    (lambda ds: ds.assign_coords(view=np.array(["cam0", "../up"], object)), {}, "view name '../up' is not a valid name"),
])
def test_bad_zarr_recordings_are_refused_at_discovery(tmp_path, change, kwargs, message):
    found = _zarr_variant(tmp_path, change, **kwargs)
    with pytest.raises((InputError, CatalogError)) as err:
        found()
    assert message in str(err.value)
    if kwargs:
        assert "has no frames (0); record or render at least one frame, or remove the sequence" in str(err.value)


def test_a_good_zarr_recording_passes_the_door(tmp_path):
    [seq] = _zarr_variant(tmp_path, lambda ds: ds)()
    assert (seq.id, seq.views, seq.n_frames) == ("seqA", ("cam0", "cam1"), 20)


@pytest.mark.parametrize("kind,store", [("zarr", "x.zarr"), ("images", "x")])
def test_a_dataset_pattern_may_not_leave_its_folder(tmp_path, kind, store):
    if kind == "zarr":
        write_raw_zarr(tmp_path / "outside" / store)
    else:
        write_png_sequence(tmp_path / "outside" / store)
    project = tmp_path / "a" / "b"
    (project / "data").mkdir(parents=True)
    pattern = "../../../outside/*" + (".zarr" if kind == "zarr" else "")
    (project / "catalog.yaml").write_text(f"data_roots: [.]\ndatasets:\n  rec:\n    kind: {kind}\n    path: data\n"
                                          f"    pattern: '{pattern}'\n")
    catalog = load_catalog(project / "catalog.yaml")
    with pytest.raises(CatalogError) as err:
        discover(catalog, catalog.datasets["rec"])
    assert str(err.value).startswith(f"catalog.yaml (line 3): datasets.rec.pattern: {pattern!r} leaves the dataset's "
                                     "folder; a pattern matches names inside 'path'")


def test_a_studio_sequence_id_that_is_not_a_plain_name_is_refused(tmp_path):
    (tmp_path / "catalog.yaml").write_text("datasets:\n  default:\n    kind: studio\n    defaults: {frames: 4}\n"
                                           "    sequences:\n      '../../x': {motion: jumping_jack}\n")
    catalog = load_catalog(tmp_path / "catalog.yaml")
    with pytest.raises(CatalogError) as err:
        discover(catalog, catalog.datasets["default"])
    assert str(err.value) == ("catalog.yaml (line 2): datasets.default: sequence id '../../x' is not a valid name: ids "
                              "become file names, so they must match [A-Za-z0-9_-][A-Za-z0-9_.-]* (letters, digits, "
                              "_ - ., not starting with '.'); rename it")


def test_a_png_gap_stops_the_run_before_any_stage(tmp_path):
    seq_dir = tmp_path / "recs" / "take1"
    write_png_sequence(seq_dir)
    (seq_dir / "k1" / "ir" / "000002.png").unlink()
    mocapflow("init", tmp_path / "recs", cwd=tmp_path)
    proc = mocapflow("run", "--catalog", tmp_path / "recs" / "catalog.yaml", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == (f"error: {seq_dir / 'k1' / 'ir'}: frame 000002.png is missing (frames jump from 1 "
                                   "to 3); frames must be numbered consecutively: renumber them or fill the gap")
    assert not (tmp_path / "recs" / "storage").exists()
