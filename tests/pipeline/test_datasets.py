"""Dataset readers (zarr, 16-bit PNG folders), `mocapflow init`, and bad raw inputs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import xarray as xr
import yaml

from conftest import ROOT, last_json, mocapflow, read_artifacts, write_raw_zarr
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.datasets import DATASET_KINDS, discover
from mocapflow.pipeline.errors import CatalogError


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
                                                    "poses/take1"])
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
    allowed = ["kind", *DATASET_KINDS[kind].options]
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


@pytest.mark.parametrize("name", ["catalog.yaml", "benchmarks/catalog.yaml", "training/catalog.yaml",
                                  "training/validation.yaml", "demo"])
def test_the_shipped_catalogs_still_load_and_discover_their_sequences(tmp_path, name):
    if name == "demo":
        from mocapflow.pipeline.demo import DemoOptions, prepare

        catalog = prepare(tmp_path, DemoOptions())
    else:
        catalog = load_catalog(ROOT / name)
    assert catalog.datasets
    for dataset in catalog.datasets.values():
        assert set(dataset.options) <= set(DATASET_KINDS[dataset.kind].options)
        found = discover(catalog, dataset)
        assert found and all(s.n_frames > 0 and s.views for s in found)
    if name == "demo":
        assert sorted(s.id for s in found) == ["classic_squat_s2", "elbow_flexion_s3", "jumping_jack_s1"]
