"""Clothing over the mesh body: a cloth layer that carries the tape, moves it and partly hides it.

DeepMoCap's subjects wear the reflector set over their clothes (Chatzitofis et al. 2019, §3.1: the sticky straps and
patches are "effortlessly placed", "approximately" where Figure 2 shows). With a sequence's ``cloth_cm: c`` the mesh
studio (tasks/deepmocap/film/mesh_synth.py) films a cloth surface instead of the skin:

- **thickness** (``cloth_thickness``): the skin pushed out along its normal by 0 to ``c`` cm, a base per body part
  (tight on one, loose on another) plus folds as low-frequency noise (wavelengths 10-30 cm), smoothed over the mesh so
  that it has no steps; the head and hands stay bare. Depth, IR and scene flow are those of the cloth surface.
- **slip** (``tape_slips``): a tape on cloth sits where the cloth put it: moved along its segment (and a patch
  sideways) by up to SLIP_M, and out with the cloth, its whole shift held under SHIFT_CAP_M; the ground truth
  reflectors are where the tape is.
- **folds over the tape** (``fold_cover``): a fold lying over part of a strap or patch hides it; the hidden share
  varies per tape (none to about half).

The cloth is a displaced skin: it follows the body rigidly (no dynamics, no sliding over time), and its folds are
fixed on the rest pose. Pure functions of arrays and seeded random generators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from mocapflow.tasks.shared.mesh_body import MeshBody, part_of_bone
from mocapflow.tasks.studio.mesh_render import vertex_normals

CLOTH_MAX_M = 0.03  # sportswear to a sweatshirt's fold: 0-3 cm off the skin (the range; an assumption)
BARE_PARTS = ("head", "l_hand", "r_hand")  # face and hands are not covered
BASE_RANGE = (0.25, 0.8)  # a part's base thickness, as a share of the cloth's maximum (tight to loose)
FOLD_AMPLITUDE = 0.45  # the folds' swing, as a share of the maximum
FOLD_WAVELENGTHS_M = (0.10, 0.30)  # low-frequency folds: a sleeve's or a shirt's, 10-30 cm apart (an assumption)
SMOOTH_ITERATIONS = 8  # neighbour averaging over the mesh's edges (each step ~1-2 cm on Anny's mesh)
SLIP_M = 0.015  # a tape on cloth ends up to 1.5 cm from where it was meant to be (placement is approximate, §3.1)
SHIFT_CAP_M = 0.025  # slip and the cloth's thickness together move a tape at most this much (the issue: 2-3 cm)
COVER_WAVELENGTHS_M = (0.04, 0.09)  # a fold over a tape is a few cm wide (an assumption)
COVER_THRESHOLD_RANGE = (0.2, 1.3)  # per tape: a fold hides it where the fold field exceeds this (> 1: nowhere)
ON_CLOTH_M = 0.003  # a tape is on cloth (and can slip and be hidden) where the cloth is at least this thick


class ClothError(ValueError):
    """A cloth layer the studio cannot make."""


@dataclass(frozen=True)
class Cloth:
    thickness: np.ndarray  # (vertex,) metres off the skin
    cover_waves: np.ndarray  # (3, 3) fold-over-tape waves, cycles per metre (rest pose)
    cover_phase: np.ndarray  # (reflector, 3)
    cover_threshold: np.ndarray  # (reflector,) inf: never hidden


def _waves(rng: np.random.Generator, count: int, wavelengths: tuple[float, float]) -> np.ndarray:
    """``count`` plane waves in random directions, wavelengths drawn in ``wavelengths``: (count, 3) cycles/m."""
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d / rng.uniform(*wavelengths, (count, 1))


def _field(waves: np.ndarray, phase: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Mean of sines of plane waves at ``points`` (n, 3): in [-1, 1].  phase (3,) or (n, 3) -> (n,)"""
    return np.sin(2 * np.pi * points @ waves.T + phase).mean(axis=1)


def cloth_thickness(body: MeshBody, max_m: float, rng: np.random.Generator) -> np.ndarray:
    """Each vertex's cloth thickness, 0 to ``max_m``: a base per fine body part plus folds, smoothed.  -> (vertex,)"""
    if not 0 <= max_m <= CLOTH_MAX_M:
        raise ClothError(f"cloth thickness {100 * max_m:g} cm is outside 0-{100 * CLOTH_MAX_M:g} cm; clothes stand "
                         f"0-3 cm off the skin, give a thickness in that range")
    parts = sorted({part_of_bone(n) for n in body.bone_names})
    base = dict(zip(parts, rng.uniform(*BASE_RANGE, len(parts))))
    vertex_part = np.array([part_of_bone(n) for n in body.bone_names])[body.vertex_bone]
    waves = _waves(rng, 3, FOLD_WAVELENGTHS_M)
    folds = _field(waves, rng.uniform(0, 2 * np.pi, 3), body.vertices)
    bare = np.isin(vertex_part, BARE_PARTS)
    share = np.array([base[p] for p in vertex_part]) + FOLD_AMPLITUDE * folds
    thick = np.where(bare, 0.0, np.clip(share, 0.0, 1.0) * max_m)
    edges = np.concatenate([body.faces[:, [0, 1]], body.faces[:, [1, 2]], body.faces[:, [2, 0]]])
    n = len(body.vertices)
    adjacency = sparse.coo_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]],
                                                             np.r_[edges[:, 1], edges[:, 0]])), shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0  # shared edges counted once
    mean = sparse.diags(1.0 / np.maximum(np.asarray(adjacency.sum(axis=1)).ravel(), 1.0)) @ adjacency
    for _ in range(SMOOTH_ITERATIONS):
        thick = 0.5 * thick + 0.5 * (mean @ thick)
    return np.where(bare, 0.0, np.clip(thick, 0.0, max_m))  # smoothing tapers the cloth towards the bare parts


def cloth_vertices(vertices: np.ndarray, faces: np.ndarray, thickness: np.ndarray) -> np.ndarray:
    """The cloth surface over posed skin ``vertices`` (vertex, 3): each pushed out along its normal.  -> (vertex, 3)"""
    return vertices + vertex_normals(vertices, faces) * thickness[:, None]


def tape_thickness(body: MeshBody, placements, thickness: np.ndarray) -> np.ndarray:
    """The cloth's thickness under each tape (a patch's face, a strap's ring).  -> (reflector,)"""
    return np.array([thickness[p.ring].mean() if p.kind == "strap" else thickness[body.faces[p.face]].mean()
                     for p in placements])


def tape_slips(under: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each tape's slip on the cloth (along its segment, sideways), metres, from the cloth's thickness ``under`` it:
    up to SLIP_M in a random direction, none on bare skin, and with the thickness within SHIFT_CAP_M.
    (reflector,) -> (reflector, 2)"""
    angle = rng.uniform(0, 2 * np.pi, len(under))
    size = rng.uniform(0.3, 1.0, len(under)) * SLIP_M
    size = np.minimum(size, np.sqrt(np.maximum(SHIFT_CAP_M**2 - under**2, 0.0)))
    size = np.where(under >= ON_CLOTH_M, size, 0.0)
    return np.column_stack([size * np.cos(angle), size * np.sin(angle)])


def make_cloth(body: MeshBody, max_m: float, under: np.ndarray, thickness: np.ndarray,
               rng: np.random.Generator) -> Cloth:
    """The cloth of a take: its ``thickness`` (cloth_thickness) and its folds over the tapes (``under``: the
    thickness under each, tape_thickness); a tape on bare skin is never hidden."""
    waves = _waves(rng, 3, COVER_WAVELENGTHS_M)
    phase = rng.uniform(0, 2 * np.pi, (len(under), 3))
    threshold = np.where(under >= ON_CLOTH_M, rng.uniform(*COVER_THRESHOLD_RANGE, len(under)), np.inf)
    return Cloth(thickness, waves, phase, threshold)


def fold_cover(cloth: Cloth, rid: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Which tape points a fold hides: rid (n,) tape index (>= 0), rest (n, 3) rest-pose points.  -> (n,) bool"""
    if not len(rid):
        return np.zeros(0, bool)
    return _field(cloth.cover_waves, cloth.cover_phase[rid], rest) > cloth.cover_threshold[rid]


def hidden_share(cloth: Cloth, rid: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Share of each tape's points (rid (n,), rest (n, 3)) a fold hides.  -> (reflector,)"""
    hidden = fold_cover(cloth, rid, rest)
    count = np.bincount(rid, minlength=len(cloth.cover_threshold))
    return np.bincount(rid, weights=hidden, minlength=len(count)) / np.maximum(count, 1)
