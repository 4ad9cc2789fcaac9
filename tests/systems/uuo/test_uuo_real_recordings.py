"""The recorded takes of the UUO benchmark on real data (benchmarks/recordings, uuo_real.yaml, uuo_real_tuning.yaml):
every shipped file reads as a labelled recording, small, with its source and licence in docs/data.md, and every take
of the two catalogs has a prior table (benchmarks/uuo_real_priors.py) that places all 20 joints from its labels."""

from __future__ import annotations

import functools
import importlib.util
import re
import sys

import numpy as np
import pytest

from mocapflow.systems.uuo.marker_files import read_markers
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.uuo.labelled import base_label
from shared_data import ROOT, skip_unless_beside_checkout

RECORDINGS = ROOT / "benchmarks" / "recordings"
FILES = sorted(RECORDINGS.rglob("*.c3d"))
SECTION = "## Recorded takes for the UUO benchmark"
LICENCES = r"Apache-2\.0|MIT|BSD-[23]-Clause|CC0|CC-BY|CMU"  # the shipped files' licences (CMU: free for all uses)


@functools.cache
def _module(name: str):
    """A script of benchmarks/ (not a package) as a module, loaded once."""
    spec = importlib.util.spec_from_file_location(f"benchmarks_{name}", ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _rows() -> dict[str, list[str]]:
    """docs/data.md's table of recorded takes: file name -> its cells."""
    text = (ROOT / "docs" / "data.md").read_text()
    assert SECTION in text, f"docs/data.md has no section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        found = re.search(r"`([^`]*\.c3d)`", cells[0]) if line.startswith("|") else None
        if found:
            rows[found.group(1).rsplit("/", 1)[-1]] = cells
    return rows


def test_the_recordings_are_a_few_small_files():
    assert len(FILES) >= 8
    assert all(f.stat().st_size < 1 << 20 for f in FILES)
    assert sum(f.stat().st_size for f in RECORDINGS.rglob("*") if f.is_file()) < 8 << 20
    assert all(re.fullmatch(r"[a-z0-9_]+\.c3d", f.name) for f in FILES)  # <source>_<motion>.c3d


@pytest.mark.parametrize("path", FILES, ids=[f.name for f in FILES])
def test_every_recording_reads_as_a_labelled_take_with_its_rate(path):
    ds = read_markers(path, labels="use")
    labels = [str(label) for label in ds["label"].values]
    assert ds.attrs["fps"] > 0 and 60 <= ds.sizes["frame"] <= 120
    assert len(labels) >= 30 and all(labels) and not any(label.startswith("unlabelled") for label in labels)
    assert len(set(labels)) == len(labels)  # one trajectory per label, as written
    assert ds.attrs["file_up_axis"] == "Z (found from the markers)"  # shipped Z up
    z = ds["position"].values[..., 2]
    assert np.isfinite(ds["position"].values).any(axis=-1).mean() > 0.95  # windows without long gaps
    assert np.nanpercentile(z, 1) > -0.1 and 1.2 < np.nanmax(z) < 2.6  # a person's markers in metres, Z up


@pytest.mark.parametrize("path", FILES, ids=[f.name for f in FILES])
def test_every_recording_has_a_row_in_docs_naming_its_source_and_licence(path):
    rows = _rows()
    assert path.name in rows, f"docs/data.md's table of recorded takes has no row for {path.name}"
    cells = " | ".join(rows[path.name])
    assert re.search(LICENCES, cells), f"{path.name}: no licence named in {cells!r}"
    assert re.search(r"https://github\.com/[\w.-]+/[\w.-]+", cells) and re.search(r"\b[0-9a-f]{40}\b", cells), cells


def test_the_cut_script_and_the_priors_script_name_every_shipped_file():
    cut, priors = _module("uuo_real_recordings"), _module("uuo_real_priors")
    assert sorted(cut.OUT / f"{take}.c3d" for take in cut.TAKES) == FILES
    shipped = {path for path, _ in priors.TAKES.values() if RECORDINGS in path.parents}
    assert shipped == set(FILES)


def _prior_takes():
    """Every take of the priors script; those read from ../shared marked needs_shared."""
    takes = _module("uuo_real_priors").TAKES
    return [pytest.param(take, id=take, marks=[] if RECORDINGS in path.parents else [pytest.mark.needs_shared])
            for take, (path, _) in sorted(takes.items())]


@pytest.mark.parametrize("take", _prior_takes())
def test_every_take_s_prior_table_places_the_20_joints_from_its_labels(take, tmp_path):
    priors = _module("uuo_real_priors")
    path, table = priors.TAKES[take]
    if RECORDINGS not in path.parents:
        skip_unless_beside_checkout(path.name)  # the script reads ../shared beside the checkout
    ds = read_markers(path, up="z", labels="use")
    labels = [base_label(label) for label in ds["label"].values]
    joints = priors.joints_from_labels(ds["position"].values.astype(np.float64), labels, table)
    assert joints.shape == (ds.sizes["frame"], len(JOINT_NAMES), 3)
    seen = np.isfinite(joints).all(axis=(1, 2))
    assert seen.mean() > 0.9
    j = {name: joints[seen, i] for i, name in enumerate(JOINT_NAMES)}
    length = {bone: float(np.median(np.linalg.norm(j[a] - j[b], axis=-1))) for bone, (a, b) in {
        "thigh": ("LeftHip", "LeftKnee"), "shank": ("RightKnee", "RightAnkle"), "upper arm": ("LeftShoulder", "LeftElbow"),
        "forearm": ("RightElbow", "RightWrist"), "trunk": ("Hips", "Neck"), "shoulders": ("LeftShoulder", "RightShoulder"),
        "hips": ("LeftHip", "RightHip")}.items()}
    assert 0.3 < length["thigh"] < 0.6 and 0.3 < length["shank"] < 0.6, length  # an adult's segments, metres
    assert 0.2 < length["upper arm"] < 0.45 and 0.18 < length["forearm"] < 0.4, length
    assert 0.3 < length["trunk"] < 0.6 and 0.25 < length["shoulders"] < 0.5 and 0.1 < length["hips"] < 0.3, length
    assert np.median(j["Head"][:, 2] - j["Hips"][:, 2]) > 0.2  # head over hips (a hockey stance leans forward)
    left = np.median(np.linalg.norm(j["LeftHip"] - j["LeftShoulder"], axis=-1))
    crossed = np.median(np.linalg.norm(j["LeftHip"] - j["RightShoulder"], axis=-1))
    assert left < crossed  # the sides not swapped: the left hip nearer the left shoulder
    written = np.load(priors.write_prior(take, path, table, out=tmp_path))
    np.testing.assert_array_equal(written["joints"], np.where(seen[:, None, None], joints, np.nan))
    assert float(written["fps"]) == ds.attrs["fps"]


def _catalog_takes(name: str) -> list[str]:
    """The takes a catalog names, found without their prior files (uuo_real_priors.py writes those under storage/,
    which a fresh checkout has not)."""
    from dataclasses import replace

    from mocapflow.pipeline.catalog import load_catalog
    from mocapflow.pipeline.datasets import discover

    catalog = load_catalog(ROOT / "benchmarks" / name)
    return sorted(s.id for dataset in catalog.datasets.values()
                  for s in discover(catalog, replace(dataset, options={k: v for k, v in dataset.options.items()
                                                                       if k != "prior"})))


def test_the_tuning_split_s_takes_have_prior_tables_and_are_not_the_benchmark_s():
    priors = _module("uuo_real_priors")
    takes = _catalog_takes("uuo_real_tuning.yaml")
    assert 2 <= len(takes) <= 4 and set(takes) <= set(priors.TAKES)
    assert all(priors.TAKES[take][0].parent == RECORDINGS / "tuning" for take in takes)


@pytest.mark.needs_shared
def test_the_benchmark_s_takes_have_prior_tables_ten_recordings_of_four_marker_sets_or_more():
    skip_unless_beside_checkout("benchmarks/uuo_real.yaml")
    priors = _module("uuo_real_priors")
    takes = _catalog_takes("uuo_real.yaml")
    assert len(takes) >= 10 and set(takes) <= set(priors.TAKES), sorted(set(takes) - set(priors.TAKES))
    assert len({id(priors.TAKES[take][1]) for take in takes}) >= 4  # marker sets
    assert not set(takes) & set(_catalog_takes("uuo_real_tuning.yaml"))
