"""The real data some tests read from ``../shared/data`` beside the checkout, and the ``needs_shared`` marker.

Tests read the CMU BVH clips (``../shared/data/motions``), the labelled C3D recordings (``c3d``) and a Qualisys
camera calibration (``calibration``). A test
marked ``needs_shared`` is
skipped, with a message naming what is missing and where it is expected, when that folder is absent; with
``MOCAPFLOW_REQUIRE_SHARED=1`` (CI) it fails instead. ``MOCAPFLOW_SHARED_DATA`` points the tests at
another copy of the folder. Loaded by tests/conftest.py, or as a plugin (``-p shared_data``).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOCAPFLOW_SHARED_DATA") or ROOT.parent / "shared" / "data")
MOTIONS = SHARED / "motions"
C3D = SHARED / "c3d"
CALIBRATION = SHARED / "calibration"
C3D_FILES = ("ezc3d_qualisys_gait_forceplates.c3d", "ktk_kinematics_tennis_serve.c3d", "bts_c3d_sample_gait_with_gaps.c3d",
             "qualisys_duplicate_labels_fragmented.c3d")
CALIBRATION_FILES = ("pose2sim_demo_Calib.qca.txt",)
# The clips the tests name; a fuller copy of the folder may hold more, and every clip there is tested.
CMU_CLIPS = ("cmu_12_01_walk.bvh", "cmu_14_14_jumping_jacks.bvh", "cmu_14_14_jog_in_place_excerpt_f0440-1035.bvh",
             "cmu_14_14_squats_excerpt_f1020-1600.bvh", "cmu_14_14_knee_raise_excerpt_f1590-2270.bvh")
REQUIRE = "MOCAPFLOW_REQUIRE_SHARED"


def cmu_clips() -> list[Path]:
    """Every CMU clip of the shared folder; where the folder is missing, the clips the tests expect there (their
    tests then skip, or fail in CI, through ``needs_shared``)."""
    found = sorted(MOTIONS.glob("*.bvh")) if MOTIONS.is_dir() else []
    return found or [MOTIONS / name for name in CMU_CLIPS]


def reads_shared(path: Path) -> bool:
    """Whether the catalog at ``path`` names files of the shared folder (``.../shared/data/...``): its datasets
    cannot be discovered in a plain clone."""
    return "shared/data/" in path.read_text()


def catalog_param(root: Path, name: str):
    """``name`` as a pytest parameter, marked ``needs_shared`` when the catalog ``root / name`` reads the shared
    folder (see reads_shared)."""
    path = root / name
    marks = [pytest.mark.needs_shared] if path.is_file() and reads_shared(path) else []
    return pytest.param(name, marks=marks, id=name)


def skip_unless_beside_checkout(what: str) -> None:
    """Skip a test of ``what`` (a shipped catalog, which names ``../shared`` beside the checkout) where
    ``$MOCAPFLOW_SHARED_DATA`` points the tests at another copy: the catalog would not find it."""
    beside = ROOT.parent / "shared" / "data"
    if not beside.is_dir() or beside.resolve() != SHARED.resolve():
        pytest.skip(f"{what} reads ../shared/data beside the checkout ({beside}), not the copy the tests read "
                    f"({SHARED}); put the data there to run it")


def missing() -> str | None:
    """What is missing of the shared data the tests read, or None."""
    if not MOTIONS.is_dir():
        return (f"the real CMU BVH clips are missing: expected the folder {MOTIONS} (../shared/data/motions beside "
                "the checkout, or $MOCAPFLOW_SHARED_DATA/motions); see the README, 'Test data'")
    absent = [name for name in CMU_CLIPS if not (MOTIONS / name).is_file()]
    if absent:
        return f"CMU BVH clip(s) missing from {MOTIONS}: {', '.join(absent)}; see the README, 'Test data'"
    absent = [name for name in C3D_FILES if not (C3D / name).is_file()]
    if absent:
        return f"C3D recording(s) missing from {C3D}: {', '.join(absent)}; see the README, 'Test data'"
    absent = [name for name in CALIBRATION_FILES if not (CALIBRATION / name).is_file()]
    if absent:
        return f"calibration file(s) missing from {CALIBRATION}: {', '.join(absent)}; see the README, 'Test data'"
    return None


def pytest_configure(config):
    config.addinivalue_line("markers", "needs_shared: reads the real data in ../shared/data (skipped where it is "
                                      f"missing, an error with {REQUIRE}=1)")


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    if item.get_closest_marker("needs_shared") is None:
        return
    problem = missing()
    if problem is None:
        return
    if os.environ.get(REQUIRE) == "1":
        pytest.fail(f"{problem} ({REQUIRE}=1: missing shared data is an error)", pytrace=False)
    pytest.skip(problem)
