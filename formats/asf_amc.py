"""The CMU motion capture database's own format: an Acclaim skeleton (ASF) and motion (AMC), read into a clip.

An ASF file gives the skeleton at rest: ``:units`` (a length multiplier, ``angle deg`` or ``rad``), the
``:root`` (the order of its AMC values, e.g. ``TX TY TZ RX RY RZ``, its rest ``position`` and
``orientation`` composed in the order ``axis`` names), each bone of ``:bonedata`` (``direction`` in world
axes, ``length``, ``axis ax ay az XYZ``: the orientation of its local axes, ``dof rx ry rz``: the order
of its AMC values) and the ``:hierarchy`` (a parent, then its children, per line). An AMC file gives,
per frame (a line holding the frame number), one line per bone: its name and its degrees of freedom's
values (the root's: translation, then rotation, as its ``order`` says).

Acclaim ASF/AMC specification (M. Schafer, 1994; CMU's notes on it): a bone's axes are
C = the ``axis`` angles (about X, Y, Z) applied in the order the token names, each about a fixed axis
(``XYZ``: C = Rz(az) Ry(ay) Rx(ax)); its motion M composes its dof rotations the same way in the order
``dof`` lists them (``rx ry rz``: M = Rz Ry Rx); relative to its parent, in the rest pose's world axes,
the bone turns by C M C⁻¹ (the spec's L = C⁻¹ M C B in row vectors). A bone starts where its parent ends
(the skeleton has no gaps) and ends at ``direction * length``.

The take is read straight into the clip a BVH file is parsed into (tasks/shared/bvh_clip.py; no BVH text is
written in between): a joint per bone at the bone's start, named after the bone, the root at its position, an End
Site ``<bone>_End`` at each leaf bone's end; every rotation as Z Y X channels. Lengths stay in the file's units
(the multiplier is kept, for information: retargeting removes the unit); angles follow ``:units`` (the AMC's own ``:DEGREES`` / ``:RADIANS`` where given). The
AMC file holds no frame rate: the caller gives it (the CMU database records at 120 fps).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.bvh_clip import BVHClip

AXES = "xyz"
ROTATIONS = ("rx", "ry", "rz")
TRANSLATIONS = ("tx", "ty", "tz")
CMU_FPS = 120.0
MAX_TRANSLATION_SIZES = 1e3  # a root farther than this many skeleton sizes from the origin is a broken value


class ASFError(ValueError):
    """An ASF or AMC text that cannot be parsed, or that does not fit its skeleton."""


@dataclass(frozen=True)
class Bone:
    name: str
    vector: np.ndarray  # (3,) direction * length, world axes at rest, the file's units
    axes: np.ndarray  # (3, 3) C: the bone's local axes in world axes at rest
    dof: tuple[str, ...]  # the order of its AMC values: "rx" "ry" "rz" (the root: also "tx" "ty" "tz")


@dataclass(frozen=True)
class ASF:
    bones: tuple[Bone, ...]  # the root first, then every bone after its parent
    parents: np.ndarray  # (bone,) -1 for the root
    position: np.ndarray  # (3,) the root's rest position
    angle_unit: str  # "deg" | "rad"
    length_unit: float  # the file's length multiplier (CMU: 0.45, i.e. lengths in inches / 0.45)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bones)


def _lines(text: str) -> list[tuple[int, list[str]]]:
    """(line number, tokens) of every non-empty line; '#' starts a comment, commas and parentheses are blanks."""
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        tokens = line.split("#", 1)[0].replace(",", " ").replace("(", " ").replace(")", " ").split()
        if tokens:
            out.append((n, tokens))
    return out


def _sections(text: str) -> dict[str, list[tuple[int, list[str]]]]:
    """keyword (":root" -> "root") -> its lines, the keyword line's own tokens first when it has any."""
    sections: dict[str, list] = {}
    current = None
    for n, tokens in _lines(text):
        if tokens[0].startswith(":"):
            current = tokens[0][1:].lower()
            sections[current] = [(n, tokens[1:])] if len(tokens) > 1 else []
        elif current is None:
            raise ASFError(f"line {n}: {tokens[0]!r} before any ':keyword' section")
        else:
            sections[current].append((n, tokens))
    return sections


def _numbers(n: int, tokens: list[str], count: int, what: str) -> np.ndarray:
    try:
        values = np.array([float(t) for t in tokens[:count]])
    except ValueError:
        raise ASFError(f"line {n}: {what} must be {count} numbers, found {tokens[:count]}") from None
    if len(values) != count:
        raise ASFError(f"line {n}: {what} must be {count} numbers, found {tokens}")
    if not np.isfinite(values).all():
        raise ASFError(f"line {n}: {what} must be finite numbers, found {tokens[:count]}; fix the file's export")
    return values


def _order(n: int, token: str, what: str) -> str:
    order = token.lower()
    if sorted(order) != list(AXES):
        raise ASFError(f"line {n}: {what} must name the axes X, Y and Z once each (e.g. XYZ), found {token!r}")
    return order


def _turn(angles_xyz: np.ndarray, order: str) -> np.ndarray:
    """Rotations about X, Y, Z by ``angles_xyz`` (radians) applied in ``order``, each about a fixed axis.
    (..., 3) -> (..., 3, 3)"""
    angles = np.asarray(angles_xyz)[..., [AXES.index(a) for a in order]]
    return Rotation.from_euler(order, angles.reshape(-1, 3)).as_matrix().reshape(angles.shape[:-1] + (3, 3))


def parse_asf(text: str) -> ASF:
    """Parse ASF text; raise ASFError naming the line on malformed input."""
    sections = _sections(text)
    for needed in ("root", "bonedata", "hierarchy"):
        if needed not in sections:
            raise ASFError(f"the ASF has no ':{needed}' section")
    angle_unit, length_unit = _units(sections.get("units", []))
    scale = np.pi / 180 if angle_unit == "deg" else 1.0
    root, position = _root(sections["root"], scale)
    bones = {b.name: b for b in _bonedata(sections["bonedata"], scale)}
    children = _hierarchy(sections["hierarchy"], set(bones))
    order, parents = ["root"], [-1]
    for i, name in enumerate(order):  # breadth first: every bone after its parent
        for child in children.get(name, ()):
            order.append(child)
            parents.append(i)
    unplaced = sorted(set(bones) - set(order))
    if unplaced:
        raise ASFError(f"bones {unplaced} are not under the root in the :hierarchy; give each one a parent")
    return ASF((root,) + tuple(bones[n] for n in order[1:]), np.array(parents), position, angle_unit, length_unit)


def _units(lines) -> tuple[str, float]:
    angle, length = "deg", 1.0
    for n, tokens in lines:
        key = tokens[0].lower()
        if key == "angle":
            angle = tokens[1].lower() if len(tokens) > 1 else ""
            if angle not in ("deg", "rad"):
                raise ASFError(f"line {n}: units angle must be deg or rad, found {tokens[1:]}")
        elif key == "length":
            length = float(_numbers(n, tokens[1:], 1, "units length")[0])
    return angle, length


def _root(lines, scale: float) -> tuple[Bone, np.ndarray]:
    fields = {tokens[0].lower(): (n, tokens[1:]) for n, tokens in lines}
    n, order = fields.get("order", (0, ["TX", "TY", "TZ", "RX", "RY", "RZ"]))
    dof = tuple(t.lower() for t in order)
    if not set(dof) <= set(ROTATIONS + TRANSLATIONS) or len(set(dof)) != len(dof):
        raise ASFError(f"line {n}: the root's order must list TX TY TZ RX RY RZ (each at most once), found {order}")
    n, axis = fields.get("axis", (0, ["XYZ"]))
    axes_order = _order(n, axis[0] if axis else "", "the root's axis")
    position = _numbers(*fields.get("position", (0, ["0", "0", "0"])), 3, "the root's position")
    n, orientation = fields.get("orientation", (0, ["0", "0", "0"]))
    axes = _turn(_numbers(n, orientation, 3, "the root's orientation") * scale, axes_order)
    return Bone("root", np.zeros(3), axes, dof), position


def _bonedata(lines, scale: float) -> list[Bone]:
    bones, fields, start = [], None, 0
    for n, tokens in lines:
        key = tokens[0].lower()
        if key == "begin":
            fields, start = {}, n
        elif key == "end":
            if fields is None:
                raise ASFError(f"line {n}: 'end' without 'begin' in :bonedata")
            bones.append(_bone(fields, start, scale))
            fields = None
        elif fields is None:
            raise ASFError(f"line {n}: {tokens[0]!r} outside a begin/end block in :bonedata")
        elif key in ("id", "name", "direction", "length", "axis", "dof", "limits", "bodymass", "cofmass"):
            fields[key] = (n, tokens[1:])
        elif "limits" not in fields:  # further lines of limits carry numbers only
            raise ASFError(f"line {n}: unknown bone field {tokens[0]!r}")
    if fields is not None:
        raise ASFError(f"line {start}: a :bonedata block is not closed by 'end'")
    if not bones:
        raise ASFError("the ASF's :bonedata holds no bone")
    return bones


def _bone(fields: dict, start: int, scale: float) -> Bone:
    for needed in ("name", "direction", "length", "axis"):
        if needed not in fields:
            raise ASFError(f"line {start}: the bone has no {needed!r}")
    name = fields["name"][1][0]
    n, direction = fields["direction"]
    vector = _numbers(n, direction, 3, f"bone {name}'s direction")
    if not np.linalg.norm(vector) > 0:
        raise ASFError(f"line {n}: bone {name}'s direction is zero; give the unit vector it points along")
    length = float(_numbers(*fields["length"], 1, f"bone {name}'s length")[0])
    n, axis = fields["axis"]
    axes = _turn(_numbers(n, axis, 3, f"bone {name}'s axis") * scale, _order(n, axis[3] if len(axis) > 3 else "",
                                                                                f"bone {name}'s axis order"))
    n, dof = fields.get("dof", (start, []))
    dof = tuple(d.lower() for d in dof)
    if not set(dof) <= set(ROTATIONS) or len(set(dof)) != len(dof):
        raise ASFError(f"line {n}: bone {name}'s dof {list(dof)}: only rotations rx ry rz (each at most once) are "
                       "supported on bones; translations and 'l' belong to no skeleton this reads")
    return Bone(name, vector / np.linalg.norm(vector) * length, axes, dof)


def _hierarchy(lines, names: set[str]) -> dict[str, list[str]]:
    children: dict[str, list[str]] = {}
    seen: set[str] = set()
    for n, tokens in lines:
        if tokens[0].lower() in ("begin", "end"):
            continue
        for name in tokens:
            if name != "root" and name not in names:
                raise ASFError(f"line {n}: the :hierarchy names {name!r}, which :bonedata does not define")
        twice = seen & set(tokens[1:])
        if twice or "root" in tokens[1:]:
            raise ASFError(f"line {n}: {sorted(twice) or ['root']} already has a parent in the :hierarchy")
        seen |= set(tokens[1:])
        children.setdefault(tokens[0], []).extend(tokens[1:])
    return children


def parse_amc(text: str, asf: ASF) -> np.ndarray:
    """The AMC's values in ``asf``'s order (each bone's dof, bones in asf.bones order), angles in radians.
    # (frame, value)"""
    width = {b.name: len(b.dof) for b in asf.bones}
    columns = dict(zip(width, np.cumsum([0] + list(width.values()))[:-1]))
    total = sum(width.values())
    unit, frames, filled, frame_numbers = asf.angle_unit, [], [], []
    limit = MAX_TRANSLATION_SIZES * max(_size(asf), 1e-9)
    for n, tokens in _lines(text):
        if tokens[0].startswith(":"):
            flag = tokens[0].lower()
            unit = {":degrees": "deg", ":radians": "rad"}.get(flag, unit)
        elif len(tokens) == 1 and tokens[0].isdigit():
            frame_numbers.append(tokens[0])
            frames.append(np.zeros(total))
            filled.append(set())
        elif not frames:
            raise ASFError(f"AMC line {n}: {tokens[0]!r} before the first frame number")
        elif tokens[0] not in width:
            raise ASFError(f"AMC line {n}: bone {tokens[0]!r} is not in the skeleton; is this the take's ASF?")
        else:
            name = tokens[0]
            values = _amc_values(n, tokens, asf, width[name], frame_numbers[-1], limit)
            frames[-1][columns[name]:columns[name] + width[name]] = values
            filled[-1].add(name)
    if not frames:
        raise ASFError("the AMC holds no frame")
    moving = {name for name, w in width.items() if w}
    for k, done in enumerate(filled):
        if moving - done:
            raise ASFError(f"AMC frame {k + 1} lacks bones {sorted(moving - done)}")
    values = np.array(frames)  # (frame, value)
    if unit == "deg":
        angles = [columns[b.name] + i for b in asf.bones for i, d in enumerate(b.dof) if d in ROTATIONS]
        values[:, angles] = np.radians(values[:, angles])
    return values


def _size(asf: ASF) -> float:
    """The rest skeleton's largest extent along an axis, in the file's units."""
    ends = np.zeros((len(asf.bones), 3))
    for j, bone in enumerate(asf.bones):  # parents come first
        ends[j] = bone.vector + (ends[asf.parents[j]] if asf.parents[j] >= 0 else 0)
    return float(np.ptp(np.vstack([ends, np.zeros(3)]), axis=0).max())


def _amc_values(n: int, tokens: list[str], asf: ASF, count: int, frame: str, limit: float) -> np.ndarray:
    """A bone line's values, each finite and (a translation) within ``limit`` of the origin, else ASFError naming
    the line, the AMC frame, the bone and the degree of freedom."""
    name = tokens[0]
    try:
        values = np.array([float(t) for t in tokens[1:]])
    except ValueError:
        raise ASFError(f"AMC line {n}: bone {name}'s values must be {count} numbers, found {tokens[1:]}") from None
    if len(values) != count:
        raise ASFError(f"AMC line {n}: bone {name} has {count} dof in the ASF, found {len(values)} values")
    dof = next(b.dof for b in asf.bones if b.name == name)
    for value, d in zip(values.tolist(), dof):
        if not np.isfinite(value) or (d in TRANSLATIONS and abs(value) > limit):
            bound = (f"finite and within {limit:g} of the origin ({MAX_TRANSLATION_SIZES:g} times the skeleton's "
                     "size)" if d in TRANSLATIONS else "a finite angle")
            raise ASFError(f"AMC line {n}: frame {frame}, bone {name}, dof {d} is {value!r}: it must be {bound}; "
                           "re-export the take, or cut the broken frames out")
    return values


def bone_rotations(asf: ASF, values: np.ndarray) -> np.ndarray:
    """Each bone's rotation relative to its parent in the rest pose's world axes, C M C⁻¹ (module docstring).
    (frame, value) -> (frame, bone, 3, 3)"""
    out = np.tile(np.eye(3), (values.shape[0], len(asf.bones), 1, 1))
    col = 0
    for j, bone in enumerate(asf.bones):
        rotations = [(i, d[1]) for i, d in enumerate(bone.dof) if d in ROTATIONS]
        if rotations:
            order = "".join(axis for _, axis in rotations)
            motion = Rotation.from_euler(order, values[:, [col + i for i, _ in rotations]]).as_matrix()  # M
            out[:, j] = bone.axes @ motion @ bone.axes.T
        col += len(bone.dof)
    return out


def root_translation(asf: ASF, values: np.ndarray) -> np.ndarray:
    """The root's position per frame: its AMC translation where the root has one, else its rest position.
    (frame, value) -> (frame, 3)"""
    out = np.tile(asf.position, (values.shape[0], 1))
    for i, d in enumerate(asf.bones[0].dof):
        if d in TRANSLATIONS:
            out[:, TRANSLATIONS.index(d)] = values[:, i]
    return out


def to_clip(asf: ASF, values: np.ndarray, fps: float = CMU_FPS) -> BVHClip:
    """The take as a clip: a joint per bone at its start, End Sites at the leaves, Z Y X rotation channels."""
    if not fps > 0:
        raise ASFError(f"the AMC's frame rate must be positive, got {fps}")
    names, parents, offsets, channels, index = [], [], [], [], {}
    for j, bone in enumerate(asf.bones):
        parent = int(asf.parents[j])
        index[j] = len(names)
        names.append(bone.name)
        parents.append(index[parent] if parent >= 0 else -1)
        offsets.append(asf.bones[parent].vector if parent >= 0 else asf.position)
        channels.append((("Xposition", "Yposition", "Zposition") if parent < 0 else ()) +
                        ("Zrotation", "Yrotation", "Xrotation"))
        if not np.any(asf.parents == j):
            names.append(f"{bone.name}_End")
            parents.append(index[j])
            offsets.append(bone.vector)
            channels.append(())
    rotations = bone_rotations(asf, values)  # (frame, bone, 3, 3)
    with warnings.catch_warnings():  # at gimbal lock scipy picks one of the equal decompositions: still exact
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        euler = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_euler("ZYX", degrees=True)
    data = np.concatenate([root_translation(asf, values), euler.reshape(values.shape[0], -1)], axis=1)
    return BVHClip(tuple(names), np.array(parents), np.array(offsets, float), tuple(channels), 1.0 / fps, data)


def read_asf_amc(asf_text: str, amc_text: str, fps: float = CMU_FPS) -> BVHClip:
    """An ASF skeleton and an AMC take of it as a clip at ``fps`` (the AMC holds no frame rate)."""
    asf = parse_asf(asf_text)
    return to_clip(asf, parse_amc(amc_text, asf), fps)
