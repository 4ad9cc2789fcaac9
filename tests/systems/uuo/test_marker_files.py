"""Marker files in: real C3D recordings and TRC, onto the shared axes (metres, Z up)."""

from __future__ import annotations

import ezc3d
import numpy as np
import pytest

from conftest import SHARED, last_json, mocapflow, read_artifacts
from mocapflow.pipeline.errors import InputError
from mocapflow.systems.uuo.marker_files import read_markers, up_from_data
from mocapflow.schemas import get_schema

C3D = SHARED / "c3d"


@pytest.mark.parametrize("name, up, fps, unit", [
    ("ezc3d_qualisys_gait_forceplates.c3d", "z", 200.0, 0.001),
    ("ktk_kinematics_tennis_serve.c3d", "z", 50.0, 1.0),
    ("bts_c3d_sample_gait_with_gaps.c3d", "y", 100.0, 0.001),
])
@pytest.mark.needs_shared
def test_real_c3d_files_read_in_metres_with_z_up(name, up, fps, unit):
    ds = read_markers(C3D / name, up=up)
    get_schema("raw_markers").validate(ds)
    raw = ezc3d.c3d(str(C3D / name))["data"]["points"][:3].transpose(2, 1, 0) * unit  # (frame, marker, 3)
    assert ds.position.shape == raw.shape and ds.attrs["fps"] == fps
    z = ds.position.values[..., 2]
    assert np.nanpercentile(z, 1) > -0.1 and 0.5 < np.nanpercentile(z, 99) < 2.6  # a standing person, Z up
    expected = raw @ np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]).T if up == "y" else raw
    np.testing.assert_allclose(ds.position.values, expected, atol=1e-6, equal_nan=True)
    assert list(ds.marker.values[:2]) == ["m000", "m001"] and "label" not in ds  # labels dropped by default


@pytest.mark.parametrize("name, up", [
    ("ezc3d_qualisys_gait_forceplates.c3d", "z"), ("ktk_kinematics_tennis_serve.c3d", "z"),
    ("bts_c3d_sample_gait_with_gaps.c3d", "y"), ("qualisys_duplicate_labels_fragmented.c3d", "z"),
    ("c3dorg_sample01_Eb015pr_gait.c3d", "z")])
@pytest.mark.needs_shared
def test_the_up_axis_is_found_from_the_markers_when_not_given(name, up):
    found = read_markers(C3D / name)  # up: auto, the default
    assert found.attrs["file_up_axis"] == f"{up.upper()} (found from the markers)"
    np.testing.assert_array_equal(found.position.values, read_markers(C3D / name, up=up).position.values)
    turned = read_markers(C3D / name, up=up).position.values  # Z up; now written Y up: found again
    assert up_from_data(turned @ np.linalg.inv(np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])).T) == "y"
    assert up_from_data(turned) == "z"


@pytest.mark.needs_shared
def test_gaps_are_nan_and_fragmented_labels_stay_apart():
    ds = read_markers(C3D / "qualisys_duplicate_labels_fragmented.c3d", labels="use")
    assert np.isnan(ds.position.values).any()
    names = list(ds.label.values)
    repeated = [n for n in set(names) if names.count(n) > 1]
    assert repeated  # one marker split over several trajectories
    ids = list(ds.marker.values)
    assert len(set(ids)) == len(ids) and f"{repeated[0]}#2" in ids
    gaps = read_markers(C3D / "bts_c3d_sample_gait_with_gaps.c3d", up="y").position.values
    assert 0.3 < np.isnan(gaps[..., 0]).mean() < 0.7


def test_a_trc_file_is_read_with_its_units_rate_gaps_and_y_up(tmp_path):
    path = tmp_path / "take.trc"
    path.write_text("PathFileType\t4\t(X/Y/Z)\ttake.trc\n"
                    "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
                    "60\t60\t3\t2\tmm\t60\t1\t3\n"
                    "Frame#\tTime\tLASI\t\t\tRASI\t\t\n"
                    "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
                    "1\t0.0\t100\t950\t20\t-100\t951\t21\n"
                    "2\t0.0167\t101\t952\t22\t\t\t\n"
                    "3\t0.0333\t102\t954\t24\t-98\t955\t25\n")
    ds = read_markers(path, up="y", labels="use")
    assert list(ds.marker.values) == ["LASI", "RASI"] and ds.attrs["fps"] == 60.0
    np.testing.assert_allclose(ds.position.values[0, 0], [0.100, -0.020, 0.950], atol=1e-6)  # Y up -> Z up
    assert np.isnan(ds.position.values[1, 1]).all() and not np.isnan(ds.position.values[2, 1]).any()
    np.testing.assert_allclose(ds.timestamp.values, [0, 1 / 60, 2 / 60])


@pytest.mark.needs_shared
def test_bad_marker_files_and_settings_are_refused(tmp_path):
    (tmp_path / "x.c3d").write_bytes(b"not a c3d")
    with pytest.raises(InputError, match="not a readable C3D file"):
        read_markers(tmp_path / "x.c3d")
    with pytest.raises(InputError, match="up axis 'x' is not one of auto, z, y"):
        read_markers(C3D / "ktk_kinematics_tennis_serve.c3d", up="x")
    with pytest.raises(InputError, match="export C3D or TRC"):
        read_markers(tmp_path / "take.csv")
    (tmp_path / "short.trc").write_text("PathFileType\t4\n")
    with pytest.raises(InputError, match="needs its 5 header lines"):
        read_markers(tmp_path / "short.trc")


@pytest.mark.parametrize("up", ["y", "z"])
def test_an_exported_trc_reads_back_as_the_markers_it_came_from(tmp_path, up):
    import xarray as xr

    from mocapflow.systems.deepmocap.export import write_trc

    rng = np.random.default_rng(0)
    position = rng.uniform(-1, 2, (5, 3, 3)).astype(np.float32)
    position[2, 1] = np.nan
    markers = xr.Dataset({"position": (("frame", "reflector", "xyz"), position)},
                         coords={"reflector": ["A", "B", "C"], "xyz": ["x", "y", "z"]}, attrs={"fps": 30.0, "up_axis": "Z"})
    write_trc(markers, tmp_path / "m.trc", up=up)
    back = read_markers(tmp_path / "m.trc", up=up, labels="use")
    assert list(back.marker.values) == ["A", "B", "C"] and back.attrs["fps"] == 30.0
    np.testing.assert_allclose(back.position.values, position, atol=1e-5, equal_nan=True)


@pytest.mark.needs_shared
def test_a_markers_dataset_runs_through_the_engine(tmp_path):
    import shutil

    (tmp_path / "takes").mkdir()
    for name in ("ktk_kinematics_tennis_serve.c3d", "qualisys_duplicate_labels_fragmented.c3d"):
        shutil.copy(C3D / name, tmp_path / "takes" / name)
    (tmp_path / "catalog.yaml").write_text(
        "data_roots: [.]\nstorage: {root: storage/, region_frames: 64}\n"
        "datasets:\n  lab: {kind: markers, path: takes, labels: use}\n"
        "stages:\n  markers: {task: ingest_markers, dataset: lab}\n")
    summary = last_json(mocapflow("run", "--json", cwd=tmp_path))
    assert sorted(summary["executed"]) == ["markers/ktk_kinematics_tennis_serve",
                                           "markers/qualisys_duplicate_labels_fragmented"]
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(tmp_path / "storage").items()}
    direct = read_markers(C3D / "qualisys_duplicate_labels_fragmented.c3d", labels="use")
    np.testing.assert_array_equal(stored["markers/qualisys_duplicate_labels_fragmented"]["position"],
                                  direct.position.values)
    assert last_json(mocapflow("run", "--json", cwd=tmp_path))["executed"] == []
    (tmp_path / "catalog.yaml").write_text((tmp_path / "catalog.yaml").read_text().replace("labels: use", "up: x"))
    proc = mocapflow("run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "up axis 'x' is not one of auto, z, y" in proc.stderr
