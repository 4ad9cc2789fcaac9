"""A `markers` dataset reading several folders (systems/uuo/readers.py): `path` a list of folders, `pattern` one glob
for all or one per folder, take ids unique across the folders, and the refusals."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.formats.trc import trc_text
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.datasets import discover, read_frames
from mocapflow.pipeline.errors import CatalogError


def _take(path, offset: float, frames: int = 6) -> np.ndarray:
    """A TRC take of two markers whose coordinates start at ``offset`` mm; returns its positions in metres."""
    xyz = offset + np.arange(frames * 2 * 3, dtype=float).reshape(frames, 2, 3)
    xyz[..., 2] += 900.0  # a standing height, so the up axis is plain
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(trc_text(xyz, ["LASI", "RASI"], 50.0, np.arange(frames), "z", path.name))
    return xyz / 1000.0


def _catalog(root, dataset: str):
    (root / "catalog.yaml").write_text(f"data_roots: [.]\ndatasets:\n  lab: {dataset}\n"
                                       "stages:\n  markers: {task: ingest_markers, dataset: lab}\n")
    catalog = load_catalog(root / "catalog.yaml")
    return catalog, catalog.datasets["lab"]


def test_takes_come_from_every_folder_each_with_its_own_glob(tmp_path):
    gait = _take(tmp_path / "shared" / "gait.trc", 0.0)
    _take(tmp_path / "shared" / "static.trc", 100.0)  # not matched by the shared folder's glob
    run = _take(tmp_path / "mine" / "run.trc", 500.0, frames=4)
    serve = _take(tmp_path / "mine" / "serve.trc", 900.0)
    catalog, dataset = _catalog(tmp_path, "{kind: markers, path: [shared, mine], pattern: ['g*.trc', '*.trc'], "
                                          "labels: use, up: z, takes: {run: {frames: [1, 3]}}}")
    seqs = discover(catalog, dataset)
    assert [s.id for s in seqs] == ["gait", "run", "serve"]
    assert [s.n_frames for s in seqs] == [6, 2, 6]
    assert seqs[0].spec["path"] == str(tmp_path / "shared" / "gait.trc")
    assert seqs[1].spec["path"] == str(tmp_path / "mine" / "run.trc")
    by_id = {s.id: s for s in seqs}
    np.testing.assert_allclose(read_frames(dataset, by_id["gait"], 0, 6).position.values, gait, atol=1e-6)
    np.testing.assert_allclose(read_frames(dataset, by_id["run"], 0, 2).position.values, run[1:3], atol=1e-6)
    np.testing.assert_allclose(read_frames(dataset, by_id["serve"], 2, 4).position.values, serve[2:4], atol=1e-6)
    assert list(read_frames(dataset, by_id["gait"], 0, 6).label.values) == ["LASI", "RASI"]

    catalog, dataset = _catalog(tmp_path, "{kind: markers, path: [shared, mine], pattern: '*.trc'}")
    assert [s.id for s in discover(catalog, dataset)] == ["gait", "run", "serve", "static"]  # one glob for both
    catalog, dataset = _catalog(tmp_path, "{kind: markers, path: [mine], pattern: 'r*.trc'}")
    assert [s.id for s in discover(catalog, dataset)] == ["run"]


def test_a_take_found_in_two_folders_is_refused_naming_both_files(tmp_path):
    _take(tmp_path / "a" / "gait.trc", 0.0)
    _take(tmp_path / "b" / "gait.trc", 10.0)
    _take(tmp_path / "b" / "run.trc", 20.0)
    catalog, dataset = _catalog(tmp_path, "{kind: markers, path: [a, b], pattern: '*.trc'}")
    with pytest.raises(CatalogError, match=r"take 'gait' is both .*a/gait\.trc and .*b/gait\.trc; .*rename one"):
        discover(catalog, dataset)
    catalog, dataset = _catalog(tmp_path, "{kind: markers, path: [a, b], pattern: ['*.trc', 'r*.trc']}")
    assert [s.id for s in discover(catalog, dataset)] == ["gait", "run"]  # a narrower glob settles it


@pytest.mark.parametrize("dataset, match", [
    ("{kind: markers, path: [a, b], pattern: ['*.trc']}", r"1 globs for the 2 folders of 'path'"),
    ("{kind: markers, path: a, pattern: ['*.trc', '*.c3d']}", r"a list of globs needs 'path' to be a list"),
    ("{kind: markers, path: []}", r"path: expected a folder or a non-empty list of folders"),
    ("{kind: markers, path: [a, 3]}", r"path: expected a folder or a non-empty list of folders"),
    ("{kind: markers, path: [a, a]}", r"a folder is named twice"),
    ("{kind: markers, path: [a, ../outside]}", r"path\[1\]: path '../outside' resolves to .*outside the declared "
                                                r"data_roots"),
    ("{kind: markers, path: [a, b], pattern: ['*.trc', '../*.trc']}", r"path\[1\]\.pattern: '../\*\.trc' leaves the "
                                                                      r"dataset's folder"),
])
def test_bad_folder_lists_are_refused_at_discovery(tmp_path, dataset, match):
    _take(tmp_path / "a" / "gait.trc", 0.0)
    _take(tmp_path / "b" / "run.trc", 0.0)
    (tmp_path / "outside").mkdir()
    catalog, lab = _catalog(tmp_path, dataset)
    with pytest.raises(CatalogError, match=match):
        discover(catalog, lab)


def test_a_missing_folder_in_the_list_is_named(tmp_path):
    from mocapflow.pipeline.errors import InputError

    _take(tmp_path / "a" / "gait.trc", 0.0)
    catalog, dataset = _catalog(tmp_path, "{kind: markers, path: [a, b], pattern: '*.trc'}")
    with pytest.raises(InputError, match=r"path\[1\]: .*/b is not a folder"):
        discover(catalog, dataset)
