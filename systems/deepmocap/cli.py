"""DeepMoCap's command ``mocapflow synth``: renders studio takes for its IR-depth sensors as raw-sequence stores.

Added to the command line by DeepMoCap's system declaration (``commands``), as a plug-in adds its own.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from mocapflow.pipeline.errors import MocapflowError
from mocapflow.systems.deepmocap.film import write_sequence
from mocapflow.systems.studio.specs import make_spec, read_layout
from mocapflow.tasks.studio.motion import EXERCISES
from mocapflow.tasks.deepmocap.film.synth import build_rig


@click.command()
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="folder for <sequence>.zarr")
@click.option("--motion", "motions", multiple=True, required=True, metavar="NAME_OR_FILE",
              help="an exercise name, a .bvh clip or an .amc take (repeatable; one sequence each)")
@click.option("--views", default=3, show_default=True, help="sensors on the default ring")
@click.option("--frames", default=None, type=int, help="frames per sequence [90; a BVH clip's length]")
@click.option("--fps", default=30.0, show_default=True)
@click.option("--seed", default=0, show_default=True, help="subject, placement and noise seed")
@click.option("--subject-height", default=None, type=float, help="metres, 1.50-2.00 [random from the seed]")
@click.option("--noise", default=1.0, show_default=True, help="sensor noise level (0 = clean)")
@click.option("--layout", "layout_file", default=None, type=click.Path(dir_okay=False, exists=True),
              help="camera layout YAML (ring: {count, radius, height} or sensors: [{name, position}])")
@click.option("--body", type=click.Choice(["capsule", "mesh"]), default="capsule", show_default=True,
              help="the subject: the template's capsules or the Anny mesh body")
@click.option("--motion-map", "motion_map", default=None, type=click.Path(dir_okay=False, exists=True),
              help="joint map YAML {template joint: BVH joint} for the clips' skeleton")
@click.option("--skeleton", default=None, type=click.Path(dir_okay=False, exists=True),
              help="the ASF skeleton of the .amc takes")
@click.option("--amc-fps", "amc_fps", default=None, type=float, help="the .amc takes' frame rate [120]")
@click.option("--force", is_flag=True, help="overwrite existing sequences in --out")
def synth(out_dir, motions, views, frames, fps, seed, subject_height, noise, layout_file, body, motion_map, skeleton,
          amc_fps, force):
    """Render studio sequences (raw-sequence zarr stores with ground truth)."""
    layout = read_layout(Path(layout_file), "--layout") if layout_file else None
    out = Path(out_dir)
    jobs = []
    for motion in motions:
        raw = {"motion": motion, "views": views, "fps": fps, "seed": seed, "noise": noise, "body": body,
               "subject_height": subject_height, **({"frames": frames} if frames is not None else {}),
               **({"motion_map": motion_map} if motion_map and motion not in EXERCISES else {})}
        if motion.lower().endswith(".amc"):
            raw.update({k: v for k, v in (("skeleton", skeleton), ("amc_fps", amc_fps)) if v is not None})
        spec, motion_file, _ = make_spec(raw, f"--motion {motion}", lambda p: Path(p).resolve(), layout,
                                         skeleton_hint="pass --skeleton subject.asf")
        name = Path(motion).stem if motion_file is not None else motion
        target = out / f"{name}.zarr"
        if target.exists() and not force:
            raise MocapflowError(f"{target} exists; pass --force to overwrite it or choose another --out")
        jobs.append((spec, motion_file.clip if motion_file is not None else None, target))
    out.mkdir(parents=True, exist_ok=True)
    for spec, clip, target in jobs:
        started = time.perf_counter()
        rig = build_rig(spec, clip)
        write_sequence(rig, str(target))
        click.echo(f"wrote {target} ({rig.n_frames} frames x {len(rig.views)} views, "
                   f"{time.perf_counter() - started:.1f} s)")
