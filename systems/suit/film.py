"""The suit's filming of the studio's takes (systems/studio): the dataset kind ``studio_suit``, the suit printed on
the take's posed body and filmed by a ring of grey cameras (tasks/suit/takes.py).

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

Sequences take the studio's fields (systems/studio/specs.py; the take of tasks/studio/take.py, always on the mesh
body: no Kinect rig is built). The
suit is printed on the reference body's UV layout once per size, so every subject wears the same pattern.
"""

from __future__ import annotations

import dataclasses
from importlib.metadata import version
from typing import Any, Mapping

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.pipeline.datasets import SequenceInfo
from mocapflow.pipeline.errors import CatalogError
from mocapflow.pipeline.hashing import digest
from mocapflow.pipeline.registry import coerce, did_you_mean
from mocapflow.schemas.raw import DIST_COEFS
from mocapflow.systems.studio.specs import check_in_view, fingerprint, frame_count, sequence_specs, take_for, view_check
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.suit.pattern import SUITS, Suit, make_suit
from mocapflow.tasks.suit import takes
from mocapflow.tasks.studio.take import Take

_RIGS: BoundedCache[str, tuple] = BoundedCache(2)  # fingerprint -> (take, suit rig), this process
_SUITS: BoundedCache[str, Suit] = BoundedCache(4)


def reference_suit(name: str) -> Suit:
    """The suit ``name`` printed on the reference body's UV layout (the same garment for every subject)."""
    def make() -> Suit:
        ref = mesh_body(Phenotype())
        return make_suit(ref, SUITS[name])

    return _SUITS.get_or_make(name, make)


def _settings(opts: Mapping[str, Any], where: str) -> tuple[str, takes.SuitCameras, takes.SuitLook]:
    name = str(opts.get("suit", "medium"))
    if name not in SUITS:
        raise CatalogError(f"{where}.suit: unknown suit {name!r}{did_you_mean(name, SUITS)}; suits: {sorted(SUITS)}")
    cams = coerce(opts.get("cameras") or {}, takes.SuitCameras, f"{where}.cameras")
    look = coerce(opts.get("look") or {}, takes.SuitLook, f"{where}.look")
    return name, cams, look


class StudioSuitReader:
    """Checkerboard-suit takes filmed in the studio by a ring of grey cameras, as suit_images with ground truth."""

    options = ("sequences", "defaults", "suit", "cameras", "look", "out_of_view")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        name, cams, look = _settings(dataset.options, dataset.where)
        views = tuple(takes.camera_names(cams.count))
        check = view_check(dataset)
        out = []
        # views = 1: the spec's Kinect ring is not filmed (the suit's cameras are); kept so the take's fingerprint stays
        for seq_id, _, _, (spec, text, source) in sequence_specs(catalog, dataset, "studio_suit", mesh_only=True,
                                                                 forced={"views": 1}):
            fp = digest({"take": fingerprint(spec, text), "suit": name, "cameras": dataclasses.asdict(cams),
                         "look": dataclasses.asdict(look), "studio": takes.SUIT_STUDIO_VERSION})
            out.append(SequenceInfo(seq_id, views, frame_count(spec, text), fp,
                                    {"spec": spec, "source": source, "suit": name, "cameras": cams, "look": look,
                                     "out_of_view": check}, image=(cams.height, cams.width)))
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        """Frames [start, stop) of a suit take in the suit_images schema, with ground truth."""
        take, rig = rig_for(seq)
        return film_take(take, rig, seq, start, stop)


def film_take(take: Take, rig: takes.SuitRig, seq, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of a take's posed body filmed by the suit's rig, in suit_images with its ground truth."""
    frames = takes.film(rig, take.mesh.posed.vertices, range(start, stop))
    return suit_dataset(rig, take, frames, seq, start, stop)


def rig_for(seq) -> tuple[Take, takes.SuitRig]:
    """The take and the suit's cameras filming it, made once per worker process."""
    def build():
        info = seq.spec
        shot, suit = take_for(seq), reference_suit(info["suit"])
        rig = takes.suit_rig(shot.body, suit, info["cameras"], info["look"], info["spec"].seed)
        check_in_view(seq.id, rig.cameras, shot.mesh.posed.heads[:shot.n_frames, shot.body.joint_bones()],
                      info.get("out_of_view", "warn"))
        return shot, rig

    return _RIGS.get_or_make(seq.fingerprint, build)


def suit_dataset(rig: takes.SuitRig, take: Take, shot: takes.SuitFrames, seq, start: int,
                 stop: int) -> xr.Dataset:
    suit, cams, n = rig.suit, rig.cameras, stop - start
    quats = Rotation.from_matrix(take.mesh.rotations[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    data = {
        "image": (("view", "frame", "y", "x"), shot.image),
        "timestamp": (("frame",), np.arange(start, stop) / float(take.spec.fps)),
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
                      take.mesh.posed.heads[start:stop][:, take.body.joint_bones()].astype(np.float32)),
        "gt_bone_rotations": (("frame", "bone", "quat"), quats),
        "gt_root": (("frame", "xyz"), take.mesh.root[start:stop]),
    }
    coords = {"view": np.array([c.name for c in cams], dtype=object), "frame": np.arange(start, stop, dtype=np.int64),
              "corner": np.arange(suit.n_corners, dtype=np.int64), "dist_coef": np.array(DIST_COEFS, dtype=object),
              "bone": np.array(take.body.bone_names, dtype=object)}
    attrs = {"fps": float(take.spec.fps), "suit": seq.spec["suit"], "length_unit": "m", "up_axis": "Z",
             "body_model": f"anny {version('anny')}", "phenotype": dataclasses.asdict(take.body.phenotype),
             "suit_studio_version": takes.SUIT_STUDIO_VERSION, "seed": int(take.spec.seed),
             "motion": take.motion.label}
    return xr.Dataset(data, coords=coords, attrs=attrs)
