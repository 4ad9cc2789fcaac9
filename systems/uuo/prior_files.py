"""Monocular prior files in: per-frame 3D joints a user brings from any monocular method, for UUO's ``file_prior``.

    joints = read_prior(path, frames=n, fps=rate)      # -> (frame, joint, xyz) metres, Z up, NaN for lost frames

One file per take, ``<take id>.npz`` or ``<take id>.json`` in the folder a ``markers`` dataset names as
``prior`` (see docs/uuo.md). Keys:

- ``joints``: (frame, joint, 3) numbers, one row per frame of the marker recording; a lost frame is NaN (JSON:
  ``null``) in every coordinate;
- ``fps``: the frame rate, equal to the marker recording's;
- ``joint_names`` (optional): the names of the joint axis, in the file's order; they must include every one of
  the template's 20 joints (tasks/shared/body.py JOINT_NAMES, SMPL-like: Hips, SpineBase, Neck, Head, Left/Right
  Shoulder, Elbow, Wrist, Hand, Hip, Knee, Ankle, Foot); others are dropped. Without it the joint axis is those
  20 in that order;
- ``up`` (optional): ``"z"`` (default) or ``"y"`` (a Y-up estimate, turned onto Z up like a Y-up marker file);
- ``unit`` (optional): ``"m"`` (default), ``"cm"`` or ``"mm"``.

An ``.npz`` is read with ``allow_pickle=False``: object arrays (pickles) are refused.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from mocapflow.pipeline.errors import InputError
from mocapflow.systems.uuo.marker_files import UNITS_M, UPS
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP

SUFFIXES = (".npz", ".json")
KEYS = ("joints", "fps", "joint_names", "up", "unit")
FORMAT_HELP = ("a prior file holds 'joints' (frame, joint, 3), 'fps', and optionally 'joint_names', 'up' (z|y) and "
               "'unit' (m|cm|mm); see docs/uuo.md")


def prior_path(folder: Path, take: str) -> Path:
    """The prior file of a take in ``folder``: ``<take>.npz`` or ``<take>.json`` (exactly one)."""
    found = [folder / f"{take}{suffix}" for suffix in SUFFIXES if (folder / f"{take}{suffix}").is_file()]
    if not found:
        raise InputError(f"{folder}: no prior file for take {take!r}; write {take}.npz or {take}.json there "
                         f"({FORMAT_HELP}), or use prior: simulated or none")
    if len(found) > 1:
        raise InputError(f"{folder}: take {take!r} has two prior files {[p.name for p in found]}; keep one")
    return found[0]


def read_prior(path: Path, *, frames: int, fps: float) -> np.ndarray:
    """A prior file's joints (frame, 20, 3) in metres, Z up, NaN on lost frames, checked against the marker
    recording's frame count and rate."""
    path = Path(path)
    raw = _npz(path) if path.suffix.lower() == ".npz" else _json(path)
    unknown = sorted(set(raw) - set(KEYS))
    if unknown:
        raise InputError(f"{path}: unknown key(s) {unknown}; {FORMAT_HELP}")
    for key in ("joints", "fps"):
        if key not in raw:
            raise InputError(f"{path}: key {key!r} is missing; {FORMAT_HELP}")
    joints = _numbers(path, "joints", raw["joints"])
    names = [str(n) for n in np.atleast_1d(raw.get("joint_names", JOINT_NAMES))]
    if joints.ndim != 3 or joints.shape[2] != 3 or joints.shape[1] != len(names):
        raise InputError(f"{path}: key 'joints' has shape {joints.shape}; expected (frame, {len(names)}, 3), one "
                         f"row of {len(names)} joints (joint_names) per frame")
    missing = [j for j in JOINT_NAMES if j not in names]
    if missing:
        raise InputError(f"{path}: key 'joint_names' lacks {missing}; a prior gives the template's joints "
                         f"{list(JOINT_NAMES)} (rename the estimator's joints to these)")
    joints = joints[:, [names.index(j) for j in JOINT_NAMES]]
    if joints.shape[0] != frames:
        raise InputError(f"{path}: key 'joints' has {joints.shape[0]} frames but the marker recording has {frames}; "
                         "a prior gives one row per marker frame (resample it to the markers, NaN where lost)")
    rate = _scalar(path, "fps", raw["fps"])
    if not (np.isfinite(rate) and rate > 0) or abs(rate - fps) > 1e-3 * fps:
        raise InputError(f"{path}: key 'fps' is {rate}, the marker recording's rate is {fps}; resample the prior to "
                         "the markers' rate")
    up = str(raw.get("up", "z")).strip().lower()
    if up not in UPS:
        raise InputError(f"{path}: key 'up' is {up!r}; use one of {list(UPS)}")
    unit = str(raw.get("unit", "m")).strip().lower()
    if unit not in UNITS_M:
        raise InputError(f"{path}: key 'unit' is {unit!r}; use one of {list(UNITS_M)}")
    partial = ~np.isfinite(joints).all(axis=(1, 2)) & np.isfinite(joints).any(axis=(1, 2))
    if partial.any():
        raise InputError(f"{path}: key 'joints', frame {int(np.flatnonzero(partial)[0])} is partly NaN; a lost frame "
                         "is NaN in every joint, an estimated one finite in every joint")
    if not np.isfinite(joints).any():
        raise InputError(f"{path}: key 'joints' is NaN on every frame; a prior needs at least one estimated frame")
    joints = joints * UNITS_M[unit]
    return joints @ Y_UP_TO_Z_UP.T if up == "y" else joints


def _npz(path: Path) -> dict:
    try:
        _check_npz_sizes(path)
        with np.load(path, allow_pickle=False) as npz:
            return {key: npz[key] for key in npz.files}
    except ValueError as exc:  # an object array (it would need unpickling), or a damaged array
        if "allow_pickle" not in str(exc):
            raise InputError(f"{path}: not a readable .npz file ({exc}); {FORMAT_HELP}") from exc
        raise InputError(f"{path}: holds a pickled (object) array, which is not read ({exc}); save plain numeric "
                         "and string arrays (np.savez with float joints and str joint_names)") from exc
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, KeyError, NotImplementedError, UnicodeDecodeError) \
            as exc:
        raise InputError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc}); the file is damaged: "
                         f"save it again ({FORMAT_HELP})") from exc


MAX_NPZ_BYTES = 1 << 30  # a prior of a million frames is 480 MB
MAX_DEFLATE_RATIO = 1100  # deflate packs at most ~1032:1


def _check_npz_sizes(path: Path) -> None:
    """Refuse, before anything is allocated, an .npz whose members claim more bytes than the archive can hold:
    each array's header (its shape and type) against its member's size, each member's size against what its
    compressed bytes can unpack to."""
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            if info.file_size > min(MAX_NPZ_BYTES, MAX_DEFLATE_RATIO * max(info.compress_size, 1)):
                raise InputError(f"{path}: member {info.filename!r} claims {info.file_size} bytes from "
                                 f"{info.compress_size} stored; the file is damaged or not a prior: save it again")
            with archive.open(info) as member:
                try:
                    version = np.lib.format.read_magic(member)
                    read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                        np.lib.format.read_array_header_2_0
                    shape, _, dtype = read_header(member)
                except ValueError:
                    continue  # not an array np.load reads; it says so itself
            claimed = dtype.itemsize
            for n in shape:
                claimed *= n
            if claimed > info.file_size:
                raise InputError(f"{path}: array {info.filename!r} claims shape {shape} of {dtype} ({claimed} bytes), "
                                 f"more than its {info.file_size} bytes hold; the file is damaged: save it again")


def _json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a readable JSON file ({exc}); {FORMAT_HELP}") from exc
    if not isinstance(data, dict):
        raise InputError(f"{path}: the JSON must be an object; {FORMAT_HELP}")
    return data


def _numbers(path: Path, key: str, value) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64)  # JSON null -> NaN
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: key {key!r} is not an array of numbers ({exc})") from exc
    return array


def _scalar(path: Path, key: str, value) -> float:
    array = _numbers(path, key, value)
    if array.size != 1:
        raise InputError(f"{path}: key {key!r} must be one number, got shape {array.shape}")
    return float(array.reshape(()))
