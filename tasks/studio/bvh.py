"""BVH motion: parsing, forward kinematics, and retargeting onto the template body.

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
database's ASF bones (``CMU_ASF_NAMES``, for tasks/studio/asf_amc.py) or a map the user gives
(``{template joint: BVH joint}``, see :func:`joint_map`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any, Mapping

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
# The CMU database's ASF bones, each a joint at the bone's start (tasks/studio/asf_amc.py).
CMU_ASF_NAMES = _sided({"Hips": ("root",), "SpineBase": ("upperback",), "Neck": ("lowerneck",), "Head": ("head",),
                        "{side}Shoulder": ("{s}humerus",), "{side}Elbow": ("{s}radius",), "{side}Wrist": ("{s}wrist",),
                        "{side}Hand": ("{s}fingers",), "{side}Hip": ("{s}femur",), "{side}Knee": ("{s}tibia",),
                        "{side}Ankle": ("{s}foot",), "{side}Foot": ("{s}toes",)})


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

    def count(tok, line, what):
        """A whole number of ``what`` (a CHANNELS count, Frames), at most the tokens the text holds."""
        value = number(tok, line)
        if not (np.isfinite(value) and value >= 0 and value == int(value)):
            raise BVHError(f"line {line}: the number of {what} must be a whole number, found {tok!r}")
        value = int(value)
        if value > len(tokens):
            raise BVHError(f"line {line}: {value} {what}, more than the file holds ({len(tokens)} values in all)")
        return value

    take("HIERARCHY")
    tok, line = take()
    while tok in ("ROOT", "JOINT", "End"):
        name = take()[0]
        if tok != "ROOT" and not stack:
            raise BVHError(f"line {line}: {tok} outside any joint")
        if tok == "End":
            name = f"{names[stack[-1]]}_End"
        names.append(name)
        parents.append(stack[-1] if stack else -1)
        take("{")
        take("OFFSET")
        offsets.append([number(*take(what="an OFFSET number")) for _ in range(3)])
        chans: tuple[str, ...] = ()
        if tok != "End":
            take("CHANNELS")
            count_tok, count_line = take()
            chans = tuple(take()[0] for _ in range(count(count_tok, count_line, "channels")))
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
    n_frames = count(*take(), "frames")
    take("Frame")
    take("Time:")
    frame_time = number(*take())
    rest = list(it)
    values = np.array([number(tok, ln) for tok, ln in rest])
    width = sum(len(c) for c in channels)
    if not (n_frames > 0 and MIN_FRAME_TIME_S <= frame_time <= MAX_FRAME_TIME_S):
        raise BVHError(f"Frames ({n_frames}) must be positive and Frame Time ({frame_time}) a time in seconds from "
                       f"{MIN_FRAME_TIME_S:g} to {MAX_FRAME_TIME_S:g}")
    if not width:
        raise BVHError("no joint has CHANNELS: the clip has no motion; export it with its channels")
    if values.size != n_frames * width:
        raise BVHError(f"MOTION holds {values.size} numbers, expected Frames {n_frames} x {width} channels")
    clip = BVH(tuple(names), np.array(parents), np.array(offsets, float), tuple(channels), frame_time,
               values.reshape(n_frames, width))
    _check_numbers(clip, [ln for _, ln in rest])
    return clip


MIN_FRAME_TIME_S, MAX_FRAME_TIME_S = 1e-6, 3600.0  # a Frame Time outside these is no sampling rate (a broken file)
# A translation farther than this many times the skeleton's own size from the origin is no motion capture (a body
# of 1.7 m: 1.7 km); unit-free, so inches, centimetres and millimetres alike. Rotations beyond MAX_ANGLE_DEG (278
# turns) are a broken export, not unwrapped Euler angles.
MAX_TRANSLATION_SIZES = 1e3
MAX_ANGLE_DEG = 1e5


def _check_numbers(clip: BVH, lines: list[int]) -> None:
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


def format_bvh(clip: BVH) -> str:
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


def world_positions(bvh: BVH, user_map: Mapping[str, str] | None = None, rest_frame: RestFrame = "auto") -> np.ndarray:
    """The clip's joint positions in the studio's axes (Z up, facing +Y), in the file's units, its added T-pose
    frame dropped, as ``retarget`` sees them.  # (frame, joint, 3)"""
    mapping = joint_map(bvh, user_map, rest_frame)
    index = {n: i for i, n in enumerate(bvh.names)}
    data = bvh.data[1:] if _starts_with_tpose(bvh) else bvh.data
    _, pos = BVH(bvh.names, bvh.parents, bvh.offsets, bvh.channels, bvh.frame_time, data).forward_kinematics()
    _, rest = rest_pose(bvh, mapping, rest_frame)
    world = _facing(rest, index[mapping["LeftHip"][1]], index[mapping["RightHip"][1]]) @ Y_UP_TO_Z_UP
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


def joint_map(bvh: BVH, user_map: Mapping[str, str] | None = None, rest_frame: RestFrame = "auto") -> dict:
    """template joint -> (BVH joint whose rotation it follows, BVH bone start, BVH bone end), "inherit" (the neck),
    absent for the end joints (hands, feet).

    From ``user_map`` ({template joint: BVH joint}, keys among MAP_KEYS, every one of REQUIRED_KEYS) when given,
    else from the first of KNOWN_SKELETONS the file's joints satisfy. Raises BVHError naming the joints missing, a
    bone without length, or a rest pose (see rest_pose) that does not stand.
    """
    mapping = _from_user_map(bvh, user_map) if user_map is not None else _known(bvh)
    _, rest = rest_pose(bvh, mapping, rest_frame)
    _check_lengths(bvh, mapping, rest)
    return mapping


def _known(bvh: BVH) -> dict:
    closest = []
    for order, skeleton in enumerate(KNOWN_SKELETONS):
        if skeleton.triples is not None:
            needed = {n for m in skeleton.triples.values() if m != "inherit" for n in m}
            missing = sorted(needed - set(bvh.names))
        else:
            needed = {key: names for key, names in skeleton.names.items() if key in REQUIRED_KEYS}
            missing = [names[0] for names in needed.values() if _find(names, bvh.names) is None]
        missing += [n for n in skeleton.signature if n not in bvh.names and n not in missing]
        if not missing:
            return dict(skeleton.triples) if skeleton.triples is not None else _triples(bvh, skeleton.names)
        closest.append((len(missing) / (len(needed) + len(skeleton.signature)), order, missing))
    share, order, missing = min(closest)
    labels = ", ".join(s.label for s in KNOWN_SKELETONS)
    nearest = ("none names a joint of this file" if share == 1 else
               f"the closest, {KNOWN_SKELETONS[order].label}, lacks joints {missing}")
    raise BVHError(f"the skeleton matches no known naming ({labels}); {nearest}; give a joint map "
                   f"{{template joint: BVH joint}} naming a joint of the file for each of {list(REQUIRED_KEYS)}")


def _from_user_map(bvh: BVH, user_map: Mapping[str, str]) -> dict:
    unknown = sorted(set(user_map) - set(MAP_KEYS))
    if unknown:
        raise BVHError(f"the joint map names unknown template joints {unknown}; its keys are {list(MAP_KEYS)}")
    absent = [k for k in REQUIRED_KEYS if k not in user_map]
    if absent:
        raise BVHError(f"the joint map lacks template joints {absent}; name a BVH joint for each of "
                       f"{list(REQUIRED_KEYS)} (and {list(END_KEYS)} where a joint has several children)")
    lacking = {k: v for k, v in user_map.items() if _find((v,), bvh.names) is None}
    if lacking:
        raise BVHError(f"the joint map names joints the file lacks: {lacking}; its joints are "
                       f"{[n for n in bvh.names if not n.endswith('_End')]}")
    return _triples(bvh, {k: (v,) for k, v in user_map.items()})


def _find(candidates, names) -> int | None:
    """Index of the first candidate among ``names``, exactly or after a namespace prefix ("mixamorig:Hips")."""
    for name in candidates:
        if name in names:
            return names.index(name)
        hits = [i for i, n in enumerate(names) if n.rsplit(":", 1)[-1] == name]
        if len(hits) == 1:
            return hits[0]
    return None


def _triples(bvh: BVH, table: Mapping[str, tuple[str, ...]]) -> dict:
    """A name table's triples: each rotating template joint follows the BVH joint just above its bone's end
    (the whole chain from the bone's start, e.g. every spine joint below the neck); the hips follow the root."""
    found = {key: _find(names, bvh.names) for key, names in table.items()}
    out: dict[str, tuple[str, str, str] | str] = {"Neck": "inherit"}
    for joint, end in BONE_END.items():
        start, stop = found[joint], found.get(end)
        if stop is None:
            stop = _only_child(bvh, start, end)
        if not _below(bvh.parents, stop, start):
            raise BVHError(f"{end} ({bvh.names[stop]}) is not below {joint} ({bvh.names[start]}) in the skeleton; "
                           "map them to a joint and one of its descendants")
        follow = start if joint == "Hips" else int(bvh.parents[stop])
        out[joint] = _without_empty_end(bvh, (follow, start, stop))
    return out


def _without_empty_end(bvh: BVH, triple: tuple[int, int, int]) -> tuple[str, str, str]:
    """The triple's names; where its bone ends at an End Site of zero length (Bandai Namco's set has only such), the
    bone points instead to the start's one child joint of some length, else along the bone into the start (the
    head continues the neck, the hand the forearm), still following the start's rotation."""
    follow, start, stop = triple
    size = max(float(np.ptp(rest_positions(bvh), axis=0).max()), 1e-9)
    if bvh.channels[stop] or np.any(bvh.parents == stop) or np.linalg.norm(bvh.offsets[stop]) > 1e-6 * size:
        return bvh.names[follow], bvh.names[start], bvh.names[stop]
    children = [int(c) for c in np.flatnonzero(bvh.parents == start)
                if c != stop and np.linalg.norm(bvh.offsets[c]) > 1e-6 * size]
    if len(children) == 1:
        return bvh.names[start], bvh.names[start], bvh.names[children[0]]
    if bvh.parents[start] < 0:
        raise BVHError(f"the bone of {bvh.names[start]} ends at an End Site of zero length, and the root has no bone "
                       "into it; map a joint and a child of it some distance away")
    return bvh.names[start], bvh.names[int(bvh.parents[start])], bvh.names[start]


def _only_child(bvh: BVH, joint: int, key: str) -> int:
    children = np.flatnonzero(bvh.parents == joint)
    if len(children) != 1:
        raise BVHError(f"{bvh.names[joint]} has {len(children)} children ({[bvh.names[c] for c in children]}); "
                       f"name the joint its bone points to as {key!r} in the joint map")
    return int(children[0])


def _below(parents: np.ndarray, joint: int, ancestor: int) -> bool:
    while joint >= 0:
        joint = int(parents[joint])
        if joint == ancestor:
            return True
    return False


def rest_positions(bvh: BVH) -> np.ndarray:
    """Every joint's position with all rotations at zero, the root at its OFFSET, in the file's axes and units."""
    rest = np.zeros((len(bvh.names), 3))  # (joint, 3); parents come before their children in a BVH
    for j, parent in enumerate(bvh.parents):
        rest[j] = bvh.offsets[j] + (rest[parent] if parent >= 0 else 0)
    return rest


def _check_lengths(bvh: BVH, mapping: dict, rest: np.ndarray) -> None:
    size = np.ptp(rest, axis=0).max()
    for joint, m in mapping.items():
        if m != "inherit" and np.linalg.norm(rest[bvh.names.index(m[2])] - rest[bvh.names.index(m[1])]) <= 1e-6 * size:
            raise BVHError(f"the bone of {joint} ({m[1]} -> {m[2]}) has no length in the rest pose, so it has no "
                           "direction; map the joints to a bone that does")


# The rest pose retargeting measures rotations from: None = every rotation channel at zero (the format's own), an
# int = that MOTION frame (0 = the first), "auto" = the zero pose where it stands upright along +Y, else frame 0.
# A clip that stands along +Y in most of its frames is Y up: the error then names a frame to take (rest_pose).
RestFrame = int | str | None


def rest_pose(bvh: BVH, mapping: dict, rest_frame: RestFrame = "auto") -> tuple[np.ndarray | None, np.ndarray]:
    """The rest pose's global rotations (None for the zero pose: the identity) and joint positions, in the file's
    axes; BVHError when it does not stand upright along +Y, saying what would.  # (joint, 3, 3), (joint, 3)"""
    if rest_frame is None or rest_frame == "auto":
        zero = rest_positions(bvh)
        if _stands(_up(bvh, mapping, zero[None]))[0]:
            return None, zero
        if rest_frame is None:
            raise BVHError(_not_upright(bvh, mapping, "the zero pose (every rotation channel at zero)", zero))
        return _frame_rest(bvh, mapping, 0, "frame 0 ('auto': the zero pose does not stand either)")
    if isinstance(rest_frame, str) or not 0 <= rest_frame < bvh.data.shape[0]:
        raise BVHError(f"rest_frame {rest_frame!r} is none of None (the zero pose), 'auto' or a frame of the clip "
                       f"(0-{bvh.data.shape[0] - 1})")
    return _frame_rest(bvh, mapping, int(rest_frame), f"frame {rest_frame}")


def _frame_rest(bvh: BVH, mapping: dict, k: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``k``'s global rotations and positions as the rest pose, or BVHError when it does not stand."""
    rot, pos = BVH(bvh.names, bvh.parents, bvh.offsets, bvh.channels, bvh.frame_time,
                   bvh.data[k:k + 1]).forward_kinematics()
    if not _stands(_up(bvh, mapping, pos))[0]:
        raise BVHError(_not_upright(bvh, mapping, what, pos[0]))
    return rot[0], pos[0]


UPRIGHT = 0.7  # a pose stands when its head is above its ankles within about 45 degrees of +Y (cos 45.6 = 0.7)


def _stands(up: np.ndarray) -> np.ndarray:
    """Whether each head-minus-ankles vector points up along +Y.  # (pose, 3) -> (pose,) bool"""
    return up[:, 1] > UPRIGHT * np.linalg.norm(up, axis=1)


def _up(bvh: BVH, mapping: dict, pos: np.ndarray) -> np.ndarray:
    """Head minus the ankles' midpoint per pose.  # (pose, joint, 3) -> (pose, 3)"""
    index = {n: i for i, n in enumerate(bvh.names)}
    head = mapping["Head"]
    head = head[2] if head[2] == head[0] else head[1]  # a bone continued from the neck ends at the head
    ankles = np.mean([pos[:, index[mapping[f"{side}Ankle"][1]]] for side in SIDES], axis=0)
    return pos[:, index[head]] - ankles


def _not_upright(bvh: BVH, mapping: dict, what: str, rest: np.ndarray) -> str:
    """Why the rest pose cannot be used, and the fix: a frame where the clip stands, or exporting it Y up."""
    up = _up(bvh, mapping, rest[None])[0]
    _, pos = bvh.forward_kinematics()
    ups = _up(bvh, mapping, pos)
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


def retarget(bvh: BVH, subject: Subject, *, fps: float = 30.0, n_frames: int | None = None,
             start_s: float = 0.0, label: str = "bvh", user_map: Mapping[str, str] | None = None,
             rest_frame: RestFrame = "auto") -> Motion:
    """``bvh``'s motion on the template body of ``subject``, resampled to ``fps``; ``user_map``: see joint_map;
    ``rest_frame``: the pose rotations are measured from (see rest_pose)."""
    index = {n: i for i, n in enumerate(bvh.names)}
    mapping = joint_map(bvh, user_map, rest_frame)
    hip, knee, ankle = (mapping[j][1] for j in ("LeftHip", "LeftKnee", "LeftAnkle"))
    data = bvh.data[1:] if _starts_with_tpose(bvh) else bvh.data
    rot, pos = BVH(bvh.names, bvh.parents, bvh.offsets, bvh.channels, bvh.frame_time, data).forward_kinematics()
    rest_rot, rest = rest_pose(bvh, mapping, rest_frame)
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
    local, root = _resample(local, root, bvh.fps, fps, n_frames, start_s)
    if not whole:  # a window of the clip: centre the frames filmed, not the whole clip (a travelling clip wanders off)
        root[:, :2] -= root[:, :2].mean(axis=0)
    root = root + np.array([0, 0, offsets[0, 2] - root[:, 2].mean()])
    root[:, 2] -= lowest_foot_point(local, root, subject).min()
    return Motion(local, root, fps, label)


def _starts_with_tpose(bvh: BVH) -> bool:
    rotations = [i for i, c in enumerate(c for chans in bvh.channels for c in chans) if c.endswith("rotation")]
    return bvh.data.shape[0] > 1 and np.allclose(bvh.data[0, rotations], 0.0)


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
