"""Small motion files written by hand for the tests: a Mixamo-style BVH clip (and, below, an ASF/AMC pair and a
clip shaped like Bandai Namco's research set)."""

from __future__ import annotations

import re
import warnings

import numpy as np
from scipy.spatial.transform import Rotation

# A Mixamo-style skeleton, written by hand: zero rotation is a T-pose (arms along +-X), Y up, facing +Z, centimetres.
# Its bones point where the template's do at rest (the neck leans back 1 in 27, the foot runs 11.5 forward, 3 down).
HIERARCHY = """\
HIERARCHY
ROOT mixamorig:Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT mixamorig:Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT mixamorig:Spine1
    {
      OFFSET 0 13.5 -0.5
      CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT mixamorig:Neck
      {
        OFFSET 0 13.5 -0.5
        CHANNELS 3 Zrotation Xrotation Yrotation
        JOINT mixamorig:Head
        {
          OFFSET 0 9 0.5
          CHANNELS 3 Zrotation Xrotation Yrotation
          End Site
          {
            OFFSET 0 18 0
          }
        }
      }
{arms}
    }
  }
{legs}
}
"""
ARM = """\
      JOINT mixamorig:{side}Shoulder
      {{
        OFFSET {x7} 12 -0.5
        CHANNELS 3 Zrotation Xrotation Yrotation
        JOINT mixamorig:{side}Arm
        {{
          OFFSET {x10} 0 0
          CHANNELS 3 Zrotation Xrotation Yrotation
          JOINT mixamorig:{side}ForeArm
          {{
            OFFSET {x28} 0 0
            CHANNELS 3 Zrotation Xrotation Yrotation
            JOINT mixamorig:{side}Hand
            {{
              OFFSET {x25} 0 0
              CHANNELS 3 Zrotation Xrotation Yrotation
              JOINT mixamorig:{side}HandThumb1
              {{
                OFFSET {x3} -1 3
                CHANNELS 3 Zrotation Xrotation Yrotation
                End Site
                {{
                  OFFSET {x3} 0 2
                }}
              }}
              JOINT mixamorig:{side}HandMiddle1
              {{
                OFFSET {x10} 0 0
                CHANNELS 3 Zrotation Xrotation Yrotation
                End Site
                {{
                  OFFSET {x3} 0 0
                }}
              }}
            }}
          }}
        }}
      }}"""
LEG = """\
  JOINT mixamorig:{side}UpLeg
  {{
    OFFSET {x9} -6 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT mixamorig:{side}Leg
    {{
      OFFSET 0 -45 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT mixamorig:{side}Foot
      {{
        OFFSET 0 -43 0
        CHANNELS 3 Zrotation Xrotation Yrotation
        JOINT mixamorig:{side}ToeBase
        {{
          OFFSET 0 -3 11.5
          CHANNELS 3 Zrotation Xrotation Yrotation
          End Site
          {{
            OFFSET 0 0 5
          }}
        }}
      }}
    }}
  }}"""


def _sides(template: str) -> str:
    return "\n".join(template.format(side=side, **{f"x{k}": k * sign for k in (3, 7, 9, 10, 25, 28)})
                     for side, sign in (("Left", 1), ("Right", -1)))


# Frames: the T-pose a clip often starts with (dropped), the T-pose, the left arm raised 90 degrees sideways, the
# right knee bent 90 degrees, and the hips turned 90 degrees to the left with the root 44 cm forward and the left
# elbow bent 90 degrees forward. Values per joint: Zrotation Xrotation Yrotation (degrees); root position in cm.
FRAMES = [{}, {}, {"LeftArm": (90, 0, 0)}, {"RightLeg": (0, 90, 0)},
          {"Hips": (0, 0, 90), "root": (0, 100, 44), "LeftForeArm": (0, 0, -90)}]


def mixamo_text(prefix: str = "mixamorig:") -> str:
    hierarchy = HIERARCHY.replace("{arms}", _sides(ARM)).replace("{legs}", _sides(LEG))
    joints = [name.split(":")[1] for name in re.findall(r"(?:ROOT|JOINT) (\S+)", hierarchy)]
    rows = []
    for frame in FRAMES:
        row = list(frame.get("root", (0, 100, 0)))
        for joint in joints:
            row += frame.get(joint, (0, 0, 0))
        rows.append(" ".join(f"{v:g}" for v in row))
    motion = f"MOTION\nFrames: {len(FRAMES)}\nFrame Time: {1 / 30!r}\n" + "\n".join(rows) + "\n"
    return (hierarchy + motion).replace("mixamorig:", prefix)


# The same skeleton named otherwise needs a joint map: this one, its names prefixed.
USER_MAP = {"Hips": "Hips", "SpineBase": "Spine", "Neck": "Neck", "Head": "Head",
            **{f"{side}{joint}": f"{side}{bvh_joint}" for side in ("Left", "Right")
               for joint, bvh_joint in (("Shoulder", "Arm"), ("Elbow", "ForeArm"), ("Wrist", "Hand"),
                                        ("Hand", "HandMiddle1"), ("Hip", "UpLeg"), ("Knee", "Leg"),
                                        ("Ankle", "Foot"), ("Foot", "ToeBase"))}}


# A CMU-named ASF skeleton (the database's bone names; a T-pose, Y up, facing +Z, its left at +X), and a take of it.
# (bone, parent, direction, length, axis angles, dof); the right side mirrors the left (x negated, l -> r).
CMU_BONES = [
    ("lhipjoint", "root", (0.6, -0.8, 0), 10, (0, 0, 0), ()),
    ("lfemur", "lhipjoint", (0, -1, 0), 45, (0, 0, 20), ("rx", "ry", "rz")),
    ("ltibia", "lfemur", (0, -1, 0), 43, (0, 0, 0), ("rx",)),
    ("lfoot", "ltibia", (0, -3, 11.5), 11.885, (-90, 0, 20), ("rx", "rz")),
    ("ltoes", "lfoot", (0, 0, 1), 5, (-90, 0, 20), ("rx",)),
    ("lowerback", "root", (0, 1, 0), 10, (0, 0, 0), ("rx", "ry", "rz")),
    ("upperback", "lowerback", (0, 13.5, -0.5), 13.509, (0, 0, 0), ("rx", "ry", "rz")),
    ("thorax", "upperback", (0, 13.5, -0.5), 13.509, (0, 0, 0), ("rx", "ry", "rz")),
    ("lowerneck", "thorax", (0, 1, 0), 5, (0, 0, 0), ("rx", "ry", "rz")),
    ("upperneck", "lowerneck", (0, 1, 0), 4, (0, 0, 0), ("rx", "ry", "rz")),
    ("head", "upperneck", (0, 1, 0), 18, (0, 0, 0), ("rx", "ry", "rz")),
    ("lclavicle", "thorax", (1, 0.2, 0), 15, (0, 0, -20), ("ry", "rz")),
    ("lhumerus", "lclavicle", (1, 0, 0), 28, (0, 0, 0), ("rx", "ry", "rz")),
    ("lradius", "lhumerus", (1, 0, 0), 25, (0, 0, 90), ("rx",)),
    ("lwrist", "lradius", (1, 0, 0), 3, (0, 0, 90), ("ry",)),
    ("lhand", "lwrist", (1, 0, 0), 7, (0, 0, 90), ("rx", "rz")),
    ("lfingers", "lhand", (1, 0, 0), 5, (0, 0, 90), ("rx",)),
    ("lthumb", "lwrist", (1, 0, 1), 4, (-90, 0, 45), ("rx", "rz")),
]


def _cmu_bones():
    out = []
    for name, parent, (x, y, z), length, axis, dof in CMU_BONES:
        out.append((name, parent, (x, y, z), length, axis, dof))
        if name[0] == "l" and not name.startswith("lower"):  # a left bone (not the lower back or neck)
            mirror = "r" + parent[1:] if parent[0] == "l" and not parent.startswith("lower") else parent
            out.append(("r" + name[1:], mirror, (-x, y, z), length, (axis[0], -axis[1], -axis[2]), dof))
    return out


def cmu_asf_text() -> str:
    lines = [":version 1.10", ":name VICON", ":units", "  mass 1.0", "  length 0.45", "  angle deg", ":documentation",
             "  written by hand for the tests", ":root", "   order TX TY TZ RX RY RZ", "   axis XYZ",
             "   position 0 0 0", "   orientation 0 0 0", ":bonedata"]
    for i, (name, _, direction, length, axis, dof) in enumerate(_cmu_bones(), 1):
        lines += ["  begin", f"     id {i}", f"     name {name}", "     direction " + " ".join(map(str, direction)),
                  f"     length {length}", "     axis " + " ".join(map(str, axis)) + " XYZ"]
        if dof:
            lines += ["    dof " + " ".join(dof), "    limits " + "\n           ".join("(-180.0 180.0)" for _ in dof)]
        lines.append("  end")
    children: dict[str, list[str]] = {}
    for name, parent, *_ in _cmu_bones():
        children.setdefault(parent, []).append(name)
    lines += [":hierarchy", "  begin"] + [f"    {p} {' '.join(c)}" for p, c in children.items()] + ["  end"]
    return "\n".join(lines) + "\n"


def cmu_amc_text() -> str:
    """Frames: the rest pose twice (the first is dropped as a clip's leading T-pose), the left knee bent 90 degrees,
    the right arm raised sideways to the vertical, and every bone turned some way with the root moved and turned."""
    bones = _cmu_bones()
    frames = [{}, {}, {"ltibia": (90,)}, {"rhumerus": (0, 0, -90)},
              {"root": (5, 90, -3, 10, 30, -5), **{name: tuple(float(7 * ((i + k) % 5) - 14) for k in range(len(dof)))
                                                      for i, (name, _, _, _, _, dof) in enumerate(bones)}}]
    lines = ["#!OML:ASF subject.asf", ":FULLY-SPECIFIED", ":DEGREES"]
    for k, frame in enumerate(frames, 1):
        lines += [str(k), "root " + " ".join(map(str, frame.get("root", (0, 90, 0, 0, 0, 0))))]
        lines += [f"{name} " + " ".join(map(str, frame.get(name, (0,) * len(dof)))) for name, *_, dof in bones if dof]
    return "\n".join(lines) + "\n"


# A skeleton shaped like the Bandai Namco research motion set's: every joint has six channels (a non-root joint's
# position channels hold its offset), every End Site has zero length, and the zero pose lies along +X (the root's
# rotation stands the subject up: the clip itself is Y up). Written here standing (a T-pose, Y up, facing +Z, its
# left at +X, centimetres): (joint, parent, offset); the right side mirrors the left.
LYING_BONES = [("joint_Root", None, (0, 0, 0)), ("Hips", "joint_Root", (0, 95, 0)), ("Spine", "Hips", (0, 10, 0)),
               ("Chest", "Spine", (0, 15, -0.5)), ("Neck", "Chest", (0, 25, -0.5)), ("Head", "Neck", (0, 10, 0.5)),
               ("Shoulder_L", "Chest", (7, 20, -0.5)), ("UpperArm_L", "Shoulder_L", (10, 0, 0)),
               ("LowerArm_L", "UpperArm_L", (28, 0, 0)), ("Hand_L", "LowerArm_L", (25, 0, 0)),
               ("UpperLeg_L", "Hips", (9, -6, 0)), ("LowerLeg_L", "UpperLeg_L", (0, -42, 0)),
               ("Foot_L", "LowerLeg_L", (0, -41, 0)), ("Toes_L", "Foot_L", (0, -5, 12))]
LYING_MAP = {"Hips": "Hips", "SpineBase": "Spine", "Neck": "Neck", "Head": "Head",
             **{f"{side}{joint}": f"{part}_{side[0]}" for side in ("Left", "Right")
                for joint, part in (("Shoulder", "UpperArm"), ("Elbow", "LowerArm"), ("Wrist", "Hand"),
                                    ("Hip", "UpperLeg"), ("Knee", "LowerLeg"), ("Ankle", "Foot"))}}
# Frames, as each joint's rotation in the standing skeleton (scipy rotation vectors, degrees, the file's axes): a
# relaxed T-pose (elbows bent 20 degrees forward), the right knee bent 90 degrees, a step 40 cm forward turned 90
# degrees to the left (about +Y), the left arm raised 60 degrees.
LYING_FRAMES = [{"LowerArm_L": (0, -20, 0), "LowerArm_R": (0, 20, 0)},
                {"LowerArm_L": (0, -20, 0), "LowerArm_R": (0, 20, 0), "LowerLeg_R": (90, 0, 0)},
                {"root": (0, 0, 40), "joint_Root": (0, 90, 0)},
                {"UpperArm_L": (0, 0, 60)}]


def _lying_bones():
    mirrored = [(n.replace("_L", "_R"), p.replace("_L", "_R"), (-x, y, z))
                for n, p, (x, y, z) in LYING_BONES if n.endswith("_L")]
    return LYING_BONES + mirrored


def lying_text(lying: bool = True) -> str:
    """The clip as Bandai Namco's set writes it (``lying``), or as the same motion of the same skeleton standing at
    zero rotation with three rotation channels per joint (its End Sites of zero length too)."""
    bones = _lying_bones()
    stand = Rotation.from_euler("z", 90 if lying else 0, degrees=True)  # the zero pose turned up: X -> Y
    children = {}
    for name, parent, _ in bones:
        children.setdefault(parent, []).append(name)
    order, lines = [], ["HIERARCHY"]

    def write(name, offset, depth):
        pad, six = "  " * depth, lying or depth == 0
        zero_pose = np.round(stand.inv().apply(offset), 9) + 0.0  # exact: 95, not 95 and 2e-14 beside it
        lines.extend([pad + ("ROOT " if depth == 0 else "JOINT ") + name, pad + "{",
                      f"{pad}  OFFSET " + " ".join(f"{v!r}" for v in zero_pose.tolist()),
                      f"{pad}  CHANNELS {6 if six else 3} " + ("Xposition Yposition Zposition " if six else "")
                      + "Zrotation Yrotation Xrotation"])
        order.append((name, zero_pose, six))
        for child in children.get(name, []):
            write(child, next(o for n, _, o in bones if n == child), depth + 1)
        if name not in children:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 0 0", f"{pad}  }}"])
        lines.append(pad + "}")

    write("joint_Root", (0, 0, 0), 0)
    rows = []
    for frame in LYING_FRAMES:
        row = []
        for name, zero_pose, six in order:
            turn = Rotation.from_rotvec(frame.get(name, (0, 0, 0)), degrees=True)
            local = turn * stand if name == "joint_Root" else stand.inv() * turn * stand  # Rz^T L Rz (parent's axes)
            position = frame.get("root", (0, 0, 0)) if name == "joint_Root" else zero_pose
            with warnings.catch_warnings():  # at gimbal lock scipy picks one of the equal decompositions
                warnings.filterwarnings("ignore", message="Gimbal lock detected")
                row += (list(position) if six else []) + local.as_euler("ZYX", degrees=True).tolist()
        rows.append(" ".join(f"{float(v)!r}" for v in row))
    return "\n".join(lines) + f"\nMOTION\nFrames: {len(rows)}\nFrame Time: {1 / 30!r}\n" + "\n".join(rows) + "\n"
