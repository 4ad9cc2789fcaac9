"""The Acclaim ASF/AMC reader (formats/asf_amc.py): a small skeleton and take written by hand, read straight into a
clip."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.formats import asf_amc

# Four bones: a spine up, an upper arm whose axes are turned 90 degrees about Z (its local x is the world's y), a
# forearm whose axes are turned by X 90 then Z 90 (local x, y, z are the world's y, z, x), and a thigh down.
ASF = """\
# written by hand after the Acclaim ASF/AMC specification
:version 1.10
:name tiny
:units
  mass 1.0
  length 0.45
  angle deg
:documentation
  four bones, lengths in the file's units
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name lowerback
     direction 0 1 0
     length 10
     axis 0 0 0  XYZ
    dof rx ry rz
    limits (-inf inf)
           (-inf inf)
           (-inf inf)
  end
  begin
     id 2
     name lhumerus
     direction 1 0 0
     length 20
     axis 0 0 90 XYZ
    dof rx
    limits (-180.0 180.0)
  end
  begin
     id 3
     name lradius
     direction 1 0 0
     length 15
     axis 90 0 90 XYZ
    dof rx rz
    limits (-180.0 180.0)
           (-180.0 180.0)
  end
  begin
     id 4
     name lfemur
     direction 0 -2 0
     length 40
     axis 0 0 0 XYZ
    dof rx ry rz
  end
:hierarchy
  begin
    root lowerback lfemur
    lowerback lhumerus
    lhumerus lradius
  end
"""
# Per frame: root (tx ty tz rx ry rz), lhumerus rx, lradius (rx rz), lfemur rx; every other value 0.
FRAMES = [((0, 0, 0, 0, 0, 0), 0, (0, 0), 0),
          ((0, 0, 0, 0, 0, 0), 90, (0, 0), 0),
          ((1, 2, 3, 0, 90, 0), 0, (0, 0), 0),
          ((0, 0, 0, 0, 0, 0), 0, (90, 0), 0),
          ((0, 0, 0, 0, 0, 0), 0, (90, 90), 90)]


def amc(frames=FRAMES, flag=":DEGREES", scale=1.0) -> str:
    lines = ["#!OML:ASF tiny.asf", ":FULLY-SPECIFIED", flag]
    for k, (root, humerus, radius, femur) in enumerate(frames, 1):
        rot = [v * scale for v in root[3:]]
        lines += [str(k), "root " + " ".join(map(str, list(root[:3]) + rot)), "lowerback 0 0 0",
                  f"lhumerus {humerus * scale}", f"lradius {radius[0] * scale} {radius[1] * scale}",
                  f"lfemur {femur * scale} 0 0"]
    return "\n".join(lines) + "\n"


# Where the elbow (lradius's start), the forearm's end and the thigh's end are, frame by frame, worked out by
# hand from the specification (a bone turns by C M C^-1, M composed in its dof order about fixed axes):
EXPECTED = {
    "lradius": [(20, 10, 0), (0, 10, -20), (1, 12, -17), (20, 10, 0), (20, 10, 0)],
    # 1: rest. 2: lhumerus rx 90 about its local x, the world's y: (1,0,0) -> (0,0,-1), the forearm along.
    # 3: the root at (1,2,3) turned 90 about y. 4: lradius rx 90 about its local x (world y): (1,0,0) -> (0,0,-1).
    # 5: then rz 90 about its local z (world x): (0,0,-1) -> (0,1,0); the thigh rx 90: (0,-1,0) -> (0,0,-1).
    "lradius_End": [(35, 10, 0), (0, 10, -35), (1, 12, -32), (20, 10, -15), (20, 25, 0)],
    "lfemur_End": [(0, -40, 0), (0, -40, 0), (1, -38, 3), (0, -40, 0), (0, 0, -40)],
}


def positions(clip):
    _, pos = clip.forward_kinematics()
    return {name: pos[:, clip.names.index(name)] for name in EXPECTED}


def test_an_amc_take_moves_its_bones_as_the_specification_says():
    skeleton = asf_amc.parse_asf(ASF)
    assert skeleton.names == ("root", "lowerback", "lfemur", "lhumerus", "lradius") and skeleton.length_unit == 0.45
    np.testing.assert_array_equal(skeleton.parents, [-1, 0, 0, 1, 3])
    clip = asf_amc.read_asf_amc(ASF, amc(), fps=120.0)
    assert clip.fps == pytest.approx(120.0) and clip.data.shape[0] == 5
    for name, got in positions(clip).items():
        np.testing.assert_allclose(got, np.array(EXPECTED[name], float), atol=1e-9, err_msg=name)


def test_radians_in_the_asf_or_the_amc_give_the_same_take():
    degrees = positions(asf_amc.read_asf_amc(ASF, amc()))
    amc_radians = positions(asf_amc.read_asf_amc(ASF, amc(flag=":RADIANS", scale=np.pi / 180)))
    asf_radians = ASF.replace("angle deg", "angle rad").replace("axis 90 0 90", f"axis {np.pi / 2!r} 0 {np.pi / 2!r}") \
        .replace("axis 0 0 90", f"axis 0 0 {np.pi / 2!r}")
    both = positions(asf_amc.read_asf_amc(asf_radians, amc(flag="", scale=np.pi / 180)))
    for name in EXPECTED:
        np.testing.assert_allclose(amc_radians[name], degrees[name], atol=1e-9)
        np.testing.assert_allclose(both[name], degrees[name], atol=1e-9)


@pytest.mark.parametrize("asf,amc_text,message", [
    (ASF.replace(":hierarchy", ":hierarchi"), None, "the ASF has no ':hierarchy' section"),
    (ASF.replace("dof rx\n", "dof rx l\n"), None, r"bone lhumerus's dof \['rx', 'l'\]: only rotations"),
    (ASF.replace("lhumerus lradius", "lhumerus lradius lulna"), None, "names 'lulna', which :bonedata does not"),
    (ASF.replace("    lhumerus lradius\n", ""), None, r"bones \['lradius'\] are not under the root"),
    (ASF.replace("axis 0 0 90 XYZ", "axis 0 0 90 XXZ"), None, "axis order must name the axes X, Y and Z once"),
    (ASF.replace("direction 1 0 0\n     length 20", "direction 1 0\n     length 20"), None,
     "bone lhumerus's direction must be 3 numbers"),
    (ASF, amc().replace("lhumerus 90.0", "lhumerus 90.0 0"), "bone lhumerus has 1 dof in the ASF, found 2 values"),
    (ASF, amc().replace("lfemur 90.0 0 0\n", ""), r"AMC frame 5 lacks bones \['lfemur'\]"),
    (ASF, amc().replace("lowerback", "upperback"), "bone 'upperback' is not in the skeleton"),
    (ASF, ":FULLY-SPECIFIED\n", "the AMC holds no frame"),
    # Broken numbers are refused where they are read, naming the line, the frame, the bone and the dof.
    (ASF, amc().replace("lhumerus 90.0", "lhumerus nan"), r"AMC line 13: frame 2, bone lhumerus, dof rx is nan"),
    (ASF, amc().replace("root 1 2 3", "root 1e308 2 3"),
     r"AMC line 17: frame 3, bone root, dof tx is 1e\+308: it must be finite and within"),
    (ASF.replace("length 20", "length inf"), None, r"line \d+: bone lhumerus's length must be finite numbers"),
])
def test_malformed_asf_and_amc_are_clear_errors(asf, amc_text, message):
    with pytest.raises(asf_amc.ASFError, match=message):
        asf_amc.read_asf_amc(asf, amc_text if amc_text is not None else amc())
