"""Step 2 of UUO's marker-part matching: where on the body are the markers? (Milef et al. 2024, §3.4.2)

The K rigid groups of the segmentation (segmentation.py) are read as a kinematic chain of K parts. Every
connected chain of K parts of the body (the fine parts of mesh_body.PARTS joined as the skeleton joins them) is a
candidate; the prior body's skin vertices of that chain are fitted to all the markers of the take: one rotation
about the vertical for the take (started at the hypothesis' yaw) and one translation per frame (started from the
median marker, §3.4), by iterated closest points; the candidate with the least one-directional chamfer
distance from the markers to its vertices (Eq. 1) wins. Chains of 15 parts or more are the whole body.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.kinematics import rigid_fit
from mocapflow.tasks.shared.mesh_body import MeshBody, part_of_bone

_SIDE_CHAINS = (("torso", "{s}_upper_arm"), ("{s}_upper_arm", "{s}_forearm"), ("{s}_forearm", "{s}_hand"),
                ("hips", "{s}_thigh"), ("{s}_thigh", "{s}_shank"), ("{s}_shank", "{s}_foot"))
PART_EDGES = (("hips", "torso"), ("torso", "head")) + tuple(
    (a.format(s=side), b.format(s=side)) for side in ("left", "right") for a, b in _SIDE_CHAINS)
PART_NAMES = tuple(sorted({p for edge in PART_EDGES for p in edge}))


class MatchingError(ValueError):
    """Markers or settings part matching cannot use."""


@dataclass(frozen=True)
class MatchConfig:
    min_group: int = 2  # groups with fewer markers do not count toward the chain's length K
    frames: int = 60  # frames the search fits (evenly spaced over the take)
    vertices: int = 1000  # skin vertices per candidate chain in the search (evenly spaced)
    iterations: int = 20  # closest-point iterations per candidate
    whole_body_from: int = 7  # chains this long or longer are the whole body
    grow_until_m: float = 0.045  # the chain grows while its RMS chamfer distance exceeds this ...
    grow_gain: float = 0.01  # ... and a neighbouring part cuts the chamfer by this share
    rigid_min_markers: int = 6  # a frame with this many samples on the chain gets its own rotation
    keep: float = 0.9  # each closest-point step places the body by this share of the samples closest to it ...
    keep_rotation: float = 0.9  # ... and turns it by this share (lower: only the parts the prior has right)

    def __post_init__(self):
        if self.min_group < 1 or self.frames < 2 or self.vertices < 10 or self.iterations < 1:
            raise MatchingError(f"matching needs min_group >= 1, frames >= 2, vertices >= 10 and iterations >= 1, "
                                f"got {self.min_group}, {self.frames}, {self.vertices}, {self.iterations}")


@dataclass(frozen=True)
class Match:
    parts: tuple[str, ...]  # the chosen chain
    yaw: float  # radians, the take's rotation about z that brings the prior onto the markers
    rotation: np.ndarray  # (frame, 3, 3) each frame's rotation of the prior (the yaw, refined per frame)
    translation: np.ndarray  # (frame, 3) after the rotation
    chamfer: float  # Eq. (1), m^2
    candidates: int


def evenly(items: np.ndarray, count: int) -> np.ndarray:
    """At most ``count`` evenly spaced entries of ``items`` (all of them when fewer)."""
    return items[np.linspace(0, len(items) - 1, min(count, len(items))).astype(int)]


def chain_length(segments: np.ndarray, min_group: int) -> int:
    """K: the rigid groups with at least ``min_group`` markers (at least 1).  segments (marker,) -> int"""
    sizes = np.bincount(segments[segments >= 0]) if len(segments) else np.zeros(0, int)
    return int(max(1, (sizes >= min_group).sum()))


def connected_chains(k: int) -> list[tuple[str, ...]]:
    """Every connected set of ``k`` parts of the body graph (PART_EDGES), each sorted; all parts when k >= 15."""
    if k >= len(PART_NAMES):
        return [PART_NAMES]
    near = {p: set() for p in PART_NAMES}
    for a, b in PART_EDGES:
        near[a].add(b)
        near[b].add(a)
    level = {frozenset([p]) for p in PART_NAMES}
    for _ in range(k - 1):
        level = {s | {n} for s in level for p in s for n in near[p] if n not in s}
    return sorted(tuple(sorted(s)) for s in level)


def part_vertices(body: MeshBody, parts: tuple[str, ...]) -> np.ndarray:
    """Skin vertices whose strongest bone belongs to one of ``parts``.  -> (n,) vertex indices"""
    inside = np.array([part_of_bone(n) in parts for n in body.bone_names])[body.vertex_bone]
    return np.flatnonzero(inside & skin_mask(body))


def skin_mask(body: MeshBody) -> np.ndarray:
    """Whether each vertex is a corner of an outer skin face.  -> (vertex,) bool"""
    skin = np.zeros(len(body.vertices), bool)
    skin[body.faces[body.skin].ravel()] = True
    return skin


def yaw_matrix(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def closest(points: np.ndarray, vertices: np.ndarray, chunk: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Each point's closest vertex in its frame and the squared distance, a few frames at a time.
    points (frame, n, 3), vertices (frame, vertex, 3) -> (frame, n) int, (frame, n)"""
    import torch

    index = np.empty(points.shape[:2], np.int64)
    for s in range(0, len(points), chunk):
        d = torch.cdist(torch.from_numpy(np.ascontiguousarray(points[s:s + chunk], np.float64)),
                        torch.from_numpy(np.ascontiguousarray(vertices[s:s + chunk], np.float64)),
                        compute_mode="use_mm_for_euclid_dist")  # (chunk, n, vertex); float64: ties aside, exact
        index[s:s + chunk] = d.argmin(-1).numpy()
    nearest = np.take_along_axis(vertices, index[..., None], 1)  # (frame, n, 3)
    return index, ((points - nearest) ** 2).sum(-1)


class NearestSkin:
    """Each frame's closest skin vertex to points given in the skin's own frame, for a skin searched many times
    (iterated closest points move the points, not the skin): one k-d tree (scipy's cKDTree) over every frame's
    vertices, the frames set apart along x; a point whose nearest vertex lies in another frame (a point farther
    from its skin than the gap) is searched among its own frame's vertices.  vertices (frame, vertex, 3)"""

    def __init__(self, vertices: np.ndarray):
        from scipy.spatial import cKDTree

        self.vertices = vertices
        self.gap = 4.0 * float(np.ptp(vertices.reshape(-1, 3), axis=0).max()) + 1.0
        self.shift = np.arange(len(vertices))[:, None] * np.array([self.gap, 0.0, 0.0])  # (frame, 3)
        self.tree = cKDTree((vertices + self.shift[:, None]).reshape(-1, 3))

    def query(self, points: np.ndarray, frames: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """points (frame', n, 3) of ``frames`` (default: every frame) -> closest vertex (frame', n), squared
        distance (frame', n)"""
        frames = np.arange(len(self.vertices)) if frames is None else np.asarray(frames)
        n_vertex = self.vertices.shape[1]
        _, flat = self.tree.query(points + self.shift[frames][:, None])
        index = flat - frames[:, None] * n_vertex
        stray = (index < 0) | (index >= n_vertex)
        for f, i in zip(*np.nonzero(stray)):  # beyond the gap: its own frame's vertices, by brute force
            index[f, i] = int(np.argmin(((self.vertices[frames[f]] - points[f, i]) ** 2).sum(-1)))
        nearest = np.take_along_axis(self.vertices[frames], index[..., None], 1)
        return index, ((points - nearest) ** 2).sum(-1)


def fit_yaw(markers: np.ndarray, vertices: np.ndarray, yaw: float, iterations: int, keep: float = 0.9,
            keep_rotation: float = 0.9) -> tuple[float, np.ndarray, float]:
    """Iterated closest points with one yaw for the take and a translation per frame.

    The first half of the iterations moves the body by one translation for the whole take (well posed even
    where a frame has few markers); the second half frees each frame's. Each step moves the body by the ``keep``
    share of samples closest to it (ghosts and markers off the candidate stay out) and turns it by the
    ``keep_rotation`` share (the limbs the prior has wrong would turn it).
    markers (frame, marker, 3) NaN where unseen; vertices (frame, vertex, 3) the prior's posed candidate skin
    -> (yaw, translation (frame, 3), chamfer Eq. (1) in m^2 over all samples)
    """
    seen = np.isfinite(markers).all(-1)  # (frame, marker)
    m = np.where(seen[..., None], markers, 0.0)
    rot = yaw_matrix(yaw)
    t = np.nanmedian(markers[seen], axis=0) - np.median(vertices.reshape(-1, 3), axis=0) @ rot.T  # §3.4: medians
    t = np.broadcast_to(t, (len(markers), 3)).copy()
    skin = NearestSkin(vertices)
    t[:, 2] += _best_lift(m, seen, skin, rot, t)  # ICP slides slowly along a standing body
    for it in range(iterations + 1):
        nearest, d2 = skin.query((m - t[:, None]) @ rot)  # the markers in the skin's frame: v = rot^T (m - t)
        chamfer = float(d2[seen].mean())  # Eq. (1)
        if it == iterations:
            break
        use = seen & (d2 <= np.quantile(d2[seen], keep))
        turn = seen & (d2 <= np.quantile(d2[seen], keep_rotation))
        v = np.take_along_axis(vertices, nearest[..., None], 1)  # (frame, marker, 3) matched prior vertices
        per_frame = it >= iterations // 2
        yaw = _yaw_step(m, v, turn, per_frame)
        rot = yaw_matrix(yaw)
        if per_frame:
            count = np.maximum(use.sum(1), 1)[:, None]
            step = (np.where(use[..., None], m, 0.0).sum(1) - np.where(use[..., None], v, 0.0).sum(1) @ rot.T) / count
            t = np.where(use.any(1)[:, None], step, t)
        else:
            t = np.broadcast_to(m[use].mean(0) - v[use].mean(0) @ rot.T, t.shape).copy()
    return yaw, t, chamfer


def _yaw_step(m: np.ndarray, v: np.ndarray, use: np.ndarray, per_frame: bool) -> float:
    """The yaw best turning matched prior vertices onto their markers, each centred per frame or over the take.
    m, v (frame, marker, 3), use (frame, marker) -> radians"""
    if per_frame:
        count = np.maximum(use.sum(1), 1)[:, None, None]
        p = v - np.where(use[..., None], v, 0.0).sum(1, keepdims=True) / count
        q = m - np.where(use[..., None], m, 0.0).sum(1, keepdims=True) / count
        p, q = p[use], q[use]
    else:
        p, q = v[use] - v[use].mean(0), m[use] - m[use].mean(0)
    return float(np.arctan2((p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]).sum(), (p[:, :2] * q[:, :2]).sum()))


def _best_lift(m: np.ndarray, seen: np.ndarray, skin: NearestSkin, rot: np.ndarray, t: np.ndarray,
               reach: float = 0.6, step: float = 0.03) -> float:
    """The vertical shift (of a grid) of the skin placed by ``rot`` and ``t`` with the least chamfer on a few
    frames."""
    frames = evenly(np.arange(len(m)), 8)
    lifts = np.arange(-reach, reach + step / 2, step)
    up = np.array([0.0, 0.0, 1.0])
    scores = []
    for lift in lifts:
        _, d2 = skin.query((m[frames] - t[frames, None] - lift * up) @ rot, frames)
        scores.append(np.median(d2[seen[frames]]) if seen[frames].any() else 0.0)
    return float(lifts[int(np.argmin(scores))])


def search_parts(markers: np.ndarray, segments: np.ndarray, body: MeshBody, prior_vertices, yaw: float,
                 config: MatchConfig) -> tuple[tuple[str, ...], float, float, int]:
    """The chain of parts the markers sit on, searched on ``config.frames`` frames from one yaw hypothesis:
    every connected chain of K parts fitted, the best grown part by part while a neighbour pays.
    markers (frame, marker, 3); segments (marker,); prior_vertices as for match_parts
    -> (parts, the fitted yaw in radians, its chamfer Eq. (1) in m^2, candidates tried)"""
    k = chain_length(segments, config.min_group)
    chains = connected_chains(len(PART_NAMES) if k >= config.whole_body_from else k)

    def trial(parts: tuple[str, ...], start_yaw: float, iterations: int):
        return try_chain(markers, body, prior_vertices, parts, start_yaw, config, iterations)

    parts, fit = min(((p, trial(p, yaw, config.iterations)) for p in chains), key=lambda c: c[1][2])
    tried = len(chains)
    while len(parts) < len(PART_NAMES) and fit[2] > config.grow_until_m ** 2:  # grow while a neighbour pays
        grown = [tuple(sorted(parts + (n,))) for n in _neighbours(parts)]
        tried += len(grown)
        best_parts, best_fit = min(((p, trial(p, fit[0], config.iterations // 2 + 1)) for p in grown),
                                   key=lambda c: c[1][2])
        if best_fit[2] > (1.0 - config.grow_gain) * fit[2]:
            break
        parts, fit = best_parts, best_fit
    return parts, fit[0], fit[2], tried


def search_frames(markers: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` evenly spaced frames with a marker that the search fits."""
    seen_frames = np.flatnonzero(np.isfinite(markers).all(-1).any(1))
    if not len(seen_frames):
        raise MatchingError("no frame of the take has a marker; part matching needs markers")
    return evenly(seen_frames, count)


def try_chain(markers: np.ndarray, body: MeshBody, prior_vertices, parts: tuple[str, ...], yaw: float,
              config: MatchConfig, iterations: int | None = None) -> tuple[float, np.ndarray, float]:
    """One candidate chain fitted to the markers on the search's frames from ``yaw`` (fit_yaw).
    -> (yaw, translation (frame', 3), chamfer Eq. (1) in m^2)"""
    frames = search_frames(markers, config.frames)
    index = evenly(part_vertices(body, parts), config.vertices)
    return fit_yaw(markers[frames], prior_vertices(frames, index), yaw,
                   config.iterations if iterations is None else iterations, config.keep, config.keep_rotation)


def mirror_parts(parts: tuple[str, ...]) -> tuple[str, ...]:
    """A chain with its sides swapped (left_thigh <-> right_thigh), sorted."""
    swap = {"left": "right", "right": "left"}
    return tuple(sorted(swap[p.split("_", 1)[0]] + "_" + p.split("_", 1)[1] if p.split("_", 1)[0] in swap else p
                        for p in parts))


def match_parts(markers: np.ndarray, segments: np.ndarray, body: MeshBody, prior_vertices, yaw: float,
                config: MatchConfig, parts: tuple[str, ...] | None = None) -> Match:
    """The chain of parts the markers sit on and the prior's placement, for one yaw hypothesis.

    markers (frame, marker, 3); segments (marker,); prior_vertices(frames, vertex_indices) -> (frame', n, 3) the
    prior's posed skin at chosen frames and vertices (a callable, so only what the search needs is skinned).
    ``parts``: a chain already found (hypotheses.screen): no search, the prior placed on it from ``yaw``.
    """
    n_frames = markers.shape[0]
    searched = parts is None
    if searched:
        parts, yaw, chamfer, tried = search_parts(markers, segments, body, prior_vertices, yaw, config)
    index = part_vertices(body, parts)
    index = evenly(index, 2 * config.vertices)
    yaw_all, t, chamfer_all = fit_yaw(markers, prior_vertices(np.arange(n_frames), index), yaw, config.iterations,
                                      config.keep, config.keep_rotation)
    yaw_fit = yaw if searched else yaw_all  # a chain given: its yaw refined on every frame
    if not searched:
        chamfer, tried = chamfer_all, 0
    have = np.isfinite(markers).all(-1).any(1)
    for axis in range(3):  # frames without a marker take the translation of their neighbours
        t[:, axis] = np.interp(np.arange(n_frames), np.flatnonzero(have), t[have, axis])
    rotation, t = fit_rigid(markers, prior_vertices(np.arange(n_frames), index), yaw_matrix(yaw_fit), t,
                            config.iterations // 2 + 1, config.rigid_min_markers, config.keep,
                            config.keep_rotation)
    return Match(parts, yaw_fit, rotation, t, chamfer, tried)


def fit_rigid(markers: np.ndarray, vertices: np.ndarray, rot: np.ndarray, t: np.ndarray, iterations: int,
              min_markers: int, keep: float = 0.9, keep_rotation: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's own rotation and translation by iterated closest points (Kabsch), from the take's; frames
    with fewer than ``min_markers`` usable samples keep the take's rotation. The monocular prior's root turns
    and drifts a little over a take; this registers every frame (RR, per frame).
    markers (frame, marker, 3), vertices (frame, vertex, 3), rot (3, 3), t (frame, 3) -> (frame, 3, 3), (frame, 3)"""
    seen = np.isfinite(markers).all(-1)
    m = np.where(seen[..., None], markers, 0.0)
    rots = np.broadcast_to(rot, (len(markers), 3, 3)).copy()
    t = t.copy()
    skin = NearestSkin(vertices)
    for _ in range(iterations):
        nearest, d2 = skin.query(np.einsum("fji,fvj->fvi", rots, m - t[:, None]))  # rots^T (m - t)
        v = np.take_along_axis(vertices, nearest[..., None], 1)
        for f in range(len(markers)):
            if not seen[f].any():
                continue
            use = seen[f] & (d2[f] <= np.quantile(d2[f][seen[f]], keep))
            turn = seen[f] & (d2[f] <= np.quantile(d2[f][seen[f]], keep_rotation))
            if turn.sum() >= min_markers:
                rots[f] = rigid_fit(v[f, turn], m[f, turn])[0]
            t[f] = m[f, use].mean(0) - rots[f] @ v[f, use].mean(0)
    return rots, t


def _neighbours(parts: tuple[str, ...]) -> list[str]:
    out = {b for a, b in PART_EDGES if a in parts} | {a for a, b in PART_EDGES if b in parts}
    return sorted(out - set(parts))
