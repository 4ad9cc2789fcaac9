"""Camera calibrations from other systems, as the project's per-view calibration (``calibration.yaml``'s ``views``).

Formats:
  qca     Qualisys ``.qca`` / ``.qca.txt`` (XML): every active camera, named by its ``serial``
  toml    anipose / Pose2Sim ``Calib.toml``: one table per camera (``name size matrix distortions rotation
          translation``, optional ``fisheye``); the ``metadata`` table is skipped
  opencv  an OpenCV FileStorage file (``.yml``, ``.yaml``, ``.xml``) of one camera, named by the file's stem

Every reader returns ``{view: {fx, fy, cx, cy, dist: [k1, k2, p1, p2, k3], cam_to_world: 4x4, width, height}}``,
plain numbers ready for ``yaml.safe_dump``: intrinsics in pixels, the pose camera-to-world in metres with Z up
(the OpenCV camera: x right, y down, z forward). Each view is checked as a camera (``calibrated_camera``).

Units and axes are explicit: ``unit`` is the length unit of the file's positions and translations (``mm`` or
``m``; a .qca is in millimetres, a Pose2Sim toml in metres, an OpenCV file says nothing, so ``unit`` is required
for it) and ``up`` the file's up axis (``z``, or ``y`` to turn a Y-up world onto Z up). A camera more than
``MAX_DISTANCE_M`` from the origin, or cameras all within ``MIN_SPREAD_M`` of each other, are refused as a unit
mistake. Failures raise :class:`InputError` naming the file, the camera, the key, the bad value and the fix.
"""

from __future__ import annotations

import re
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import yaml

from mocapflow.pipeline.errors import InputError
from mocapflow.tasks.shared.cameras import (CalibrationError, Camera, calibrated_camera, pose_from_extrinsics,
                                            pose_from_qualisys, reframed)
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP

UNITS_M = {"mm": 0.001, "m": 1.0}
UPS = ("z", "y")
MAX_DISTANCE_M = 100.0  # farther from the origin than any capture volume: the file's unit was likely mm, not m
MIN_SPREAD_M = 0.01  # cameras (two or more, not all at one point) closer than this: likely metres read as mm
QCA_SUBPIXELS = 64  # .qca intrinsics are in 1/64 pixel
_NAME = re.compile("[A-Za-z0-9_-][A-Za-z0-9_.-]*")  # datasets.NAME_RULE: view names become parts of paths
Views = dict[str, dict[str, Any]]


def read_calibration(path: Path, fmt: str, *, unit: str | None = None, up: str = "z") -> Views:
    """The per-view calibration in ``path``, a file of format ``fmt`` (``FORMATS``); ``unit`` None: the format's
    own (qca: mm, toml: m; opencv has none and needs one)."""
    path = Path(path)
    if fmt not in FORMATS:
        raise InputError(f"{path}: unknown calibration format {fmt!r}; use one of {', '.join(FORMATS)}")
    return FORMATS[fmt](path, unit=unit, up=up)


def read_qca(path: Path, *, unit: str | None = None, up: str = "z") -> Views:
    """A Qualisys .qca calibration (XML): per camera ``transform`` (position x y z, rotation r11 .. r33, see
    ``cameras.pose_from_qualisys``), ``intrinsic`` (focal lengths and centre in 1/64 pixel of the sensor, distortion
    radialDistortion1-3, tangentalDistortion1-2) and ``fov_video`` (the video image's window on the sensor, in
    pixels, inclusive: its size, and the offset of its centre). A camera with ``active="0"`` is skipped; a
    ``viewrotation`` other than 0 is refused.

    The distortion coefficients are taken as they are: they multiply powers of the normalized image radius, which
    has no unit, so the 1/64 pixel scale of the focal lengths does not apply to them (Pose2Sim's converter divides
    them by 64 as well; that is not done here)."""
    scale, rotation = _frame(path, unit or "mm", up)
    text = _text(path)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(f"{path}: not a readable .qca XML file ({exc}); export the calibration from QTM "
                         "(a .qca or .qca.txt file)") from exc
    cameras = root.findall("cameras/camera")
    if root.tag != "calibration" or not cameras:
        raise InputError(f"{path}: no <calibration><cameras><camera> elements; not a Qualisys .qca calibration")
    views: Views = {}
    for index, element in enumerate(cameras):
        name = element.get("serial") or f"camera {index + 1}"
        where = f"{path}: camera {name!r}"
        if element.get("serial") is None:
            raise InputError(f"{where}: has no 'serial' attribute (its view name); add one")
        if element.get("active", "1").strip() == "0":
            continue
        turned = _qca_number(element, "viewrotation", where, default=0.0)
        if turned != 0:
            raise InputError(f"{where}: viewrotation is {element.get('viewrotation')!r}; only unrotated images "
                             "(viewrotation 0) are imported: the calibration describes the sensor's image, so set "
                             "the camera's image rotation to 0 in QTM and export the calibration again")
        transform, intrinsic, fov = (_qca_child(element, tag, where) for tag in ("transform", "intrinsic", "fov_video"))
        rot = np.array([[_qca_number(transform, f"r{i}{j}", where) for j in (1, 2, 3)] for i in (1, 2, 3)])
        _check_rotation(rot, where, "transform r11..r33")
        position = np.array([_qca_number(transform, axis, where) for axis in "xyz"]) * scale
        left, top, right, bottom = (_qca_number(fov, side, where) for side in ("left", "top", "right", "bottom"))
        values = dict(fx=_qca_number(intrinsic, "focalLengthU", where) / QCA_SUBPIXELS,
                      fy=_qca_number(intrinsic, "focalLengthV", where) / QCA_SUBPIXELS,
                      cx=_qca_number(intrinsic, "centerPointU", where) / QCA_SUBPIXELS - left,
                      cy=_qca_number(intrinsic, "centerPointV", where) / QCA_SUBPIXELS - top,
                      dist=[_qca_number(intrinsic, key, where) for key in
                            ("radialDistortion1", "radialDistortion2", "tangentalDistortion1", "tangentalDistortion2")]
                      + [_qca_number(intrinsic, "radialDistortion3", where, default=0.0)],
                      cam_to_world=reframed(pose_from_qualisys(rot, position), rotation),
                      width=right - left + 1, height=bottom - top + 1)
        _add(views, name, values, path, where)
    if not views:
        raise InputError(f"{path}: every camera is inactive (active=\"0\"); nothing to import")
    return _checked(views, path, unit or "mm")


def read_toml(path: Path, *, unit: str | None = None, up: str = "z") -> Views:
    """An anipose / Pose2Sim ``Calib.toml``: per camera table ``name``, ``size`` [width, height] (pixels),
    ``matrix`` (3x3 intrinsics), ``distortions`` [k1, k2, p1, p2(, k3)], ``rotation`` (world-to-camera Rodrigues
    vector) and ``translation`` (world-to-camera, in ``unit``: Pose2Sim writes metres, anipose the unit of its
    board); ``fisheye = true`` is refused (the project's cameras use the pinhole model)."""
    scale, rotation = _frame(path, unit or "m", up)
    try:
        doc = tomllib.loads(_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc}); expected one table per camera with name, size, matrix, "
                         "distortions, rotation and translation") from exc
    tables = {key: value for key, value in doc.items() if key != "metadata"}
    if not tables:
        raise InputError(f"{path}: no camera tables; expected [cam_1] ... tables with name, size, matrix, "
                         "distortions, rotation and translation")
    views: Views = {}
    for key, table in tables.items():
        where = f"{path}: [{key}]"
        if not isinstance(table, dict):
            raise InputError(f"{where} must be a table of a camera's calibration, got {table!r}")
        for needed in ("name", "size", "matrix", "distortions", "rotation", "translation"):
            if needed not in table:
                raise InputError(f"{where} has no {needed!r}; a camera needs name, size, matrix, distortions, "
                                 "rotation and translation")
        if table.get("fisheye", False) not in (False, 0):
            raise InputError(f"{where}: fisheye = {table['fisheye']!r}; fisheye cameras are not imported (the "
                             "project's cameras use the pinhole model k1 k2 p1 p2 k3): calibrate with fisheye = false")
        name = table["name"]
        if not isinstance(name, str):
            raise InputError(f"{where}: 'name' must be a string (the view's name), got {name!r}")
        size = _array(table["size"], (2,), where, "size", "[width, height] in pixels")
        K = _array(table["matrix"], (3, 3), where, "matrix", "a 3x3 intrinsic matrix [[fx, 0, cx], [0, fy, cy], "
                                                               "[0, 0, 1]]")
        rvec = _array(table["rotation"], (3,), where, "rotation", "a world-to-camera Rodrigues vector [rx, ry, rz]")
        tvec = _array(table["translation"], (3,), where, "translation", "a world-to-camera translation [tx, ty, tz]")
        values = dict(**_intrinsics(K, where, "matrix"),
                      dist=_distortion(table["distortions"], where, "distortions"),
                      cam_to_world=reframed(pose_from_extrinsics(rvec, tvec * scale), rotation),
                      width=size[0], height=size[1])
        _add(views, name, values, path, f"{where} (camera {name!r})")
    return _checked(views, path, unit or "m")


# OpenCV FileStorage keys: the first of each tuple found is used
OPENCV_KEYS = {"K": ("camera_matrix", "K", "cameraMatrix"),
               "dist": ("distortion_coefficients", "dist", "dist_coeffs", "D"),
               "R": ("R", "rvec"), "T": ("T", "tvec"),
               "width": ("image_width",), "height": ("image_height",)}


def read_opencv(path: Path, *, unit: str | None = None, up: str = "z") -> Views:
    """One camera from an OpenCV FileStorage file (YAML or XML, as ``cv2.FileStorage`` writes it; read here, not by
    OpenCV's parser, so that a damaged file is refused rather than crashing or hanging it): intrinsics
    ``camera_matrix`` (or ``K``), distortion ``distortion_coefficients`` (or ``dist``; 4 or 5 coefficients, more
    only if the extra ones are 0), the world-to-camera rotation ``R`` (3x3, or a Rodrigues vector; or ``rvec``) and
    translation ``T`` (or ``tvec``, in ``unit``), and ``image_width``, ``image_height``. The view is named by the
    file's stem. The file does not say its unit, so ``unit`` is required."""
    if unit is None:
        raise InputError(f"{path}: an OpenCV calibration file does not say the unit of its translation T; pass the "
                         f"unit of the calibration target you measured (--unit mm or --unit m)")
    scale, rotation = _frame(path, unit, up)
    storage = _filestorage(path, _text(path))
    name = path.name.split(".")[0]
    where = f"{path} (camera {name!r})"
    nodes = {what: _fs_node(storage, keys, path) for what, keys in OPENCV_KEYS.items()}
    K = _array(_fs_value(nodes["K"], path), (3, 3), str(path), nodes["K"][0],
               "a 3x3 intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    R = np.asarray(_fs_value(nodes["R"], path), dtype=np.float64)
    if R.size == 3:
        R = R.reshape(3)
    elif R.shape != (3, 3):
        raise InputError(f"{path}: {nodes['R'][0]!r} must be a 3x3 world-to-camera rotation or a Rodrigues vector "
                         f"(3 numbers), got shape {R.shape}")
    if R.shape == (3, 3):
        _check_rotation(_array(R, (3, 3), str(path), nodes["R"][0], "a 3x3 world-to-camera rotation"), str(path),
                        nodes["R"][0])
    else:
        _array(R, (3,), str(path), nodes["R"][0], "a world-to-camera Rodrigues vector (3 numbers)")
    T = _array(np.asarray(_fs_value(nodes["T"], path), dtype=np.float64).reshape(-1), (3,), str(path),
               nodes["T"][0], "a world-to-camera translation (3 numbers)")
    values = dict(**_intrinsics(K, str(path), nodes["K"][0]),
                  dist=_distortion(_fs_value(nodes["dist"], path), str(path), nodes["dist"][0]),
                  cam_to_world=reframed(pose_from_extrinsics(R, T * scale), rotation),
                  width=_fs_value(nodes["width"], path), height=_fs_value(nodes["height"], path))
    views: Views = {}
    _add(views, name, values, path, where)
    return _checked(views, path, unit)


FORMATS: dict[str, Callable[..., Views]] = {"qca": read_qca, "toml": read_toml, "opencv": read_opencv}


def calibration_document(views: Mapping[str, Mapping[str, Any]], fps: float) -> dict:
    """The content of a calibration.yaml: ``fps`` and ``views``."""
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps {fps!r} is not a positive number of frames per second; give the recording's rate")
    return {"fps": float(fps), "views": {name: dict(values) for name, values in views.items()}}


def write_calibration(path: Path, views: Mapping[str, Mapping[str, Any]], fps: float, *, force: bool = False) -> Path:
    """Write ``views`` and ``fps`` as a calibration.yaml at ``path``; an existing file is kept unless ``force``."""
    path = Path(path)
    document = calibration_document(views, fps)
    if path.exists() and not force:
        raise InputError(f"{path} exists; pass --force to overwrite it, or choose another --out")
    if path.is_dir():
        raise InputError(f"{path} is a folder; --out names the calibration.yaml file to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


def cameras_of(views: Mapping[str, Mapping[str, Any]]) -> dict[str, Camera]:
    """The checked :class:`Camera` of every view."""
    return {name: calibrated_camera(name, **values) for name, values in views.items()}


# ---- shared checks ------------------------------------------------------------------------------
def _frame(path: Path, unit: str, up: str) -> tuple[float, np.ndarray]:
    """The scale to metres and the world rotation onto Z up of a file's ``unit`` and ``up``."""
    if unit not in UNITS_M:
        raise InputError(f"{path}: unit {unit!r} is not one of {', '.join(UNITS_M)}; say the unit of the file's "
                         "positions and translations")
    if up not in UPS:
        raise InputError(f"{path}: up axis {up!r} is not one of {', '.join(UPS)}; say which axis of the file's world "
                         "is up")
    return UNITS_M[unit], (Y_UP_TO_Z_UP if up == "y" else np.eye(3))


def _text(path: Path) -> str:
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError as exc:
        raise InputError(f"{path} does not exist; give the path of the calibration file") from exc
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from exc
    if not text.strip():
        raise InputError(f"{path} is empty; export the calibration again")
    return text


def _array(value, shape: tuple[int, ...], where: str, key: str, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {key!r} must be {what}, got {value!r} (not numbers in rows of one length)") from exc
    if arr.shape != shape:
        got = "x".join(map(str, arr.shape)) or "a single number"
        raise InputError(f"{where}: {key!r} must be {what}, got {got}: {arr.tolist()}")
    if not np.isfinite(arr).all():
        raise InputError(f"{where}: {key!r} has a value that is not finite: {arr.tolist()}")
    return arr


def _intrinsics(K: np.ndarray, where: str, key: str) -> dict[str, float]:
    """fx fy cx cy of a 3x3 intrinsic matrix without skew."""
    zeros_ok = np.allclose([K[1, 0], K[2, 0], K[2, 1]], 0.0) and np.isclose(K[2, 2], 1.0)
    if not zeros_ok:
        raise InputError(f"{where}: {key!r} must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
        raise InputError(f"{where}: {key!r} has a skew of {K[0, 1]} (row 1, column 2); the project's cameras have "
                         "none: recalibrate without skew")
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}


def _distortion(value, where: str, key: str) -> list[float]:
    """k1 k2 p1 p2 k3 of 4 or 5 OpenCV coefficients (more only where the extra ones are 0: the rational and
    thin-prism models are not imported)."""
    try:
        coefs = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {key!r} must be distortion coefficients [k1, k2, p1, p2(, k3)], got {value!r} "
                         "(not numbers)") from exc
    if coefs.size < 4 or (coefs.size > 5 and np.any(coefs[5:] != 0)):
        raise InputError(f"{where}: {key!r} must be 4 or 5 distortion coefficients [k1, k2, p1, p2(, k3)], got "
                         f"{coefs.size}: {coefs.tolist()}; the rational and thin-prism models are not imported")
    if not np.isfinite(coefs).all():
        raise InputError(f"{where}: {key!r} has a value that is not finite: {coefs.tolist()}")
    return [float(c) for c in (list(coefs[:5]) + [0.0] * (5 - min(coefs.size, 5)))]


def _check_rotation(rot: np.ndarray, where: str, key: str) -> None:
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4) or np.linalg.det(rot) <= 0:
        raise InputError(f"{where}: {key} is not a rotation (orthonormal, determinant 1): {np.round(rot, 6).tolist()}; "
                         "fix or export the calibration again")


def _add(views: Views, name: str, values: dict, path: Path, where: str) -> None:
    """Check one camera (its view name, then its values as a Camera) and add it as plain numbers."""
    if not _NAME.fullmatch(name):
        raise InputError(f"{where}: camera name {name!r} is not a valid view name: view names become partition names, "
                         "so they must match [A-Za-z0-9_-][A-Za-z0-9_.-]*; rename the camera in the file")
    if name in views:
        raise InputError(f"{path}: two cameras are named {name!r}; give every camera its own name")
    try:
        camera = calibrated_camera(name, **values)
    except CalibrationError as exc:
        raise InputError(f"{where}: {exc}") from exc
    views[name] = {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "dist": list(camera.dist),
                   "cam_to_world": [[float(v) for v in row] for row in camera.cam_to_world],
                   "width": camera.width, "height": camera.height}


def _checked(views: Views, path: Path, unit: str) -> Views:
    """Refuse camera positions that betray a wrong ``unit``."""
    centres = np.array([np.asarray(v["cam_to_world"])[:3, 3] for v in views.values()])
    far = np.linalg.norm(centres, axis=1)
    if far.max() > MAX_DISTANCE_M:
        name = list(views)[int(np.argmax(far))]
        raise InputError(f"{path}: camera {name!r} would be {far.max():.1f} m from the origin (read with unit "
                         f"{unit!r}); is the file in millimetres? pass --unit mm")
    if len(centres) > 1:
        spread = max(np.linalg.norm(a - b) for i, a in enumerate(centres) for b in centres[i + 1:])
        if 0 < spread < MIN_SPREAD_M:
            raise InputError(f"{path}: the cameras would all lie within {spread * 1000:.2f} mm of each other (read with "
                             f"unit {unit!r}); is the file in metres? pass --unit m")
    return views


# ---- .qca ------------------------------------------------------------------------------------------
def _qca_child(element: ET.Element, tag: str, where: str) -> ET.Element:
    child = element.find(tag)
    if child is None:
        raise InputError(f"{where}: has no <{tag}> element; export the calibration again from QTM")
    return child


def _qca_number(element: ET.Element, key: str, where: str, default: float | None = None) -> float:
    raw = element.get(key)
    if raw is None:
        if default is not None:
            return default
        raise InputError(f"{where}: <{element.tag}> has no {key!r} attribute; export the calibration again from QTM")
    try:
        value = float(raw)
    except ValueError as exc:
        raise InputError(f"{where}: <{element.tag}> {key}={raw!r} is not a number; fix the value") from exc
    if not np.isfinite(value):
        raise InputError(f"{where}: <{element.tag}> {key}={raw!r} is not finite; fix the value")
    return value


# ---- OpenCV FileStorage --------------------------------------------------------------------------
MAX_OPENCV_BYTES = 1 << 20  # one camera's calibration is a few hundred bytes
_MATRIX_TAG = re.compile(r"!!opencv-(?:nd-)?matrix")


def _filestorage(path: Path, text: str) -> dict[str, Any]:
    """The top-level values of an OpenCV FileStorage file, YAML or XML: numbers, strings, lists, and each
    ``opencv-matrix`` as a float array of its rows and columns."""
    if len(text) > MAX_OPENCV_BYTES:
        raise InputError(f"{path}: {len(text)} characters, over the {MAX_OPENCV_BYTES} of an OpenCV calibration file; "
                         "give the file of one camera")
    if text.lstrip().startswith("<"):
        return _filestorage_xml(path, text)
    body = "\n".join(line for line in text.splitlines() if not line.startswith("%"))  # the %YAML directive
    body = _MATRIX_TAG.sub("", body)
    try:
        if any(isinstance(event, yaml.AliasEvent) for event in yaml.parse(body, Loader=yaml.SafeLoader)):
            raise InputError(f"{path}: uses YAML aliases (*name), which an OpenCV calibration file has none of; write "
                             "the values out")
        doc = yaml.safe_load(body)
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not a readable OpenCV FileStorage file (YAML or XML, as cv2.FileStorage writes "
                         f"it): {exc}") from exc
    if not isinstance(doc, dict):
        raise InputError(f"{path}: not an OpenCV FileStorage file: expected a mapping of keys (camera_matrix, ...), "
                         f"got {type(doc).__name__}")
    return {str(key): _fs_matrix(path, str(key), value) for key, value in doc.items()}


def _filestorage_xml(path: Path, text: str) -> dict[str, Any]:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(f"{path}: not a readable OpenCV FileStorage file (XML, as cv2.FileStorage writes it): "
                         f"{exc}") from exc
    if root.tag != "opencv_storage":
        raise InputError(f"{path}: the XML's root is <{root.tag}>, an OpenCV FileStorage file's is <opencv_storage>")
    out: dict[str, Any] = {}
    for node in root:
        if node.get("type_id") in ("opencv-matrix", "opencv-nd-matrix"):
            fields = {child.tag: (child.text or "").strip() for child in node}
            out[node.tag] = _fs_matrix(path, node.tag, {k: _xml_scalar(v) if k != "data" else v.split()
                                                        for k, v in fields.items()})
        elif len(node):
            out[node.tag] = [_xml_scalar((child.text or "").strip()) for child in node]
        else:
            words = (node.text or "").split()
            out[node.tag] = _xml_scalar(words[0]) if len(words) == 1 else [_xml_scalar(w) for w in words] \
                if words else ""
    return out


def _xml_scalar(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text.strip('"')


def _fs_matrix(path: Path, key: str, value):
    """An ``opencv-matrix`` mapping (rows, cols, dt, data) as a float array (rows, cols); other values as they are."""
    if not (isinstance(value, dict) and {"rows", "cols", "data"} <= set(value)):
        return value
    rows, cols, data = value["rows"], value["cols"], value["data"]
    if isinstance(data, str):
        data = data.split()
    if not (isinstance(rows, int) and isinstance(cols, int) and rows >= 0 and cols >= 0 and isinstance(data, list)):
        raise InputError(f"{path}: {key!r} is an opencv-matrix whose rows {rows!r}, cols {cols!r} are not counts or "
                         "whose data is not a list; write the matrix with cv2.FileStorage")
    try:
        numbers = np.array([float(v) for v in data], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {key!r} has data that are not all numbers ({exc}); fix the value") from exc
    if rows * cols == 0 or len(numbers) % (rows * cols):
        raise InputError(f"{path}: {key!r} is a {rows}x{cols} opencv-matrix but holds {len(numbers)} numbers; fix "
                         "its rows, cols or data")
    channels = len(numbers) // (rows * cols)
    return numbers.reshape(rows, cols * channels)


def _fs_node(storage: dict, keys: tuple[str, ...], path: Path):
    for key in keys:
        if key in storage:
            return key, storage[key]
    found = ", ".join(storage) or "none"
    raise InputError(f"{path}: has no {' or '.join(repr(k) for k in keys)}; an OpenCV camera file needs "
                     f"camera_matrix, distortion_coefficients, R (or rvec), T (or tvec), image_width and "
                     f"image_height (keys found: {found})")


def _fs_value(keyed, path: Path):
    """A FileStorage value's number, or its numbers as an array (a matrix, or a sequence of numbers)."""
    key, value = keyed
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, list) and value and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                 for v in value):
        return np.array(value, dtype=np.float64)
    shown = value if isinstance(value, str) else f"a value of type {type(value).__name__}"
    raise InputError(f"{path}: {key!r} must be a number or a matrix of numbers, got {shown!r}; fix the value")
