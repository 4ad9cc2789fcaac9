"""Prior files for the labelled reference of benchmarks/uuo_real.yaml and uuo_real_tuning.yaml: the template's joints
estimated from the labelled markers of each recording (a joint at the mean of the markers around it), written in the
`file` prior format (systems/uuo/prior_files.py) to storage/uuo_real_priors/<take>.npz.

    python benchmarks/uuo_real_priors.py

Only the references use them (labels known); the unlabelled solves never do. One table per marker set: Vicon's
Plug-in Gait (ktk_kinematics_tennis_serve, the biomechZoo hockey takes), the Qualisys sports/gait set of
ezc3d_qualisys_gait_forceplates, CMU's 41 markers, OpenSim's Gait2354 set (subject01) and the full-body set of
OpenSim's running and Moco walking takes. A hip joint is the mean of the side's pelvis markers, 8 cm lower (a rough
hip centre); SpineBase lies 30 % of the way from the pelvis centre to the mid-trunk markers. A joint no marker sits
on (a hand or head of a set without hand or head markers) lies past its segment's end (``Beyond``), as far as the
template's proportions put it. A name listed twice weighs twice in a mean; a joint takes the mean of the markers of
its list the file has (a set's variants name their foot markers differently), at least one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapflow.systems.uuo.marker_files import read_markers
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.uuo.labelled import base_label

ROOT = Path(__file__).resolve().parents[1]
C3D = ROOT.parent / "shared" / "data" / "c3d"
RECORDINGS = ROOT / "benchmarks" / "recordings"
OUT = ROOT / "storage" / "uuo_real_priors"
DOWN = np.array([0.0, 0.0, -0.08])
HAND_PAST_WRIST = 0.08 / 0.146  # the template's hand past the wrist, as a share of the forearm (tasks/shared/body.py)
HEAD_PAST_NECK = 0.07 / 0.315  # its head above the neck, as a share of the pelvis-to-neck length


@dataclass(frozen=True)
class Beyond:
    """A joint past a segment's end: ``tip + k (tip - base)``, tip and base each the mean of their markers."""

    tip: tuple[str, ...]
    base: tuple[str, ...]
    k: float


def _right(name: str) -> str:
    if name.startswith("L_"):
        return "R_" + name[2:]
    return "R" + name[1:] if name.startswith("L") else name  # a midline marker (V.Sacral, S2) stays


def _sides(table: dict) -> dict:
    out = dict(table)
    for joint, names in table.items():
        if joint.startswith("Left"):
            out[joint.replace("Left", "Right")] = (
                Beyond(tuple(map(_right, names.tip)), tuple(map(_right, names.base)), names.k)
                if isinstance(names, Beyond) else tuple(map(_right, names)))
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
CMU = _sides({  # CMU's 41 markers: Plug-in Gait's upper body, waist markers (front, back) for the pelvis
    "Hips": ("LFWT", "RFWT", "LBWT", "RBWT"), "Neck": ("C7", "CLAV"), "Head": ("LFHD", "RFHD", "LBHD", "RBHD"),
    "LeftShoulder": ("LSHO",), "LeftElbow": ("LELB",), "LeftWrist": ("LWRA", "LWRB"), "LeftHand": ("LFIN",),
    "LeftHip": ("LFWT", "LBWT"), "LeftKnee": ("LKNE",), "LeftAnkle": ("LANK",), "LeftFoot": ("LTOE",),
    "trunk": ("T10", "STRN"),
})
OPENSIM_GAIT2354 = _sides({  # one sacral marker, weighed as the two ASIS; knee and ankle from the segments' markers
    # around them (their means lie 5 and 3 cm from the knee and ankle centres of the subject's static trial)
    "Hips": ("L.ASIS", "R.ASIS", "V.Sacral", "V.Sacral"), "Neck": ("L.Acromium", "R.Acromium"),
    "Head": ("L.Temple", "R.Temple", "Top.Head"), "LeftShoulder": ("L.Acromium",), "LeftElbow": ("L.Elbow",),
    "LeftWrist": ("L.Wrist.Med", "L.Wrist.Lat"),
    "LeftHand": Beyond(("L.Wrist.Med", "L.Wrist.Lat"), ("L.Elbow",), HAND_PAST_WRIST),
    "LeftHip": ("L.ASIS", "L.ASIS", "V.Sacral"), "LeftKnee": ("L.Thigh.Front", "L.Shank.Upper", "L.Shank.Front"),
    "LeftAnkle": ("L.Heel", "L.Midfoot.Sup"), "LeftFoot": ("L.Toe.Med", "L.Toe.Lat"), "trunk": ("Sternum", "V.Sacral"),
})
_PELVIS = ("L.ASIS", "R.ASIS", "L.PSIS", "R.PSIS")
OPENSIM_FULL_BODY = _sides({  # no head or hand marker; the running take has MT1 and MT5, the walking one MT5 and Toe
    "Hips": _PELVIS, "Neck": ("L.Clavicle", "R.Clavicle"),
    "Head": Beyond(("L.Clavicle", "R.Clavicle"), _PELVIS, HEAD_PAST_NECK), "LeftShoulder": ("L.Shoulder",),
    "LeftElbow": ("L.Elbow",), "LeftWrist": ("L.Wrist",), "LeftHand": Beyond(("L.Wrist",), ("L.Elbow",), HAND_PAST_WRIST),
    "LeftHip": ("L.ASIS", "L.PSIS"), "LeftKnee": ("L.Knee",), "LeftAnkle": ("L.Ankle",),
    "LeftFoot": ("L.MT1", "L.MT5", "L.Toe"), "trunk": ("L.Clavicle", "R.Clavicle", "L.PSIS", "R.PSIS"),
})

# take -> (its file, its marker set's table): every take of uuo_real.yaml and of uuo_real_tuning.yaml
TAKES = {
    "ezc3d_qualisys_gait_forceplates": (C3D / "ezc3d_qualisys_gait_forceplates.c3d", QUALISYS),
    "ktk_kinematics_tennis_serve": (C3D / "ktk_kinematics_tennis_serve.c3d", PLUG_IN_GAIT),
    "opensim_subject01_walk": (RECORDINGS / "opensim_subject01_walk.c3d", OPENSIM_GAIT2354),
    "opensim_duathlon_run": (RECORDINGS / "opensim_duathlon_run.c3d", OPENSIM_FULL_BODY),
    "opensim_moco_walk": (RECORDINGS / "opensim_moco_walk.c3d", OPENSIM_FULL_BODY),
    "cmu_06_01_walk": (RECORDINGS / "cmu_06_01_walk.c3d", CMU),
    "cmu_02_05_punch": (RECORDINGS / "cmu_02_05_punch.c3d", CMU),
    "cmu_135_02_karate": (RECORDINGS / "cmu_135_02_karate.c3d", CMU),
    "biomechzoo_hockey_wrist_shot": (RECORDINGS / "biomechzoo_hockey_wrist_shot.c3d", PLUG_IN_GAIT),
    "biomechzoo_hockey_shot": (RECORDINGS / "biomechzoo_hockey_shot.c3d", PLUG_IN_GAIT),
    "cmu_85_02_jump": (RECORDINGS / "tuning" / "cmu_85_02_jump.c3d", CMU),
    "cmu_85_12_dance": (RECORDINGS / "tuning" / "cmu_85_12_dance.c3d", CMU),
}


def joints_from_labels(positions: np.ndarray, labels: list[str], table: dict) -> np.ndarray:
    """(frame, marker, 3), labels -> (frame, 20, 3) template joints"""
    def mean(names):
        have = [n for n in names if n in labels]
        if not have:
            raise KeyError(f"none of the markers {list(names)} is in the recording (labels: {sorted(set(labels))})")
        return np.mean([positions[:, labels.index(n)] for n in have], axis=0)

    def joint(spec):
        if isinstance(spec, Beyond):
            tip = mean(spec.tip)
            return tip + spec.k * (tip - mean(spec.base))
        return mean(spec)

    joints = {name: joint(table[name]) for name in JOINT_NAMES if name != "SpineBase"}
    joints["SpineBase"] = 0.7 * joints["Hips"] + 0.3 * mean(table["trunk"])
    for side in ("Left", "Right"):
        joints[f"{side}Hip"] = joints[f"{side}Hip"] + DOWN
    return np.stack([joints[name] for name in JOINT_NAMES], axis=1)


def write_prior(take: str, path: Path, table: dict, out: Path = OUT) -> Path:
    """The prior file of one take: its joints over the whole recording (Z up, as the catalogs read it)."""
    ds = read_markers(path, up="z", labels="use")
    labels = [base_label(label) for label in ds["label"].values]
    joints = joints_from_labels(ds["position"].values.astype(np.float64), labels, table)
    joints[~np.isfinite(joints).all(axis=(1, 2))] = np.nan  # a frame missing a marker is lost
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / f"{take}.npz", joints=joints, fps=float(ds.attrs["fps"]), joint_names=np.array(JOINT_NAMES))
    print(f"{out / take}.npz: {len(joints)} frames, {int(np.isnan(joints[:, 0, 0]).sum())} lost")
    return out / f"{take}.npz"


def main() -> None:
    for take, (path, table) in TAKES.items():
        write_prior(take, path, table)


if __name__ == "__main__":
    main()
