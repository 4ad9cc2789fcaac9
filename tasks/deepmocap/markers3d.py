"""From labelled 2D reflectors to labelled 3D optical data (DeepMoCap §3.4): 2D→3D mapping (§3.4.1)
and multi-view fusion (§3.4.2, Appendix A).

2D→3D: only the plain 2D estimates are lifted; a ``recovered`` one (tasks/deepmocap/reflectors2d.py), with
``lift_recovered``, only where no view has a plain one. A reflector returns no depth (its region is a
hole in the depth map), so its distance d_R is the median depth of the valid pixels on the contour of
its region; when n > 1 estimates share one region, the contour pixels (image position + depth) are
clustered into n groups (k-means) and each estimate takes the group nearest to it. The region centre
is back-projected through the undistorted intrinsics at that depth and taken to the world frame by
the extrinsics.

Fusion: a patch is seen from one side, so its views agree on one surface point: the
confidence-weighted mean over views (Eq. 10), after rejecting a view farther than a tolerance from
the others' median. A strap is seen from all sides, each view on the surface facing it: the limb
centre is where the surface normals meet, i.e. the closest points between the normal lines of each
pair of views (Eq. A1), averaged; a strap seen by one view only is pushed along its normal by the
limb radius. The total confidence C_f is the mean of the views' confidences. Beyond the paper, a view's
lifted point below the floor or above the ceiling is dropped before fusion (a label read on the background's
depth never reaches 3D), and so is one farther across the floor from the frame's body (the median of every view's
lifted points, the trunk) than a tall adult's reach. Each view's own centre guess and confidence are kept
beside the fused point, so that a later stage can use a view that fusion outvoted.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import xarray as xr
from scipy import ndimage

from mocapflow.tasks.shared.cameras import Camera, camera_of
from mocapflow.tasks.shared.reflectors import REFLECTOR_TABLE

KINDS = {name: kind for name, kind, *_ in REFLECTOR_TABLE}
# Nominal limb radius (m) under each strap: forearm and shin of a 1.75 m adult.
NOMINAL_RADIUS = {"ELBOW": 0.040, "WRIST": 0.033, "CALF": 0.052, "ANKLE": 0.042}
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))  # one 4-connected dilation step


def nominal_radius(name: str) -> float:
    return next(r for key, r in NOMINAL_RADIUS.items() if name.endswith(key))


@dataclass(frozen=True)
class Markers3DConfig:
    contour_px: int = 2  # width of the ring around a region whose valid depths give d_R
    max_depth_spread_mm: float = 150.0  # contour depths this far behind the nearest quartile are background
    patch_tolerance_m: float = 0.05  # a patch view farther than this from the views' median is rejected
    strap_tolerance_m: float = 0.08
    min_confidence: float = 0.0  # 2D estimates below this are not lifted
    lift_recovered: bool = False  # True: a recovered 2D estimate (reflectors2d) is lifted where no view has a plain one
    # a view's lifted point below the floor or above the ceiling (world z, m) is no reflector on a person (a region
    # read on the background's depth, a label on a speck): it is dropped before fusion, never averaged in
    floor_m: float = -0.10
    ceiling_m: float = 2.80
    # a view's lifted point farther than this across the floor (m) from the frame's body, the median of every view's
    # lifted points, is no reflector on that body: half the arm span of a 2.2 m adult is 1.1 m (0: no reach test)
    body_reach_m: float = 1.2

    def __post_init__(self):
        if not self.ceiling_m > self.floor_m:
            raise ValueError(f"ceiling_m must exceed floor_m (e.g. 2.8 > -0.1), got {self.ceiling_m} <= {self.floor_m}")
        if self.body_reach_m < 0:
            raise ValueError(f"body_reach_m must be >= 0 metres (0: off; e.g. 1.2), got {self.body_reach_m}")


def region_depths(xy: np.ndarray, region_of: np.ndarray, blob_id: np.ndarray, depth: np.ndarray, *,
                  contour_px: int, max_depth_spread_mm: float) -> np.ndarray:
    """d_R (mm) of every estimate: median valid depth on its region's contour; NaN where none.

    xy (n, 2) px; region_of (n,) blob label of each estimate (0: none); blob_id, depth (y, x).  -> (n,)
    """
    out = np.full(len(xy), np.nan)
    boxes = _boxes(blob_id)  # box of region k at index k - 1
    for label in np.unique(region_of[region_of > 0]):
        members = np.nonzero(region_of == label)[0]
        ys, xs = _contour(blob_id, depth, label, boxes[label - 1], contour_px)
        if len(xs) == 0:
            continue
        z = depth[ys, xs].astype(np.float64)
        if len(members) == 1 or len(xs) < len(members):
            out[members] = _surface_depth(z, max_depth_spread_mm)
            continue
        groups = split_region(np.stack([xs, ys], 1).astype(np.float64), z, xy[members])
        for k, m in enumerate(members):
            out[m] = _surface_depth(z[groups == k] if (groups == k).any() else z, max_depth_spread_mm)
    return out


def _boxes(blob_id: np.ndarray) -> list:
    """``ndimage.find_objects(blob_id)``, searched within the box of every region together (reflectors cover a
    small part of the image).  (y, x) -> box (slice, slice) of region k at index k - 1, None where absent"""
    rows, cols = np.flatnonzero(blob_id.any(axis=1)), np.flatnonzero(blob_id.any(axis=0))
    if len(rows) == 0:
        return []
    top, left = int(rows[0]), int(cols[0])
    return [None if box is None else (slice(box[0].start + top, box[0].stop + top),
                                      slice(box[1].start + left, box[1].stop + left))
            for box in ndimage.find_objects(blob_id[top:rows[-1] + 1, left:cols[-1] + 1])]


def _contour(blob_id: np.ndarray, depth: np.ndarray, label: int, box: tuple[slice, slice],
             width: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the valid-depth pixels within ``width`` px around region ``label`` (not on it).

    Works on the region's bounding ``box`` grown by ``width``, not the whole image.  (y, x) x2 -> (m,), (m,)"""
    top, left = max(box[0].start - width, 0), max(box[1].start - width, 0)
    window = (slice(top, box[0].stop + width), slice(left, box[1].stop + width))
    region = blob_id[window] == label
    grown = cv2.dilate(region.view(np.uint8), _CROSS, iterations=width).view(bool)  # 4-connected steps
    ring = grown & ~region & (depth[window] > 0)
    ry, rx = np.nonzero(ring)
    return ry + top, rx + left


def _surface_depth(z: np.ndarray, max_spread_mm: float) -> float:
    """Median of the contour depths on the body: background seen past a limb's edge lies far behind.

    np.median(z[z <= np.percentile(z, 25) + max_spread_mm]), the same bits, from one sort of these few values
    (numpy's quantile machinery costs tens of microseconds a call, thousands of calls a take).  (m,) finite -> float
    """
    s = np.sort(z)
    at = 0.25 * (len(s) - 1)  # np.percentile's linear method: the virtual index (n - 1) q, then its lerp
    lo = int(at)
    gamma, a, b = at - lo, s[lo], s[min(lo + 1, len(s) - 1)]
    quartile = b - (b - a) * (1 - gamma) if gamma >= 0.5 else a + (b - a) * gamma
    k = int(np.searchsorted(s, quartile + max_spread_mm, side="right"))  # the kept depths are s[:k]
    if k == 0:
        return float("nan")
    return float(s[k // 2] if k % 2 else (s[k // 2 - 1] + s[k // 2]) / 2)


def split_region(pixels: np.ndarray, z: np.ndarray, estimates: np.ndarray) -> np.ndarray:
    """Assign contour pixels (m, 2) with depths (m,) of a region shared by n estimates (n, 2) to them.
    Clusters (x, y, depth in px-comparable units) with k-means seeded at the estimates.  -> (m,) index"""
    from sklearn.cluster import KMeans  # here, not at the top: importing it cost every CLI call about 0.3 s

    scale = 0.1  # 1 px ~ 10 mm of depth at Kinect range
    n = len(estimates)
    seeds = np.column_stack([estimates, np.full(n, np.median(z) * scale)])
    features = np.column_stack([pixels, z * scale])
    km = KMeans(n_clusters=n, init=seeds, n_init=1, random_state=0).fit(features)
    # cluster -> estimate: each estimate takes the cluster whose centre is nearest in the image
    cost = np.linalg.norm(km.cluster_centers_[:, None, :2] - estimates[None], axis=-1)  # (cluster, estimate)
    owner = np.full(n, -1)
    for c, e in sorted(np.ndindex(n, n), key=lambda ce: cost[ce]):
        if owner[c] == -1 and e not in owner:
            owner[c] = e
    return owner[km.labels_]


def closest_points(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Closest points of the lines p1 + s d1 and p2 + t d2; None when parallel.   # Eq. (A1), DeepMoCap

    s = (b e - c d) / (a c - b^2), t = (a e - b d) / (a c - b^2) with a = d1.d1, b = d1.d2, c = d2.d2,
    d = d1.w, e = d2.w, w = p1 - p2.
    """
    w = p1 - p2
    a, b, c, d, e = d1 @ d1, d1 @ d2, d2 @ d2, d1 @ w, d2 @ w
    den = a * c - b * b
    if den < 1e-9:
        return None
    s, t = (b * e - c * d) / den, (a * e - b * d) / den
    return p1 + s * d1, p2 + t * d2


def fuse_patch(points: np.ndarray, weights: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Confidence-weighted mean of a patch's views after rejecting outliers.  (v, 3), (v,) -> (3,), used (v,)"""
    used = np.linalg.norm(points - np.median(points, axis=0), axis=1) <= tolerance
    if not used.any():
        used = weights == weights.max()
    w = weights[used]
    return (points[used] * w[:, None]).sum(0) / w.sum(), used  # Eq. (10), DeepMoCap


def fuse_strap(points: np.ndarray, rays: np.ndarray, weights: np.ndarray, radius: float,
               tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Limb centre of a strap from its surface points and viewing rays (v, 3) each.  -> (3,), used (v,)"""
    inward = points + rays * radius  # each view's own guess: one radius behind its surface point
    if len(points) == 1:
        return inward[0], np.ones(1, bool)
    centres, pair_weights = [], []
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            found = closest_points(points[i], rays[i], points[j], rays[j])
            if found is None:
                continue
            mid = (found[0] + found[1]) / 2
            # meeting points behind both surfaces and near both guesses only; opposite views meet far away
            if np.linalg.norm(mid - inward[i]) <= tolerance and np.linalg.norm(mid - inward[j]) <= tolerance:
                centres.append(mid)
                pair_weights.append(weights[i] * weights[j])
    if not centres:
        centre, used = fuse_patch(inward, weights, tolerance)
        return centre, used
    centre = np.average(np.array(centres), axis=0, weights=np.array(pair_weights))
    return centre, np.linalg.norm(inward - centre, axis=1) <= tolerance


def _region_labels(xy: np.ndarray, blob_id: np.ndarray, reach: int = 3) -> np.ndarray:
    """The region label under (or within ``reach`` px of) each estimate; 0 where none: the nearest labelled pixel
    of its (2 reach + 1)² window, the first in raster order of those equally near.  (n, 2) -> (n,)"""
    h, w = blob_id.shape
    at = np.rint(xy).astype(int)  # (n, 2) as (x, y)
    step = np.arange(-reach, reach + 1)
    ys, xs = at[:, 1, None, None] + step[:, None], at[:, 0, None, None] + step  # (n, k, 1), (n, 1, k)
    inside = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)  # (n, k, k)
    labels = np.where(inside, blob_id[np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)], 0).reshape(len(xy), -1)
    d2 = (step[:, None] ** 2 + step**2).ravel()  # (k²,) squared distance of each window pixel, raster order
    nearest = np.argmin(np.where(labels > 0, d2, np.iinfo(np.int64).max), axis=1)
    out = labels[np.arange(len(xy)), nearest].astype(np.int64)
    for i in np.flatnonzero((at < -reach).any(axis=1)):  # a slice from below -reach wraps round: as the loop did
        out[i] = _region_label_at(at[i], blob_id, reach)
    return out


def _region_label_at(at: np.ndarray, blob_id: np.ndarray, reach: int) -> int:
    """``_region_labels`` of one estimate at whole pixel ``at`` (x, y), by slicing its window."""
    x, y = int(at[0]), int(at[1])
    window = blob_id[max(y - reach, 0):y + reach + 1, max(x - reach, 0):x + reach + 1]
    ys, xs = np.nonzero(window)
    if len(xs) == 0:
        return 0
    k = np.argmin((xs + max(x - reach, 0) - x) ** 2 + (ys + max(y - reach, 0) - y) ** 2)
    return int(window[ys[k], xs[k]])


def lift_view(x, y, confidence, blob_id, depth, camera: Camera, *, contour_px, max_depth_spread_mm, min_confidence):
    """World points, rays and confidences of one view-frame's estimates.  (R,) x3, (y, x) x2 -> (R, 3) x2, (R,)"""
    points = np.full((len(x), 3), np.nan)
    rays = np.full((len(x), 3), np.nan)
    xy = np.column_stack([x, y]).astype(np.float64)
    ok = np.nonzero(np.isfinite(xy[:, 0]) & (confidence > min_confidence))[0]
    if len(ok) == 0:
        return points, rays
    labels = _region_labels(xy[ok], blob_id)
    d = region_depths(xy[ok], labels, blob_id, depth, contour_px=contour_px, max_depth_spread_mm=max_depth_spread_mm)
    good = np.isfinite(d)
    if good.any():
        p, r = camera.backproject(xy[ok][good], d[good] / 1000.0)  # depth in mm
        points[ok[good]], rays[ok[good]] = p, r
    return points, rays


def fuse_frame(points, rays, confidence, names, *, patch_tolerance_m, strap_tolerance_m):
    """Fused xyz (R, 3), C_f (R,), views used (R,) and per-view residuals (R, V) of one frame.
    points, rays (V, R, 3), confidence (V, R)."""
    n_views, n_refl = confidence.shape
    xyz, conf = np.full((n_refl, 3), np.nan), np.zeros(n_refl)
    used_n, residual = np.zeros(n_refl, np.int8), np.full((n_refl, n_views), np.nan)
    for r, name in enumerate(names):
        seen = np.nonzero(np.isfinite(points[:, r, 0]))[0]
        if len(seen) == 0:
            continue
        p, w = points[seen, r], np.maximum(confidence[seen, r], 1e-3)
        if KINDS[name] == "strap":
            radius = nominal_radius(name)
            centre, used = fuse_strap(p, rays[seen, r], w, radius, strap_tolerance_m)
            p = p + rays[seen, r] * radius  # residuals of a strap view: from its own centre guess
        else:
            centre, used = fuse_patch(p, w, patch_tolerance_m)
        xyz[r], conf[r], used_n[r] = centre, confidence[seen[used], r].mean(), used.sum()  # C_f: mean of the views'
        residual[r, seen] = np.linalg.norm(p - centre, axis=1)
    return xyz, conf, used_n, residual


def view_centres(points: np.ndarray, rays: np.ndarray, names: list[str]) -> np.ndarray:
    """Each view's own guess of each reflector's centre: a patch's surface point, a strap's surface point
    one nominal radius along the viewing ray (as in ``fuse_strap``).  (view, frame, R, 3) x2 -> (view, frame, R, 3)"""
    radius = np.array([nominal_radius(n) if KINDS[n] == "strap" else 0.0 for n in names])  # (R,)
    return points + rays * radius[:, None]


def last_resort(found: np.ndarray, recovered: np.ndarray) -> np.ndarray:
    """Which 2D estimates to lift: every plain one, and a recovered one (``reflectors2d``'s recovery rules) only
    where no view has a plain estimate of that reflector in that frame.  (view, frame, R) bool x2 -> (view, frame, R)"""
    plain = found & ~recovered
    return plain | (found & ~plain.any(axis=0, keepdims=True))


def beyond_reach(points: np.ndarray, reach_m: float) -> np.ndarray:
    """Which lifted points lie farther across the floor than ``reach_m`` from their frame's body, the median of the
    frame's lifted points over every view and reflector (the trunk, as most reflectors are near it).
    (view, frame, reflector, 3) -> (view, frame, reflector) bool"""
    n_views, n_frames, n_refl, _ = points.shape
    per_frame = points.transpose(1, 0, 2, 3).reshape(n_frames, n_views * n_refl, 3)
    seen = np.isfinite(per_frame[..., 0]).any(axis=1)  # (frame,)
    centre = np.full((n_frames, 3), np.nan)
    centre[seen] = np.nanmedian(per_frame[seen], axis=1)
    distance = np.linalg.norm((points - centre[None, :, None])[..., :2], axis=-1)  # horizontal
    with np.errstate(invalid="ignore"):
        return np.isfinite(distance) & (distance > reach_m)


def markers3d(reflectors: xr.Dataset, masks: xr.Dataset, frames: xr.Dataset, config: Markers3DConfig) -> xr.Dataset:
    """Labelled 3D reflectors of a sequence from every view's 2D estimates, region masks, depth and calibration."""
    views, names = list(reflectors["view"].values), [str(n) for n in reflectors["reflector"].values]
    n_frames, n_refl = reflectors.sizes["frame"], len(names)
    points = np.full((len(views), n_frames, n_refl, 3), np.nan)
    rays = np.full_like(points, np.nan)
    confidence = reflectors["confidence"].transpose("view", "frame", "reflector").values.astype(np.float64)
    lifted = np.ones(confidence.shape, bool)  # (view, frame, reflector)
    if "recovered" in reflectors:
        found = np.isfinite(reflectors["x"].transpose("view", "frame", "reflector").values)
        recovered = reflectors["recovered"].transpose("view", "frame", "reflector").values.astype(bool)
        lifted = last_resort(found, recovered) if config.lift_recovered else ~recovered
    for v, view in enumerate(views):
        cam, est, m = frames.sel(view=view), reflectors.sel(view=view), masks.sel(view=view)
        camera = camera_of(frames, view)
        x, y, blob_id, depth = est["x"].values, est["y"].values, m["blob_id"].values, cam["depth"].values  # (frame, …)
        x = np.where(lifted[v], x, np.nan)  # (frame, reflector)
        for i in range(n_frames):
            points[v, i], rays[v, i] = lift_view(
                x[i], y[i], confidence[v, i], blob_id[i], depth[i], camera, contour_px=config.contour_px,
                max_depth_spread_mm=config.max_depth_spread_mm, min_confidence=config.min_confidence)
    height = points[..., 2]  # (view, frame, reflector)
    with np.errstate(invalid="ignore"):
        outside = np.isfinite(height) & ((height < config.floor_m) | (height > config.ceiling_m))
    points[outside], rays[outside] = np.nan, np.nan
    far = beyond_reach(points, config.body_reach_m) if config.body_reach_m else np.zeros(outside.shape, bool)
    points[far], rays[far] = np.nan, np.nan
    fused = [fuse_frame(points[:, i], rays[:, i], confidence[:, i], names, patch_tolerance_m=config.patch_tolerance_m,
                        strap_tolerance_m=config.strap_tolerance_m) for i in range(n_frames)]
    xyz, conf, used, residual = (np.stack(column) for column in zip(*fused))
    own = view_centres(points, rays, names)  # (view, frame, reflector, 3)
    own_conf = np.where(np.isfinite(own[..., 0]), confidence, 0.0)  # (view, frame, reflector)
    return xr.Dataset(
        {"position": (("frame", "reflector", "xyz"), xyz.astype(np.float32)),
         "confidence": (("frame", "reflector"), conf.astype(np.float32)),
         "views": (("frame", "reflector"), used.astype(np.int8)),
         "residual": (("frame", "reflector", "view"), residual.astype(np.float32)),
         "view_position": (("frame", "reflector", "view", "xyz"), own.transpose(1, 2, 0, 3).astype(np.float32)),
         "view_confidence": (("frame", "reflector", "view"), own_conf.transpose(1, 2, 0).astype(np.float32))},
        coords={"frame": reflectors["frame"].values, "reflector": names, "view": np.array(views, dtype=object),
                "xyz": ["x", "y", "z"]},
        attrs={"length_unit": "m", "up_axis": "Z", "fps": float(frames.attrs["fps"]),
               "rejected_view_estimates": int(outside.sum()),  # lifted outside the floor-ceiling band
               "beyond_reach_view_estimates": int(far.sum())},  # lifted beyond the body's reach
    )
