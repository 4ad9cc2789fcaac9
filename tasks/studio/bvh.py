"""BVH motion: parsing, forward kinematics, and retargeting onto the template body.

Retargeting transfers each mapped bone's global rotation change from the BVH rest pose, then
corrects it by the smallest rotation that makes the template bone point where the BVH bone
points. The template keeps its own bone lengths (so they are constant), the root translation is
scaled by the ratio of leg lengths, the clip is centred on the capture centre, and a constant
height offset puts the lowest foot contact on the floor. CMU (cgspeed) skeletons are supported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mocapflow.tasks.shared.body import JOINT_INDEX, JOINT_NAMES, PARENTS, Subject, rest_offsets
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP, forward_kinematics
from mocapflow.tasks.studio.motion import Motion, lowest_foot_point


# template joint: (BVH joint whose rotation it follows, BVH bone start, BVH bone end) or "inherit"
def _cmu_map(spine, limbs, wrist: str, finger: str) -> dict:
    """template joint -> (BVH joint it follows, BVH bone start, BVH bone end), "inherit" for the neck.

    ``limbs``: (template joint, BVH joint, next BVH joint) per side; ``wrist``/``finger`` name the BVH
    wrist and the finger joint its bone points to ({side} = Left/Right, {s} = L/R).
    """
    out: dict[str, tuple[str, str, str] | str] = {"Hips": spine[0], "SpineBase": spine[1], "Neck": "inherit",
                                                  "Head": ("Head", "Head", "Head_End")}
    for side in ("Left", "Right"):
        for joint, bvh, nxt in limbs:
            out[f"{side}{joint}"] = (f"{side}{bvh}", f"{side}{bvh}", f"{side}{nxt}")
        hand = wrist.format(side=side, s=side[0])
        out[f"{side}Wrist"] = (hand, hand, finger.format(side=side, s=side[0]))
    return out


# CMU cgspeed naming as in subject 12 (LeftUpLeg, Spine1, ...).
CMU_MAP = _cmu_map((("Hips", "Hips", "Spine1"), ("Spine1", "Spine", "Neck")),
                   (("Shoulder", "Arm", "ForeArm"), ("Elbow", "ForeArm", "Hand"), ("Hip", "UpLeg", "Leg"),
                    ("Knee", "Leg", "Foot"), ("Ankle", "Foot", "ToeBase")),
                   "{side}Hand", "{side}HandIndex1")
# The other cgspeed naming, as in subject 14 (LeftHip, Chest2, lowerneck, ...).
CMU_MAP_ALT = _cmu_map((("Hips", "Hips", "Chest2"), ("Chest2", "Chest", "lowerneck")),
                       (("Shoulder", "Shoulder", "Elbow"), ("Elbow", "Elbow", "Wrist"), ("Hip", "Hip", "Knee"),
                        ("Knee", "Knee", "Ankle"), ("Ankle", "Ankle", "Toe")),
                       "{side}Wrist", "{s}Fingers")
MAPPINGS = (CMU_MAP, CMU_MAP_ALT)


class BVHError(ValueError):
    """A BVH text that cannot be parsed or retargeted."""


@dataclass(frozen=True)
class BVH:
    names: tuple[str, ...]  # joints and end sites ("<parent>_End")
    parents: np.ndarray
    offsets: np.ndarray  # (joint, 3)
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    data: np.ndarray  # (frame, channel)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def forward_kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (frame, joint, 3, 3) and positions (frame, joint, 3), in the file's axes and units."""
        n = self.data.shape[0]
        local = np.tile(np.eye(3), (n, len(self.names), 1, 1))  # (frame, joint, 3, 3)
        translation = np.tile(self.offsets, (n, 1, 1))  # (frame, joint, 3): the offset, or the position channels
        col = 0
        for j, chans in enumerate(self.channels):
            values = self.data[:, col:col + len(chans)]
            col += len(chans)
            for k, chan in enumerate(chans):
                axis = chan[0].lower()
                if chan.endswith("rotation"):
                    local[:, j] = local[:, j] @ Rotation.from_euler(axis, values[:, k:k + 1], degrees=True).as_matrix()
                else:
                    translation[:, j, "xyz".index(axis)] = values[:, k]
        root = int(np.flatnonzero(self.parents < 0)[0])
        return forward_kinematics(local, translation[:, root], translation, self.parents)


def parse_bvh(text: str) -> BVH:
    """Parse BVH text; raise BVHError naming the line on malformed input."""
    tokens = [(tok, n) for n, line in enumerate(text.splitlines(), 1) for tok in line.split()]
    it = iter(tokens)
    names, parents, offsets, channels, stack = [], [], [], [], []

    def take(expected=None, what=None):
        try:
            tok, line = next(it)
        except StopIteration:
            raise BVHError(f"unexpected end of file (expected {expected or what or 'more data'})") from None
        if expected is not None and tok != expected:
            raise BVHError(f"line {line}: expected {expected!r}, found {tok!r}")
        return tok, line

    def number(tok, line):
        try:
            return float(tok)
        except ValueError:
            raise BVHError(f"line {line}: expected a number, found {tok!r}") from None

    take("HIERARCHY")
    tok, line = take()
    while tok in ("ROOT", "JOINT", "End"):
        name = take()[0]
        if tok == "End":
            name = f"{names[stack[-1]]}_End"
        if tok != "ROOT" and not stack:
            raise BVHError(f"line {line}: {tok} outside any joint")
        names.append(name)
        parents.append(stack[-1] if stack else -1)
        take("{")
        take("OFFSET")
        offsets.append([number(*take(what="an OFFSET number")) for _ in range(3)])
        chans: tuple[str, ...] = ()
        if tok != "End":
            take("CHANNELS")
            count_tok, count_line = take()
            chans = tuple(take()[0] for _ in range(int(number(count_tok, count_line))))
            bad = [c for c in chans if c not in {f"{a}{k}" for a in "XYZ" for k in ("position", "rotation")}]
            if bad:
                raise BVHError(f"line {count_line}: unknown channel(s) {bad}")
        channels.append(chans)
        stack.append(len(names) - 1)
        tok, line = take()
        while tok == "}":
            stack.pop()
            if not stack:
                break
            tok, line = take()
        else:
            continue
        tok, line = take()
    if stack or not names:
        raise BVHError("the HIERARCHY section is not closed or has no joints")
    if tok != "MOTION":
        raise BVHError(f"line {line}: expected 'MOTION', found {tok!r}")
    take("Frames:")
    n_frames = int(number(*take()))
    take("Frame")
    take("Time:")
    frame_time = number(*take())
    values = np.array([number(tok, ln) for tok, ln in it])
    width = sum(len(c) for c in channels)
    if n_frames <= 0 or frame_time <= 0:
        raise BVHError(f"Frames ({n_frames}) and Frame Time ({frame_time}) must be positive")
    if values.size != n_frames * width:
        raise BVHError(f"MOTION holds {values.size} numbers, expected Frames {n_frames} x {width} channels")
    return BVH(tuple(names), np.array(parents), np.array(offsets, float), tuple(channels), frame_time,
               values.reshape(n_frames, width))


def world_positions(bvh: BVH) -> np.ndarray:
    """The clip's joint positions in the studio's axes (Z up, facing +Y), in the file's units, its added T-pose
    frame dropped, as ``retarget`` sees them.  # (frame, joint, 3)"""
    mapping = _mapping(bvh.names)
    index = {n: i for i, n in enumerate(bvh.names)}
    data = bvh.data[1:] if _starts_with_tpose(bvh) else bvh.data
    _, pos = BVH(bvh.names, bvh.parents, bvh.offsets, bvh.channels, bvh.frame_time, data).forward_kinematics()
    world = _facing(bvh, index[mapping["LeftHip"][0]], index[mapping["RightHip"][0]]) @ Y_UP_TO_Z_UP
    return pos @ world.T


def mapping(names) -> dict:
    """template joint -> (BVH joint it follows, BVH bone start, BVH bone end), "inherit" or absent: the first
    known mapping (CMU's two cgspeed namings) that ``names`` satisfy; BVHError naming the missing joints."""
    return _mapping(names)


def _mapping(names) -> dict:
    """The first known joint mapping that ``names`` satisfy."""
    missing = []
    for mapping in MAPPINGS:
        needed = {n for m in mapping.values() if m != "inherit" for n in m}
        missing.append(sorted(needed - set(names)))
        if not missing[-1]:
            return mapping
    raise BVHError(f"the BVH skeleton lacks joints {min(missing, key=len)}; a CMU (cgspeed) skeleton is expected")


def retarget(bvh: BVH, subject: Subject, *, fps: float = 30.0, n_frames: int | None = None,
             start_s: float = 0.0, label: str = "bvh") -> Motion:
    """``bvh``'s motion on the template body of ``subject``, resampled to ``fps``."""
    index = {n: i for i, n in enumerate(bvh.names)}
    mapping = _mapping(bvh.names)
    hip, knee, ankle = (mapping[j][0] for j in ("LeftHip", "LeftKnee", "LeftAnkle"))
    data = bvh.data[1:] if _starts_with_tpose(bvh) else bvh.data
    rot, pos = BVH(bvh.names, bvh.parents, bvh.offsets, bvh.channels, bvh.frame_time, data).forward_kinematics()
    world = _facing(bvh, index[hip], index[mapping["RightHip"][0]]) @ Y_UP_TO_Z_UP
    rot = world @ rot @ world.T  # rest global rotations are the identity
    pos = pos @ world.T
    offsets = rest_offsets(subject)
    glob = np.tile(np.eye(3), (rot.shape[0], len(JOINT_NAMES), 1, 1))
    for j, name in enumerate(JOINT_NAMES):
        m = mapping.get(name)
        if m is None:
            glob[:, j] = glob[:, PARENTS[j]]  # end joints: no rotation of their own
        elif m == "inherit":
            glob[:, j] = glob[:, PARENTS[j]]
        else:
            glob[:, j] = _aligned(rot[:, index[m[0]]], _rest_direction(name, offsets),
                                  pos[:, index[m[2]]] - pos[:, index[m[1]]])
    local = glob.copy()
    for j, parent in enumerate(PARENTS):
        if parent >= 0:
            local[:, j] = np.swapaxes(glob[:, parent], 1, 2) @ glob[:, j]
    scale = _leg_length(offsets) / _leg_length_bvh(pos[0], index[hip], index[knee], index[ankle])
    root = pos[:, index["Hips"]] * scale
    root[:, :2] -= root[:, :2].mean(axis=0)
    local, root = _resample(local, root, bvh.fps, fps, n_frames, start_s)
    root = root + np.array([0, 0, offsets[0, 2] - root[:, 2].mean()])
    root[:, 2] -= lowest_foot_point(local, root, subject).min()
    return Motion(local, root, fps, label)


def _starts_with_tpose(bvh: BVH) -> bool:
    rotations = [i for i, c in enumerate(c for chans in bvh.channels for c in chans) if c.endswith("rotation")]
    return bvh.data.shape[0] > 1 and np.allclose(bvh.data[0, rotations], 0.0)


def _facing(bvh: BVH, left_hip: int, right_hip: int) -> np.ndarray:
    """Rotation about Z that turns the BVH rest pose to face +Y (its left side to -X)."""
    rest = np.zeros((len(bvh.names), 3))
    for j, parent in enumerate(bvh.parents):
        rest[j] = bvh.offsets[j] + (rest[parent] if parent >= 0 else 0)
    left = Y_UP_TO_Z_UP @ (rest[left_hip] - rest[right_hip])
    angle = np.arctan2(left[1], left[0])
    return Rotation.from_euler("z", np.pi - angle).as_matrix()


def _rest_direction(name: str, offsets: np.ndarray) -> np.ndarray:
    j = JOINT_INDEX[name]
    child = next((c for c, p in enumerate(PARENTS) if p == j), None)
    d = offsets[child] if child is not None else np.array([0.0, 0.0, 1.0])  # the head points up
    return d / np.linalg.norm(d)


def _aligned(delta: np.ndarray, rest_dir: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``delta`` followed by the smallest rotation taking ``delta @ rest_dir`` onto ``target``.  # (frame, 3, 3)"""
    current = delta @ rest_dir
    target = target / np.maximum(np.linalg.norm(target, axis=1, keepdims=True), 1e-9)
    axis = np.cross(current, target)
    sin = np.linalg.norm(axis, axis=1)
    cos = np.einsum("fi,fi->f", current, target)
    rotvec = axis / np.maximum(sin, 1e-12)[:, None] * np.arctan2(sin, cos)[:, None]
    return Rotation.from_rotvec(rotvec).as_matrix() @ delta


def _leg_length(offsets: np.ndarray) -> float:
    return float(np.linalg.norm(offsets[JOINT_INDEX["LeftKnee"]]) + np.linalg.norm(offsets[JOINT_INDEX["LeftAnkle"]]))


def _leg_length_bvh(pos: np.ndarray, hip: int, knee: int, ankle: int) -> float:
    return float(np.linalg.norm(pos[knee] - pos[hip]) + np.linalg.norm(pos[ankle] - pos[knee]))


def available_frames(bvh: BVH, fps: float, start_s: float = 0.0) -> int:
    """Frames of ``bvh``'s motion (its added T-pose frame excluded) at ``fps`` from ``start_s`` on."""
    samples = bvh.data.shape[0] - (1 if _starts_with_tpose(bvh) else 0)
    return _available(samples, bvh.fps, fps, start_s)


def _available(samples: int, src_fps: float, fps: float, start_s: float) -> int:
    return int(np.floor(((samples - 1) / src_fps - start_s) * fps + 1e-9)) + 1


def _resample(local, root, src_fps, fps, n_frames, start_s):
    duration = (root.shape[0] - 1) / src_fps
    available = _available(root.shape[0], src_fps, fps, start_s)
    if start_s < 0 or available <= 0:
        raise BVHError(f"start {start_s} s is outside the clip ({duration:.2f} s)")
    if n_frames is None:
        n_frames = available
    if n_frames > available:
        raise BVHError(f"the clip holds {available} frames at {fps} fps from {start_s} s; asked for {n_frames}")
    t_src = np.arange(root.shape[0]) / src_fps
    t = start_s + np.arange(n_frames) / fps
    out = np.empty((n_frames,) + local.shape[1:])
    for j in range(local.shape[1]):
        out[:, j] = Slerp(t_src, Rotation.from_matrix(local[:, j]))(t).as_matrix()
    return out, np.stack([np.interp(t, t_src, root[:, k]) for k in range(3)], axis=1)
