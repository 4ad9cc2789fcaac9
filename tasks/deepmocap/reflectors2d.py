"""Greedy inference of the labelled 2D reflector set (DeepMoCap §3.3.3, filtering of §5.1.3).

Per reflector channel: candidates are the confidence-map peaks (non-maximum suppression, E^S); each
candidate at frame f is scored against the candidates of the same reflector at f-1 by the line
integral of the optical flow field L along the segment between them (Eq. 7-8, sampled uniformly);
the fused confidence is E = E^S + (1 - E^S)·E^L (Eq. 9) and the best candidate is the estimate.
Filtering: the estimate must lie in a reflector (black) region of at least b_min pixels; its final
position is that region's centre at full resolution (sub-pixel; a long region is cut to the pixels
near the estimate, and with ``split_px`` > 0 a region shared by estimates that far apart is split
among them by k-means, when their reflectors are neighbours on the body (``split_neighbours_m``));
of estimates closer than 3 px the more confident stays; one estimate per reflector and image; an
estimate below c_min is dropped. A second pass (``recover_dropped``) gives the dropped estimates a wider
reach (a region up to ``recover_snap_px`` away, a part of a region held by a reflector within
``recover_neighbours_m``) without moving a kept one; what it keeps is flagged ``recovered``, a right label
more often than not but from a less certain region, so 3D (tasks/deepmocap/markers3d.py) leaves it out by default.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy import ndimage

from mocapflow.tasks.deepmocap import targets
from mocapflow.tasks.deepmocap.skeleton import neighbours


@dataclass(frozen=True)
class GreedyConfig:
    peak_threshold: float = 0.1  # E^S of the weakest candidate
    max_candidates: int = 3  # per reflector and frame
    line_samples: int = 10  # points of the Eq. (8) sum
    b_min: int = 5  # smallest reflector region, pixels
    min_distance_px: float = 3.0  # of two estimates closer than this, the more confident stays
    snap_px: float = 6.0  # how far from an estimate its reflector region may start, pixels
    region_radius_px: float = 10.0  # pixels of a region counted towards its centre
    split_px: float = 4.0  # > 0: estimates this far apart on one region split it (k-means); 0: off (see docs)
    split_neighbours_m: float = 0.10  # > 0: only reflectors this close on the rest-pose body split a region; 0: any
    c_min: float = 0.1  # smallest accepted fused confidence E
    # Recovery (see ``recover_dropped``): estimates the rules above dropped, kept in 2D and flagged ``recovered``.
    recover_snap_px: float = 9.0  # > 0: a dropped estimate's region may start this far from it; 0: no recovery
    recover_neighbours_m: float = 0.12  # a dropped estimate may take a part of a region held by reflectors this close


def peaks(confidence: np.ndarray, threshold: float, max_n: int) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of one confidence map, strongest first, refined to sub-cell by a 3x3 centroid.
    (hy, hx) -> cells (n, 2) as (x, y), values (n,)"""
    return peak_sets(np.asarray(confidence)[None], threshold, max_n)[0]


def peak_sets(confidence: np.ndarray, threshold: float, max_n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``peaks`` of every map of a stack, in one filtering pass.  (R, hy, hx) -> R x (cells (n, 2), values (n,))"""
    c = np.asarray(confidence, np.float32)
    is_peak = (c == ndimage.maximum_filter(c, size=(1, 3, 3), mode="constant")) & (c >= threshold)
    rs, ys, xs = np.nonzero(is_peak)  # every map's peaks, map by map
    keep = _strongest(c[rs, ys, xs], rs, len(c), max_n)
    rs, ys, xs = rs[keep], ys[keep], xs[keep]
    weights = np.clip(np.pad(c, ((0, 0), (1, 1), (1, 1))), 0, None)
    dy, dx = np.mgrid[-1:2, -1:2]
    w = weights[rs[:, None, None], ys[:, None, None] + 1 + dy, xs[:, None, None] + 1 + dx]  # (n, 3, 3) neighbourhoods
    total = w.sum(axis=(1, 2))
    cells = np.stack([xs + (w * dx).sum(axis=(1, 2)) / total, ys + (w * dy).sum(axis=(1, 2)) / total], axis=1)
    cells, values = cells.astype(np.float64).reshape(-1, 2), c[rs, ys, xs].astype(np.float64)
    return [(cells[a:b], values[a:b]) for a, b in _spans(np.bincount(rs, minlength=len(c)))]


def _spans(counts: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of consecutive groups of these sizes (np.split's pieces, without its per-piece cost)."""
    stops = np.cumsum(counts).tolist()
    return list(zip([0] + stops[:-1], stops))


def _strongest(values: np.ndarray, group: np.ndarray, n_groups: int, max_n: int) -> np.ndarray:
    """Indices of the ``max_n`` largest values of each group, groups in order, each in the order that
    ``np.argsort(-values_of_the_group)[:max_n]`` gives (a group holding equal values is sorted on its own, since
    that sort may order ties its own way).  values, group (n,) sorted by group -> (k,)"""
    order = np.lexsort((-values, group))  # by group, then strongest first
    counts = np.bincount(group, minlength=n_groups)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(len(order)) - np.repeat(starts, counts)  # place of each sorted entry within its group
    same = (group[order][1:] == group[order][:-1]) & (values[order][1:] == values[order][:-1])
    if not same.any():
        return order[rank < max_n]
    tied = set(group[order][1:][same].tolist())
    return np.concatenate([np.zeros(0, np.int64)] + [
        starts[g] + np.argsort(-values[starts[g]:starts[g] + counts[g]])[:max_n] if g in tied
        else order[starts[g]:starts[g] + counts[g]][:max_n] for g in range(n_groups)])


def bilinear(field: np.ndarray, points: np.ndarray, which: np.ndarray | None = None) -> np.ndarray:
    """Sample a (hy, hx, k) field at points (n, 2) (x, y cells), zero outside; or, with ``which`` (n,), a stack
    of fields (R, hy, hx, k), point i in field ``which[i]``.  -> (n, k)"""
    if which is None:
        field, which = field[None], np.zeros(len(points), int)
    h, w = field.shape[1:3]
    x, y = points[:, 0], points[:, 1]
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    out = np.zeros((len(points), field.shape[3]))
    for dx in (0, 1):
        for dy in (0, 1):
            xi, yi = x0 + dx, y0 + dy
            weight = (1 - np.abs(x - xi)) * (1 - np.abs(y - yi))
            inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            out[inside] += weight[inside, None] * field[which[inside], yi[inside], xi[inside]]
    return out


def line_integral(field: np.ndarray, start: np.ndarray, end: np.ndarray, samples: int) -> float:
    """E^L: mean of L(p(u)) . (end - start)/||end - start|| over u uniform in [0, 1].  field (hy, hx, 2)

    E^L = integral_0^1 L(p(u)) . (d2 - d1) / ||d2 - d1|| du, p(u) = (1 - u) d1 + u d2   # Eq. (7)-(8), DeepMoCap
    """
    return float(line_integrals(field, np.asarray(start, float)[None], np.asarray(end, float)[None], samples)[0, 0])


def line_integrals(field: np.ndarray, starts: np.ndarray, ends: np.ndarray, samples: int) -> np.ndarray:
    """``line_integral`` from every start to every end in one sampling pass; 0 where they coincide.
    field (hy, hx, 2), starts (m, 2), ends (n, 2) -> (m, n)"""
    return line_integral_sets(field[None], [starts], [ends], samples)[0]


def line_integral_sets(fields: np.ndarray, starts: list, ends: list, samples: int) -> list[np.ndarray]:
    """``line_integrals`` of every field of a stack in one sampling pass.
    fields (R, hy, hx, 2), starts R x (m_r, 2), ends R x (n_r, 2) -> R x (m_r, n_r)"""
    shapes = [(len(a), len(b)) for a, b in zip(starts, ends)]
    if not shapes:
        return []
    first, last, which = _pairs(starts, ends, np.array(shapes).reshape(-1, 2))  # (P, 2) x2, (P,)
    delta = last - first
    length = np.linalg.norm(delta, axis=-1, keepdims=True)
    u = np.linspace(0.0, 1.0, samples)[:, None]  # (samples, 1)
    points = (1 - u) * first[:, None] + u * last[:, None]  # (P, samples, 2)
    values = bilinear(fields, points.reshape(-1, 2), np.repeat(which, samples)).reshape(points.shape)
    direction = np.divide(delta, length, out=np.zeros_like(delta), where=length >= 1e-9)
    integral = (values @ direction[..., None])[..., 0].mean(axis=-1)  # Eq. (7)-(8), DeepMoCap
    return [integral[a:b].reshape(shape) for (a, b), shape in zip(_spans([m * n for m, n in shapes]), shapes)]


def _pairs(starts: list, ends: list, shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (start, end) pair of each field, row-major, and the field of each.
    starts R x (m_r, 2), ends R x (n_r, 2), shapes (R, 2) as (m_r, n_r) -> first (P, 2), last (P, 2), which (P,)"""
    m, n = shapes[:, 0], shapes[:, 1]
    which = np.repeat(np.arange(len(shapes)), m * n)  # (P,)
    k = np.arange(len(which)) - np.repeat(np.cumsum(m * n) - m * n, m * n)  # pair index within its field
    first_at = (np.cumsum(m) - m)[which] + k // n[which]  # rows of the stacked starts and ends
    last_at = (np.cumsum(n) - n)[which] + k % n[which]
    stacked = [np.concatenate([np.zeros((0, 2))] + [np.asarray(a, float).reshape(-1, 2) for a in arrays])
               for arrays in (starts, ends)]
    return stacked[0][first_at], stacked[1][last_at], which


def fuse(e_s, e_l):
    """E = E^S + (1 - E^S)·E^L, with E^L clipped to [0, 1]; floats or arrays.   # Eq. (9), DeepMoCap"""
    return e_s + (1.0 - e_s) * np.clip(e_l, 0.0, 1.0)


def reflector_region(xy: np.ndarray, blob_id: np.ndarray, blob_area: np.ndarray, *, snap_px: float,
                     radius_px: float) -> tuple[np.ndarray, int, int] | None:
    """Centre (x, y), area and label of the reflector region at (or within ``snap_px`` of) image point ``xy``;
    None if none. A region wider than ``radius_px`` (touching reflectors, a strap seen along) gives the mean
    of its pixels within ``radius_px`` of the point."""
    h, w = blob_id.shape
    r = int(np.ceil(radius_px))
    x0, y0 = max(int(xy[0]) - r, 0), max(int(xy[1]) - r, 0)
    window = blob_id[y0:min(int(xy[1]) + r + 2, h), x0:min(int(xy[0]) + r + 2, w)]
    ys, xs = np.nonzero(window)
    if len(xs) == 0:
        return None
    px = np.stack([xs + x0, ys + y0], axis=1).astype(np.float64)
    d = np.linalg.norm(px - xy, axis=1)
    nearest = int(np.argmin(d))
    if d[nearest] > snap_px:
        return None
    labels = window[ys, xs]
    label = labels[nearest]
    on = labels == label
    region = px[on]
    centre = region.mean(axis=0)
    area = int(blob_area[label - 1])
    if len(region) == area and np.linalg.norm(region - centre, axis=1).max() <= radius_px:
        return centre, area, int(label)  # a reflector-sized region: its centre
    return px[on & (d <= radius_px)].mean(axis=0), area, int(label)  # shared or long: the near part


def split_region(seeds: np.ndarray, blob_id: np.ndarray, label: int, iterations: int = 5) -> np.ndarray:
    """Centres of the parts of one region shared by several estimates: k-means of its pixels (Lloyd),
    seeded at the estimates, so touching reflectors get their own centres.  (n, 2) -> (n, 2)"""
    ys, xs = np.nonzero(blob_id == label)
    px = np.stack([xs, ys], axis=1).astype(np.float64)  # (pixels, 2)
    centres = np.asarray(seeds, np.float64).copy()
    for _ in range(iterations):
        part = np.argmin(((px[:, None] - centres[None]) ** 2).sum(-1), axis=1)
        centres = np.stack([px[part == k].mean(0) if (part == k).any() else centres[k] for k in range(len(centres))])
    return centres


def claim_part(seed: np.ndarray, holders: np.ndarray, blob_id: np.ndarray, label: int, *,
               split_px: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The part of region ``label`` that a further estimate at ``seed`` (2,) takes beside the estimates
    ``holders`` (n, 2) already on it: k-means of its pixels seeded at them and it (``split_region``); None
    when the seed lies within ``split_px`` of a holder.  -> its centre (2,), the holders' parts (n, 2)"""
    if np.linalg.norm(holders - seed, axis=1).min() < split_px:
        return None
    parts = split_region(np.vstack([holders, seed]), blob_id, label)
    return parts[-1], parts[:-1]


def suppress_close(xy: np.ndarray, confidence: np.ndarray, min_distance: float) -> np.ndarray:
    """Keep mask: of estimates closer than ``min_distance``, the more confident.  (R, 2), (R,) -> (R,)

    Strongest first, each estimate still kept drops the others within reach that are no more confident."""
    keep = np.isfinite(xy[:, 0])
    order = np.argsort(-confidence)
    close = np.linalg.norm(xy[:, None] - xy[None], axis=-1) < min_distance  # (R, R), False where NaN
    np.fill_diagonal(close, False)
    dominated = close & (confidence[None] <= confidence[:, None])  # row i: whom estimate i drops
    for i in order[keep[order]]:
        if keep[i]:
            keep &= ~dominated[i]
    return keep


def _candidates(confidence: np.ndarray, threshold: float, max_n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """NMS candidates of every reflector of one frame.  (R, hy, hx) -> R x (cells (n, 2), E^S (n,))"""
    return peak_sets(confidence, threshold, max_n)


def _to_image(affine: np.ndarray, cells: np.ndarray, stride: int) -> np.ndarray:
    return targets.apply_affine(affine.reshape(2, 3), targets.from_cells(cells, stride))


def _to_cells(affine: np.ndarray, image_xy: np.ndarray, stride: int) -> np.ndarray:
    return targets.to_cells(targets.apply_affine(targets.invert_affine(affine.reshape(2, 3)), image_xy), stride)


def estimate_frame(confidence, off, affine, prev, stride: int, config: GreedyConfig):
    """Best candidate of every reflector of one frame, scored with the OFF against the previous frame.

    confidence (R, hy, hx), off (R, hy, hx, 2), affine (6,) crop -> image; prev: (candidates, affine) of
    f-1 or None.  -> image xy (R, 2) NaN where no candidate, fused confidence E (R,), candidates
    """
    cands = _candidates(confidence, config.peak_threshold, config.max_candidates)
    earlier = [np.empty((0, 2))] * len(cands)
    if prev is not None:  # f-1 candidates, moved into this frame's crop
        moved = _to_cells(affine, _to_image(prev[1], np.concatenate([cells for cells, _ in prev[0]]), stride), stride)
        earlier = np.split(moved, np.cumsum([len(cells) for cells, _ in prev[0]])[:-1])
    links = line_integral_sets(off, earlier, [cells for cells, _ in cands], config.line_samples)  # R x (m_r, n_r)
    chosen = np.full((len(cands), 2), np.nan)  # cells
    best = np.zeros(len(cands))
    for r, ((cells, e_s), link) in enumerate(zip(cands, links)):
        if len(cells):
            e = fuse(e_s, link.max(axis=0, initial=0.0))  # (n_r,) with each candidate's best f-1 link
            k = int(np.argmax(e))
            best[r], chosen[r] = e[k], cells[k]
    xy = np.full_like(chosen, np.nan)
    found = np.isfinite(chosen[:, 0])
    xy[found] = _to_image(affine, chosen[found], stride)
    return xy, best, cands


def filter_frame(xy, confidence, blob_id, blob_area, config: GreedyConfig, may_split: np.ndarray | None = None,
                 may_recover: np.ndarray | None = None):
    """§5.1.3 filtering of one image's estimates.
    -> region centres (R, 2) NaN if rejected, E (R,), sizes (R,), recovered (R,) bool

    ``may_split`` (R, R) bool: which reflectors may split a region they share (see ``neighbours``; None: any).
    With ``config.recover_snap_px`` > 0, ``recover_dropped`` gives the dropped estimates a second chance
    (``may_recover``: its ``may_share``); those it keeps are ``recovered``.
    """
    b_min, split_px = config.b_min, config.split_px
    out = np.full_like(xy, np.nan)
    size = np.zeros(len(xy), np.int32)
    label = np.zeros(len(xy), np.int64)
    for r in np.nonzero(np.isfinite(xy[:, 0]) & (confidence >= config.c_min))[0]:
        region = reflector_region(xy[r], blob_id, blob_area, snap_px=config.snap_px, radius_px=config.region_radius_px)
        if region is not None and region[1] >= b_min:
            out[r], size[r], label[r] = region
    regions, count = np.unique(label[label > 0], return_counts=True)
    for shared in regions[count > 1] if split_px > 0 else ():  # one region, distinct estimates: a part each
        on = np.flatnonzero(label == shared)
        seeds = np.flatnonzero(suppress_close(xy[on], confidence[on], split_px))  # the distinct ones
        if len(seeds) > 1 and (may_split is None or may_split[np.ix_(on[seeds], on[seeds])].all()):
            centres = split_region(xy[on[seeds]], blob_id, shared)
            nearest = np.argmin(((xy[on][:, None] - xy[on[seeds]][None]) ** 2).sum(-1), axis=1)
            out[on] = centres[nearest]  # an estimate close to a stronger one shares its centre (then suppressed)
    keep = suppress_close(out, confidence, config.min_distance_px)
    out[~keep] = np.nan
    size[~keep] = 0
    label[~keep] = 0
    recovered = np.zeros(len(xy), bool)
    if config.recover_snap_px > 0:
        found = recover_dropped(xy, confidence, out, label, blob_id, blob_area, config, may_share=may_recover)
        for r, (centre, area, region) in found.items():
            out[r], size[r], label[r], keep[r], recovered[r] = centre, area, region, True, True
    return out, np.where(keep, confidence, 0.0), size, recovered


def recover_dropped(xy, confidence, out, label, blob_id, blob_area, config: GreedyConfig,
                    may_share: np.ndarray | None) -> dict[int, tuple[np.ndarray, int, int]]:
    """A second chance for the estimates that ``filter_frame`` dropped, strongest first, which never moves or
    removes a kept one: a region within ``recover_snap_px`` of the estimate, of at least ``b_min`` pixels, either
    free, or held only by reflectors that ``may_share`` it (R, R; None: by none) and at least ``split_px`` from
    the estimate, whose part of it (k-means, seeded at the holders' and its own estimates) it takes; its centre
    at least ``min_distance_px`` from every other estimate kept (from a holder's part, for the holders).
    -> {reflector: (centre (2,), area, region label)}
    """
    found = {}
    held_xy, held_label = out.copy(), label.copy()  # (R, 2), (R,): kept, then recovered too
    dropped = np.flatnonzero(np.isfinite(xy[:, 0]) & ~np.isfinite(out[:, 0]) & (confidence >= config.c_min))
    for r in dropped[np.argsort(-confidence[dropped], kind="stable")]:
        region = reflector_region(xy[r], blob_id, blob_area, snap_px=config.recover_snap_px,
                                  radius_px=config.region_radius_px)
        if region is None or region[1] < config.b_min:
            continue
        centre, area, region_label = region
        holders = np.flatnonzero(held_label == region_label)
        others = held_xy.copy()
        if len(holders):
            part = claim_part(xy[r], xy[holders], blob_id, region_label, split_px=config.split_px) \
                if may_share is not None and may_share[r, holders].all() else None
            if part is None:
                continue
            centre, others[holders] = part  # apart from the holders' parts, not their whole-region centres
        if np.nanmin(np.linalg.norm(others - centre, axis=1), initial=np.inf) < config.min_distance_px:
            continue
        found[r] = (centre, area, region_label)
        held_xy[r], held_label[r] = centre, region_label
    return found


def greedy_reflectors(heatmaps: xr.Dataset, masks: xr.Dataset, config: GreedyConfig) -> xr.Dataset:
    """Labelled 2D reflectors of every view and frame (``heatmaps`` starts one frame early, for f-1)."""
    stride = int(heatmaps.attrs["stride"])
    shape = (heatmaps.sizes["view"], heatmaps.sizes["frame"], heatmaps.sizes["reflector"])
    out = {k: np.full(shape + (2,), np.nan) for k in ("xy", "candidate")}
    out.update({k: np.zeros(shape) for k in ("confidence", "candidate_confidence")})
    out["size"] = np.zeros(shape, np.int32)
    out["recovered"] = np.zeros(shape, bool)
    frames = heatmaps["frame"].values
    names = [str(n) for n in heatmaps["reflector"].values]
    may_split = neighbours(names, config.split_neighbours_m)
    may_recover = neighbours(names, config.recover_neighbours_m)  # None (0 m): no region is shared on the second pass
    for v, view in enumerate(heatmaps["view"].values):
        h, m = heatmaps.sel(view=view), masks.sel(view=view)
        conf, off, crop = h["confidence"].values.astype(np.float32), h["off"].values.astype(np.float32), h["crop"].values
        prev = None
        for i, frame in enumerate(frames):
            xy, e, cands = estimate_frame(conf[i], off[i], crop[i], prev if i and frames[i - 1] == frame - 1 else None,
                                          stride, config)
            prev = (cands, crop[i])
            out["candidate"][v, i], out["candidate_confidence"][v, i] = xy, e
            j = int(np.nonzero(m["frame"].values == frame)[0][0])
            out["xy"][v, i], out["confidence"][v, i], out["size"][v, i], out["recovered"][v, i] = filter_frame(
                xy, e, m["blob_id"].values[j], m["blob_area"].values[j], config, may_split=may_split,
                may_recover=may_recover)
    dims = ("view", "frame", "reflector")
    f32 = lambda a: (dims, a.astype(np.float32))  # noqa: E731
    return xr.Dataset(
        {"x": f32(out["xy"][..., 0]), "y": f32(out["xy"][..., 1]), "confidence": f32(out["confidence"]),
         "region_size": (dims, out["size"]), "recovered": (dims, out["recovered"]),
         "candidate_x": f32(out["candidate"][..., 0]), "candidate_y": f32(out["candidate"][..., 1]),
         "candidate_confidence": f32(out["candidate_confidence"])},
        coords={"view": heatmaps["view"].values, "frame": frames, "reflector": heatmaps["reflector"].values},
        attrs={"b_min": int(config.b_min), "c_min": float(config.c_min)},
    )
