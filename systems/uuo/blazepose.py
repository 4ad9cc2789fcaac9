"""BlazePose GHUM's two networks, fetched from the mediapipe wheel on PyPI, for the monocular prior.

    python -m mocapflow.systems.uuo.blazepose DIR

downloads mediapipe 0.10.14's wheel (pip download, no dependencies, nothing installed), takes
``pose_detection.tflite`` and ``pose_landmark_full.tflite`` out of it into DIR, and checks their sha256. Point
the ``monocular_prior`` stage's ``detector`` and ``landmarker`` parameters at them (DIR inside the catalog's
data_roots). The models are Google's, under the Apache License 2.0 (mediapipe's licence).
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from mocapflow.pipeline.hashing import file_digest

log = logging.getLogger(__name__)

WHEEL = "mediapipe==0.10.14"
MODELS = {  # file -> (path inside the wheel, sha256)
    "pose_detection.tflite": ("mediapipe/modules/pose_detection/pose_detection.tflite",
                              "9ba9dd3d42efaaba86b4ff0122b06f29c4122e756b329d89dca1e297fd8f866c"),
    "pose_landmark_full.tflite": ("mediapipe/modules/pose_landmark/pose_landmark_full.tflite",
                                  "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f"),
}


class FetchError(RuntimeError):
    """The models could not be fetched or are not the expected ones."""


def present(folder: Path) -> bool:
    """Whether both networks are in ``folder`` with their expected sha256."""
    return all((folder / name).is_file() and file_digest(str(folder / name)) == sha for name, (_, sha) in MODELS.items())


def extract(wheel: Path, folder: Path) -> None:
    """The two networks taken out of mediapipe's wheel into ``folder``, their sha256 checked."""
    folder.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(wheel) as zf:
        for name, (inside, sha) in MODELS.items():
            data = zf.read(inside)
            if hashlib.sha256(data).hexdigest() != sha:
                raise FetchError(f"{inside} in {wheel.name} has sha256 {hashlib.sha256(data).hexdigest()[:12]}, "
                                 f"expected {sha[:12]}; the wheel is not {WHEEL}'s")
            (folder / name).write_bytes(data)


def fetch(folder: Path) -> Path:
    """Both networks in ``folder`` (downloaded unless already there); returns the folder."""
    folder = Path(folder)
    if present(folder):
        return folder
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "pip", "download", WHEEL, "--no-deps", "--only-binary=:all:",
               "--python-version", "3.11", "--platform", "manylinux_2_17_x86_64", "-d", tmp, "-q"]
        log.info("downloading %s (about 36 MB)", WHEEL)
        done = subprocess.run(cmd, capture_output=True, text=True)
        wheels = list(Path(tmp).glob("mediapipe-*.whl"))
        if done.returncode != 0 or not wheels:
            raise FetchError(f"pip could not download {WHEEL} (exit {done.returncode}): {done.stderr.strip()[-400:]}; "
                             "check the connection to PyPI, or put the wheel's two .tflite files in the folder")
        extract(wheels[0], folder)
    return folder


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        out = fetch(args.folder)
    except FetchError as exc:
        log.error("%s", exc)
        return 1
    log.info("%s: %s", out, ", ".join(MODELS))
    return 0


if __name__ == "__main__":
    sys.exit(main())
