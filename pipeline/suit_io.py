"""Checkerboard-suit takes filmed in the studio, as a dataset kind (``studio_suit``).

    datasets:
      suit_train:
        kind: studio_suit
        suit: small                          # the print: small (about 1,100 corners) or medium (about 1,400)
        cameras: {count: 12, width: 1536, height: 2048, radius: 3.0}
        look: {noise: 1.0, blur_px: [0.3, 0.7]}
        defaults: {frames: 30}
        sequences:
          squat_s11: {motion: classic_squat, seed: 11}
          walk: {motion: ../shared/data/motions/cmu_12_01_walk.bvh, seed: 9001}

Sequences take the studio's fields (tasks/studio/synth.py SequenceSpec; the body is always the mesh body). The
suit is printed on the reference body's UV layout once per size, so every subject wears the same pattern.
"""

from __future__ import annotations

import dataclasses
from importlib.metadata import version
from typing import Any, Mapping

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.errors import CatalogError
from mocapflow.pipeline.hashing import digest
from mocapflow.pipeline.registry import coerce, did_you_mean
from mocapflow.pipeline.studio_io import fingerprint, frame_count, make_spec
from mocapflow.schemas.raw import DIST_COEFS
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.studio import suit_takes
from mocapflow.tasks.studio.synth import build_rig
from mocapflow.tasks.suit.pattern import SUITS, Suit, make_suit

_RIGS: BoundedCache[str, tuple] = BoundedCache(2)  # fingerprint -> (mesh rig, suit rig), this process
_SUITS: BoundedCache[str, Suit] = BoundedCache(4)


def reference_suit(name: str) -> Suit:
    """The suit ``name`` printed on the reference body's UV layout (the same garment for every subject)."""
    def make() -> Suit:
        ref = mesh_body(Phenotype())
        return make_suit(ref.uv, ref.vertices, ref.faces, ref.skin, SUITS[name])

    return _SUITS.get_or_make(name, make)


def _settings(opts: Mapping[str, Any], where: str) -> tuple[str, suit_takes.SuitCameras, suit_takes.SuitLook]:
    name = str(opts.get("suit", "medium"))
    if name not in SUITS:
        raise CatalogError(f"{where}.suit: unknown suit {name!r}{did_you_mean(name, SUITS)}; suits: {sorted(SUITS)}")
    cams = coerce(opts.get("cameras") or {}, suit_takes.SuitCameras, f"{where}.cameras")
    look = coerce(opts.get("look") or {}, suit_takes.SuitLook, f"{where}.look")
    return name, cams, look


def discover(catalog, dataset) -> list:
    from mocapflow.pipeline.datasets import SequenceInfo

    opts = dataset.options
    sequences = opts.get("sequences") or {}
    if not isinstance(sequences, dict) or not sequences:
        raise CatalogError(f"{dataset.where}: a studio_suit dataset needs 'sequences: {{id: {{motion: ...}}}}'")
    name, cams, look = _settings(opts, dataset.where)
    out = []
    for seq_id, body in sequences.items():
        where = f"{dataset.where}.sequences.{seq_id}"
        fields = {**(opts.get("defaults") or {}), **(body or {})}
        if fields.setdefault("body", "mesh") != "mesh":
            raise CatalogError(f"{where}: suit takes are filmed on the mesh body; drop 'body' or set it to mesh")
        fields["views"] = 1  # the Kinect ring of the studio spec is not used; the suit's cameras film
        spec, text, path = make_spec(fields, where, lambda p, w=where: catalog.resolve_data_path(p, w))
        fp = digest({"take": fingerprint(spec, text), "suit": name, "cameras": dataclasses.asdict(cams),
                     "look": dataclasses.asdict(look), "studio": suit_takes.SUIT_STUDIO_VERSION})
        views = tuple(f"cam{i:02d}" for i in range(cams.count))
        out.append(SequenceInfo(str(seq_id), views, frame_count(spec, text), fp,
                                {"spec": spec, "bvh_text": text, "suit": name, "cameras": cams, "look": look}))
    return out


def rig_for(seq) -> tuple:
    def build():
        info = seq.spec
        mesh_rig = build_rig(info["spec"], info["bvh_text"])
        rig = suit_takes.suit_rig(mesh_rig.body, reference_suit(info["suit"]), info["cameras"], info["look"],
                                  info["spec"].seed)
        return mesh_rig, rig

    return _RIGS.get_or_make(seq.fingerprint, build)


def read(dataset, seq, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of a suit take in the suit_images schema, with ground truth."""
    mesh_rig, rig = rig_for(seq)
    shot = suit_takes.film(rig, mesh_rig.take.posed.vertices, range(start, stop))
    return suit_dataset(rig, mesh_rig, shot, seq, start, stop)


def suit_dataset(rig: suit_takes.SuitRig, mesh_rig, shot: suit_takes.SuitFrames, seq, start: int, stop: int) -> xr.Dataset:
    suit, cams, n = rig.suit, rig.cameras, stop - start
    quats = Rotation.from_matrix(mesh_rig.take.rotations[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    data = {
        "image": (("view", "frame", "y", "x"), shot.image),
        "timestamp": (("frame",), np.arange(start, stop) / float(mesh_rig.spec.fps)),
        "dist": (("view", "dist_coef"), np.array([c.dist for c in cams], float)),
        "cam_to_world": (("view", "row", "col"), np.array([c.cam_to_world for c in cams], float)),
        **{k: (("view",), np.array([float(getattr(c, k)) for c in cams])) for k in ("fx", "fy", "cx", "cy")},
        **{k: (("view",), np.array([int(getattr(c, k)) for c in cams], np.int64)) for k in ("width", "height")},
        "code": (("square",), np.array(suit.codes, dtype=object)),
        "square_corners": (("square", "k"), suit.square_corners.astype(np.int64)),
        "cells": (("cell", "k"), suit.cells.astype(np.int64)),
        "corner_face": (("corner",), suit.corner_face.astype(np.int64)),
        "corner_bary": (("corner", "uv"), suit.corner_bary.astype(np.float64)),
        "gt_corners": (("frame", "corner", "xyz"), shot.corners.astype(np.float32)),
        "gt_corners2d": (("view", "frame", "corner", "uv"), shot.corners2d.astype(np.float32)),
        "gt_visible": (("view", "frame", "corner"), shot.visible),
        "gt_readable": (("view", "frame", "corner"), shot.readable),
        "gt_joints": (("frame", "joint", "xyz"),
                      mesh_rig.take.posed.heads[start:stop][:, mesh_rig.body.joint_bones()].astype(np.float32)),
        "gt_bone_rotations": (("frame", "bone", "quat"), quats),
        "gt_root": (("frame", "xyz"), mesh_rig.take.root[start:stop]),
    }
    coords = {"view": np.array([c.name for c in cams], dtype=object), "frame": np.arange(start, stop, dtype=np.int64),
              "corner": np.arange(suit.n_corners, dtype=np.int64), "dist_coef": np.array(DIST_COEFS, dtype=object),
              "bone": np.array(mesh_rig.body.bone_names, dtype=object)}
    attrs = {"fps": float(mesh_rig.spec.fps), "suit": seq.spec["suit"], "length_unit": "m", "up_axis": "Z",
             "body_model": f"anny {version('anny')}", "phenotype": dataclasses.asdict(mesh_rig.body.phenotype),
             "suit_studio_version": suit_takes.SUIT_STUDIO_VERSION, "seed": int(mesh_rig.spec.seed),
             "motion": mesh_rig.motion.label}
    return xr.Dataset(data, coords=coords, attrs=attrs)
