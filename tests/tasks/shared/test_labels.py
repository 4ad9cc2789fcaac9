"""Labels: mirrored names and the limb pairs present."""

from mocapflow.tasks.shared.labels import mirrored, mirrored_pairs
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES


def test_mirrored_exchanges_sides_and_keeps_the_midline():
    assert mirrored("F_L_HEAD") == "F_R_HEAD" and mirrored("R_CALF") == "L_CALF"
    assert mirrored("B_SPINEMID") == "B_SPINEMID"
    assert sorted(mirrored(n) for n in REFLECTOR_NAMES) == sorted(REFLECTOR_NAMES)  # the table is symmetric


def test_mirrored_pairs_of_the_names_present():
    names = ["R_CALF", "L_CALF", "L_FOOT", "B_HEAD"]
    assert mirrored_pairs(names) == [(1, 0)]  # L_FOOT has no right foot here
    assert len(mirrored_pairs(list(REFLECTOR_NAMES))) == 6
