"""Monocular prior files in (systems/uuo/prior_files.py): the format's keys, its refusals, and a take's prior file
through the engine into a `file_prior` body."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

from conftest import last_json, mocapflow, read_artifacts
from mocapflow.pipeline.errors import InputError
from mocapflow.systems.uuo.prior_files import read_prior
from mocapflow.tasks.shared.body import JOINT_NAMES

Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # Z-up world -> a Y-up file's axes


def _joints(frames=6, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(0, 0.3, (frames, len(JOINT_NAMES), 3)) + [0.0, 0.0, 1.0]


def test_an_npz_in_millimetres_y_up_with_its_own_joint_order_comes_back_in_metres_z_up(tmp_path):
    truth = _joints()
    truth[2] = np.nan  # a lost frame
    order = np.random.default_rng(1).permutation(len(JOINT_NAMES))
    names = np.array(JOINT_NAMES)[order].tolist() + ["Nose"]  # an estimator's extra joint is dropped
    file_joints = np.concatenate([truth[:, order], np.zeros((6, 1, 3))], axis=1) @ Y_UP.T * 1000.0
    np.savez(tmp_path / "take.npz", joints=file_joints, fps=30.0, joint_names=np.array(names), up="y", unit="mm")
    out = read_prior(tmp_path / "take.npz", frames=6, fps=30.0)
    np.testing.assert_allclose(out, truth, atol=1e-9)
    assert np.isnan(out[2]).all() and np.isfinite(np.delete(out, 2, axis=0)).all()


def test_a_json_prior_with_null_for_a_lost_frame(tmp_path):
    truth = _joints(frames=3)
    rows = truth.tolist()
    rows[1] = [[None, None, None]] * len(JOINT_NAMES)
    (tmp_path / "take.json").write_text(json.dumps({"joints": rows, "fps": 50}))
    out = read_prior(tmp_path / "take.json", frames=3, fps=50.0)
    np.testing.assert_allclose(out[[0, 2]], truth[[0, 2]])
    assert np.isnan(out[1]).all()


@pytest.mark.parametrize("content, match", [
    ({"fps": 30.0}, r"key 'joints' is missing; a prior file holds 'joints'"),
    ({"joints": _joints()}, r"key 'fps' is missing"),
    ({"joints": _joints()[:, :19], "fps": 30.0}, r"key 'joints' has shape \(6, 19, 3\); expected \(frame, 20, 3\)"),
    ({"joints": _joints(frames=5), "fps": 30.0}, r"key 'joints' has 5 frames but the marker recording has 6; .*resample"),
    ({"joints": _joints(), "fps": 25.0}, r"key 'fps' is 25.0, the marker recording's rate is 30.0; resample"),
    ({"joints": _joints(), "fps": 30.0, "joint_names": np.array(JOINT_NAMES[:-1] + ("Toe",))},
     r"key 'joint_names' lacks \['RightFoot'\]; .*rename"),
    ({"joints": _joints(), "fps": 30.0, "up": "x"}, r"key 'up' is 'x'; use one of \['auto', 'z', 'y'\]"),
    ({"joints": _joints(), "fps": 30.0, "betas": np.zeros(10)}, r"unknown key\(s\) \['betas'\]"),
    ({"joints": np.where(np.arange(20)[None, :, None] == 3, np.nan, _joints()), "fps": 30.0},
     r"frame 0 is partly NaN; a lost frame is NaN in every joint"),
])
def test_bad_prior_files_are_refused_naming_the_file_the_key_and_the_fix(tmp_path, content, match):
    np.savez(tmp_path / "take.npz", **content)
    with pytest.raises(InputError, match=match) as info:
        read_prior(tmp_path / "take.npz", frames=6, fps=30.0)
    assert str(tmp_path / "take.npz") in str(info.value)


def test_a_pickled_npz_is_refused_without_unpickling(tmp_path):
    class Boom:
        def __reduce__(self):
            return (exec, ("raise SystemExit('unpickled')",))

    np.savez(tmp_path / "take.npz", joints=np.array([Boom()], dtype=object), fps=30.0)
    with pytest.raises(InputError, match=r"take.npz: holds a pickled \(object\) array, which is not read"):
        read_prior(tmp_path / "take.npz", frames=6, fps=30.0)
    (tmp_path / "junk.npz").write_bytes(pickle.dumps({"joints": 1}))
    with pytest.raises(InputError, match=r"junk.npz: (not a readable .npz file|holds a pickled)"):
        read_prior(tmp_path / "junk.npz", frames=6, fps=30.0)


def _trc(path, positions, fps):
    """A Z-up TRC file in millimetres of positions (frame, marker, 3) m."""
    n, m, _ = positions.shape
    lines = ["PathFileType\t4\t(X/Y/Z)\ttake.trc",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{fps}\t{fps}\t{n}\t{m}\tmm\t{fps}\t1\t{n}",
             "Frame#\tTime\t" + "\t".join(f"M{i}\t\t" for i in range(m)).rstrip("\t"),
             "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, m + 1))]
    for f in range(n):
        lines.append(f"{f + 1}\t{f / fps:.5f}\t" + "\t".join("" if np.isnan(v) else f"{v * 1000:.3f}"
                                                            for v in positions[f].ravel()))
    path.write_text("\n".join(lines) + "\n")


def test_a_takes_prior_file_becomes_a_body_prior_through_the_engine(tmp_path):
    from mocapflow.tasks.uuo import takes as uuo
    from mocapflow.tasks.deepmocap.film.synth import build_rig
    from mocapflow.tasks.studio.spec import SequenceSpec

    rig = build_rig(SequenceSpec("side_reaches", frames=24, seed=34, body="mesh", views=1))
    layout = uuo.layout(rig.body, np.random.default_rng(1), 20)
    take = uuo.marker_dataset(rig.body, layout, uuo.capture(uuo.marker_paths(rig.body, layout,
                              rig.take.posed.vertices[:24]), uuo.MarkerFaults.clean(), np.random.default_rng(2)),
                              rig.take, 30.0, 0, 24)
    (tmp_path / "takes").mkdir()
    (tmp_path / "priors").mkdir()
    _trc(tmp_path / "takes" / "reach.trc", take.position.values.astype(np.float64), 30.0)
    truth = take.gt_joints.values.astype(np.float64)
    np.savez(tmp_path / "priors" / "reach.npz", joints=truth[4:20], fps=30.0)  # frames 4-19 only: refused
    (tmp_path / "catalog.yaml").write_text(
        "data_roots: [.]\nstorage: {root: storage/, region_frames: 8}\n"
        "datasets:\n  lab: {kind: markers, path: takes, pattern: '*.trc', prior: priors}\n"
        "stages:\n  markers: {task: ingest_markers, dataset: lab}\n"
        "  prior: {task: file_prior, inputs: [markers], params: {iterations: 100}}\n")
    proc = mocapflow("run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "reach.npz: key 'joints' has 16 frames but the marker recording has 24" in proc.stderr
    np.savez(tmp_path / "priors" / "reach.npz", joints=truth, fps=30.0)
    summary = last_json(mocapflow("run", "--json", cwd=tmp_path))
    assert sorted(summary["executed"]) == ["markers/reach", "prior/reach"]
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(tmp_path / "storage").items()}
    np.testing.assert_allclose(stored["markers/reach"]["prior_joints"], truth, atol=1e-6)
    error = np.linalg.norm(stored["prior/reach"]["joints"] - truth, axis=-1)
    assert error.mean() < 0.02 and stored["prior/reach"]["valid"].all(), error.mean()
    (tmp_path / "priors" / "reach.npz").unlink()
    proc = mocapflow("run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "no prior file for take 'reach'; write reach.npz or reach.json" in proc.stderr


def test_a_frame_window_crops_the_markers_and_their_prior_alike_and_takes_override_the_up_axis(tmp_path):
    from mocapflow.pipeline.catalog import load_catalog
    from mocapflow.pipeline.datasets import discover, read_frames
    from mocapflow.pipeline.errors import CatalogError

    (tmp_path / "takes").mkdir()
    (tmp_path / "priors").mkdir()
    positions = np.arange(10 * 2 * 3, dtype=float).reshape(10, 2, 3) / 100.0
    for take in ("a", "b"):
        _trc(tmp_path / "takes" / f"{take}.trc", positions, 50.0)
        np.savez(tmp_path / "priors" / f"{take}.npz", joints=_joints(frames=10), fps=50.0)
    (tmp_path / "catalog.yaml").write_text(
        "data_roots: [.]\ndatasets:\n  lab:\n    kind: markers\n    path: takes\n    pattern: '*.trc'\n"
        "    prior: priors\n    up: z\n    frames: [2, 7]\n    takes: {b: {up: y, frames: [4, 6]}}\n"
        "stages:\n  markers: {task: ingest_markers, dataset: lab}\n")
    catalog = load_catalog(tmp_path / "catalog.yaml")
    seqs = {s.id: s for s in discover(catalog, catalog.datasets["lab"])}
    assert seqs["a"].n_frames == 5 and seqs["b"].n_frames == 2
    a = read_frames(catalog.datasets["lab"], seqs["a"], 0, 5)
    b = read_frames(catalog.datasets["lab"], seqs["b"], 0, 2)
    np.testing.assert_allclose(a.position.values, positions[2:7], atol=1e-6)
    np.testing.assert_allclose(a.prior_joints.values, _joints(frames=10)[2:7], atol=1e-6)
    np.testing.assert_allclose(b.position.values, positions[4:6] @ np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]).T,
                               atol=1e-6)  # Y up -> Z up
    assert list(a.frame.values) == list(range(5))
    (tmp_path / "catalog.yaml").write_text((tmp_path / "catalog.yaml").read_text().replace("{b: {", "{c: {"))
    catalog = load_catalog(tmp_path / "catalog.yaml")
    with pytest.raises(CatalogError, match=r"takes: \['c'\] name no file"):
        discover(catalog, catalog.datasets["lab"])
