"""Disk per view-frame of the cache: bytes of every stage's stored chunks, per variable, divided by the view-frames
of the take, after one `mocapflow run` of the held-out chain (benchmarks/capsule.yaml's stages, one sequence of the
CMU walk, 3 views at 512x424) in a temporary folder:

    python benchmarks/cache_size.py [--frames 48]

Sizes are the files on disk (chunks, zarr metadata, lineage and digests), as ``du --apparent-size`` counts them;
``total_kb`` sums every stage, ``derived_kb`` every stage but the recording (``frames``), which is what the
cache adds to it. Also the seconds each stage's regions took (lineage), to see what a codec costs in time.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from pipeline import CLIP, catalog_text, mocapflow, stage_seconds  # noqa: E402  (benchmarks/pipeline.py)

VIEWS = 3


def tree_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def stage_sizes(storage: Path, view_frames: int) -> dict[str, dict]:
    """Per stage: KB per view-frame of each stored variable (its chunk folder) and of the whole stage folder."""
    out = {}
    for stage_dir in sorted(p for p in storage.iterdir() if p.is_dir() and p.name != "logs"):
        variables: dict[str, int] = {}
        for group in stage_dir.glob("*/data.zarr"):
            for var in (p for p in group.iterdir() if p.is_dir()):
                variables[var.name] = variables.get(var.name, 0) + tree_bytes(var)
        out[stage_dir.name] = {
            "kb": round(tree_bytes(stage_dir) / view_frames / 1024, 2),
            "variables_kb": {k: round(v / view_frames / 1024, 2)
                             for k, v in sorted(variables.items(), key=lambda kv: -kv[1]) if v >= 0.1 * 1024 * view_frames},
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--keep", type=Path, help="run in this folder and keep it (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "catalog.yaml").write_text(catalog_text(args.frames, "fast", str(CLIP)))
        mocapflow(folder, "run", "--workers", str(args.workers))
        view_frames = VIEWS * args.frames
        stages = stage_sizes(folder / "storage", view_frames)
        seconds = stage_seconds(folder / "storage")
    total = sum(s["kb"] for s in stages.values())
    print(json.dumps({
        "motion": CLIP.stem, "frames": args.frames, "views": VIEWS,
        "total_kb": round(total, 1), "derived_kb": round(total - stages.get("frames", {"kb": 0})["kb"], 1),
        "stages": stages,
        "compute_ms_per_view_frame": {k: round(1000 * v / view_frames, 1) for k, v in sorted(seconds.items())},
    }, indent=1))


if __name__ == "__main__":
    main()
