"""BlazePose's two networks for the monocular prior's tests, fetched once per machine from the mediapipe wheel.

``MOCAPFLOW_BLAZEPOSE`` names the folder (default ~/.cache/mocapflow/blazepose; CI fetches into it before the
tests). Where they cannot be had (no connection to PyPI, LiteRT not installed) the tests that need them skip,
naming why; with ``MOCAPFLOW_REQUIRE_MODELS=1`` (CI) they fail instead.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REQUIRE = "MOCAPFLOW_REQUIRE_MODELS"


def models_folder() -> Path:
    return Path(os.environ.get("MOCAPFLOW_BLAZEPOSE", Path.home() / ".cache" / "mocapflow" / "blazepose"))


def blazepose_files() -> tuple[Path, Path]:
    """(pose_detection.tflite, pose_landmark_full.tflite), fetched if needed; skips (fails in CI) without them."""
    from mocapflow.systems.uuo.blazepose import FetchError, fetch, present

    folder = models_folder()
    why = None
    try:
        import ai_edge_litert  # noqa: F401
    except ImportError:
        why = "LiteRT (the monocular extra: pip install 'mocapflow[monocular]') is not installed"
    if why is None and not present(folder):
        try:
            fetch(folder)
        except FetchError as exc:
            why = f"BlazePose's networks could not be fetched into {folder}: {exc}"
    if why is not None:
        if os.environ.get(REQUIRE) == "1":
            pytest.fail(f"{why} ({REQUIRE}=1)")
        pytest.skip(why)
    return folder / "pose_detection.tflite", folder / "pose_landmark_full.tflite"
