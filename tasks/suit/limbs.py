"""Limbs the labelled corners do not hold, posed on the corner detections no label claims (beyond Chen et al. 2021).

The suit's body fit (tasks/suit/body_fit) poses a bone from the triangulated corners it carries. A limb whose corners
the 2D chain labels in no view (the forearms of bent, swinging arms: their squares are too bent to read) has no
corner at all, and the fit leaves it where its pose prior puts it, the rest pose's straight arm: 5-30 cm from the
truth, and hole filling (Eq. 8) has nothing to move it by. CornerdetNet still finds most of those corners; only their
labels are missing. So, in each frame where a searched bone's own part has fewer than ``min_corners`` observed
corners:

1. the bone is turned about its head (its world rotation times R, R over a grid of rotations within ``reach_deg``
   of the fitted pose, then finer grids about the best ``keep``), carrying every corner of its subtree; each R is
   scored by the corners of the bone's part that face a camera and fall in its image: sum over views and corners of
   max(0, 1 - (d / match_px)^2), d the distance to the nearest detection no label claims (labels of other corners
   claim the detections within ``claimed_px``);
2. at the best R each such corner takes, in each view, the nearest unclaimed detection within ``match_px`` (one
   corner per detection, the nearest), and is triangulated from them as the chain's labels are (tasks/suit/
   reconstruct, the 1.5 px rule of §3.3).

The caller fits the body again with these corners added (``fill.fill_suit_detections``); they are not observations
of the suit (``observed`` stays False) and do not constrain the non-articulated displacements of Eq. (8).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.cameras import Camera
from mocapflow.tasks.suit.reconstruct import ReconstructConfig, reconstruct_frames


class LimbError(ValueError):
    """Detections, labels, cameras or settings the limb search cannot use."""


@dataclass(frozen=True)
class LimbConfig:
    """min_corners, match_px and min_share chosen on training motions (benchmarks/suit_fill_tune.py)."""

    bones: tuple[str, ...] = ("upperarm01.L", "upperarm01.R", "lowerarm01.L", "lowerarm01.R")  # parents first
    min_corners: int = 20  # fewer observed corners of a bone's part in a frame: the bone is searched there
    reach_deg: float = 170.0  # the search's reach about the fitted pose
    coarse_deg: float = 10.0  # the first grid's step
    fine_deg: tuple[float, ...] = (3.0, 1.0)  # each finer grid's step, about the best ``keep`` of the last
    keep: int = 8
    match_px: float = 8.0  # a corner's detection lies this close to its predicted pixel
    claimed_px: float = 1.0  # a detection this close to another corner's label is that corner's
    min_share: float = 0.0  # the best pose's support over its corners facing a camera in its image (their views),
    # at least: below it the bone keeps its fitted pose and no corner is placed
    coarse_points: int = 16  # the first grid scores at most this many of the bone's corners (spread over them)

    def __post_init__(self):
        if self.min_corners < 0 or min(self.keep, self.coarse_points) < 1 \
                or min(self.coarse_deg, self.match_px, self.claimed_px, *self.fine_deg) <= 0 \
                or not 0 < self.reach_deg <= 180 or not 0 <= self.min_share <= 1:
            raise LimbError(f"limb search settings out of range: min_corners >= 0, keep and coarse_points >= 1, "
                            f"positive steps, match_px and claimed_px, 0 < reach_deg <= 180, 0 <= min_share <= 1 "
                            f"(got {self})")


@dataclass(frozen=True)
class View:
    """One camera and the detections of one frame no label claims."""

    camera: Camera
    tree: cKDTree | None  # over the unclaimed detections (n, 2); None where there is none


@dataclass(frozen=True)
class Limb:
    """A searched bone: its index, the corners it carries (its subtree's) and those scored (its own part's)."""

    bone: int
    subtree: np.ndarray  # (bone,) bool: the bone and the bones below it
    carried: np.ndarray  # (corner,) bool
    scored: np.ndarray  # (corner,) bool


# --- what the search sees ---------------------------------------------------------------------------------------------


def unclaimed(detections: np.ndarray, labels: np.ndarray, claimed_px: float) -> list[np.ndarray]:
    """Each frame's detections farther than ``claimed_px`` from every label.  detections (frame, detection, 2),
    labels (frame, corner, 2), NaN where none -> [(n, 2)] per frame"""
    out = []
    for det, lab in zip(detections, labels):
        det = det[np.isfinite(det).all(1)]
        lab = lab[np.isfinite(lab).all(1)]
        if len(det) and len(lab):
            near, _ = cKDTree(lab).query(det, distance_upper_bound=claimed_px)
            det = det[~np.isfinite(near)]
        out.append(det)
    return out


def views_of(cameras: Sequence[Camera], free: Sequence[np.ndarray]) -> list[View]:
    """One frame's views.  free: per view the unclaimed detections (n, 2)"""
    return [View(cam, cKDTree(d) if len(d) else None) for cam, d in zip(cameras, free)]


def limbs_of(bone_names: Sequence[str], bone_parents: np.ndarray, corner_bone: np.ndarray, part_of,
             bones: Sequence[str]) -> list[Limb]:
    """The searched bones.  corner_bone (corner,) each corner's dominant bone; part_of(name) -> its part."""
    unknown = [b for b in bones if b not in bone_names]
    if unknown:
        raise LimbError(f"the body has no bone {', '.join(map(repr, unknown))}; limbs.bones names Anny's bones "
                        "(e.g. lowerarm01.L)")
    names = list(bone_names)
    part = np.array([part_of(names[k]) for k in corner_bone])  # each corner's part
    out = []
    for name in bones:
        b = names.index(name)
        subtree = np.zeros(len(names), bool)
        subtree[b] = True
        for k in range(b + 1, len(names)):  # parents come first
            subtree[k] |= bone_parents[k] >= 0 and subtree[bone_parents[k]]
        out.append(Limb(b, subtree, subtree[corner_bone], part == part_of(name)))
    return out


# --- the search -------------------------------------------------------------------------------------------------------


def rotation_grid(step_deg: float, reach_deg: float) -> np.ndarray:
    """Rotations whose rotation vectors lie on a cubic grid of ``step_deg`` within ``reach_deg``.  -> (k, 3, 3)"""
    r = np.radians(np.arange(-reach_deg, reach_deg + 1e-9, step_deg))
    g = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    return Rotation.from_rotvec(g[np.linalg.norm(g, axis=1) <= np.radians(reach_deg) + 1e-9]).as_matrix()


def _posed(rotations: np.ndarray, pivot: np.ndarray, points: np.ndarray, normals: np.ndarray):
    """Points and normals turned by each rotation about ``pivot``.  -> (k, c, 3) x 2"""
    return (pivot + np.einsum("kij,cj->kci", rotations, points - pivot),
            np.einsum("kij,cj->kci", rotations, normals))


def _pixels(view: View, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Pixels of the points that face the camera and fall in its image, NaN elsewhere.  (..., 3) -> (..., 2)"""
    cam = view.camera
    facing = ((cam.cam_to_world[:3, 3] - points) * normals).sum(-1) > 0
    uv = np.full(points.shape[:-1] + (2,), np.nan)
    found, _ = cam.project(points[facing])  # NaN behind the camera
    inside = (found[:, 0] >= 0) & (found[:, 1] >= 0) & (found[:, 0] < (cam.width or np.inf)) \
        & (found[:, 1] < (cam.height or np.inf))
    uv[facing] = np.where(inside[:, None], found, np.nan)
    return uv


def score(rotations: np.ndarray, pivot: np.ndarray, points: np.ndarray, normals: np.ndarray,
          views: Sequence[View], match_px: float) -> np.ndarray:
    """Each rotation's support: sum over views and points of max(0, 1 - (d / match_px)^2), d the distance of the
    turned point's pixel to the nearest unclaimed detection; and how many (point, view) pairs it counts (the
    point faces the camera and falls in its image).  points, normals (c, 3) -> (k,) x 2"""
    moved, turned = _posed(rotations, pivot, points, normals)
    total, seen = np.zeros(len(rotations)), np.zeros(len(rotations))
    for view in views:
        if view.tree is None:
            continue
        uv = _pixels(view, moved, turned)  # (k, c, 2)
        ok = np.isfinite(uv).all(-1)
        d, _ = view.tree.query(uv[ok], distance_upper_bound=match_px)
        support = np.zeros(ok.shape)
        support[ok] = np.maximum(0.0, 1.0 - (np.minimum(d, match_px) / match_px) ** 2)
        total += support.sum(1)
        seen += ok.sum(1)
    return total, seen


def search(pivot: np.ndarray, points: np.ndarray, normals: np.ndarray, views: Sequence[View],
           config: LimbConfig) -> tuple[np.ndarray, float]:
    """The rotation about ``pivot`` best supported by the detections: a coarse grid, then finer ones about the best
    ``keep`` of each.  -> (3, 3), its support's share of the (point, view) pairs it counts (``score``)"""
    candidates = rotation_grid(config.coarse_deg, config.reach_deg)
    some = np.unique(np.linspace(0, len(points) - 1, min(config.coarse_points, len(points))).round().astype(int))
    scores, _ = score(candidates, pivot, points[some], normals[some], views, config.match_px)
    last = config.coarse_deg
    for step in config.fine_deg:
        best = candidates[np.argsort(scores)[::-1][:config.keep]]
        local = rotation_grid(step, last)  # about each: one step of the last grid around it
        candidates = np.concatenate([best, np.einsum("lij,kjm->klim", local, best).reshape(-1, 3, 3)])
        scores, _ = score(candidates, pivot, points, normals, views, config.match_px)
        last = step
    best = candidates[int(np.argmax(scores))]
    support, seen = score(best[None], pivot, points, normals, views, config.match_px)
    return best, float(support[0] / max(seen[0], 1.0))


def matched_pixels(points: np.ndarray, normals: np.ndarray, views: Sequence[View], match_px: float) -> np.ndarray:
    """Each point's unclaimed detection in each view within ``match_px`` of its pixel, one point per detection (the
    nearest).  points, normals (c, 3) -> (view, c, 2), NaN where none"""
    out = np.full((len(views), len(points), 2), np.nan)
    for v, view in enumerate(views):
        if view.tree is None:
            continue
        uv = _pixels(view, points, normals)
        ok = np.flatnonzero(np.isfinite(uv).all(-1))
        d, idx = view.tree.query(uv[ok], distance_upper_bound=match_px)
        hit = np.isfinite(d)
        ok, d, idx = ok[hit], d[hit], idx[hit]
        first = np.lexsort((d, idx))  # by detection, nearest first
        keep = first[np.r_[True, idx[first][1:] != idx[first][:-1]]] if len(first) else first
        out[v, ok[keep]] = view.tree.data[idx[keep]]
    return out


# --- a take -----------------------------------------------------------------------------------------------------------


def limb_pixels(posed: np.ndarray, normals: np.ndarray, heads: np.ndarray, observed: np.ndarray,
                limbs: Sequence[Limb], views: Sequence[Sequence[View]], config: LimbConfig) -> np.ndarray:
    """Detections matched to the corners of each searched bone, in each frame where its part has fewer than
    ``min_corners`` observed corners.  posed, normals (frame, corner, 3) the fitted body's corners and their normals;
    heads (frame, bone, 3) the bones' heads; observed (frame, corner); views per frame -> (frame, view, corner, 2)"""
    out = np.full((len(posed), len(views[0]) if len(views) else 0, posed.shape[1], 2), np.nan)
    for f in range(len(posed)):
        points, turned, pivots = posed[f].copy(), normals[f].copy(), heads[f].copy()
        for limb in limbs:
            if (observed[f] & limb.scored).sum() >= config.min_corners:
                continue
            wanted = limb.scored & ~observed[f]
            if not wanted.any():
                continue
            pivot = pivots[limb.bone].copy()
            r, share = search(pivot, points[wanted], turned[wanted], views[f], config)
            if share < config.min_share:
                continue
            points[limb.carried] = pivot + (points[limb.carried] - pivot) @ r.T  # the subtree turned with it
            turned[limb.carried] = turned[limb.carried] @ r.T
            pivots[limb.subtree] = pivot + (pivots[limb.subtree] - pivot) @ r.T
            out[f][:, wanted] = matched_pixels(points[wanted], turned[wanted], views[f], config.match_px)
    return out


def limb_points(xy: np.ndarray, cameras: Sequence[Camera]) -> np.ndarray:
    """The matched corners triangulated as the chain's labels are (§3.3, Chen et al. 2021).
    xy (frame, view, corner, 2) -> (frame, corner, 3), NaN where not reconstructed"""
    if not np.isfinite(xy).any():
        return np.full(xy.shape[:1] + xy.shape[2:3] + (3,), np.nan)
    return reconstruct_frames(xy, cameras, ReconstructConfig()).position
