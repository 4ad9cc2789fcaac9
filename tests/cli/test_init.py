"""`mocapflow init FOLDER` for every kind of recording a newcomer brings: C3D/TRC marker files (UUO), a DeepMoCap
take in the authors' format, suit images with a calibration (a studio rehearsal: the suit reads no recorded images),
raw stores as before; each scaffold loads as a catalog, the marker one runs its first stages; an empty, unrecognised
or mixed folder and an unreadable file each get one message, and nothing is written."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from conftest import ROOT, last_json, mocapflow, write_raw_zarr
from mocapflow.cli.scaffold import KINECT_V2, KINDS, scaffold
from mocapflow.formats.c3d import read_trajectories, write_points
from mocapflow.formats.trc import trc_text
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.errors import InputError
from mocapflow.pipeline.plan import build_plan

RECORDING = ROOT / "benchmarks" / "recordings" / "opensim_subject01_walk.c3d"  # shipped, 41 markers at 60 Hz


def write_c3d(path, frames=30):
    """The first ``frames`` frames of a shipped walk, written again as a small C3D (mm, Z up)."""
    xyz, fps, names, unit = read_trajectories(RECORDING)
    assert unit == "mm"
    xyz = np.nan_to_num(xyz[:frames])
    write_points(path, xyz, names, fps, -1.0, np.zeros(xyz.shape[:2]))


def write_trc(path, frames=10):
    xyz = np.random.default_rng(1).uniform(-500, 1500, (frames, 4, 3))
    path.write_text(trc_text(xyz, ["A", "B", "C", "D"], 100.0, np.arange(frames), "z", path.name))


def write_dmc_take(take, views=("D4", "D6"), frames=3, size=(64, 48), depth_bits=16):
    """A tiny take in the DeepMoCap dataset's layout: per view its extrinsics (Kinect axes: x left, y up; mm) and
    numbered 16-bit depth PGMs with their colorized depth, a few reflector pixels black."""
    width, height = size
    # a sensor 3 m behind the origin looking along world +y, its camera y up: rows of R, then the position in mm
    rotation = "-1 0 0\n0 0 1\n0 1 0\n"
    for k, view in enumerate(views):
        (take / view).mkdir(parents=True)
        (take / f"{view}.extrinsics").write_text(rotation + f"{500.0 * k} -3000 1000\n")
        for f in range(frames):
            stem = take / view / f"take_{view}_{100 + f:05d}"
            depth = np.full((height, width), 2500 if depth_bits == 16 else 250, np.uint16 if depth_bits == 16 else np.uint8)
            jet = cv2.applyColorMap(np.full((height, width), 120, np.uint8), cv2.COLORMAP_JET)
            jet[20:23, 30:33] = 0  # a reflector
            assert cv2.imwrite(f"{stem}depth.pgm", depth) and cv2.imwrite(f"{stem}mc_blob.png", jet)


def write_suit_sequence(seq, views=("cam0", "cam1", "cam2"), size=(384, 512)):
    """Grey images of a suit sequence with its calibration.yaml: cameras on a 2.5 m ring looking at the centre."""
    calib = {"fps": 5.0, "views": {}}
    for k, view in enumerate(views):
        angle = 2 * np.pi * k / len(views)
        centre = np.array([2.5 * np.cos(angle), 2.5 * np.sin(angle), 1.2])
        z = -centre / np.linalg.norm(centre)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = np.stack([x, y, z], axis=1), centre
        calib["views"][view] = {"fx": 800.0, "fy": 800.0, "cx": size[0] / 2, "cy": size[1] / 2, "dist": [0.0] * 5,
                                "cam_to_world": pose.tolist(), "width": size[0], "height": size[1]}
        (seq / view).mkdir(parents=True)
        for f in range(2):
            assert cv2.imwrite(str(seq / view / f"{f:06d}.png"), np.full((size[1], size[0]), 90 + f, np.uint8))
    (seq / "calibration.yaml").write_text(yaml.safe_dump(calib))


def planned(path):
    catalog = load_catalog(path)
    return catalog, build_plan(catalog, None)


def test_marker_files_become_a_uuo_catalog_that_runs_its_first_stages(tmp_path):
    recs = tmp_path / "recs"
    recs.mkdir()
    write_c3d(recs / "walk.c3d")
    write_c3d(recs / "walk_short.c3d", frames=20)
    proc = mocapflow("init", recs, cwd=tmp_path)
    assert "wrote" in proc.stdout and "(markers)" in proc.stdout and "markers only (no_prior)" in proc.stderr
    assert sorted(p.name for p in recs.iterdir()) == ["catalog.yaml", "walk.c3d", "walk_short.c3d"]  # no draft left
    catalog, plan = planned(recs / "catalog.yaml")
    dataset = catalog.datasets["recorded"]
    assert dataset.kind == "markers" and dataset.options["pattern"] == "*.c3d"
    assert catalog.stages["prior"].task == "no_prior" and catalog.stages["body"].task == "best_hypothesis"
    assert sorted(s.id for s in plan.sequences) == ["walk", "walk_short"]
    summary = last_json(mocapflow("run", "--catalog", recs / "catalog.yaml", "--until", "segments", "--json",
                                  cwd=tmp_path, timeout=600))
    assert sorted(summary["executed"]) == ["markers/walk", "markers/walk_short", "segments/walk",
                                           "segments/walk_short"]


def test_prior_files_beside_every_take_make_a_file_prior_and_a_video_is_named_as_not_read(tmp_path):
    write_c3d(tmp_path / "walk.c3d")
    write_trc(tmp_path / "jog.trc")
    for take, frames, fps in (("walk", 30, 60.0), ("jog", 10, 100.0)):
        np.savez(tmp_path / f"{take}.npz", joints=np.zeros((frames, 20, 3)) + np.linspace(0, 1.7, 20)[:, None],
                 fps=fps)
    (tmp_path / "walk.mp4").write_bytes(b"\x00")
    made = scaffold(tmp_path)
    catalog, plan = planned(made.path)
    assert made.kind == "markers" and catalog.stages["prior"].task == "file_prior"
    assert catalog.datasets["recorded"].options["prior"] == "."
    assert catalog.datasets["recorded"].options["pattern"] == "*.[ct][3r][cd]"  # both suffixes, nothing else
    assert sorted(s.id for s in plan.sequences) == ["jog", "walk"]
    assert any("walk.mp4" in n and "not read" in n for n in made.notes), made.notes
    # a prior for one take only: markers only, the note naming the take without one
    (tmp_path / "jog.npz").unlink()
    made = scaffold(tmp_path, force=True)
    assert load_catalog(made.path).stages["prior"].task == "no_prior"
    assert any("not for ['jog']" in n for n in made.notes), made.notes


@pytest.mark.parametrize("one_take", [False, True])
def test_a_deepmocap_take_becomes_a_dmc_catalog_with_nominal_kinect_intrinsics_flagged(tmp_path, one_take):
    write_dmc_take(tmp_path / "dmc" / "take1")
    folder = tmp_path / "dmc" / "take1" if one_take else tmp_path / "dmc"
    made = scaffold(folder)
    catalog, plan = planned(made.path)
    dataset = catalog.datasets["recordings"]
    assert made.kind == "dmc" and dataset.kind == "dmc"
    assert [s.id for s in plan.sequences] == ["take1"] and plan.sequences[0].views == ("D4", "D6")
    assert dataset.options["intrinsics"]["fx"] == pytest.approx(KINECT_V2["fx"] * 64 / 512, abs=0.01)  # scaled to 64 x 48
    assert any("nominal Kinect v2" in n and "replace `intrinsics`" in n for n in made.notes), made.notes
    text = made.path.read_text()
    assert "NOMINAL Kinect v2 intrinsics" in text and "poses:" in text  # the whole chain, flagged
    assert "frames/take1" in plan.items and "masks/take1/D4" in plan.items


def test_suit_images_say_the_suit_reads_none_and_scaffold_a_rehearsal_with_a_rig_like_theirs(tmp_path):
    write_suit_sequence(tmp_path / "suit" / "take1")
    made = scaffold(tmp_path / "suit")
    catalog, plan = planned(made.path)
    dataset = catalog.datasets["rehearsal"]
    assert made.kind == "suit" and dataset.kind == "studio_suit"
    # the rig's count and radius; its small images raised to the size the shipped networks read (about 1 px per mm)
    assert dataset.options["cameras"] == {"count": 3, "width": 1536, "height": 2048, "radius": 2.5}
    assert any("no reader of recorded images" in n and "NOT read" in n and "384 x 512 would give" in n
               for n in made.notes), made.notes
    assert {"corners", "codes", "points", "filled"} <= set(catalog.stages)
    assert len(plan.by_stage()["corners"]) == 3  # one partition per camera


def test_raw_stores_are_scaffolded_as_before(tmp_path):
    write_raw_zarr(tmp_path / "recs" / "a.zarr")
    made = scaffold(tmp_path / "recs")
    assert made.kind == "zarr" and load_catalog(made.path).datasets["recordings"].kind == "zarr"


def refused(folder, *args):
    """init on ``folder`` through the CLI: its error, after checking it is one message and nothing was written."""
    before = sorted(p.relative_to(folder) for p in folder.rglob("*")) if folder.exists() else None
    proc = mocapflow("init", folder, *args, cwd=folder.parent, check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("error:") == 1 and proc.stdout == "", proc.stderr
    after = sorted(p.relative_to(folder) for p in folder.rglob("*")) if folder.exists() else None
    assert after == before  # nothing written, no draft left
    return proc.stderr


def test_bad_folders_get_one_message_each_and_nothing_is_written(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    message = refused(empty)
    assert "is empty" in message and all(need.split(":")[0] in message for need in KINDS.values())

    odd = tmp_path / "odd"
    odd.mkdir()
    (odd / "notes.txt").write_text("my takes\n")
    message = refused(odd)
    assert "holds no recordings init knows (notes.txt)" in message and "C3D or TRC marker files" in message

    mixed = tmp_path / "mixed"
    mixed.mkdir()
    write_c3d(mixed / "walk.c3d")
    write_dmc_take(mixed / "take1")
    message = refused(mixed)
    assert "recordings of 2 kinds" in message and "walk.c3d" in message and "take1/" in message

    damaged = tmp_path / "damaged"
    damaged.mkdir()
    write_c3d(damaged / "walk.c3d")
    (damaged / "broken.c3d").write_bytes((damaged / "walk.c3d").read_bytes()[:1500])  # cut short
    message = refused(damaged)
    assert "refused at the door, so no catalog was written" in message and "broken.c3d" in message

    preview = tmp_path / "preview"
    write_dmc_take(preview / "take1", depth_bits=8)  # a scaled preview, not the raw depth
    message = refused(preview)
    assert "8-bit PGM" in message and "no catalog was written" in message


def test_an_existing_catalog_is_kept_unless_forced(tmp_path):
    write_trc(tmp_path / "jog.trc")
    (tmp_path / "catalog.yaml").write_text("mine\n")
    with pytest.raises(InputError, match="exists; pass --force"):
        scaffold(tmp_path)
    assert (tmp_path / "catalog.yaml").read_text() == "mine\n"
    assert scaffold(tmp_path, force=True).kind == "markers"
