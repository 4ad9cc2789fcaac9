"""`mocapflow export`: labelled 3D markers as C3D (ezc3d) or TRC files, solved poses as BVH; UUO's solved bodies as
a labelled C3D, a BVH of the solved rig or a report page (pipeline/export_uuo.py).

Both marker formats carry the labels (DeepMoCap's reflector names), the frame rate and the unit (millimetres, the
convention of both). C3D keeps the Z-up world of mocapflow (POINT:X_SCREEN/Y_SCREEN) and stores floats, with
POINT:SCALE negative (the spec's flag for float data) and of magnitude max |coordinate| / 32000 or the largest
residual / 255, whichever is larger. Its residual is the mean distance of the fused views from the point (mm) for
markers3d, 0 for a smoothed stage (the C3D convention for filtered or interpolated data: no measurement residual)
and -1 for a missing point; the camera bits name the fused views (the first seven) for markers3d, none once filtered.
TRC is Y up by default (OpenSim's convention: the world rotated about x, x stays, y = z, z = -y, so handedness is
kept) or Z up on request, the axis in an ``UpAxis`` column after the eight standard header fields; missing samples
are empty fields.

BVH follows the convention of animation tools: Y up, the subject facing +Z, centimetres, the template's 20 joints (each
leaf closed by an End Site continuing its bone), root channels ``X/Y/Zposition Z/X/Yrotation`` (absolute: the root's
OFFSET is 0 0 0) and ``Z/X/Yrotation`` elsewhere. Frames the solver left unsolved hold the nearest solved pose.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from scipy.spatial.transform import Rotation

from mocapflow.pipeline.errors import InputError, PlanError, StorageError
from mocapflow.pipeline.evaluate import final_stage, stage_writing
from mocapflow.pipeline.plan import build_plan, select
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP
from mocapflow.tasks.studio.bvh import parse_bvh

UNIT_SCALE = 1000.0  # metres -> millimetres
SUIT_SCHEMAS = {"c3d": ("suit_filled", "suit_points"), "ply": ("suit_filled",)}  # pipeline/export_suit.py
BVH_SCALE = 100.0  # metres -> centimetres
# mocapflow world (x right, y forward, z up) -> BVH (Y up, facing +Z, the subject's left +X)
Z_UP_TO_Y_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])


def _arrays(markers: xr.Dataset) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    """xyz (frame, marker, 3) mm in the Z-up world, labels, rate, residual (frame, marker) mm: the mean distance of
    the fused views from the point where the stage keeps one (markers3d), 0 for a point that filtering produced
    (the C3D convention for processed data), -1 where the point is missing."""
    up = str(markers.attrs.get("up_axis", "Z"))
    if up.upper() != "Z":
        raise InputError(f"markers with up_axis {up!r} cannot be exported: the export rotates the Z-up world of "
                         "mocapflow; recompute the markers (their up_axis must be 'Z')")
    xyz = markers["position"].transpose("frame", "reflector", "xyz").values.astype(np.float64) * UNIT_SCALE
    names = [str(n) for n in markers["reflector"].values]
    fps = float(markers.attrs["fps"])
    residual = np.zeros(xyz.shape[:2])
    if "residual" in markers:
        per_view = markers["residual"].transpose("frame", "reflector", "view").values.astype(np.float64)
        seen = np.isfinite(per_view).any(axis=-1)
        residual[seen] = np.nanmean(per_view[seen], axis=-1) * UNIT_SCALE
    residual = np.where(np.isfinite(xyz).all(axis=-1), residual, -1.0)
    return xyz, names, fps, residual


def _camera_masks(markers: xr.Dataset, shape: tuple[int, int]) -> np.ndarray:
    """C3D camera bits (frame, marker): bit v set where view v (the first 7 views) was fused; 0 for filtered data."""
    mask = np.zeros(shape, dtype=np.int64)
    if "residual" in markers:
        seen = np.isfinite(markers["residual"].transpose("frame", "reflector", "view").values)[..., :7]
        mask = (seen * (1 << np.arange(seen.shape[-1]))).sum(axis=-1)
    return mask


def c3d_scale(xyz: np.ndarray, residual: np.ndarray) -> float:
    """POINT:SCALE for float storage: negative (the C3D sign for floats), magnitude the larger of the spec's
    max |coordinate| / 32000 and the largest residual / 255 (the residual is one byte in units of |SCALE|)."""
    coords = np.abs(xyz[np.isfinite(xyz)])
    return -max(coords.max() / 32000.0 if coords.size else 0.0, residual.max(initial=0.0) / 255.0, 1e-3)


def write_c3d(markers: xr.Dataset, path: Path) -> None:
    xyz, names, fps, residual = _arrays(markers)
    scale = c3d_scale(xyz, residual)
    word4 = np.where(residual < 0, -1, (_camera_masks(markers, residual.shape) << 8)
                     | np.clip(np.rint(residual / abs(scale)), 0, 255).astype(np.int64))
    _write(path, lambda p: _write_c3d(p, xyz, names, fps, scale, word4))


def _write_c3d(path: Path, xyz: np.ndarray, names: list[str], fps: float, scale: float, word4: np.ndarray,
               descriptions: list[str] | None = None) -> None:
    """Float (Intel) C3D with the spec's point word 4 (camera bits in the high byte, residual / |SCALE| in the low
    byte, -1 when missing) and the header's scale equal to POINT:SCALE. ezc3d writes the file; word 4 and the header
    scale are then set here, as ezc3d puts the residual in the high byte of word 4 and leaves the header scale at -1."""
    import ezc3d

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = names
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["POINT"]["SCALE"]["value"] = [scale]
    if descriptions is not None:
        c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = descriptions
    c3d.add_parameter("POINT", "X_SCREEN", "+X")
    c3d.add_parameter("POINT", "Y_SCREEN", "+Z")  # Z up
    points = np.ones((4, len(names), xyz.shape[0]))
    points[:3] = xyz.transpose(2, 1, 0)  # (xyz, marker, frame)
    c3d["data"]["points"] = points
    c3d.write(str(path))
    data = bytearray(path.read_bytes())
    data[12:16] = np.float32(scale).tobytes()  # header words 7-8: POINT:SCALE
    start = (int(np.frombuffer(data, "<u2", 1, 16)[0]) - 1) * 512  # header word 9: first data block
    n = xyz.shape[0] * len(names) * 4
    block = np.frombuffer(data, "<f4", n, start).reshape(xyz.shape[0], len(names), 4).copy()
    block[..., 3] = word4
    data[start:start + 4 * n] = block.tobytes()
    path.write_bytes(bytes(data))


def read_c3d(path: Path) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    """xyz (frame, marker, 3) mm, labels, rate, residuals (frame, marker) mm (-1 where missing) of a float C3D file
    written by :func:`write_c3d`. Coordinates through ezc3d; residuals decoded from point word 4 as the C3D spec
    lays it out (ezc3d reads float files' residual byte from the wrong half of the word)."""
    import ezc3d

    c3d = ezc3d.c3d(str(path))
    points = c3d["data"]["points"][:3].transpose(2, 1, 0)
    scale = float(c3d["parameters"]["POINT"]["SCALE"]["value"][0])
    data = path.read_bytes()
    start = (int(np.frombuffer(data, "<u2", 1, 16)[0]) - 1) * 512
    word4 = np.frombuffer(data, "<f4", points.size // 3 * 4, start).reshape(points.shape[:2] + (4,))[..., 3]
    word4 = word4.astype(np.int64)
    residual = np.where(word4 < 0, -1.0, (word4 & 0xFF) * abs(scale))
    return (points, list(c3d["parameters"]["POINT"]["LABELS"]["value"]),
            float(c3d["parameters"]["POINT"]["RATE"]["value"][0]), residual)


# mocapflow world (Z up) -> TRC Y up: x stays, y = z, z = -y (a rotation about x, so handedness is kept)
TRC_Y_UP = Y_UP_TO_Z_UP.T  # the inverse rotation
TRC_UP = ("y", "z")


def write_trc(markers: xr.Dataset, path: Path, up: str = "y") -> None:
    """TRC in millimetres, Y up by default (OpenSim's convention; ``up="z"`` keeps the Z-up world). The up axis is
    written in an ``UpAxis`` column after the eight standard header fields."""
    if up not in TRC_UP:
        raise InputError(f"TRC up axis {up!r} is not one of {list(TRC_UP)}; pass --up y (OpenSim) or --up z")
    xyz, names, fps, _ = _arrays(markers)
    if up == "y":
        xyz = xyz @ TRC_Y_UP.T
    n_frames = xyz.shape[0]
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\tUpAxis",
             f"{fps:.2f}\t{fps:.2f}\t{n_frames}\t{len(names)}\tmm\t{fps:.2f}\t1\t{n_frames}\t{up.upper()}",
             "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names).rstrip("\t"),
             "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, len(names) + 1))]
    frames = markers["frame"].values
    for i in range(n_frames):
        values = "\t".join("" if np.isnan(v) else f"{v:.3f}" for v in xyz[i].ravel())
        lines.append(f"{int(frames[i]) + 1}\t{frames[i] / fps:.5f}\t{values}")
    _write(path, lambda p: p.write_text("\n".join(lines) + "\n"))


def read_trc(path: Path) -> tuple[np.ndarray, list[str], float]:
    """xyz (frame, marker, 3) mm in the file's axes, labels and rate of a TRC file written by :func:`write_trc`."""
    rows = path.read_text().splitlines()
    header = dict(zip(rows[1].split("\t"), rows[2].split("\t")))
    names = [n for n in rows[3].split("\t")[2:] if n]
    data = [[float(v) if v else np.nan for v in row.split("\t")[2:]] for row in rows[5:] if row.strip()]
    return np.array(data).reshape(len(data), len(names), 3), names, float(header["DataRate"])


def _filled(poses: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (frame, joint, 4) and root positions (frame, 3), unsolved frames held from the nearest solved."""
    quat = poses["rotation"].transpose("frame", "joint", "quat").values.astype(np.float64)
    root = poses["position"].transpose("frame", "joint", "xyz").values[:, 0].astype(np.float64)
    solved = np.isfinite(quat).all(axis=(1, 2)) & np.isfinite(root).all(axis=1)
    if not solved.any():
        raise InputError("the poses hold no solved frame; nothing to write as BVH (check the markers and skeleton stages)")
    nearest = np.flatnonzero(solved)[np.abs(np.arange(len(solved))[:, None] - np.flatnonzero(solved)).argmin(axis=1)]
    return quat[nearest], root[nearest]


def bvh_text(poses: xr.Dataset) -> str:
    """BVH text (Y up, centimetres) of solved poses on their skeleton."""
    names = [str(n) for n in poses["joint"].values]
    parents = _parents(poses)
    quat, root = _filled(poses)
    return bvh_core(names, parents, poses["offset"].transpose("joint", "xyz").values.astype(np.float64), quat, root,
                    float(poses.attrs["fps"]))


def bvh_core(names: list[str], parents: np.ndarray, offsets: np.ndarray, quat: np.ndarray, root: np.ndarray,
             fps: float) -> str:
    """BVH text of a skeleton: offsets (joint, 3) m from the parent in mocapflow's Z-up world, local rotations
    (frame, joint, 4) x y z w, root positions (frame, 3) m; written Y up, centimetres."""
    offsets = offsets @ Z_UP_TO_Y_UP.T * BVH_SCALE
    children = {j: [c for c in range(len(names)) if parents[c] == j] for j in range(len(names))}
    lines, order = ["HIERARCHY"], []  # order: joints as the hierarchy lists them, the MOTION column order

    def emit(j: int, depth: int) -> None:
        order.append(j)
        pad = "  " * depth
        kind = "ROOT" if parents[j] < 0 else "JOINT"
        chans = "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if parents[j] < 0 else \
            "3 Zrotation Xrotation Yrotation"
        offset = np.zeros(3) if parents[j] < 0 else offsets[j]  # the root's position is all in its channels
        lines.extend([f"{pad}{kind} {names[j]}", f"{pad}{{", f"{pad}  OFFSET {_xyz(offset)}",
                      f"{pad}  CHANNELS {chans}"])
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {_xyz(0.3 * offsets[j])}", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(int(np.flatnonzero(parents < 0)[0]), 0)
    local = Z_UP_TO_Y_UP @ Rotation.from_quat(quat.reshape(-1, 4)).as_matrix() @ Z_UP_TO_Y_UP.T
    euler = Rotation.from_matrix(local).as_euler("ZXY", degrees=True).reshape(quat.shape[:2] + (3,))  # R = Rz Rx Ry
    motion = np.concatenate([root @ Z_UP_TO_Y_UP.T * BVH_SCALE, euler[:, order].reshape(len(euler), -1)], axis=1)
    lines += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [" ".join(f"{v:.5f}" for v in row) for row in motion]
    return "\n".join(lines) + "\n"


def _parents(poses: xr.Dataset) -> np.ndarray:
    names = [str(n) for n in poses["joint"].values]
    if names != list(JOINT_NAMES):
        raise InputError(f"poses joints {names} are not the template's {list(JOINT_NAMES)}; BVH export needs the template")
    return PARENTS


def _xyz(v: np.ndarray) -> str:
    return " ".join(f"{x:.5f}" for x in v)


def write_bvh(poses: xr.Dataset, path: Path) -> None:
    text = bvh_text(poses)
    _write(path, lambda p: p.write_text(text))


def read_bvh_joints(path: Path) -> tuple[np.ndarray, list[str], float]:
    """World joint positions (frame, joint, 3) in metres, Z up, of a BVH file, its joint names (no End Sites), rate."""
    bvh = parse_bvh(path.read_text())
    _, pos = bvh.forward_kinematics()
    keep = [i for i, n in enumerate(bvh.names) if not n.endswith("_End")]
    return pos[:, keep] @ Z_UP_TO_Y_UP / BVH_SCALE, [bvh.names[i] for i in keep], bvh.fps  # row @ M = M^T p


def _write(path: Path, write) -> None:
    if path.suffix.lower() not in (".c3d", ".trc", ".bvh"):
        raise InputError(f"export file {path} must end in .c3d, .trc or .bvh")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".partial" + path.suffix)
        write(tmp)
        tmp.replace(path)
    except OSError as exc:
        raise StorageError(f"cannot write {path}: {exc.strerror}; choose another --out") from exc


WRITERS = {"c3d": write_c3d, "trc": write_trc, "bvh": write_bvh}
SCHEMAS = {"c3d": ("smoothed_markers", "markers3d", "uuo_body"), "trc": ("smoothed_markers", "markers3d"),
           "bvh": ("poses", "uuo_body"), "report": ("uuo_body",)}


def _default_stage(catalog, fmt: str) -> str | None:
    """The stage a format exports when none is named: the plausibility-checked markers, else the last smoothed or
    fused ones, the poses, or the first UUO solve that chooses among hypotheses (the headline one of `mocapflow
    evaluate`)."""
    for schema in SCHEMAS[fmt]:
        if schema == "uuo_body":
            found = [s.name for s in catalog.stages.values() if s.spec.output == schema and schema in s.spec.inputs.values()]
            if found:
                return found[0]
        elif (found := final_stage(catalog, schema)):
            return found
    return None


def export_files(catalog, sequences: str | None, fmt: str, stage: str | None, out_dir: Path,
                 workers: int, processes: bool = True, up: str | None = None) -> list[Path]:
    """Write ``<out_dir>/<sequence>.<fmt>`` for every sequence of ``stage`` (computing missing partitions first
    on ``workers`` local worker processes, or threads); a UUO report is ``<out_dir>/<sequence>/report.html``.
    ``up`` is TRC's up axis, ``y`` (default) or ``z``."""
    from mocapflow.pipeline.scheduler import compute_missing

    if up is not None and fmt != "trc":
        raise InputError(f"--up {up} applies to TRC only ({fmt} has a fixed up axis: C3D Z, BVH Y); drop --up")
    if fmt == "ply" or (stage in catalog.stages and catalog.stages[stage].spec.output in SUIT_SCHEMAS["c3d"]) or \
            (stage is None and fmt == "c3d" and not any(stage_writing(catalog, s) for s in SCHEMAS["c3d"])
             and any(stage_writing(catalog, s) for s in SUIT_SCHEMAS["c3d"])):
        return export_suit_files(catalog, sequences, fmt, stage, out_dir, workers, processes)
    writer = (lambda data, path: write_trc(data, path, up or "y")) if fmt == "trc" else WRITERS.get(fmt)

    stage = stage or _default_stage(catalog, fmt)
    if stage not in catalog.stages:
        raise PlanError(f"no stage {stage!r} to export as {fmt} (it needs one writing {' or '.join(SCHEMAS[fmt])}); "
                        f"the catalog's stages: {list(catalog.stages)}")
    output = catalog.stages[stage].spec.output
    if output not in SCHEMAS[fmt]:
        raise PlanError(f"stage {stage!r} writes {output}; {fmt} exports {' or '.join(SCHEMAS[fmt])} — "
                        "pick another --stage")
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    reference = catalog.evaluation.get("uuo_reference")
    for needed in [stage] + ([str(reference)] if fmt == "report" and reference in catalog.stages else []):
        compute_missing(select(plan, catalog, store, only=None, until=needed), store, workers=workers,
                        processes=processes, what="cannot export")
    written = []
    for item in plan.for_stages([stage]):
        sequence = item.partition.sequence
        data = store.open(stage, item.key, item.stage.schema).load()
        if output == "uuo_body":
            written.append(_export_uuo(catalog, plan, store, stage, sequence, data, fmt, out_dir))
            continue
        path = _inside(out_dir, f"{sequence}.{fmt}")
        writer(data, path)
        written.append(path)
    return written


def _export_uuo(catalog, plan, store: Store, stage: str, sequence: str, solved: xr.Dataset, fmt: str,
                out_dir: Path) -> Path:
    """One UUO solve as a labelled C3D, a BVH of the solved rig, or a report page (pipeline/export_uuo.py)."""
    from mocapflow.pipeline import export_uuo

    markers_stage = catalog.stages[stage].inputs["markers"]
    markers = plan.open(store, markers_stage, sequence).load()
    if fmt == "c3d":
        path = _inside(out_dir, f"{sequence}.c3d")
        export_uuo.write_uuo_c3d(solved, markers, path)
        return path
    if fmt == "bvh":
        path = _inside(out_dir, f"{sequence}.bvh")
        export_uuo.write_uuo_bvh(solved, path)
        return path
    truth, against = None, ""
    raw_stage = stage_writing(catalog, "raw_markers")
    raw = plan.open(store, raw_stage, sequence) if raw_stage else None
    reference = catalog.evaluation.get("uuo_reference")
    if raw is not None and "gt_joints" in raw:
        truth, against = raw["gt_joints"].values.astype(np.float64), "the studio's truth"
    elif reference in catalog.stages and reference != stage:
        truth = plan.open(store, str(reference), sequence)["joints"].values.astype(np.float64)
        against = f"the labelled reference ({reference})"
    folder = _inside(out_dir, sequence)
    return export_uuo.write_report(folder, sequence, stage, solved, markers, truth, against, files=[])


def export_suit_files(catalog, sequences: str | None, fmt: str, stage: str | None, out_dir: Path, workers: int,
                      processes: bool = True) -> list[Path]:
    """The checkerboard suit's corners as C3D or its filled mesh as PLY (pipeline/export_suit.py)."""
    from mocapflow.pipeline.export_suit import SUIT_SCHEMAS, export_suit
    from mocapflow.pipeline.scheduler import compute_missing

    if fmt not in SUIT_SCHEMAS:
        raise PlanError(f"a suit stage exports as {' or '.join(SUIT_SCHEMAS)}, not {fmt}; pass --format c3d or ply")
    stage = stage or next((s for schema in SUIT_SCHEMAS[fmt] if (s := stage_writing(catalog, schema))), None)
    if stage not in catalog.stages or catalog.stages[stage].spec.output not in SUIT_SCHEMAS[fmt]:
        raise PlanError(f"no stage {stage!r} to export as {fmt} (it needs one writing "
                        f"{' or '.join(SUIT_SCHEMAS[fmt])}); the catalog's stages: {list(catalog.stages)}")
    images = stage_writing(catalog, "suit_images")
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    compute_missing(select(plan, catalog, store, only=None, until=stage), store, workers=workers, processes=processes,
                    what="cannot export")
    return export_suit(plan, store, images, stage, fmt, out_dir)


def _inside(out_dir: Path, name: str) -> Path:
    """``out_dir / name``, refused unless it is a file directly inside ``out_dir``."""
    path = out_dir / name
    if path.resolve().parent != out_dir.resolve() or Path(name).name != name:
        raise PlanError(f"export file name {name!r} would be written outside --out {out_dir}; a sequence id must be a "
                        "plain name (see the naming rule in the README): rename the sequence")
    return path
