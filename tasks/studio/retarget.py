"""A parsed motion clip (a BVH file's, or an ASF/AMC take's: tasks/shared/bvh_clip.py) retargeted onto the template.

Retargeting transfers each mapped bone's global rotation change from the file's own rest pose (every
rotation channel at zero, or a frame of the clip where that zero pose does not stand: ``rest_frame``, see
rest_pose; the template's rest pose is a T-pose, arms along -X/+X), then corrects it by
the smallest rotation that makes the template bone point where the BVH bone points. A skeleton whose
rest pose is a T-pose (Mixamo's) thus transfers exactly; another rest pose (CMU's splayed legs) is
absorbed by the correction. The template keeps its own bone lengths (so they are constant), the root
translation is scaled by the ratio of leg lengths (so the file's unit drops out: inches, centimetres or
metres alike), the frames filmed (the window ``start_s``/``n_frames`` cuts, after resampling; the whole clip's
samples when it is filmed whole) are centred on the capture centre, and a constant height offset puts the lowest
foot contact on the floor. Files are Y up (the format's convention); the facing comes from the rest pose.
A bone ending at an End Site of zero length points along the bone into it (Bandai Namco's research set writes
only such End Sites); any joint may carry position channels (they are its offset, frame by frame).

Which BVH joint drives which template joint is a joint map: CMU's two cgspeed namings (``CMU_MAP``,
``CMU_MAP_ALT``), Mixamo's (``MIXAMO_NAMES``, with or without a ``mixamorig:``-style prefix), the CMU
database's ASF bones (``CMU_ASF_NAMES``, for the takes formats/asf_amc.py reads) or a map the user gives
(``{template joint: BVH joint}``, see :func:`joint_map`). The files are parsed in formats/ (bvh.py, asf_amc.py);
this module only sees the parsed clip.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Mapping

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mocapflow.tasks.shared.body import JOINT_INDEX, JOINT_NAMES, PARENTS, Subject, rest_offsets
from mocapflow.tasks.shared.bvh_clip import BVHClip, BVHError, rest_positions
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP
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
CMU_SIGNATURE = ("LHipJoint", "RHipJoint")  # both cgspeed namings have them; other skeletons do not

SIDES = ("Left", "Right")
# The end of each rotating template joint's bone: its first child, and "HeadTop" (the top of the head) for the
# head, which has none. The neck inherits the spine's rotation (it carries the shoulders).
BONE_END = {"Hips": "SpineBase", "SpineBase": "Neck", "Head": "HeadTop",
            **{f"{side}{joint}": f"{side}{end}" for side in SIDES
               for joint, end in (("Shoulder", "Elbow"), ("Elbow", "Wrist"), ("Wrist", "Hand"), ("Hip", "Knee"),
                                  ("Knee", "Ankle"), ("Ankle", "Foot"))}}
REQUIRED_KEYS = ("Hips", "SpineBase", "Neck", *(k for k in BONE_END if k not in ("Hips", "SpineBase")))  # map all
END_KEYS = ("HeadTop", *(f"{side}{end}" for side in SIDES for end in ("Hand", "Foot")))  # these where ambiguous
MAP_KEYS = REQUIRED_KEYS + END_KEYS


def _sided(table: dict) -> dict:
    """A name table with "{side}" in its keys and names written out for both sides."""
    return {key.format(side=side): tuple(n.format(side=side, s=side[0].lower()) for n in names)
            for key, names in table.items() for side in (SIDES if "{side}" in key else SIDES[:1])}


# template joint -> BVH joints to try (the first the file has wins). Mixamo-style skeletons: zero rotation is a
# T-pose, Y up, centimetres; any spine chain between Spine and Neck (Spine1, Spine2, Chest) is followed whole.
MIXAMO_NAMES = _sided({"Hips": ("Hips",), "SpineBase": ("Spine",), "Neck": ("Neck",), "Head": ("Head",),
                       "HeadTop": ("HeadTop_End",), "{side}Shoulder": ("{side}Arm",),
                       "{side}Elbow": ("{side}ForeArm",), "{side}Wrist": ("{side}Hand",),
                       "{side}Hand": ("{side}HandMiddle1", "{side}HandIndex1"), "{side}Hip": ("{side}UpLeg",),
                       "{side}Knee": ("{side}Leg",), "{side}Ankle": ("{side}Foot",), "{side}Foot": ("{side}ToeBase",)})
# The CMU database's ASF bones, each a joint at the bone's start (formats/asf_amc.py).
CMU_ASF_NAMES = _sided({"Hips": ("root",), "SpineBase": ("upperback",), "Neck": ("lowerneck",), "Head": ("head",),
                        "{side}Shoulder": ("{s}humerus",), "{side}Elbow": ("{s}radius",), "{side}Wrist": ("{s}wrist",),
                        "{side}Hand": ("{s}fingers",), "{side}Hip": ("{s}femur",), "{side}Knee": ("{s}tibia",),
                        "{side}Ankle": ("{s}foot",), "{side}Foot": ("{s}toes",)})


@dataclass(frozen=True, eq=False)
class _Arrays:
    """A clip with what retargeting reads of it computed once, on first use: its rest positions and the forward
    kinematics of all its frames (the T-pose frame some files add included; ``motion`` drops it). One is made per
    call of a public function here and handed down, so no helper calls back into bvh_clip's kinematics."""

    clip: BVHClip

    @cached_property
    def index(self) -> dict[str, int]:
        """joint name -> index in the clip."""
        return {n: i for i, n in enumerate(self.clip.names)}

    @cached_property
    def rest(self) -> np.ndarray:
        """Every joint's position at zero rotation (bvh_clip.rest_positions).  # (joint, 3)"""
        return rest_positions(self.clip)

    @cached_property
    def size(self) -> float:
        """The zero pose's largest extent, the scale "of zero length" is measured against (_without_empty_end)."""
        return max(float(np.ptp(self.rest, axis=0).max()), 1e-9)

    @cached_property
    def frames(self) -> tuple[np.ndarray, np.ndarray]:
        """Every frame's global rotations and positions, file axes.  # (frame, joint, 3, 3), (frame, joint, 3)"""
        return self.clip.forward_kinematics()

    @cached_property
    def motion(self) -> tuple[np.ndarray, np.ndarray]:
        """``frames`` without the added T-pose frame: the frames retargeted (views, never written to)."""
        rot, pos = self.frames
        return (rot[1:], pos[1:]) if _starts_with_tpose(self.clip) else (rot, pos)


def world_positions(clip: BVHClip, user_map: Mapping[str, str] | None = None,
                    rest_frame: RestFrame = "auto") -> np.ndarray:
    """The clip's joint positions in the studio's axes (Z up, facing +Y), in the file's units, its added T-pose
    frame dropped, as ``retarget`` sees them.  # (frame, joint, 3)"""
    arrays = _Arrays(clip)
    mapping, _, rest = _mapped(arrays, user_map, rest_frame)
    _, pos = arrays.motion
    world = _facing(rest, arrays.index[mapping["LeftHip"][1]], arrays.index[mapping["RightHip"][1]]) @ Y_UP_TO_Z_UP
    return pos @ world.T


@dataclass(frozen=True)
class Skeleton:
    """A known skeleton: its joint map as triples or as a name table, and joints only it has."""

    label: str
    triples: Mapping[str, Any] | None = None  # template joint -> (followed, bone start, bone end) or "inherit"
    names: Mapping[str, tuple[str, ...]] | None = None  # template joint -> BVH joints to try
    signature: tuple[str, ...] = ()


KNOWN_SKELETONS = (Skeleton("CMU cgspeed", triples=CMU_MAP, signature=CMU_SIGNATURE),
                   Skeleton("CMU cgspeed (subject 14)", triples=CMU_MAP_ALT, signature=CMU_SIGNATURE),
                   Skeleton("Mixamo", names=MIXAMO_NAMES), Skeleton("CMU ASF", names=CMU_ASF_NAMES))


def joint_map(clip: BVHClip, user_map: Mapping[str, str] | None = None, rest_frame: RestFrame = "auto") -> dict:
    """template joint -> (BVH joint whose rotation it follows, BVH bone start, BVH bone end), "inherit" (the neck),
    absent for the end joints (hands, feet).

    From ``user_map`` ({template joint: BVH joint}, keys among MAP_KEYS, every one of REQUIRED_KEYS) when given,
    else from the first of KNOWN_SKELETONS the file's joints satisfy. Raises BVHError naming the joints missing, a
    bone without length, or a rest pose (see rest_pose) that does not stand.
    """
    return _mapped(_Arrays(clip), user_map, rest_frame)[0]


def _mapped(arrays: _Arrays, user_map: Mapping[str, str] | None,
            rest_frame: RestFrame) -> tuple[dict, np.ndarray | None, np.ndarray]:
    """joint_map's map, checked, and the rest pose it was checked in (rest_pose's rotations and positions)."""
    mapping = _from_user_map(arrays, user_map) if user_map is not None else _known(arrays)
    rest_rot, rest = _rest_pose(arrays, mapping, rest_frame)
    _check_lengths(arrays.clip, mapping, rest)
    return mapping, rest_rot, rest


def _known(arrays: _Arrays) -> dict:
    clip = arrays.clip
    closest = []
    for order, skeleton in enumerate(KNOWN_SKELETONS):
        if skeleton.triples is not None:
            needed = {n for m in skeleton.triples.values() if m != "inherit" for n in m}
            missing = sorted(needed - set(clip.names))
        else:
            needed = {key: names for key, names in skeleton.names.items() if key in REQUIRED_KEYS}
            missing = [names[0] for names in needed.values() if _find(names, clip.names) is None]
        missing += [n for n in skeleton.signature if n not in clip.names and n not in missing]
        if not missing:
            return dict(skeleton.triples) if skeleton.triples is not None else _triples(arrays, skeleton.names)
        closest.append((len(missing) / (len(needed) + len(skeleton.signature)), order, missing))
    share, order, missing = min(closest)
    labels = ", ".join(s.label for s in KNOWN_SKELETONS)
    nearest = ("none names a joint of this file" if share == 1 else
               f"the closest, {KNOWN_SKELETONS[order].label}, lacks joints {missing}")
    raise BVHError(f"the skeleton matches no known naming ({labels}); {nearest}; give a joint map "
                   f"{{template joint: BVH joint}} naming a joint of the file for each of {list(REQUIRED_KEYS)}")


def _from_user_map(arrays: _Arrays, user_map: Mapping[str, str]) -> dict:
    clip = arrays.clip
    unknown = sorted(set(user_map) - set(MAP_KEYS))
    if unknown:
        raise BVHError(f"the joint map names unknown template joints {unknown}; its keys are {list(MAP_KEYS)}")
    absent = [k for k in REQUIRED_KEYS if k not in user_map]
    if absent:
        raise BVHError(f"the joint map lacks template joints {absent}; name a BVH joint for each of "
                       f"{list(REQUIRED_KEYS)} (and {list(END_KEYS)} where a joint has several children)")
    lacking = {k: v for k, v in user_map.items() if _find((v,), clip.names) is None}
    if lacking:
        raise BVHError(f"the joint map names joints the file lacks: {lacking}; its joints are "
                       f"{[n for n in clip.names if not n.endswith('_End')]}")
    return _triples(arrays, {k: (v,) for k, v in user_map.items()})


def _find(candidates, names) -> int | None:
    """Index of the first candidate among ``names``, exactly or after a namespace prefix ("mixamorig:Hips")."""
    for name in candidates:
        if name in names:
            return names.index(name)
        hits = [i for i, n in enumerate(names) if n.rsplit(":", 1)[-1] == name]
        if len(hits) == 1:
            return hits[0]
    return None


def _triples(arrays: _Arrays, table: Mapping[str, tuple[str, ...]]) -> dict:
    """A name table's triples: each rotating template joint follows the BVH joint just above its bone's end
    (the whole chain from the bone's start, e.g. every spine joint below the neck); the hips follow the root."""
    clip = arrays.clip
    found = {key: _find(names, clip.names) for key, names in table.items()}
    out: dict[str, tuple[str, str, str] | str] = {"Neck": "inherit"}
    for joint, end in BONE_END.items():
        start, stop = found[joint], found.get(end)
        if stop is None:
            stop = _only_child(clip, start, end)
        if not _below(clip.parents, stop, start):
            raise BVHError(f"{end} ({clip.names[stop]}) is not below {joint} ({clip.names[start]}) in the skeleton; "
                           "map them to a joint and one of its descendants")
        follow = start if joint == "Hips" else int(clip.parents[stop])
        out[joint] = _without_empty_end(clip, (follow, start, stop), arrays.size)
    return out


def _without_empty_end(clip: BVHClip, triple: tuple[int, int, int], size: float) -> tuple[str, str, str]:
    """The triple's names; where its bone ends at an End Site of zero length (Bandai Namco's set has only such), the
    bone points instead to the start's one child joint of some length, else along the bone into the start (the
    head continues the neck, the hand the forearm), still following the start's rotation. ``size``: the zero
    pose's extent (_Arrays.size), what "zero" is relative to."""
    follow, start, stop = triple
    if clip.channels[stop] or np.any(clip.parents == stop) or np.linalg.norm(clip.offsets[stop]) > 1e-6 * size:
        return clip.names[follow], clip.names[start], clip.names[stop]
    children = [int(c) for c in np.flatnonzero(clip.parents == start)
                if c != stop and np.linalg.norm(clip.offsets[c]) > 1e-6 * size]
    if len(children) == 1:
        return clip.names[start], clip.names[start], clip.names[children[0]]
    if clip.parents[start] < 0:
        raise BVHError(f"the bone of {clip.names[start]} ends at an End Site of zero length, and the root has no bone "
                       "into it; map a joint and a child of it some distance away")
    return clip.names[start], clip.names[int(clip.parents[start])], clip.names[start]


def _only_child(clip: BVHClip, joint: int, key: str) -> int:
    children = np.flatnonzero(clip.parents == joint)
    if len(children) != 1:
        raise BVHError(f"{clip.names[joint]} has {len(children)} children ({[clip.names[c] for c in children]}); "
                       f"name the joint its bone points to as {key!r} in the joint map")
    return int(children[0])


def _below(parents: np.ndarray, joint: int, ancestor: int) -> bool:
    while joint >= 0:
        joint = int(parents[joint])
        if joint == ancestor:
            return True
    return False


def _check_lengths(clip: BVHClip, mapping: dict, rest: np.ndarray) -> None:
    size = np.ptp(rest, axis=0).max()
    for joint, m in mapping.items():
        if m != "inherit" and np.linalg.norm(rest[clip.names.index(m[2])] - rest[clip.names.index(m[1])]) <= 1e-6 * size:
            raise BVHError(f"the bone of {joint} ({m[1]} -> {m[2]}) has no length in the rest pose, so it has no "
                           "direction; map the joints to a bone that does")


# The rest pose retargeting measures rotations from: None = every rotation channel at zero (the format's own), an
# int = that MOTION frame (0 = the first), "auto" = the zero pose where it stands upright along +Y, else frame 0.
# A clip that stands along +Y in most of its frames is Y up: the error then names a frame to take (rest_pose).
RestFrame = int | str | None


def rest_pose(clip: BVHClip, mapping: dict, rest_frame: RestFrame = "auto") -> tuple[np.ndarray | None, np.ndarray]:
    """The rest pose's global rotations (None for the zero pose: the identity) and joint positions, in the file's
    axes; BVHError when it does not stand upright along +Y, saying what would.  # (joint, 3, 3), (joint, 3)"""
    return _rest_pose(_Arrays(clip), mapping, rest_frame)


def _rest_pose(arrays: _Arrays, mapping: dict, rest_frame: RestFrame) -> tuple[np.ndarray | None, np.ndarray]:
    """rest_pose from the clip's arrays: the zero pose's positions or a frame's kinematics, computed once."""
    clip = arrays.clip
    if rest_frame is None or rest_frame == "auto":
        zero = arrays.rest
        if _stands(_up(arrays, mapping, zero[None]))[0]:
            return None, zero
        if rest_frame is None:
            raise BVHError(_not_upright(arrays, mapping, "the zero pose (every rotation channel at zero)", zero))
        return _frame_rest(arrays, mapping, 0, "frame 0 ('auto': the zero pose does not stand either)")
    if isinstance(rest_frame, str) or not 0 <= rest_frame < clip.data.shape[0]:
        raise BVHError(f"rest_frame {rest_frame!r} is none of None (the zero pose), 'auto' or a frame of the clip "
                       f"(0-{clip.data.shape[0] - 1})")
    return _frame_rest(arrays, mapping, int(rest_frame), f"frame {rest_frame}")


def _frame_rest(arrays: _Arrays, mapping: dict, k: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``k``'s global rotations and positions (of all the clip's frames, T-pose frame included) as the rest
    pose, or BVHError when it does not stand."""
    rot, pos = arrays.frames
    if not _stands(_up(arrays, mapping, pos[k:k + 1]))[0]:
        raise BVHError(_not_upright(arrays, mapping, what, pos[k]))
    return rot[k], pos[k]


UPRIGHT = 0.7  # a pose stands when its head is above its ankles within about 45 degrees of +Y (cos 45.6 = 0.7)


def _stands(up: np.ndarray) -> np.ndarray:
    """Whether each head-minus-ankles vector points up along +Y.  # (pose, 3) -> (pose,) bool"""
    return up[:, 1] > UPRIGHT * np.linalg.norm(up, axis=1)


def _up(arrays: _Arrays, mapping: dict, pos: np.ndarray) -> np.ndarray:
    """Head minus the ankles' midpoint per pose.  # (pose, joint, 3) -> (pose, 3)"""
    index = arrays.index
    head = mapping["Head"]
    head = head[2] if head[2] == head[0] else head[1]  # a bone continued from the neck ends at the head
    ankles = np.mean([pos[:, index[mapping[f"{side}Ankle"][1]]] for side in SIDES], axis=0)
    return pos[:, index[head]] - ankles


def _not_upright(arrays: _Arrays, mapping: dict, what: str, rest: np.ndarray) -> str:
    """Why the rest pose cannot be used, and the fix: a frame where the clip stands, or exporting it Y up."""
    up = _up(arrays, mapping, rest[None])[0]
    _, pos = arrays.frames
    ups = _up(arrays, mapping, pos)
    standing = np.flatnonzero(_stands(ups))
    head = f"the rest pose, {what}, is not upright along +Y (head minus ankles: {np.round(up, 2).tolist()})"
    if 2 * len(standing) >= len(ups):  # a clip that stands most of the time is Y up; its rest pose is not
        return (f"{head}, but the clip stands upright along +Y in {len(standing)} of its {len(ups)} frames: take the "
                f"rest pose from one of them, rest_frame: {int(standing[0])} (the first; 'auto' takes the zero pose "
                "where it stands, else frame 0)")
    median = np.median(ups, axis=0)
    axis = int(np.argmax(np.abs(median)))
    return (f"{head}, and the clip stands along +Y in {len(standing)} of its {len(ups)} frames only (its head is "
            "above its ankles along "
            f"{'+-'[int(median[axis] < 0)]}{'XYZ'[axis]}, median head minus ankles {np.round(median, 2).tolist()}); "
            "BVH files are Y up: export the clip Y up")


def retarget(clip: BVHClip, subject: Subject, *, fps: float = 30.0, n_frames: int | None = None,
             start_s: float = 0.0, label: str = "bvh", user_map: Mapping[str, str] | None = None,
             rest_frame: RestFrame = "auto") -> Motion:
    """``bvh``'s motion on the template body of ``subject``, resampled to ``fps``; ``user_map``: see joint_map;
    ``rest_frame``: the pose rotations are measured from (see rest_pose)."""
    arrays = _Arrays(clip)  # the clip's rest positions and kinematics, each computed once for all that follows
    index = arrays.index
    mapping, rest_rot, rest = _mapped(arrays, user_map, rest_frame)
    hip, knee, ankle = (mapping[j][1] for j in ("LeftHip", "LeftKnee", "LeftAnkle"))
    rot, pos = arrays.motion
    if rest_rot is not None:  # each joint's turn from the rest frame, in world axes: G_f G_r^T
        rot = rot @ np.swapaxes(rest_rot, -1, -2)
    world = _facing(rest, index[hip], index[mapping["RightHip"][1]]) @ Y_UP_TO_Z_UP
    rot = world @ rot @ world.T  # rest global rotations are now the identity
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
    root = pos[:, index[mapping["Hips"][1]]] * scale
    whole = n_frames is None and start_s == 0
    if whole:
        root[:, :2] -= root[:, :2].mean(axis=0)
    local, root = _resample(local, root, clip.fps, fps, n_frames, start_s)
    if not whole:  # a window of the clip: centre the frames filmed, not the whole clip (a travelling clip wanders off)
        root[:, :2] -= root[:, :2].mean(axis=0)
    root = root + np.array([0, 0, offsets[0, 2] - root[:, 2].mean()])
    root[:, 2] -= lowest_foot_point(local, root, subject).min()
    return Motion(local, root, fps, label)


def _starts_with_tpose(clip: BVHClip) -> bool:
    rotations = [i for i, c in enumerate(c for chans in clip.channels for c in chans) if c.endswith("rotation")]
    return clip.data.shape[0] > 1 and np.allclose(clip.data[0, rotations], 0.0)


def _facing(rest: np.ndarray, left_hip: int, right_hip: int) -> np.ndarray:
    """Rotation about Z that turns the BVH rest pose (its joint positions) to face +Y (its left side to -X)."""
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


def available_frames(clip: BVHClip, fps: float, start_s: float = 0.0) -> int:
    """Frames of ``bvh``'s motion (its added T-pose frame excluded) at ``fps`` from ``start_s`` on."""
    samples = clip.data.shape[0] - (1 if _starts_with_tpose(clip) else 0)
    return _available(samples, clip.fps, fps, start_s)


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
