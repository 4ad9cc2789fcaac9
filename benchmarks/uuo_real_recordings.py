"""The recorded takes shipped in benchmarks/recordings/ for the UUO benchmark on real data (uuo_real.yaml) and its
tuning split (uuo_real_tuning.yaml, recordings/tuning/): short windows of public labelled optical recordings, cut
from their upstream files and written as C3D.

    python benchmarks/uuo_real_recordings.py SOURCES

SOURCES holds the upstream files at ``<owner>/<repository>/<path>`` (the repositories, commits and paths of TAKES;
docs/data.md lists them with their licences). Each take keeps a window of frames of its file, its labels (without a
subject prefix such as ``Justin:``), its unit (mm) and its rate; trajectories that are not markers on the body are
dropped (``drop``, a regex on the labels as the file writes them: a model's computed joint centres and segment axes,
a hockey stick and puck). A Y-up TRC file is turned onto Z up by the project's rotation (x stays, y becomes up).
Residuals are not kept: a sample is written present (residual 0) or missing (-1).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import ezc3d
import numpy as np

from mocapflow.formats.c3d import c3d_scale, write_points
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP

OUT = Path(__file__).resolve().parent / "recordings"
OPENSIM = ("opensim-org/opensim-core", "0435b081dc383498e217f92ca63bb97616145c14")
NIMBLE = ("keenon/nimblephysics", "c405b056fc35068027e03e0c384e84e12870b475")
RECOVERY = ("numediart/MocapRecovery", "8b185712b1015cd8bf871ee1fd3051fac2503bfc")
ZOO = ("PhilD001/biomechZoo", "a8753f2b917fabfe77e5752b682eb2db16191add")
HOCKEY = "Toolbox/Visualization/Cinema objects/c3d files"
PROPS = r"^(Stick|Puck)"  # a hockey stick's and puck's markers
PIG_MODEL = r"^(CentreOfMass|CentreOfMassFloor|[LR]?(HED|CL|FE|FO|HN|HU|RA|TI|TO|PEL|TRX)[OALP])$"  # Plug-in Gait outputs

# take -> (repository, commit), path in it, [start, stop) frames of the file, labels to drop (a regex), up axis
TAKES = {
    "opensim_subject01_walk": (OPENSIM, "Bindings/Python/tutorials/resources/Tutorial 5/subject01_walk1.trc",
                               (20, 140), None, "y"),
    "opensim_duathlon_run": (OPENSIM, "Applications/IK/tests/resources/constraintTest.trc", (1000, 1120),
                             r"^[LR]_HJC$", "y"),
    "opensim_moco_walk": (OPENSIM, "OpenSim/Examples/Moco/example3DWalking/markers_walk.trc", (60, 180), None, "y"),
    "cmu_06_01_walk": (NIMBLE, "data/c3d/cmu_dribble_shoot_basketball.c3d", (100, 220), None, "z"),
    "cmu_02_05_punch": (NIMBLE, "data/c3d/cmu_02_05.c3d", (100, 220), None, "z"),
    "cmu_135_02_karate": (RECOVERY, "data/135_02.c3d", (940, 1060), None, "z"),
    "biomechzoo_hockey_wrist_shot": (ZOO, f"{HOCKEY}/Wrist Shot Top Left 009kin fit.c3d", (150, 270), PROPS, "z"),
    "biomechzoo_hockey_shot": (ZOO, f"{HOCKEY}/ti003.c3d", (100, 220), f"{PROPS}|{PIG_MODEL}", "z"),
    # the tuning split (recordings/tuning/): other recordings, other motions
    "tuning/cmu_85_02_jump": (RECOVERY, "data/85_02.c3d", (240, 360), None, "z"),
    "tuning/cmu_85_12_dance": (RECOVERY, "data/85_12.c3d", (420, 540), None, "z"),
}


def read_source(path: Path) -> tuple[np.ndarray, list[str], float]:
    """positions (frame, marker, 3) in mm (NaN: missing), labels and rate of an upstream C3D or TRC file."""
    if path.suffix.lower() == ".c3d":
        c3d = ezc3d.c3d(str(path))
        point = c3d["parameters"]["POINT"]
        unit = str(point["UNITS"]["value"][0]).strip().lower()
        if unit != "mm":
            raise ValueError(f"{path}: unit {unit!r}; every shipped take is in mm")
        xyz = np.asarray(c3d["data"]["points"][:3], np.float64).transpose(2, 1, 0)
        xyz[np.asarray(c3d["data"]["meta_points"]["residuals"][0]).T < 0] = np.nan
        return xyz, [str(n).strip() for n in point["LABELS"]["value"]][:xyz.shape[1]], float(point["RATE"]["value"][0])
    lines = path.read_text().splitlines()  # TRC; a header written with doubled tabs is read as well
    header = dict(zip(lines[1].split(), lines[2].split()))
    if header["Units"].lower() != "mm":
        raise ValueError(f"{path}: unit {header['Units']!r}; every shipped take is in mm")
    names = [n.strip() for n in lines[3].split("\t")[2:] if n.strip()]
    rows = [[float(v) if v.strip() else np.nan for v in line.split("\t")[2:2 + 3 * len(names)]]
            for line in lines[5:] if line.strip()]
    return np.array(rows).reshape(len(rows), len(names), 3), names, float(header["DataRate"])


def cut(sources: Path, take: str) -> Path:
    (repo, _commit), rel, (start, stop), drop, up = TAKES[take]
    xyz, names, fps = read_source(sources / repo / rel)
    if stop > len(xyz):
        raise ValueError(f"{take}: frames [{start}, {stop}) reach past the file's {len(xyz)} frames")
    keep = [i for i, n in enumerate(names) if not (drop and re.search(drop, n))]  # on the labels as written
    xyz = xyz[start:stop, keep]
    names = [names[i].rsplit(":", 1)[-1].strip() for i in keep]  # no subject prefix
    if up == "y":
        xyz = xyz @ Y_UP_TO_Z_UP.T
    word4 = np.where(np.isfinite(xyz).all(axis=-1), 0.0, -1.0)
    out = OUT / f"{take}.c3d"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_points(out, xyz, names, fps, c3d_scale(xyz, np.zeros(1)), word4)
    print(f"{out}: {len(xyz)} frames at {fps:g} frames/s, {len(names)} markers, "
          f"{100 * float(np.isnan(xyz[..., 0]).mean()):.1f} % missing, {out.stat().st_size / 1024:.0f} KiB")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sources", type=Path, help="folder holding <owner>/<repository>/<path> upstream files")
    args = parser.parse_args()
    for take in TAKES:
        cut(args.sources, take)


if __name__ == "__main__":
    main()
