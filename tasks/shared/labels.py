"""Marker labels shared by every system: anatomical sides and mirrored pairs.

Sides are anatomical: an ``L_`` label sits on the subject's left. A horizontal image flip, or a
solver that confuses the legs, turns a left label into its right mirror.
"""

from __future__ import annotations

LEFT_LIMB_REFLECTORS = ("L_ELBOW", "L_WRIST", "L_HAND", "L_CALF", "L_ANKLE", "L_FOOT")  # each has a right mirror


def mirrored(name: str) -> str:
    """The label's name on the other side: ``L`` and ``R`` tokens exchanged (``F_L_HEAD`` -> ``F_R_HEAD``)."""
    swap = {"R": "L", "L": "R"}
    return "_".join(swap.get(token, token) for token in name.split("_"))


def mirrored_pairs(names: list[str]) -> list[tuple[int, int]]:
    """Indices of the left and right label of each mirrored limb pair present in ``names``."""
    return [(names.index(left), names.index(mirrored(left))) for left in LEFT_LIMB_REFLECTORS
            if left in names and mirrored(left) in names]
