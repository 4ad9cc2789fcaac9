"""`mocapflow init`: write a starter catalog.yaml for a folder of recordings, whatever system they are for.

    result = scaffold(Path("recordings"))     # -> Scaffold(path, kind, notes); FOLDER/catalog.yaml written

What the folder holds decides the catalog (one kind per folder; KINDS lists what each needs):

- ``*.c3d`` / ``*.trc`` marker files -> UUO, a ``markers`` dataset, markers only (``no_prior``), or a ``file_prior``
  where every take has ``<take>.npz`` / ``<take>.json`` beside it; a video beside a take is not read (the
  ``markers`` kind reads none: the monocular prior runs on the studio's filmed video only), and the catalog says so;
- DeepMoCap dataset takes (``<take>/<view>.extrinsics`` and ``<view>/`` folders of ``*depth.pgm`` and
  ``*mc_blob.png``), or FOLDER one such take -> a ``dmc`` dataset with the nominal Kinect v2 intrinsics, flagged
  for replacement (the files hold none);
- ``<sequence>.zarr`` raw-sequence stores, or ``<sequence>/calibration.yaml`` with ``<view>/depth`` and
  ``<view>/ir`` PNG folders -> DeepMoCap's ``zarr`` / ``images`` datasets;
- ``<sequence>/calibration.yaml`` with ``<view>/`` folders of grey images (the suit's cameras) -> the suit has no
  reader of recorded images (its only dataset kind is the studio's ``studio_suit``), so the catalog is a studio
  rehearsal: the suit filmed by a ring of cameras of your rig's count and image size, on the studio's body.

For marker files, DeepMoCap takes and the suit the catalog is written to a hidden file in FOLDER first, loaded and
planned (every recording read at the door: a damaged or unreadable file is refused by the dataset's own checks), and
only then put in place as ``catalog.yaml``; on any refusal nothing is left behind. Raw stores and PNG folders are
scaffolded as before, their frames checked by ``mocapflow run --dry-run`` before any stage runs.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from mocapflow.pipeline.errors import InputError, MocapflowError

DEFAULT_STAGES = """\
stages:
  frames:            # each raw sequence imported into the raw-sequence schema
    task: ingest
    dataset: recordings
  masks:             # reflector mask from IR + colorized depth
    task: reflector_mask
    inputs: [frames]
  flow:              # 3D optical flow (dis: fast, what the shipped FCN was trained on; primal_dual: PD-Flow)
    task: dis
    inputs: [frames]
  heatmaps:          # the two-stream FCN's confidence maps and optical flow fields (shipped weights)
    task: fcn_heatmaps
    inputs: {masks: masks, flow: flow}
  reflectors2d:      # labelled 2D reflectors per view
    task: greedy_reflectors
    inputs: {heatmaps: heatmaps, masks: masks}
  markers3d:         # labelled 3D reflectors fused over views
    task: fuse_views
    inputs: {reflectors: reflectors2d, masks: masks, frames: frames}
  smoothed:          # Kalman-filtered tracks (or butterworth, none)
    task: kalman
    inputs: {markers: markers3d}
  skeleton:          # the template calibrated to each sequence
    task: calibrate_skeleton
    inputs: {markers: smoothed}
  template:          # the template's joint rotations and positions per frame (what the checks read)
    task: solve_poses
    inputs: {skeleton: skeleton, markers: smoothed, views: markers3d}
  checked:           # implausible markers removed: outside the capture volume or off the solved template
    task: check_plausibility
    inputs: {markers: smoothed, poses: template, skeleton: skeleton, frames: frames}
  poses:             # Anny fitted to the checked reflectors: the joints scored, compared and reported
    task: fit_body_poses
    inputs: {markers: checked}
  reflectors2d_refined:  # each view's 2D labels made consistent with the template's poses
    task: refine_reflectors
    inputs: {reflectors: reflectors2d, poses: template, skeleton: skeleton, masks: masks, frames: frames}
"""


KINDS = {
    "markers": "UUO: C3D or TRC marker files (*.c3d, *.trc), one take each, in FOLDER; optionally a monocular prior "
               "per take beside it (<take>.npz or <take>.json: 3D joints per frame, docs/uuo.md)",
    "dmc": "DeepMoCap dataset takes: FOLDER/<take>/ folders (or FOLDER itself one take), each with a "
           "<view>.extrinsics per sensor and <view>/ folders of numbered *depth.pgm (16-bit) and *mc_blob.png files",
    "zarr": "DeepMoCap raw-sequence stores: FOLDER/<sequence>.zarr",
    "images": "DeepMoCap PNG folders: FOLDER/<sequence>/calibration.yaml with <view>/depth/*.png and <view>/ir/*.png "
              "(16-bit)",
    "suit": "suit images: FOLDER/<sequence>/calibration.yaml with <view>/ folders of grey images (*.png, *.jpg, "
            "*.pgm, *.tif)",
}
KIND_NAMES = {"markers": "C3D/TRC marker files (UUO)", "dmc": "DeepMoCap dataset takes",
              "zarr": "raw-sequence stores (*.zarr)", "images": "depth and IR PNG folders (DeepMoCap)",
              "suit": "suit images with a calibration"}
MARKER_SUFFIXES = (".c3d", ".trc")
PRIOR_SUFFIXES = (".npz", ".json")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".tif", ".tiff", ".bmp")
IGNORED = ("catalog.yaml", "storage", "report", "export")  # what init and a run leave in FOLDER
# The Kinect v2's nominal depth intrinsics (512 x 424), as its SDK reports them for a typical unit
KINECT_V2 = {"fx": 365.5, "fy": 365.5, "cx": 256.2, "cy": 207.3, "dist": [0.09, -0.27, 0.0, 0.0, 0.09]}
KINECT_V2_SIZE = (512, 424)
SUIT_MIN_PX = (1300, 1800)  # the suit's cameras: about a pixel per mm over the studio's 2.3 m tall view


@dataclass
class Scaffold:
    """What `mocapflow init` wrote: the catalog, the kind it found and what the user should know (warnings)."""

    path: Path
    kind: str
    notes: list[str] = field(default_factory=list)


def needs() -> str:
    """What each kind of recording needs, one line each, for the messages."""
    return "\n".join(f"  - {text}" for text in KINDS.values())


def scaffold(folder: Path, *, force: bool = False) -> Scaffold:
    """Detect the recordings in ``folder`` and write ``folder/catalog.yaml`` for them (InputError, and nothing
    written, for an empty or unrecognised folder, a folder of mixed kinds, or a recording refused at the door)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder; pass the folder that holds your recordings")
    target = folder / "catalog.yaml"
    if target.exists() and not force:
        raise InputError(f"{target} exists; pass --force to overwrite it")
    found = detect(folder)
    if len(found) > 1:
        kinds = "; ".join(f"{KIND_NAMES[k]}: {', '.join(names[:3])}{' ...' if len(names) > 3 else ''}"
                          for k, names in found.items())
        raise InputError(f"{folder} holds recordings of {len(found)} kinds ({kinds}); a catalog reads one kind "
                         "per folder: put each kind in a folder of its own and run `mocapflow init` on each")
    if not found:
        entries = _entries(folder)
        if not entries:
            raise InputError(f"{folder} is empty: there is nothing to write a catalog for; put your recordings "
                             f"there. What each kind needs:\n{needs()}")
        shown = ", ".join(p.name + ("/" if p.is_dir() else "") for p in entries[:6])
        raise InputError(f"{folder} holds no recordings init knows ({shown}{', ...' if len(entries) > 6 else ''}). "
                         f"What each kind needs:\n{needs()}")
    kind = next(iter(found))
    text, notes = WRITERS[kind](folder)
    if kind in CHECKED_AT_INIT:
        _write_checked(folder, target, text, kind)
    else:  # raw stores and PNG folders as before: their frames are checked by `run --dry-run`, before any stage
        target.write_text(text)
    return Scaffold(target, kind, notes)


def _entries(folder: Path) -> list[Path]:
    """FOLDER's entries, without hidden ones and what init and a run leave there."""
    return sorted(p for p in folder.iterdir() if not p.name.startswith(".") and p.name not in IGNORED)


def detect(folder: Path) -> dict[str, list[str]]:
    """The kinds of recording in ``folder``, each with the names that show it."""
    entries = _entries(folder)
    found: dict[str, list[str]] = {}

    def add(kind: str, name: str) -> None:
        found.setdefault(kind, []).append(name)

    if _is_dmc_take(folder):
        add("dmc", folder.name + " (one take)")
    elif _is_calibrated_sequence(folder):
        add(_sequence_kind(folder), folder.name + " (one sequence)")
    for p in entries:
        if p.is_file() and p.suffix.lower() in MARKER_SUFFIXES:
            add("markers", p.name)
        elif p.is_dir() and p.suffix == ".zarr":
            add("zarr", p.name)
        elif p.is_dir() and _is_dmc_take(p) and not _is_dmc_take(folder):
            add("dmc", p.name + "/")
        elif p.is_dir() and _is_calibrated_sequence(p):
            add(_sequence_kind(p), p.name + "/")
    return found


def _is_dmc_take(folder: Path) -> bool:
    """A DeepMoCap take: ``<view>.extrinsics`` files in it, or inside its view folders (``<view>/<view>.extrinsics``)."""
    return folder.is_dir() and (any(folder.glob("*.extrinsics"))
                                or any((v / f"{v.name}.extrinsics").is_file() for v in folder.iterdir() if v.is_dir()))


def _is_calibrated_sequence(folder: Path) -> bool:
    return (folder / "calibration.yaml").is_file()


def _sequence_kind(seq: Path) -> str:
    """``images`` (a view folder with depth/ and ir/) or ``suit`` (view folders of images and no depth)."""
    views = [p for p in seq.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name not in IGNORED]
    if any((v / "depth").is_dir() or (v / "ir").is_dir() for v in views):
        return "images"
    if any(f.suffix.lower() in IMAGE_SUFFIXES for v in views for f in v.iterdir() if f.is_file()):
        return "suit"
    return "images"  # a calibration without images: the depth-and-IR reader names what is missing


HEAD = "# Generated by `mocapflow init`; edit freely. Check it: mocapflow run --catalog {name} --dry-run\n"


def _write_checked(folder: Path, target: Path, text: str, kind: str) -> None:
    """Write ``text`` to a hidden file in ``folder``, load and plan it (every recording read at the door), then put
    it in place as ``target``; on any refusal remove it and raise one InputError."""
    from mocapflow.pipeline.catalog import load_catalog
    from mocapflow.pipeline.plan import build_plan

    try:
        handle, name = tempfile.mkstemp(dir=folder, prefix=".mocapflow-init-", suffix=".yaml")
    except OSError as exc:
        raise InputError(f"cannot write in {folder} ({exc.strerror}); init writes catalog.yaml there: make the folder "
                         "writable") from exc
    scratch = Path(name)
    try:
        with os.fdopen(handle, "w") as fh:
            fh.write(text)
        build_plan(load_catalog(scratch, ()), None)
        os.replace(scratch, target)
    except MocapflowError as exc:
        raise InputError(f"{folder}: {KIND_NAMES[kind]} found, but a recording is refused at the door, so no "
                         f"catalog was written: {_unscratched(str(exc), scratch)}") from exc
    except (OSError, ValueError) as exc:  # an unreadable file the readers do not name themselves
        raise InputError(f"{folder}: {KIND_NAMES[kind]} found, but reading them failed, so no catalog was written: "
                         f"{type(exc).__name__}: {_unscratched(str(exc), scratch)}") from exc
    finally:
        scratch.unlink(missing_ok=True)


def _at_door(folder: Path, kind: str, read, *args):
    """``read(*args)``, its refusal said as init's: nothing written."""
    try:
        return read(*args)
    except MocapflowError as exc:
        raise InputError(f"{folder}: {KIND_NAMES[kind]} found, but a recording is refused at the door, so no "
                         f"catalog was written: {exc}") from exc


def _unscratched(message: str, scratch: Path) -> str:
    """A loader's message about the hidden draft, naming catalog.yaml instead."""
    return message.replace(str(scratch), "catalog.yaml").replace(scratch.name, "catalog.yaml")


def _head(kind: str) -> str:
    return HEAD.format(name="catalog.yaml") + f"# Found: {KIND_NAMES[kind]}. Every kind: docs/data.md.\n"


# ---- UUO: C3D / TRC -------------------------------------------------------------------------------
UUO_STAGES = """\
stages:
  markers: {task: ingest_markers, dataset: recorded}   # the trajectories, metres, Z up
  segments: {task: rigid_segments, inputs: [markers]}  # markers grouped by the bone they ride
  prior: {task: %s, inputs: [markers]}%s
  screen: {task: screen_hypotheses, inputs: [markers, segments, prior]}   # root yaws 30 deg apart, mirrored
  h0: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 0}}
  h1: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 1}}
  h2: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 2}}
  h3: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 3}}
  body: {task: best_hypothesis, inputs: {markers: markers, h0: h0, h1: h1, h2: h2, h3: h3}}   # the most plausible
"""


def _glob(suffixes: set[str]) -> str:
    """One glob matching every suffix in ``suffixes`` (all the same length): ``*.c3d``, ``*.[ct][3r][dc]``."""
    columns = zip(*sorted(suffixes))
    return "*" + "".join(c[0] if len(set(c)) == 1 else "[" + "".join(sorted(set(c))) + "]" for c in columns)


def _markers(folder: Path) -> tuple[str, list[str]]:
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in MARKER_SUFFIXES)
    pattern = _glob({p.suffix for p in files})
    matched = sorted(p for p in folder.glob(pattern) if p.is_file())
    if matched != files:
        raise InputError(f"{folder}: no single file pattern picks exactly the marker files "
                         f"({sorted(set(p.name for p in matched) ^ set(p.name for p in files))} differ); give them "
                         "suffixes .c3d or .trc in one case")
    takes = [p.stem for p in files]
    priors = {t for t in takes if any((folder / f"{t}{s}").is_file() for s in PRIOR_SUFFIXES)}
    videos = sorted(p.name for p in folder.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES
                    and p.stem in takes)
    notes = []
    if priors and priors == set(takes):
        prior, comment = "file_prior", "   # the monocular estimate beside each take (<take>.npz/.json)"
        option = "    prior: .                    # each take's prior file, <take>.npz or <take>.json, here\n"
        notes.append(f"UUO: {len(takes)} take(s) with their prior files: the solve starts from them (file_prior)")
    else:
        prior, option = "no_prior", ""
        comment = ("   # markers only: a rough placement, not a pose; with <take>.npz/.json beside every take, set "
                   "the dataset's prior: . and make this file_prior")
        notes.append(f"UUO: {len(takes)} take(s), markers only (no_prior): a rough placement, not a trustworthy "
                     "pose; bring a monocular estimate per take (<take>.npz or .json, docs/uuo.md) for a pose")
        if priors:
            missing = sorted(set(takes) - priors)
            notes.append(f"prior files found for {sorted(priors)} but not for {missing}: a catalog's prior covers "
                         f"every take, so none is used; write {missing[0]}.npz (and the others') or move the takes "
                         "without one to another folder")
    if videos:
        notes.append(f"video(s) {videos} beside the takes are not read: the markers kind reads no video (the "
                     "monocular prior runs BlazePose on the studio's filmed video only); estimate each take's 3D "
                     "joints from it and save them as <take>.npz (docs/uuo.md, the file prior)")
    text = (_head("markers")
            + "# UUO: the solver groups the unlabelled markers by bone, places a body prior on them from twelve facings\n"
            "# and keeps the most plausible solve. Export: mocapflow export --catalog catalog.yaml --format c3d|bvh "
            "--out DIR\n"
            "data_roots: [.]\n"
            "storage:\n  root: storage/\n"
            "datasets:\n  recorded:\n    kind: markers\n    path: .\n"
            f"    pattern: \"{pattern}\"           # one take per file, named by the file\n"
            "    up: auto                    # found from the markers; z or y to say it (a Y-up file: y)\n"
            "    labels: ignore              # the file's labels dropped: the solver labels the trajectories itself\n"
            "    # frames: [0, 300]          # a window of each file (about a minute per hypothesis per 100 frames on "
            "two cores)\n"
            + option
            + UUO_STAGES % (prior, comment)
            + "evaluation:\n  sequences: \"*\"\n")
    return text, notes


# ---- DeepMoCap: the dataset's own files --------------------------------------------------------------
def _dmc(folder: Path) -> tuple[str, list[str]]:
    one_take = _is_dmc_take(folder)
    takes = [folder] if one_take else sorted(p for p in _entries(folder) if p.is_dir() and _is_dmc_take(p))
    depth = next((f for t in takes for f in sorted(t.glob("*/*depth.pgm"))), None)
    if depth is None:
        raise InputError(f"{takes[0]}: DeepMoCap extrinsics but no view folder of *depth.pgm files; each view needs "
                         f"<view>/ with numbered *depth.pgm and *mc_blob.png files ({KINDS['dmc']})")
    from mocapflow.systems.deepmocap.dmc_files import pgm_header
    width, height, _ = _at_door(folder, "dmc", pgm_header, depth)
    intrinsics = dict(KINECT_V2)
    if (width, height) != KINECT_V2_SIZE:  # another sensor's size: the Kinect's field of view at that size
        sx, sy = width / KINECT_V2_SIZE[0], height / KINECT_V2_SIZE[1]
        intrinsics.update(fx=round(KINECT_V2["fx"] * sx, 2), fy=round(KINECT_V2["fy"] * sy, 2),
                          cx=round(KINECT_V2["cx"] * sx, 2), cy=round(KINECT_V2["cy"] * sy, 2))
    notes = [f"DeepMoCap: {len(takes)} take(s); the files hold no intrinsics, so the catalog gives the nominal Kinect "
             f"v2's ({width} x {height}{'' if (width, height) == KINECT_V2_SIZE else ', scaled from 512 x 424'}): "
             "replace `intrinsics` with your sensors' (per view: intrinsics: {D4: {fx, ...}, ...}), or the 3D "
             "reflectors are off by the difference"]
    where = ("data_roots: [..]               # this take's folder is read from its parent\n"
             f"storage:\n  root: storage/\n  region_frames: 32\n"
             f"datasets:\n  recordings:\n    kind: dmc\n    path: ..\n    pattern: \"{folder.name}\"\n"
             if one_take else
             "data_roots: [.]\nstorage:\n  root: storage/\n  region_frames: 32\n"
             "datasets:\n  recordings:\n    kind: dmc\n    path: .                     # one folder per take\n")
    dist = ", ".join(f"{d:g}" for d in intrinsics["dist"])
    text = (_head("dmc")
            + where
            + "    # NOMINAL Kinect v2 intrinsics, not your sensors': the files hold none. Replace them (per view:\n"
            "    # intrinsics: {D4: {fx: ..., fy: ..., cx: ..., cy: ..., dist: [...]}, D6: {...}}), in the files' pixels.\n"
            f"    intrinsics: {{fx: {intrinsics['fx']}, fy: {intrinsics['fy']}, cx: {intrinsics['cx']}, "
            f"cy: {intrinsics['cy']}, dist: [{dist}]}}\n"
            "    # fps: 30, mirrored: true, up: z, unit: mm, camera_axes: kinect   (the defaults, docs/data.md)\n"
            + DEFAULT_STAGES)
    return text, notes


# ---- DeepMoCap: raw stores and PNG folders (as before) -----------------------------------------------
def _raw(kind: str):
    def write(folder: Path) -> tuple[str, list[str]]:
        if _is_calibrated_sequence(folder):
            raise InputError(f"{folder} is one sequence (its calibration.yaml is inside); run `mocapflow init "
                             f"{folder.parent}`, the folder that holds it (and other sequences)")
        text = (_head(kind)
                + "data_roots: [.]\n"
                "storage:\n  root: storage/\n  region_frames: 32\n"
                f"datasets:\n  recordings:\n    kind: {kind}\n    path: .\n"
                + DEFAULT_STAGES)
        return text, []
    return write


# ---- the suit: a studio rehearsal with a rig like the user's -------------------------------------------
def _suit(folder: Path) -> tuple[str, list[str]]:
    import numpy as np

    from mocapflow.systems.deepmocap.readers import read_calibration_yaml

    seqs = [folder] if _is_calibrated_sequence(folder) else \
        sorted(p for p in _entries(folder) if p.is_dir() and _is_calibrated_sequence(p))
    calib = _at_door(folder, "suit", read_calibration_yaml, seqs[0])  # checked as a depth recording's calibration
    cams = list(calib["cameras"].values())
    count = min(max(len(cams), 2), 64)  # two at least: a corner is triangulated from two views
    width, height = max(int(c.width) for c in cams), max(int(c.height) for c in cams)
    sized = ""
    if min(width, height) < SUIT_MIN_PX[0] or max(width, height) < SUIT_MIN_PX[1]:
        sized = (f"; your images' {width} x {height} would give the shipped networks too few pixels per square (they "
                 "read the suit at about a pixel per mm on the body), so the rehearsal films 1536 x 2048")
        width, height = 1536, 2048
    centres = np.array([np.asarray(c.cam_to_world)[:3, 3] for c in cams])
    radius = float(np.median(np.linalg.norm(centres[:, :2] - centres[:, :2].mean(0), axis=1))) if count > 1 else 3.0
    radius = round(radius, 2) if 1.0 <= radius <= 10.0 else 3.0
    notes = [f"the suit has no reader of recorded images yet (its only dataset kind is the studio's studio_suit), so "
             f"your images in {[s.name for s in seqs]} are NOT read: the catalog is a studio rehearsal, the suit filmed "
             f"on the studio's body by a ring of {count} cameras of {width} x {height} at {radius:g} m like yours (count "
             f"and image size from your calibration{sized}); a reader of suit image folders is missing in systems/suit"]
    text = (_head("suit")
            + "# The suit has NO reader of recorded images yet: this catalog does not read your images. It films the\n"
            "# suit in the studio (kind studio_suit, on the Anny mesh body) with a ring of cameras like your rig's\n"
            "# (their count and image size from your calibration.yaml), to rehearse the chain and its figures.\n"
            "data_roots: [.]\n"
            "storage:\n  root: storage/\n  region_frames: 4\n"
            "datasets:\n  rehearsal:\n    kind: studio_suit\n    suit: medium\n"
            f"    cameras: {{count: {count}, width: {width}, height: {height}, radius: {radius}}}\n"
            "    defaults: {frames: 2, fps: 5.0, start_s: 0.5}   # a few frames: each is a dozen megapixels to read\n"
            "    sequences:\n      squat: {motion: classic_squat, seed: 1}\n"
            "stages:\n"
            "  images: {task: ingest_suit, dataset: rehearsal}\n"
            "  corners: {task: find_corners, inputs: [images]}\n"
            "  quads: {task: find_quads, inputs: {images: images, corners: corners}}\n"
            "  codes: {task: read_codes, inputs: {images: images, corners: corners, quads: quads}}\n"
            "  labels: {task: label_corners, inputs: {images: images, corners: corners, quads: quads, codes: codes}}\n"
            "  grown: {task: grow_labels, inputs: {images: images, corners: corners, labels: labels}}\n"
            "  points: {task: triangulate_corners, inputs: {labels: grown, images: images}}\n"
            "  filled: {task: fill_suit, inputs: {points: points, images: images}}\n"
            "evaluation:\n  sequences: \"*\"\n")
    return text, notes


CHECKED_AT_INIT = ("markers", "dmc", "suit")  # read at the door by init itself
WRITERS = {"markers": _markers, "dmc": _dmc, "zarr": _raw("zarr"), "images": _raw("images"), "suit": _suit}
