"""BVH motion files as animation tools read them: Y up, centimetres, Euler angles ``Z X Y``.

:func:`bvh_text` writes a skeleton given in mocapflow's Z-up world in metres (offsets from each parent, local
rotations as quaternions x y z w, the root's position): each leaf is closed by an End Site continuing its bone, the
root's channels are ``X/Y/Zposition Z/X/Yrotation`` (absolute: its OFFSET is 0 0 0), the others'
``Z/X/Yrotation``. :func:`read_bvh_joints` reads any BVH file's joints back into that world (the parser is the
studio's, tasks/studio/bvh.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.errors import InputError
from mocapflow.tasks.shared.mesh_body import MeshBody
from mocapflow.tasks.studio.bvh import BVHError, parse_bvh

BVH_SCALE = 100.0  # metres -> centimetres
Z_UP_TO_Y_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])  # the subject faces +Z


def bvh_text(names: list[str], parents: np.ndarray, offsets: np.ndarray, quat: np.ndarray, root: np.ndarray,
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
        lines.extend([f"{pad}{kind} {names[j]}", f"{pad}{{", f"{pad}  OFFSET {_numbers(offset)}",
                      f"{pad}  CHANNELS {chans}"])
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {_numbers(0.3 * offsets[j])}", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(int(np.flatnonzero(parents < 0)[0]), 0)
    local = Z_UP_TO_Y_UP @ Rotation.from_quat(quat.reshape(-1, 4)).as_matrix() @ Z_UP_TO_Y_UP.T
    euler = Rotation.from_matrix(local).as_euler("ZXY", degrees=True).reshape(quat.shape[:2] + (3,))  # R = Rz Rx Ry
    motion = np.concatenate([root @ Z_UP_TO_Y_UP.T * BVH_SCALE, euler[:, order].reshape(len(euler), -1)], axis=1)
    lines += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [" ".join(f"{v:.5f}" for v in row) for row in motion]
    return "\n".join(lines) + "\n"


def anny_rig_bvh(body: MeshBody, bone_rotation: np.ndarray, root: np.ndarray, fps: float) -> str:
    """BVH text of Anny's whole rig as solved (every bone, ``body``'s rest offsets): bone_rotation (frame, bone, 4)
    x y z w each bone's world rotation from its rest orientation, root (frame, 3) the root's head. A bone's BVH
    rotation is its world rotation relative to its parent's, so the file's forward kinematics give the solved bone
    heads exactly."""
    parents = body.bone_parents
    offsets = body.rest_heads - np.where(parents[:, None] >= 0, body.rest_heads[np.maximum(parents, 0)], 0.0)
    world = Rotation.from_quat(np.asarray(bone_rotation, np.float64).reshape(-1, 4)).as_matrix()
    world = world.reshape(len(bone_rotation), -1, 3, 3)
    local = world.copy()
    child = parents >= 0
    local[:, child] = np.swapaxes(world[:, parents[child]], -1, -2) @ world[:, child]
    quats = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_quat().reshape(local.shape[:2] + (4,))
    names = [name.replace(".", "_") for name in body.bone_names]
    return bvh_text(names, parents, offsets, quats, np.asarray(root, np.float64), float(fps))


def _numbers(v: np.ndarray) -> str:
    return " ".join(f"{x:.5f}" for x in v)


def read_bvh_joints(path: Path) -> tuple[np.ndarray, list[str], float]:
    """World joint positions (frame, joint, 3) in metres, Z up, of a BVH file, its joint names (no End Sites), rate.
    A file that is not readable BVH text raises InputError naming it."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}; give the path of a BVH file") from exc
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a BVH text file (byte {exc.start} is not UTF-8 text); the file is damaged or "
                         "not a BVH file: export it again") from exc
    try:
        bvh = parse_bvh(text)
    except BVHError as exc:
        raise InputError(f"{path}: not a valid BVH file: {exc}") from exc
    _, pos = bvh.forward_kinematics()
    keep = [i for i, n in enumerate(bvh.names) if not n.endswith("_End")]
    return pos[:, keep] @ Z_UP_TO_Y_UP / BVH_SCALE, [bvh.names[i] for i in keep], bvh.fps  # row @ M = M^T p
