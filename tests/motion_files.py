"""Small motion files written by hand for the tests: a Mixamo-style BVH clip (and, below, an ASF/AMC pair)."""

from __future__ import annotations

import re

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
