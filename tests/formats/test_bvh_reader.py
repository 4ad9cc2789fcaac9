"""Reading BVH text (formats/bvh.py): malformed and absurd files are clear errors; a clip written back reads the
same."""

from __future__ import annotations

import re

import numpy as np
import pytest

from mocapflow.formats.asf_amc import read_asf_amc
from mocapflow.formats.bvh import format_bvh, parse_bvh
from mocapflow.tasks.shared.bvh_clip import BVHError
from motion_files import cmu_amc_text, cmu_asf_text, mixamo_text


@pytest.mark.parametrize("text,message", [
    ("", r"unexpected end of file \(expected HIERARCHY\)"),
    ("MOTION\n", "expected 'HIERARCHY', found 'MOTION'"),
    ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n", r"unexpected end of file \(expected an OFFSET number\)"),
    ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 x\n", "line 4: expected a number, found 'x'"),
    ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 1 Wrotation\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n0\n",
     "unknown channel"),
    ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 1 Xrotation\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n0\n",
     "MOTION holds 1 numbers, expected Frames 2 x 1 channels"),
])
def test_malformed_bvh_is_a_clear_error(text, message):
    with pytest.raises(BVHError, match=message):
        parse_bvh(text)


TWO_JOINTS = ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
              "Yrotation\nJOINT Knee\n{\nOFFSET 0 -40 0\nCHANNELS 3 Zrotation Xrotation Yrotation\nEnd Site\n{\n"
              "OFFSET 0 -40 0\n}\n}\n}\nMOTION\nFrames: 3\nFrame Time: 0.1\n")  # 80 units tall: positions within 8e4


def two_joint_clip(bad_column: int, value: str) -> tuple[str, int]:
    """The clip's text with frame 2's ``bad_column`` set to ``value``, and the line it is on."""
    rows = ["0 90 0 0 0 0 0 0 0"] * 3
    row = rows[2].split()
    row[bad_column] = value
    rows[2] = " ".join(row)
    text = TWO_JOINTS + "\n".join(rows) + "\n"
    return text, len(TWO_JOINTS.splitlines()) + 3


@pytest.mark.parametrize("column,value,where", [
    (7, "nan", "joint Knee, channel Xrotation is nan"),
    (0, "1e308", "joint Hips, channel Xposition is 1e+308"),
    (5, "-inf", "joint Hips, channel Yrotation is -inf"),
    (1, "90000", "joint Hips, channel Yposition is 90000.0"),  # beyond 1000 skeleton sizes (8e4)
    (6, "2e5", "joint Knee, channel Zrotation is 200000.0"),  # beyond 1e5 degrees
])
def test_a_non_finite_or_absurd_motion_value_is_refused_naming_its_line_frame_joint_and_channel(column, value, where):
    text, line = two_joint_clip(column, value)
    with pytest.raises(BVHError, match=rf"^line {line}: frame 2 \(0 = the first\), {re.escape(where)}, and 1 value"):
        parse_bvh(text)
    ok, _ = two_joint_clip(column, "70000" if column < 3 else "9e4")  # within the bounds: read as written
    assert parse_bvh(ok).data[2, column] == float("70000" if column < 3 else "9e4")


def test_a_non_finite_offset_is_refused_naming_its_joint():
    with pytest.raises(BVHError, match=r"the OFFSET of Knee is \[0.0, nan, 0.0\]: offsets must be finite"):
        parse_bvh(two_joint_clip(0, "0")[0].replace("OFFSET 0 -40 0\nCHANNELS", "OFFSET 0 nan 0\nCHANNELS"))


@pytest.mark.parametrize("clip", [parse_bvh(mixamo_text()), read_asf_amc(cmu_asf_text(), cmu_amc_text(), fps=30.0)],
                         ids=["mixamo", "asf_amc"])
def test_a_clip_written_back_reads_as_the_same_numbers(clip):
    again = parse_bvh(format_bvh(clip))  # joints in depth-first order: an ASF take's come breadth first
    order = [clip.names.index(name) for name in again.names]
    assert sorted(order) == list(range(len(clip.names))) and again.frame_time == clip.frame_time
    np.testing.assert_array_equal(again.offsets, clip.offsets[order])
    np.testing.assert_array_equal(again.parents, [again.names.index(clip.names[clip.parents[j]])
                                                  if clip.parents[j] >= 0 else -1 for j in order])
    np.testing.assert_array_equal(again.forward_kinematics()[1], clip.forward_kinematics()[1][:, order])
