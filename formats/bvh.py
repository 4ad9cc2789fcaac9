"""BVH motion files: reading any BVH text into a clip, and writing one as animation tools read them.

:func:`parse_bvh` reads BVH text into a :class:`~mocapflow.tasks.shared.bvh_clip.BVHClip` (joint names, parents,
offsets, channel layout, frame time, the motion array), refusing malformed or absurd values with a BVHError that
names the line; :func:`format_bvh` writes a clip back exactly. :func:`read_bvh_joints` reads a BVH file's joints into
mocapflow's world (an InputError names the file). The studio retargets a parsed clip onto its template
(tasks/studio/retarget.py).

:func:`bvh_text` writes a skeleton given in mocapflow's Z-up world in metres (offsets from each parent, local
rotations as quaternions x y z w, the root's position), Y up, centimetres, Euler angles ``Z X Y``: each leaf is closed
by an End Site continuing its bone, the root's channels are ``X/Y/Zposition Z/X/Yrotation`` (absolute: its OFFSET is
0 0 0), the others' ``Z/X/Yrotation``.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.errors import InputError
from mocapflow.tasks.shared.bvh_clip import BVHClip, BVHError, rest_positions
from mocapflow.tasks.shared.mesh_body import MeshBody

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


# ---- reading BVH text ----------------------------------------------------------------------------------------------
MIN_FRAME_TIME_S, MAX_FRAME_TIME_S = 1e-6, 3600.0  # a Frame Time outside these is no sampling rate (a broken file)
# A translation farther than this many times the skeleton's own size from the origin is no motion capture (a body
# of 1.7 m: 1.7 km); unit-free, so inches, centimetres and millimetres alike. Rotations beyond MAX_ANGLE_DEG (278
# turns) are a broken export, not unwrapped Euler angles.
MAX_TRANSLATION_SIZES = 1e3
MAX_ANGLE_DEG = 1e5
CHANNEL_NAMES = frozenset(f"{a}{k}" for a in "XYZ" for k in ("position", "rotation"))


class _Tokens:
    """The text's tokens with their line numbers, taken one by one; BVHError names the line of a bad one."""

    def __init__(self, text: str):
        self.all = [(tok, n) for n, line in enumerate(text.splitlines(), 1) for tok in line.split()]
        self.left = iter(self.all)

    def take(self, expected: str | None = None, what: str | None = None) -> tuple[str, int]:
        try:
            tok, line = next(self.left)
        except StopIteration:
            raise BVHError(f"unexpected end of file (expected {expected or what or 'more data'})") from None
        if expected is not None and tok != expected:
            raise BVHError(f"line {line}: expected {expected!r}, found {tok!r}")
        return tok, line

    def count(self, tok: str, line: int, what: str) -> int:
        """A whole number of ``what`` (a CHANNELS count, Frames), at most the tokens the text holds."""
        value = _number(tok, line)
        if not (np.isfinite(value) and value >= 0 and value == int(value)):
            raise BVHError(f"line {line}: the number of {what} must be a whole number, found {tok!r}")
        value = int(value)
        if value > len(self.all):
            raise BVHError(f"line {line}: {value} {what}, more than the file holds ({len(self.all)} values in all)")
        return value


def _number(tok: str, line: int) -> float:
    try:
        return float(tok)
    except ValueError:
        raise BVHError(f"line {line}: expected a number, found {tok!r}") from None


def parse_bvh(text: str) -> BVHClip:
    """Parse BVH text into a clip; raise BVHError naming the line on malformed input."""
    tokens = _Tokens(text)
    tokens.take("HIERARCHY")
    (names, parents, offsets, channels), (tok, line) = _hierarchy(tokens)
    if tok != "MOTION":
        raise BVHError(f"line {line}: expected 'MOTION', found {tok!r}")
    tokens.take("Frames:")
    n_frames = tokens.count(*tokens.take(), "frames")
    tokens.take("Frame")
    tokens.take("Time:")
    frame_time = _number(*tokens.take())
    rest = list(tokens.left)
    values = np.array([_number(tok, ln) for tok, ln in rest])
    width = sum(len(c) for c in channels)
    if not (n_frames > 0 and MIN_FRAME_TIME_S <= frame_time <= MAX_FRAME_TIME_S):
        raise BVHError(f"Frames ({n_frames}) must be positive and Frame Time ({frame_time}) a time in seconds from "
                       f"{MIN_FRAME_TIME_S:g} to {MAX_FRAME_TIME_S:g}")
    if not width:
        raise BVHError("no joint has CHANNELS: the clip has no motion; export it with its channels")
    if values.size != n_frames * width:
        raise BVHError(f"MOTION holds {values.size} numbers, expected Frames {n_frames} x {width} channels")
    clip = BVHClip(tuple(names), np.array(parents), np.array(offsets, float), tuple(channels), frame_time,
                   values.reshape(n_frames, width))
    _check_numbers(clip, [ln for _, ln in rest])
    return clip


def _hierarchy(tokens: _Tokens) -> tuple[tuple[list, list, list, list], tuple[str, int]]:
    """The HIERARCHY section's joints (names, parents, offsets, channels; an End Site named ``<parent>_End``) and
    the token after it."""
    names, parents, offsets, channels, stack = [], [], [], [], []
    tok, line = tokens.take()
    while tok in ("ROOT", "JOINT", "End"):
        name = tokens.take()[0]
        if tok != "ROOT" and not stack:
            raise BVHError(f"line {line}: {tok} outside any joint")
        names.append(f"{names[stack[-1]]}_End" if tok == "End" else name)
        parents.append(stack[-1] if stack else -1)
        tokens.take("{")
        tokens.take("OFFSET")
        offsets.append([_number(*tokens.take(what="an OFFSET number")) for _ in range(3)])
        channels.append(() if tok == "End" else _channels(tokens))
        stack.append(len(names) - 1)
        tok, line = tokens.take()
        while tok == "}":
            stack.pop()
            if not stack:
                break
            tok, line = tokens.take()
        else:
            continue
        tok, line = tokens.take()
    if stack or not names:
        raise BVHError("the HIERARCHY section is not closed or has no joints")
    return (names, parents, offsets, channels), (tok, line)


def _channels(tokens: _Tokens) -> tuple[str, ...]:
    """A joint's CHANNELS: their count, then their names."""
    tokens.take("CHANNELS")
    count_tok, count_line = tokens.take()
    chans = tuple(tokens.take()[0] for _ in range(tokens.count(count_tok, count_line, "channels")))
    bad = [c for c in chans if c not in CHANNEL_NAMES]
    if bad:
        raise BVHError(f"line {count_line}: unknown channel(s) {bad}")
    return chans


def _check_numbers(clip: BVHClip, lines: list[int]) -> None:
    """Raise BVHError naming the first non-finite or absurd OFFSET or MOTION value: its line, frame, joint, channel."""
    bad = np.flatnonzero(~np.isfinite(clip.offsets).all(axis=1))
    if len(bad):
        j = int(bad[0])
        raise BVHError(f"the OFFSET of {clip.names[j]} is {clip.offsets[j].tolist()}: offsets must be finite numbers; "
                       "fix the skeleton in the exporter")
    size = max(float(np.ptp(rest_positions(clip), axis=0).max()), 1e-9)
    owner = [(j, c) for j, chans in enumerate(clip.channels) for c in chans]  # each column's joint and channel
    limit = np.array([MAX_ANGLE_DEG if c.endswith("rotation") else MAX_TRANSLATION_SIZES * size for _, c in owner])
    wrong = ~np.isfinite(clip.data) | (np.abs(clip.data) > limit)
    if not wrong.any():
        return
    frame, col = (int(i) for i in np.argwhere(wrong)[0])
    j, chan = owner[col]
    value = float(clip.data[frame, col])
    what = ("a rotation must be a finite angle in degrees, within +-{:g}".format(MAX_ANGLE_DEG)
            if chan.endswith("rotation") else
            f"a position must be finite and within {MAX_TRANSLATION_SIZES:g} times the skeleton's size "
            f"({MAX_TRANSLATION_SIZES * size:g} of the file's units) of the origin")
    raise BVHError(f"line {lines[frame * clip.data.shape[1] + col]}: frame {frame} (0 = the first), joint "
                   f"{clip.names[j]}, channel {chan} is {value!r}, and {wrong.sum()} value(s) in all are so: {what}; "
                   "re-export the clip, or cut the broken frames out")


def format_bvh(clip: BVHClip) -> str:
    """BVH text of ``clip``, its numbers written exactly (``parse_bvh`` gives the same values back, its joints in
    depth-first order); a joint without channels and children named ``<parent>_End`` is written as an End Site."""
    lines, order = ["HIERARCHY"], []

    def write(j: int, depth: int) -> None:
        pad, children = "  " * depth, np.flatnonzero(clip.parents == j)
        end_site = not clip.channels[j] and not len(children) and clip.parents[j] >= 0 \
            and clip.names[j] == f"{clip.names[clip.parents[j]]}_End"
        head = "End Site" if end_site else ("ROOT " if clip.parents[j] < 0 else "JOINT ") + clip.names[j]
        lines.extend([pad + head, pad + "{", f"{pad}  OFFSET " + " ".join(f"{float(v)!r}" for v in clip.offsets[j])])
        if not end_site:
            lines.append(f"{pad}  CHANNELS {len(clip.channels[j])} " + " ".join(clip.channels[j]))
        order.append(j)
        for child in children:
            write(int(child), depth + 1)
        lines.append(pad + "}")

    write(int(np.flatnonzero(clip.parents < 0)[0]), 0)
    starts = np.cumsum([0] + [len(c) for c in clip.channels])
    columns = [c for j in order for c in range(starts[j], starts[j + 1])]  # the file's channel order
    lines += ["MOTION", f"Frames: {clip.data.shape[0]}", f"Frame Time: {float(clip.frame_time)!r}"]
    rows = io.StringIO()
    np.savetxt(rows, clip.data[:, columns], fmt="%.17g")
    return "\n".join(lines) + "\n" + rows.getvalue()


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
