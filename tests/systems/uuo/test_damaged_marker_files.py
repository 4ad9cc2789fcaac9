"""Damaged or absurd marker files are refused at load, naming the file, frame and marker: a C3D or TRC file cut
short, damaged bytes, a take with no sample, non-finite numbers and coordinates no capture volume holds."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from conftest import last_json, mocapflow
from mocapflow.formats.c3d import write_points
from mocapflow.pipeline.errors import InputError
from mocapflow.systems.uuo.marker_files import read_markers
from shared_data import C3D

NAMES = [f"M{i}" for i in range(5)]


def c3d_file(path: Path, frames: int = 1092, *, xyz: np.ndarray | None = None, missing: bool = False) -> Path:
    """A float C3D file of 5 markers within 1 m of the origin (mm), or ``xyz``; every sample missing with
    ``missing``."""
    if xyz is None:
        xyz = np.random.default_rng(0).uniform(-1000, 1000, (frames, len(NAMES), 3))
    word4 = np.full(xyz.shape[:2], -1.0 if missing else 0.0)
    write_points(path, xyz, NAMES, 100.0, -1.0, word4)
    return path


def test_a_c3d_file_cut_in_half_is_refused_with_its_frame_counts(tmp_path):
    data = c3d_file(tmp_path / "whole.c3d").read_bytes()
    assert read_markers(tmp_path / "whole.c3d").sizes["frame"] == 1092
    (tmp_path / "half.c3d").write_bytes(data[:len(data) // 2])
    with pytest.raises(InputError) as err:
        read_markers(tmp_path / "half.c3d")
    n_read = int(re.search(r"holds (\d+) of the 1092 frames its header announces", str(err.value)).group(1))
    assert 500 < n_read < 560 and str(err.value).startswith(f"{tmp_path / 'half.c3d'}: ")


@pytest.mark.needs_shared
def test_a_real_c3d_recording_cut_short_is_refused(tmp_path):
    data = (C3D / "ktk_kinematics_tennis_serve.c3d").read_bytes()
    full = read_markers(C3D / "ktk_kinematics_tennis_serve.c3d").sizes["frame"]
    (tmp_path / "cut.c3d").write_bytes(data[:len(data) * 3 // 4])
    with pytest.raises(InputError, match=rf"holds \d+ of the {full} frames its header announces"):
        read_markers(tmp_path / "cut.c3d")


def test_a_c3d_file_with_a_byte_changed_every_997_bytes_is_refused_naming_frame_and_marker(tmp_path):
    data = bytearray(c3d_file(tmp_path / "take.c3d").read_bytes())
    start = (int(np.frombuffer(bytes(data[16:18]), "<u2")[0]) - 1) * 512  # the first data block
    for i in range(start + 3, len(data), 997):  # the offsets cycle through the floats' bytes, exponents included
        data[i] = 0x7F  # a float whose high byte this becomes is about 1e38, or not a number
    (tmp_path / "damaged.c3d").write_bytes(bytes(data))
    with pytest.raises(InputError) as err:
        read_markers(tmp_path / "damaged.c3d")
    message = str(err.value)
    assert re.match(rf"{re.escape(str(tmp_path / 'damaged.c3d'))}: frame \d+ marker M\d: ", message), message
    assert "lies beyond 20 m of the origin" in message or "are not finite numbers" in message


def test_absurd_and_non_finite_c3d_coordinates_are_refused(tmp_path):
    xyz = np.random.default_rng(1).uniform(-1000, 1000, (40, len(NAMES), 3))
    xyz[7, 2, 1] = 1e30  # mm: 1e27 m
    with pytest.raises(InputError, match=r"frame 7 marker M2: y = 1e\+27 m lies beyond 20 m of the origin, outside "
                                         r"any capture volume \(1 sample\(s\) so\).*max_coordinate_m"):
        read_markers(c3d_file(tmp_path / "far.c3d", xyz=xyz))
    xyz[7, 2, 1] = np.nan  # NaN though its residual says present
    with pytest.raises(InputError, match=r"frame 7 marker M2: coordinates .* are not finite numbers though the "
                                         r"sample is marked present"):
        read_markers(c3d_file(tmp_path / "nan.c3d", xyz=xyz))
    xyz[7, 2, 1] = 25_000.0  # 25 m: beyond the default bound, inside a wider one
    with pytest.raises(InputError, match="frame 7 marker M2: y = 25 m lies beyond 20 m"):
        read_markers(c3d_file(tmp_path / "wide.c3d", xyz=xyz))
    wide = read_markers(tmp_path / "wide.c3d", up="z", max_coordinate_m=30)  # as written: no axis found from the data
    assert wide.position.values[7, 2, 1] == 25.0


def test_a_c3d_file_with_no_sample_is_refused(tmp_path):
    with pytest.raises(InputError, match=r"none of its 5 marker\(s\) has a sample in any of its 30 frame\(s\)"):
        read_markers(c3d_file(tmp_path / "empty.c3d", 30, missing=True))


TRC = ("PathFileType\t4\t(X/Y/Z)\ttake.trc\n"
       "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
       "60\t60\t{frames}\t2\tmm\t60\t1\t{frames}\n"
       "Frame#\tTime\tLASI\t\t\tRASI\t\t\n"
       "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
       "1\t0.0\t100\t950\t20\t-100\t951\t21\n"
       "2\t0.0167\t101\t952\t22\t{value}\t953\t23\n")


@pytest.mark.parametrize("value, frames, message", [
    ("1e308", 2, r"frame 1 marker RASI: x = 1e\+305 m lies beyond 20 m of the origin"),
    ("inf", 2, r"line 7 \(frame 1\) marker RASI: 'inf' is not a finite number; leave the cell empty"),
    ("nan", 2, r"line 7 \(frame 1\) marker RASI: 'nan' is not a finite number"),
    ("-99", 5, r"holds 2 of the 5 frames its header's NumFrames announces"),
])
def test_damaged_or_absurd_trc_files_are_refused(tmp_path, value, frames, message):
    path = tmp_path / "take.trc"
    path.write_text(TRC.format(frames=frames, value=value))
    with pytest.raises(InputError, match=message):
        read_markers(path, labels="use")
    with pytest.raises(InputError) as err:
        read_markers(path, labels="use")
    assert str(err.value).startswith(f"{path}: ")


def test_the_catalog_sets_how_far_a_marker_may_lie(tmp_path):
    (tmp_path / "takes").mkdir()
    xyz = np.random.default_rng(2).uniform(-1000, 1000, (20, len(NAMES), 3))
    xyz[3, 4, 0] = -25_000.0
    c3d_file(tmp_path / "takes" / "wide.c3d", xyz=xyz)
    catalog = ("data_roots: [.]\nstorage: {{root: storage/, region_frames: 64}}\n"
               "datasets:\n  lab: {{kind: markers, path: takes{extra}}}\n"
               "stages:\n  markers: {{task: ingest_markers, dataset: lab}}\n")
    (tmp_path / "catalog.yaml").write_text(catalog.format(extra=""))
    refused = mocapflow("run", cwd=tmp_path, check=False)
    assert refused.returncode == 2
    assert "frame 3 marker M4: x = -25 m lies beyond 20 m of the origin" in refused.stderr, refused.stderr
    assert str(tmp_path / "takes" / "wide.c3d") in refused.stderr and "Traceback" not in refused.stderr
    (tmp_path / "catalog.yaml").write_text(catalog.format(extra=", max_coordinate_m: 30"))
    assert last_json(mocapflow("run", "--json", cwd=tmp_path))["executed"] == ["markers/wide"]
    (tmp_path / "catalog.yaml").write_text(catalog.format(extra=", max_coordinate_m: -1"))
    bad = mocapflow("run", cwd=tmp_path, check=False)
    assert bad.returncode == 2 and "lab.max_coordinate_m: expected a positive number of metres" in bad.stderr
    assert "got -1" in bad.stderr
