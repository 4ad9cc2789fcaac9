"""Prior files for the labelled reference of benchmarks/uuo_real.yaml: the template's joints estimated from the
labelled markers of each recording (a joint at the mean of the markers around it), written in the `file` prior
format (systems/uuo/prior_files.py) to storage/uuo_real_priors/<take>.npz.

    python benchmarks/uuo_real_priors.py

Only the reference uses them (labels known); the unlabelled solves never do. Two marker sets are known: Vicon's
Plug-in Gait (ktk_kinematics_tennis_serve) and the Qualisys sports/gait set of ezc3d_qualisys_gait_forceplates.
A hip joint is the mean of the side's two pelvis markers, 8 cm lower (a rough hip centre); SpineBase lies 30 %
of the way from the pelvis centre to the mid-trunk markers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapflow.systems.uuo.marker_files import read_markers
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.uuo.labelled import base_label

C3D = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
OUT = Path(__file__).resolve().parents[1] / "storage" / "uuo_real_priors"
DOWN = np.array([0.0, 0.0, -0.08])


def _sides(table: dict) -> dict:
    out = dict(table)
    for joint, names in table.items():
        if joint.startswith("Left"):
            out[joint.replace("Left", "Right")] = tuple(n.replace("L_", "R_", 1) if n.startswith("L_") else "R" + n[1:]
                                                       for n in names)
    return out


PLUG_IN_GAIT = _sides({
    "Hips": ("LASI", "RASI", "LPSI", "RPSI"), "Neck": ("C7", "CLAV"), "Head": ("LFHD", "RFHD", "LBHD", "RBHD"),
    "LeftShoulder": ("LSHO",), "LeftElbow": ("LELB",), "LeftWrist": ("LWRA", "LWRB"), "LeftHand": ("LFIN",),
    "LeftHip": ("LASI", "LPSI"), "LeftKnee": ("LKNE",), "LeftAnkle": ("LANK",), "LeftFoot": ("LTOE",),
    "trunk": ("T10", "STRN"),
})
QUALISYS = _sides({
    "Hips": ("L_IAS", "R_IAS", "L_IPS", "R_IPS"), "Neck": ("CV7", "SNJ"), "Head": ("L_HDF", "L_HDB", "R_HDB", "R_HDF"),
    "LeftShoulder": ("L_SAJ",), "LeftElbow": ("L_HLE", "L_HME"), "LeftWrist": ("L_UHE", "L_RSP"),
    "LeftHand": ("L_HM2", "L_HM5"), "LeftHip": ("L_IAS", "L_IPS"), "LeftKnee": ("L_FLE", "L_FME"),
    "LeftAnkle": ("L_FAL", "L_TAM"), "LeftFoot": ("L_FM1", "L_FM5"), "trunk": ("TV8", "SXS"),
})
TAKES = {"ktk_kinematics_tennis_serve": PLUG_IN_GAIT, "ezc3d_qualisys_gait_forceplates": QUALISYS}


def joints_from_labels(positions: np.ndarray, labels: list[str], table: dict) -> np.ndarray:
    """(frame, marker, 3), labels -> (frame, 20, 3) template joints"""
    def mean(names):
        return np.mean([positions[:, labels.index(n)] for n in names], axis=0)

    joints = {name: mean(table[name]) for name in JOINT_NAMES if name != "SpineBase"}
    joints["SpineBase"] = 0.7 * joints["Hips"] + 0.3 * mean(table["trunk"])
    for side in ("Left", "Right"):
        joints[f"{side}Hip"] = joints[f"{side}Hip"] + DOWN
    return np.stack([joints[name] for name in JOINT_NAMES], axis=1)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for take, table in TAKES.items():
        ds = read_markers(C3D / f"{take}.c3d", labels="use")
        labels = [base_label(label) for label in ds["label"].values]
        joints = joints_from_labels(ds["position"].values.astype(np.float64), labels, table)
        joints[~np.isfinite(joints).all(axis=(1, 2))] = np.nan  # a frame missing a marker is lost
        np.savez(OUT / f"{take}.npz", joints=joints, fps=float(ds.attrs["fps"]), joint_names=np.array(JOINT_NAMES))
        print(f"{OUT / take}.npz: {len(joints)} frames, {int(np.isnan(joints[:, 0, 0]).sum())} lost")


if __name__ == "__main__":
    main()
