"""Labelled 2D reflectors made consistent with the solved poses: the motion capture (DeepMoCap §3.5) fed
back into each view's 2D reflector set (§3.3.3). Not a stage of the paper.

Each view names its reflectors alone, and alone it cannot always tell a left limb from a right one (a
side view, legs that cross) or find a reflector whose map peak lost its region to a neighbour. The
other views and the body model can: fusion (§3.4) outvotes a view's wrong labels, and the poses solved
on the calibrated template put every reflector somewhere, seen or not. This stage projects the posed
template's reflectors into each view and

1. **exchanges the labels of a mirrored pair** (L_ANKLE and R_ANKLE, the two pelvis patches, ...) where
   the view's two estimates lie clearly nearer the other label's projection (by ``exchange_margin_px``
   in sum, each within ``exchange_reach_px``); pairs closer than ``exchange_keep_m`` on the rest-pose body
   (the forehead patches) are left as they are;
2. **adds a missing reflector** where its projection falls on a reflector region (``reproject_snap_px``)
   that no estimate holds, or on its own part (k-means, as ``reflectors2d`` splits regions) of one that
   estimates at least ``reproject_split_px`` away hold, when the region's contour depth agrees with the
   projection's (within ``depth_tolerance_m``, a strap one limb radius behind its surface) and a patch
   faces the camera (cosine of its posed normal and the line of sight at least ``min_facing``). It is
   placed at the region's centre with confidence ``reprojected_confidence`` and flagged ``reprojected``.

Nothing else moves: an estimate keeps its position, confidence and region, only its label may change
(flagged ``exchanged``). The network's best candidates (``candidate_*``) pass through unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.deepmocap.markers3d import KINDS, nominal_radius, region_depths
from mocapflow.tasks.deepmocap.poses import reflector_positions
from mocapflow.tasks.deepmocap.reflectors2d import claim_part, reflector_region
from mocapflow.tasks.deepmocap.skeleton import neighbours, patch_normals
from mocapflow.tasks.shared.cameras import camera_of
from mocapflow.tasks.shared.kinematics import world_rotations
from mocapflow.tasks.shared.labels import mirrored


@dataclass(frozen=True)
class Refine2DConfig:
    exchange_reach_px: float = 20.0  # an exchanged estimate lies this close to its new label's projection
    exchange_margin_px: float = 3.0  # and the exchange shortens the pair's distances by more than this
    exchange_keep_m: float = 0.10  # mirrored reflectors this close on the rest-pose body are never exchanged
    reproject_snap_px: float = 6.0  # > 0: a missing reflector takes a region this close to its projection; 0: off
    reproject_split_px: float = 3.0  # ... or its part of a held region, this far from the holders' estimates
    depth_tolerance_m: float = 0.15  # region depth against the projection's
    min_facing: float = -0.2  # cosine of a patch's posed normal and its line of sight
    reprojected_confidence: float = 0.1  # E given to an added reflector
    b_min: int = 5  # smallest region an added reflector may take, pixels
    region_radius_px: float = 10.0  # pixels of a region counted towards its centre (as reflectors2d)
    contour_px: int = 2  # region-contour depth, as markers3d
    max_depth_spread_mm: float = 150.0

    def __post_init__(self):
        for name in ("exchange_reach_px", "exchange_margin_px", "exchange_keep_m", "reproject_snap_px",
                     "reproject_split_px"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)} (see Refine2DConfig for the defaults)")
        if not self.depth_tolerance_m > 0:
            raise ValueError(f"depth_tolerance_m must be > 0 metres (e.g. 0.15), got {self.depth_tolerance_m}")
        if not -1.0 <= self.min_facing <= 1.0:
            raise ValueError(f"min_facing is a cosine in [-1, 1] (-1: no facing test), got {self.min_facing}")


def exchangeable_pairs(names: list[str], keep_m: float) -> list[tuple[int, int]]:
    """Index pairs (left, right) of the mirrored reflectors farther apart than ``keep_m`` at rest."""
    close = neighbours(names, keep_m)
    pairs = []
    for r, name in enumerate(names):
        other = mirrored(name)
        if other != name and other in names and name < other:
            o = names.index(other)
            if close is None or not close[r, o]:
                pairs.append((r, o))
    return pairs


def reflectors_on_poses(poses: xr.Dataset, skeleton: xr.Dataset, names: list[str], frames) -> tuple[np.ndarray,
                                                                                                     np.ndarray]:
    """Where the solved poses of ``frames`` put the reflectors ``names`` on the calibrated skeleton, and their
    normals.  -> (frame, reflector, 3) x2"""
    skel = skeleton.sel(reflector=names)
    pose = poses.sel(frame=frames)
    return posed_reflectors(
        pose["rotation"].transpose("frame", "joint", "quat").values.astype(np.float64),
        pose["position"].transpose("frame", "joint", "xyz").values.astype(np.float64),
        skel["parent"].values.astype(int), skel["bone"].values.astype(int),
        skel["reflector_offset"].values.astype(np.float64), patch_normals(names))


def posed_reflectors(rotation: np.ndarray, position: np.ndarray, parents: np.ndarray, bones: np.ndarray,
                     offsets: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions and normals of the template's reflectors in the solved poses; NaN in unsolved frames.
    rotation (frame, joint, 4) local quaternions x y z w; position (frame, joint, 3); parents (joint,);
    bones (R,); offsets, normals (R, 3) in the bone frames.  -> (frame, R, 3) x2"""
    n_frames, n_joints = rotation.shape[:2]
    solved = np.isfinite(rotation).all(axis=(1, 2)) & np.isfinite(position).all(axis=(1, 2))  # (frame,)
    quat = np.where(solved[:, None, None], rotation, [0.0, 0.0, 0.0, 1.0])
    local = Rotation.from_quat(quat.reshape(-1, 4)).as_matrix().reshape(n_frames, n_joints, 3, 3)
    world = world_rotations(local, parents)  # (frame, joint, 3, 3)
    xyz = reflector_positions(world, np.nan_to_num(position), bones, offsets)  # (frame, R, 3)
    normal = np.einsum("frij,rj->fri", world[:, bones], normals)
    xyz[~solved], normal[~solved] = np.nan, np.nan
    return xyz, normal


def exchange_sides(xy: np.ndarray, ref: np.ndarray, pairs, *, reach_px: float, margin_px: float) -> np.ndarray:
    """Which estimate each label takes: itself, or its mirror's where the pair's estimates lie clearly nearer
    the other label's projection.  xy, ref (R, 2) px (NaN: none) -> (R,) indices into xy"""
    take = np.arange(len(xy))
    for a, b in pairs:
        have = np.isfinite(xy[[a, b], 0])
        if not have.any() or not np.isfinite(ref[[a, b], 0]).all():
            continue
        own = np.linalg.norm(xy[[a, b]] - ref[[a, b]], axis=1)[have]
        swapped = np.linalg.norm(xy[[a, b]] - ref[[b, a]], axis=1)[have]
        if swapped.sum() + margin_px < own.sum() and swapped.max() <= reach_px:
            take[a], take[b] = b, a
    return take


def held_regions(xy: np.ndarray, blob_id: np.ndarray, blob_area: np.ndarray, radius_px: float) -> dict[int, list]:
    """The region each estimate lies on (estimates are region centres or parts), by region label."""
    held: dict[int, list] = {}
    for point in xy[np.isfinite(xy[:, 0])]:
        found = reflector_region(point, blob_id, blob_area, snap_px=2.0, radius_px=radius_px)
        if found is not None:
            held.setdefault(found[2], []).append(point)
    return held


def free_place(ref: np.ndarray, held: dict[int, list], blob_id: np.ndarray, blob_area: np.ndarray, *,
               snap_px: float, split_px: float, b_min: int, radius_px: float) -> tuple[np.ndarray, int, int] | None:
    """Centre, region label and area that a missing reflector projected at ``ref`` (2,) can take: a free
    region near it, or its own part of a held one; None if neither."""
    found = reflector_region(ref, blob_id, blob_area, snap_px=snap_px, radius_px=radius_px)
    if found is None or found[1] < b_min:
        return None
    centre, area, label = found
    if label in held:
        part = claim_part(ref, np.array(held[label]), blob_id, label, split_px=split_px)
        if part is None or np.linalg.norm(part[1] - part[0], axis=1).min() < split_px:
            return None
        centre = part[0]
    return centre, label, area


def reproject_missing(xy, ref, depth_ref, facing, radius, blob_id, blob_area, depth,
                      config: Refine2DConfig) -> dict[int, tuple]:
    """Positions for the reflectors a view misses, from their projections, nearest the camera first.
    xy, ref (R, 2) px; depth_ref, facing, radius (R,); blob_id, depth (y, x).  -> {reflector: (centre (2,), area)}"""
    held = held_regions(xy, blob_id, blob_area, config.region_radius_px)
    added = {}
    for r in np.argsort(np.nan_to_num(depth_ref, nan=np.inf)):
        if np.isfinite(xy[r, 0]) or not np.isfinite(ref[r, 0]) or facing[r] < config.min_facing:
            continue
        place = free_place(ref[r], held, blob_id, blob_area, snap_px=config.reproject_snap_px,
                           split_px=config.reproject_split_px, b_min=config.b_min, radius_px=config.region_radius_px)
        if place is None:
            continue
        centre, label, area = place
        surface_mm = region_depths(centre[None], np.array([label]), blob_id, depth, contour_px=config.contour_px,
                                   max_depth_spread_mm=config.max_depth_spread_mm)[0]
        if not abs(surface_mm / 1000.0 + radius[r] - depth_ref[r]) <= config.depth_tolerance_m:  # NaN: no depth, no add
            continue
        added[int(r)] = (centre, area)
        held.setdefault(label, []).append(centre)
    return added


def facing_cosines(xyz: np.ndarray, normal: np.ndarray, camera_centre: np.ndarray) -> np.ndarray:
    """Cosine between each reflector's normal and its line of sight to the camera; 1 for a strap (zero
    normal).  (R, 3) x2, (3,) -> (R,)"""
    sight = camera_centre - xyz
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    length = np.linalg.norm(normal, axis=1)
    cos = (normal * sight).sum(axis=1) / np.where(length > 0, length, 1.0)
    return np.where(length > 0, cos, 1.0)


def refine_reflectors(reflectors: xr.Dataset, poses: xr.Dataset, skeleton: xr.Dataset, masks: xr.Dataset,
                      frames: xr.Dataset, config: Refine2DConfig) -> xr.Dataset:
    """`reflectors2d` of every view, relabelled and completed from the solved poses (see the module docstring)."""
    dims = ("view", "frame", "reflector")
    reflectors = reflectors.transpose(*dims, ...)
    names = [str(n) for n in reflectors["reflector"].values]
    xyz, normal = reflectors_on_poses(poses, skeleton, names, reflectors["frame"].values)  # (frame, R, 3) x2
    radius = np.array([nominal_radius(n) if KINDS[n] == "strap" else 0.0 for n in names])  # a strap: limb centre
    pairs = exchangeable_pairs(names, config.exchange_keep_m)
    est = {k: reflectors[k].values.copy() for k in ("x", "y", "confidence", "region_size")}  # (view, frame, R)
    est["recovered"] = (reflectors["recovered"].values.astype(bool) if "recovered" in reflectors
                        else np.zeros(est["x"].shape, bool))
    est["exchanged"], est["reprojected"] = np.zeros(est["x"].shape, bool), np.zeros(est["x"].shape, bool)
    for v, view in enumerate(reflectors["view"].values):
        cam, m = frames.sel(view=view), masks.sel(view=view)
        camera = camera_of(frames, view)
        for i, frame in enumerate(reflectors["frame"].values):
            j = int(np.nonzero(m["frame"].values == frame)[0][0])
            ref, depth_ref = camera.project(xyz[i])  # (R, 2), (R,)
            xy = np.column_stack([est["x"][v, i], est["y"][v, i]]).astype(np.float64)
            take = exchange_sides(xy, ref, pairs, reach_px=config.exchange_reach_px, margin_px=config.exchange_margin_px)
            for k in ("x", "y", "confidence", "region_size", "recovered"):
                est[k][v, i] = est[k][v, i][take]
            est["exchanged"][v, i] = take != np.arange(len(names))
            if config.reproject_snap_px <= 0:
                continue
            xy = np.column_stack([est["x"][v, i], est["y"][v, i]]).astype(np.float64)
            added = reproject_missing(
                xy, ref, depth_ref, facing_cosines(xyz[i], normal[i], camera.cam_to_world[:3, 3]), radius,
                m["blob_id"].values[j], m["blob_area"].values[j], cam["depth"].values[j], config)
            for r, (centre, area) in added.items():
                est["x"][v, i, r], est["y"][v, i, r] = centre
                est["confidence"][v, i, r], est["region_size"][v, i, r] = config.reprojected_confidence, area
                est["reprojected"][v, i, r] = True
    out = reflectors.copy()
    for k, values in est.items():
        out[k] = (dims, values.astype(reflectors[k].dtype if k in reflectors else bool))
    return out
