"""The studio's sequences as the catalog and the CLI give them: specs checked, motion files read, fingerprints, and
the take of each sequence (tasks/studio/take.py) made once per worker. The filming modules beside this one turn a
take into one system's raw dataset from that system's package (systems/deepmocap/film.py, systems/uuo/film.py,
systems/suit/film.py).

A studio sequence in a catalog::

    sequences:
      jj_s1: {motion: jumping_jack, seed: 1, subject_height: 1.72}
      walk:  {motion: ../shared/data/motions/cmu_12_01_walk.bvh, seed: 7}

``motion`` is an exercise name, a .bvh path or an .amc take with ``skeleton: subject.asf`` beside it
(``amc_fps``: its frame rate, 120 by default as in the CMU database), paths inside ``data_roots``;
``motion_map: my_map.yaml`` gives a skeleton no known naming fits a joint map (YAML ``{template joint:
BVH joint}``). Files are read here and parsed by formats/ (bvh.py; asf_amc.py reads an AMC take and its skeleton
straight into the same clip); the studio itself (tasks/studio, retarget.py) only sees the parsed clip. The
realism switches ``tape``, ``cloth_cm`` and ``tof_artefacts`` (all off by default) film DeepMoCap's reflectors and
sensors as they really are.
``time_base_fps`` puts a take on a clock (tasks/studio/take.py): every dataset of a catalog's ``joint_take``
films on one (120 fps unless given), so all its systems sample the same motion.
"""

from __future__ import annotations

import dataclasses
import hashlib
import typing
import warnings
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from typing import Any, Callable, Mapping

import yaml

from mocapflow.formats.asf_amc import CMU_FPS, ASFError, read_asf_amc
from mocapflow.formats.bvh import parse_bvh
from mocapflow.pipeline.errors import CatalogError, InputError, InputWarning
from mocapflow.pipeline.hashing import digest
from mocapflow.pipeline.registry import coerce, did_you_mean
from mocapflow.tasks.shared.bvh_clip import BVHClip, BVHError
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.studio import retarget
from mocapflow.tasks.studio.cameras import layout as camera_layout
from mocapflow.tasks.studio.cameras import outside_share
from mocapflow.tasks.studio import motion as motion_mod
from mocapflow.tasks.studio.motion import EXERCISES
from mocapflow.tasks.studio.spec import (MESH_STUDIO_VERSION, REALISM_FIELDS, REALISM_VERSION, STUDIO_VERSION,
                                         SequenceSpec)
from mocapflow.tasks.studio.take import TIME_BASE_FPS, Take, make_take, realism

SPEC_FIELDS = {f.name: f for f in dataclasses.fields(SequenceSpec)}
_TAKES: BoundedCache[str, Take] = BoundedCache(4)  # fingerprint -> take, this process


# Keys of a sequence that say where its motion file's skeleton and rate are, not what the studio films.
MOTION_FILE_KEYS = ("skeleton", "amc_fps")


@dataclass(frozen=True)
class MotionSource:
    """A sequence's motion file: a BVH clip, or an AMC take with its ASF skeleton and frame rate."""

    path: str
    skeleton: str | None = None
    amc_fps: float | None = None

    def __str__(self) -> str:
        return self.path if self.skeleton is None else f"{self.path} (skeleton {self.skeleton})"


@dataclass(frozen=True)
class MotionFile:
    """A sequence's motion file as read: the parsed clip, and the digest of the text it was parsed from."""

    clip: BVHClip
    digest: str  # sha256 of the BVH text; of the ASF, the AMC and the rate for an AMC take (fingerprint's "bvh")


def make_spec(raw: Mapping[str, Any], where: str, resolve: Callable[[str], Path],
              layout: Mapping | None = None,
              origin: Mapping[str, str] | None = None,
              skeleton_hint: str = "add skeleton: subject.asf"
              ) -> tuple[SequenceSpec, MotionFile | None, MotionSource | None]:
    """A validated SequenceSpec, the motion file read (or None for an exercise) and where it comes from, from a
    mapping of spec fields (and MOTION_FILE_KEYS). ``origin``: where each field was given (its catalog line), for its
    errors (else ``where.<field>``)."""
    raw = dict(raw)
    at = {k: (origin or {}).get(k, f"{where}.{k}") for k in raw}
    files = {k: raw.pop(k) for k in MOTION_FILE_KEYS if k in raw}
    for key in raw:
        if key not in SPEC_FIELDS:
            known = sorted(set(SPEC_FIELDS) | set(MOTION_FILE_KEYS))
            raise CatalogError(f"{at[key]}: unknown studio field {key!r}{did_you_mean(key, known)}; fields: {known}")
    if "motion" not in raw:
        raise CatalogError(f"{where}: no 'motion'; give an exercise name ({', '.join(sorted(EXERCISES))}), a .bvh "
                           "clip or an .amc take (with skeleton: its .asf)")
    motion = str(raw["motion"])
    source = motion_source(motion, files, where, resolve, skeleton_hint)
    motion_file = None
    if source is not None:
        motion_file = load_motion(source, where)
        raw["motion"] = "bvh"
        raw.setdefault("label", Path(source.path).stem)
        raw.setdefault("frames", None)
    elif motion not in EXERCISES:
        raise CatalogError(f"{at.get('motion', where)}: unknown exercise {motion!r}{did_you_mean(motion, EXERCISES)}; "
                           f"use one of {sorted(EXERCISES)}, a .bvh clip or an .amc take")
    if raw.get("layout") is not None:  # a sequence's own layout file, read like the dataset's
        if not isinstance(raw["layout"], str):
            raise CatalogError(f"{at['layout']}: expected a camera layout file (a path, read like the dataset's "
                               f"layout), got {raw['layout']!r}")
        raw["layout"] = read_layout(resolve(raw["layout"]), at["layout"])
    elif layout is not None:
        raw["layout"] = layout
    if raw.get("motion_map") is not None:
        raw["motion_map"] = read_motion_map(resolve(str(raw["motion_map"])), f"{where}.motion_map")
    hints = typing.get_type_hints(SequenceSpec)
    values = {k: coerce(v, hints[k], at.get(k, f"{where}.{k}")) if k not in ("layout", "motion_map") else v
              for k, v in raw.items()}
    try:
        spec = SequenceSpec(**values)
        if spec.layout is not None:
            camera_layout(spec.layout, views=spec.views)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{where}: {exc}") from exc
    if motion_file is not None:
        check_clip(spec, motion_file.clip, source, where)
    return spec, motion_file, source


def motion_source(motion: str, files: Mapping[str, Any], where: str, resolve: Callable[[str], Path],
                  skeleton_hint: str = "add skeleton: subject.asf") -> MotionSource | None:
    """Where a ``motion`` that names a file comes from (None for an exercise), its MOTION_FILE_KEYS checked;
    ``skeleton_hint``: how to give an AMC take's missing skeleton (a catalog key, a command's option)."""
    suffix = Path(motion).suffix.lower()
    if suffix == ".asf":
        raise CatalogError(f"{where}: {motion} is a skeleton; give the take as the motion and the skeleton beside "
                           f"it: motion: take.amc, skeleton: {motion}")
    if suffix != ".amc":
        if files:
            raise CatalogError(f"{where}: {sorted(files)} belong to an AMC take (motion: take.amc); "
                               f"{motion!r} needs none, so leave them out")
        return MotionSource(str(resolve(motion))) if suffix == ".bvh" else None
    if "skeleton" not in files:
        raise CatalogError(f"{where}: the AMC take {motion} needs its ASF skeleton: {skeleton_hint}")
    fps = coerce(files.get("amc_fps", CMU_FPS), float, f"{where}.amc_fps")
    if not fps > 0:
        raise CatalogError(f"{where}: amc_fps must be positive (the take's frame rate; CMU's is 120), got {fps}")
    return MotionSource(str(resolve(motion)), str(resolve(str(files["skeleton"]))), fps)


def read_motion(source: MotionSource, where: str) -> BVHClip:
    """The sequence's motion as a parsed clip (what a worker makes its take from)."""
    return load_motion(source, where).clip


def load_motion(source: MotionSource, where: str) -> MotionFile:
    """The motion file read and parsed by formats/ (a BVH clip, or an AMC take with its ASF skeleton read straight
    into a clip) with the digest its fingerprint hashes; InputError names the file, what is wrong and the fix."""
    if source.skeleton is None:
        text = _read_text(source.path, "BVH", where)
        try:
            clip = parse_bvh(text)
        except BVHError as exc:
            raise InputError(f"{where}: {source} is not a valid BVH file: {exc}") from exc
        return MotionFile(clip, hashlib.sha256(text.encode()).hexdigest())
    asf_text, amc_text = _read_text(source.skeleton, "ASF skeleton", where), _read_text(source.path, "AMC take", where)
    try:
        clip = read_asf_amc(asf_text, amc_text, source.amc_fps)
    except ASFError as exc:
        raise InputError(f"{where}: {source} cannot be read: {exc}") from exc
    texts = {"asf": hashlib.sha256(asf_text.encode()).hexdigest(), "amc": hashlib.sha256(amc_text.encode()).hexdigest()}
    return MotionFile(clip, digest({**texts, "amc_fps": source.amc_fps}, length=64))


def _read_text(path: str, what: str, where: str) -> str:
    try:
        return Path(path).read_text()
    except OSError as exc:
        raise InputError(f"{where}: cannot read {what} {path}: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise InputError(f"{where}: {what} {path} is not text (byte {exc.start} is not UTF-8); give the motion "
                         "file as the BVH, ASF or AMC text it should be") from exc


def check_clip(spec: SequenceSpec, clip: BVHClip, source: MotionSource, where: str) -> None:
    """Everything a worker would find wrong with a parsed clip, found now: its skeleton (a joint map that fits it)
    and its length at the sequence's fps, start and frames (its syntax was checked as it was read)."""
    try:
        retarget.joint_map(clip, spec.motion_map)
    except BVHError as exc:
        fix = ("fix the map" if spec.motion_map is not None else
               "write that map as YAML and name it in the sequence or its dataset's defaults, motion_map: my_map.yaml "
               "(mocapflow synth: --motion-map my_map.yaml)")
        raise InputError(f"{where}: the skeleton of {source} cannot be retargeted onto the template: {exc}; "
                         f"{fix} (see docs/studio.md, 'Motion files')") from exc
    available = retarget.available_frames(clip, spec.fps, spec.start_s)
    needed = 2 if spec.frames is None else spec.frames + 1  # one more frame gives the last one's scene flow
    if spec.start_s < 0 or available < needed:
        duration = (clip.data.shape[0] - 1) * clip.frame_time
        raise InputError(f"{where}: {source} holds {max(available - 1, 0)} frames at {spec.fps:g} fps from "
                         f"start_s {spec.start_s:g} (the clip lasts {duration:.2f} s); asked for "
                         f"{spec.frames or 'at least 1'}: lower frames or start_s")


def read_motion_map(path: Path, where: str) -> dict[str, str]:
    """A BVH joint map file: YAML ``{template joint: BVH joint}`` (tasks/studio/retarget.py, joint_map)."""
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"{where}: cannot read the joint map {path}: {exc}") from exc
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise InputError(f"{where}: the joint map {path} must be a YAML mapping of template joint to BVH joint, "
                         f"e.g. 'LeftHip: thigh_l', one a line; got {data!r:.80}")
    return data


def read_layout(path: Path, where: str) -> dict:
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"{where}: cannot read camera layout {path}: {exc}") from exc
    if not isinstance(data, dict) or not ({"ring", "sensors"} & set(data)):
        raise InputError(f"{where}: camera layout {path} needs 'ring: {{count, radius, height}}' or "
                         "'sensors: [{name, position}]'")
    return data


def frame_count(spec: SequenceSpec, motion_file: MotionFile | None) -> int:
    """Frames the sequence will have (a clip's length at the studio's fps, less one for scene flow)."""
    if spec.frames is not None:
        return spec.frames
    return retarget.available_frames(motion_file.clip, spec.fps, spec.start_s) - 1


# Spec fields added after a studio version enter the fingerprint only when set, so caches of sequences
# that leave them at their default stay valid.
LATER_FIELDS = ("variation", "body", "motion_map", "camera_roll_deg", "ir_bloom_px", "time_base_fps") + REALISM_FIELDS


def fingerprint(spec: SequenceSpec, motion_file: MotionFile | None) -> str:
    """What the sequence's take is made of: its spec, its motion file's digest (a BVH clip's is its text's sha256,
    as before clips were parsed in formats/) and the studio's versions."""
    bvh_hash = motion_file.digest if motion_file is not None else None
    fields = {k: v for k, v in dataclasses.asdict(spec).items()
              if k not in LATER_FIELDS or v != SPEC_FIELDS[k].default}
    content = {"spec": fields, "bvh": bvh_hash, "studio": STUDIO_VERSION}
    if bvh_hash and (spec.frames is not None or spec.start_s):  # a clip cut to a window is centred on it (retarget)
        content["centred_on"] = "window"
    if spec.variation:
        content["variation"] = variation_ranges()
    if spec.body == "mesh":
        content["mesh"] = {"studio": MESH_STUDIO_VERSION, "anny": version("anny")}
    if realism(spec).any:
        content["realism"] = REALISM_VERSION
    return digest(content)


def variation_ranges() -> dict:
    """The ranges a varied sequence is drawn from: a varied sequence is re-rendered when they change."""
    return {"joints": [list(row) for row in motion_mod.VARIATION], "heading_deg": motion_mod.HEADING_SWING_DEG,
            "root_speed_m_s": motion_mod.ROOT_SPEED_M_S, "root_drift_m": motion_mod.ROOT_DRIFT_M}


def take_for(seq) -> Take:
    """The take of a sequence whose spec holds its SequenceSpec (``spec``) and motion source (``source``), made once
    per worker process."""
    def make() -> Take:
        source = seq.spec["source"]
        clip = read_motion(source, f"sequence {seq.id}") if source else None
        return make_take(seq.spec["spec"], clip)

    return _TAKES.get_or_make(seq.fingerprint, make)


def sequence_specs(catalog, dataset, kind: str, *, mesh_only: bool = False, forced: Mapping[str, Any] | None = None,
                   layout: Mapping | None = None) -> list[tuple[str, str, dict, tuple]]:
    """Per sequence of a studio dataset: (id, where, its ``EXTRA_KEYS`` fields, (spec, motion file, its source)).
    A sequence's fields are the dataset's ``defaults`` and its own; ``mesh_only``: the take is filmed on the mesh
    body (another ``body`` is refused); ``forced`` fields are set whatever was given. A dataset that films the
    catalog's joint take samples each take on the joint clock (``time_base_fps``: TIME_BASE_FPS unless given), so
    every system's truth of an instant is the same."""
    joint_take = getattr(catalog, "joint_take", None)
    joint = joint_take is not None and dataset.name in joint_take.datasets
    opts = dataset.options  # its keys were checked against the reader's options when the catalog was loaded
    sequences = opts.get("sequences") or {}
    if not isinstance(sequences, dict) or not sequences:
        raise CatalogError(f"{dataset.where}: a {kind} dataset needs 'sequences: {{id: {{motion: ...}}}}'")
    out = []
    defaults = opts.get("defaults") or {}
    for seq_id, body in sequences.items():
        where = dataset.where_of("sequences", seq_id)
        fields = {**defaults, **(body or {})}
        # a field's errors name its own line: the sequence's, or the defaults' where it came from there
        origin = {k: dataset.where_of(*(("defaults", k) if k not in (body or {}) else ("sequences", seq_id, k)))
                  for k in fields}
        extra = {k: fields.pop(k) for k in EXTRA_KEYS if k in fields}
        if joint:  # one performance for every system: its motion sampled once, on one clock (take.py)
            fields.setdefault("time_base_fps", TIME_BASE_FPS)
        if mesh_only and fields.setdefault("body", "mesh") != "mesh":
            raise CatalogError(f"{where}: {kind} takes are filmed on the mesh body; drop 'body' or set it to mesh")
        fields.update(forced or {})
        spec = make_spec(fields, where, lambda p, w=where: catalog.resolve_data_path(p, w), layout, origin)
        out.append((str(seq_id), where, extra, spec))
    return out


EXTRA_KEYS = ("markers",)  # sequence keys a filming module reads itself (UUO's marker layout)


# ---- the subject in the cameras' view ----------------------------------------------------------------------------
VIEW_CHECKS = ("warn", "refuse", "off")  # a studio dataset's ``out_of_view``: what a subject leaving a view does
OUT_OF_VIEW_SHARE = 0.05  # a camera missing more than this share of the subject's joint-frames is reported


def view_check(dataset) -> str:
    """A studio dataset's ``out_of_view`` setting, checked: ``warn`` (default), ``refuse`` or ``off``."""
    raw = dataset.options.get("out_of_view", "warn")
    value = "off" if raw is False else str(raw)  # YAML reads a bare off as false
    if value not in VIEW_CHECKS:
        raise CatalogError(f"{dataset.where}.out_of_view: {value!r} is not one of {list(VIEW_CHECKS)}; warn (the "
                           "default) reports a subject leaving a camera's view, refuse fails its sequence")
    return value


def check_in_view(seq_id: str, cameras, joints, setting: str) -> None:
    """Warn (``InputWarning``) or refuse (``InputError``) when a camera cannot see more than OUT_OF_VIEW_SHARE of the
    subject's joint-frames ``joints`` (frame, joint, 3): a travelling clip walking out of the volume, a camera
    aimed away. The check covers the whole take, once per worker."""
    if setting == "off":
        return
    share = outside_share(cameras, joints)
    bad = {cam.name: float(s) for cam, s in zip(cameras, share) if s > OUT_OF_VIEW_SHARE}
    if not bad:
        return
    shares = ", ".join(f"{name} {100 * s:.0f} %" for name, s in sorted(bad.items()))
    message = (f"sequence {seq_id!r}: the subject leaves the view of {len(bad)} camera(s) (joint-frames outside: "
               f"{shares}); film a shorter window (frames, start_s), move the cameras, or set the dataset's "
               "out_of_view: off")
    if setting == "refuse":
        raise InputError(message)
    warnings.warn(message, InputWarning, stacklevel=2)
