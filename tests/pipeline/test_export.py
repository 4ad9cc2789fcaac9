"""C3D and TRC export: written and read back, the same labels, rate, values and missing samples."""

import numpy as np
import pytest
import xarray as xr

from mocapflow.pipeline.errors import InputError
from mocapflow.pipeline.export import read_c3d, read_trc, write_c3d, write_trc


def _markers(n_frames=7):
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-1, 2, (n_frames, 3, 3)).astype(np.float32)
    xyz[2, 1] = np.nan
    residual = rng.uniform(0, 0.01, (n_frames, 3, 2)).astype(np.float32)
    return xr.Dataset({"position": (("frame", "reflector", "xyz"), xyz),
                       "residual": (("frame", "reflector", "view"), residual)},
                      coords={"frame": np.arange(n_frames), "reflector": ["R_HAND", "L_HAND", "B_HEAD"],
                              "xyz": ["x", "y", "z"], "view": ["a", "b"]},
                      attrs={"fps": 30.0, "length_unit": "m", "up_axis": "Z"})


def test_c3d_round_trip(tmp_path):
    markers = _markers()
    write_c3d(markers, tmp_path / "take.c3d")
    xyz, labels, rate, residual = read_c3d(tmp_path / "take.c3d")
    assert labels == ["R_HAND", "L_HAND", "B_HEAD"] and rate == 30.0
    np.testing.assert_allclose(xyz, markers["position"].values * 1000.0, atol=1e-3)  # mm, NaN where missing
    assert residual[2, 1] == -1 and (residual[np.isfinite(xyz[..., 0])] >= 0).all()
    # C3D keeps residuals as whole units (mm)
    np.testing.assert_allclose(residual[0, 0], markers["residual"].values[0, 0].mean() * 1000.0, atol=0.5)


def test_trc_round_trip(tmp_path):
    markers = _markers()
    write_trc(markers, tmp_path / "take.trc")
    xyz, labels, rate = read_trc(tmp_path / "take.trc")
    assert labels == ["R_HAND", "L_HAND", "B_HEAD"] and rate == 30.0
    np.testing.assert_allclose(xyz, markers["position"].values * 1000.0, atol=1e-3)
    assert "\tmm\t" in (tmp_path / "take.trc").read_text().splitlines()[2]


def test_unknown_extension_is_refused(tmp_path):
    with pytest.raises(InputError, match="must end in .c3d, .trc or .bvh"):
        write_trc(_markers(), tmp_path / "take.csv")
    assert not list(tmp_path.iterdir())


def test_an_export_file_name_may_not_leave_the_out_folder(tmp_path):
    from mocapflow.pipeline.errors import PlanError
    from mocapflow.pipeline.export import _inside

    assert _inside(tmp_path / "out", "take1.trc") == tmp_path / "out" / "take1.trc"
    for name in ("../../x.trc", "sub/x.trc", "/etc/x.trc"):
        with pytest.raises(PlanError, match="would be written outside --out"):
            _inside(tmp_path / "out", name)
