"""`mocapflow export`: labelled 3D markers as C3D (ezc3d) or TRC files.

Both carry the labels (DeepMoCap's reflector names), the frame rate, the unit (millimetres, the
convention of both formats) and the up axis (Z, the world frame of mocapflow): C3D in POINT:UNITS
and POINT:X_SCREEN/Y_SCREEN, TRC in its Units column and an UpAxis column after the standard ones.
Missing samples are NaN with residual -1 in C3D and empty fields in TRC.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from mocapflow.pipeline.errors import InputError, StorageError

UNIT_SCALE = 1000.0  # metres -> millimetres


def _arrays(markers: xr.Dataset) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    xyz = markers["position"].transpose("frame", "reflector", "xyz").values.astype(np.float64) * UNIT_SCALE
    names = [str(n) for n in markers["reflector"].values]
    fps = float(markers.attrs["fps"])
    if "residual" in markers:
        residual = np.nanmean(markers["residual"].transpose("frame", "reflector", "view").values, axis=-1) * UNIT_SCALE
    else:
        residual = np.zeros(xyz.shape[:2])
    residual = np.where(np.isnan(xyz[..., 0]), -1.0, np.nan_to_num(residual, nan=0.0))
    return xyz, names, fps, residual


def write_c3d(markers: xr.Dataset, path: Path) -> None:
    import ezc3d

    xyz, names, fps, residual = _arrays(markers)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = names
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d.add_parameter("POINT", "X_SCREEN", "+X")
    c3d.add_parameter("POINT", "Y_SCREEN", "+Z")  # Z up
    points = np.ones((4, len(names), xyz.shape[0]))
    points[:3] = xyz.transpose(2, 1, 0)  # (xyz, marker, frame)
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residual.T[None]}
    _write(path, lambda p: c3d.write(str(p)))


def read_c3d(path: Path) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    """xyz (frame, marker, 3) mm, labels, rate, residuals (frame, marker) of a C3D file."""
    import ezc3d

    c3d = ezc3d.c3d(str(path))
    points = c3d["data"]["points"][:3].transpose(2, 1, 0)
    return (points, list(c3d["parameters"]["POINT"]["LABELS"]["value"]),
            float(c3d["parameters"]["POINT"]["RATE"]["value"][0]), c3d["data"]["meta_points"]["residuals"][0].T)


def write_trc(markers: xr.Dataset, path: Path) -> None:
    xyz, names, fps, _ = _arrays(markers)
    n_frames = xyz.shape[0]
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\tUpAxis",
             f"{fps:.2f}\t{fps:.2f}\t{n_frames}\t{len(names)}\tmm\t{fps:.2f}\t1\t{n_frames}\tZ",
             "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names).rstrip("\t"),
             "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, len(names) + 1))]
    frames = markers["frame"].values
    for i in range(n_frames):
        values = "\t".join("" if np.isnan(v) else f"{v:.3f}" for v in xyz[i].ravel())
        lines.append(f"{int(frames[i]) + 1}\t{frames[i] / fps:.5f}\t{values}")
    _write(path, lambda p: p.write_text("\n".join(lines) + "\n"))


def read_trc(path: Path) -> tuple[np.ndarray, list[str], float]:
    """xyz (frame, marker, 3) mm, labels and rate of a TRC file written by :func:`write_trc`."""
    rows = path.read_text().splitlines()
    header = dict(zip(rows[1].split("\t"), rows[2].split("\t")))
    names = [n for n in rows[3].split("\t")[2:] if n]
    data = [[float(v) if v else np.nan for v in row.split("\t")[2:]] for row in rows[5:] if row.strip()]
    return np.array(data).reshape(len(data), len(names), 3), names, float(header["DataRate"])


def _write(path: Path, write) -> None:
    if path.suffix.lower() not in (".c3d", ".trc"):
        raise InputError(f"export file {path} must end in .c3d or .trc")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".partial" + path.suffix)
        write(tmp)
        tmp.replace(path)
    except OSError as exc:
        raise StorageError(f"cannot write {path}: {exc.strerror}; choose another --out") from exc


WRITERS = {"c3d": write_c3d, "trc": write_trc}
