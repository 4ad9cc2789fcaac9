"""Labels grown over the suit's grid from the squares read (beyond Chen et al. 2021, who label only the corners of
squares whose code is read): detections of corners whose squares were not read, named from their labelled
neighbours.

The suit's grid (``cells``: every square, black or white, by its four corners counter-clockwise) says which corners
are a square's. Two rules predict where an unlabelled corner is in an image, and a detection within a share of the
square's size there is named that corner:

- *completion*: a square with three corners labelled is a parallelogram in the image to first order, so the fourth
  is at ``a + c - b`` (``b`` the corner opposite the missing one);
- *extension*: across an edge ``p q`` of a square whose four corners are labelled, the next square's two other
  corners continue the square's sides: ``2 p - s`` and ``2 q - r`` (``s``, ``r`` the corners behind ``p``, ``q``).

A corner predicted at two different detections, or a detection claimed for two corners, is left out. The rules run
in rounds, each on the labels of the last, so labels spread square by square from what was read (``rounds``
bounds how far). The corners are a square apart in the image, so a detection near a prediction is that corner
unless another surface hides it or the square is foreshortened; a grown detection must also be a confident one
(CornerdetNet's logit), and an extension is refused when another detection lies between it and its square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class GrowConfig:
    # chosen on the training takes (training/suit.yaml, shipped networks; docs/suit.md): readable corners labelled
    # 63.4 -> 73.3 %, wrong labels 0.12 -> 0.32 %
    rounds: int = 6  # spreading steps (0: the labels as read)
    complete_radius: float = 0.12  # a detection this share of the square's side from a completion's prediction
    extend_radius: float = 0.12  # ... from an extension's prediction
    extend: bool = True  # also extend across the edges of fully labelled squares
    min_logit: float = 3.0  # CornerdetNet's presence logit a grown detection must reach (it detects above 0)

    def __post_init__(self):
        if self.rounds < 0 or not (0 < self.complete_radius < 0.5 and 0 < self.extend_radius < 0.5):
            raise ValueError(f"rounds ({self.rounds}) must be >= 0 and the radii "
                             f"({self.complete_radius}, {self.extend_radius}) shares of a square's side in (0, 0.5): "
                             "a corner's neighbours are a side away")


def cell_edges(cells: np.ndarray) -> dict[tuple[int, int], list[tuple[int, int]]]:
    """Each grid edge (lower corner, higher corner) -> the (cell, position of the edge's first corner in it) of
    the cells that have it (one or two)."""
    edges: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for cell, corners in enumerate(cells.tolist()):
        for i in range(4):
            a, b = corners[i], corners[(i + 1) % 4]
            edges.setdefault((min(a, b), max(a, b)), []).append((cell, i))
    return edges


def _completions(cells: np.ndarray, xy: np.ndarray, known: np.ndarray, radius: float):
    """(corner, predicted xy, search radius px, origin: NaN) of the missing corner of every cell with three
    labelled."""
    k = known[cells]  # (cell, 4)
    rows = np.flatnonzero(k.sum(axis=1) == 3)
    if not len(rows):
        return _nothing()
    m = np.argmin(k[rows], axis=1)  # the missing position
    c = cells[rows]
    at = lambda shift: xy[c[np.arange(len(rows)), (m + shift) % 4]]  # noqa: E731 - the cell's corner m + shift
    before, opposite, after = at(3), at(2), at(1)
    side = 0.5 * (np.linalg.norm(before - opposite, axis=1) + np.linalg.norm(after - opposite, axis=1))
    return c[np.arange(len(rows)), m], before + after - opposite, radius * side, np.full((len(rows), 2), np.nan)


def _nothing():
    return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2))


def _extensions(cells: np.ndarray, edges: dict, xy: np.ndarray, known: np.ndarray, radius: float):
    """(corner, predicted xy, search radius px, origin: the labelled corner it continues from) of the far corners
    of the neighbours of every fully labelled cell."""
    corner, pred, reach, origin = [], [], [], []
    for cell in np.flatnonzero(known[cells].all(axis=1)):
        c = cells[cell]
        for i in range(4):
            p, q, r, s = c[i], c[(i + 1) % 4], c[(i + 2) % 4], c[(i + 3) % 4]
            across = [(n, j) for n, j in edges[(min(p, q), max(p, q))] if n != cell]
            if not across:
                continue
            n, j = across[0]  # the edge is the neighbour's corners j, j + 1 (q, p when both run counter-clockwise)
            ring = cells[n]
            far_p, far_q = ((ring[(j + 2) % 4], ring[(j + 3) % 4]) if ring[j] == q
                            else (ring[(j + 3) % 4], ring[(j + 2) % 4]))
            side = np.linalg.norm(xy[p] - xy[q])
            for target, near, behind in ((far_p, p, s), (far_q, q, r)):
                if not known[target]:
                    corner.append(target)
                    pred.append(2 * xy[near] - xy[behind])
                    reach.append(radius * side)
                    origin.append(xy[near])
    if not corner:
        return _nothing()
    return np.asarray(corner, np.int64), np.asarray(pred), np.asarray(reach), np.asarray(origin)


def _nearer_one(tree: cKDTree, detections: np.ndarray, origin: np.ndarray, found: np.ndarray) -> np.ndarray:
    """Per extension, whether another detection lies between its origin and the detection it found (nearer the
    origin, within 30 degrees of that direction): the next corner is nearer than one square (a foreshortened
    square), and what was found may be the corner after it."""
    out = np.zeros(len(origin), bool)
    for i in np.flatnonzero(np.isfinite(origin).all(axis=1)):
        ray = detections[found[i]] - origin[i]
        length = float(np.linalg.norm(ray))
        for j in tree.query_ball_point(origin[i], 0.8 * length):
            step = detections[j] - origin[i]
            along = float(step @ ray) / length
            if j != found[i] and 0.15 * length < along and along > np.cos(np.radians(30)) * np.linalg.norm(step):
                out[i] = True
                break
    return out


def grow_labels(detections: np.ndarray, detection_of: np.ndarray, cells: np.ndarray, config: GrowConfig = GrowConfig(),
                edges: dict | None = None, logits: np.ndarray | None = None) -> np.ndarray:
    """One image's labels grown over the grid.

    detections (n, 2) every detection's (x, y); detection_of (corner,) the detection labelled each suit corner
    (-1 none); cells (cell, 4) the grid's squares; logits (n,) CornerdetNet's, for ``min_logit``.
    -> detection_of with the grown labels added (corner,)"""
    detection_of = detection_of.copy()
    if not len(detections):
        return detection_of
    edges = cell_edges(cells) if edges is None else edges
    tree = cKDTree(detections)
    for _ in range(config.rounds):
        known = detection_of >= 0
        xy = np.full((len(detection_of), 2), np.nan)
        xy[known] = detections[detection_of[known]]
        found = [_completions(cells, xy, known, config.complete_radius)]
        if config.extend:
            found.append(_extensions(cells, edges, xy, known, config.extend_radius))
        corner, pred, reach, origin = (np.concatenate(parts) for parts in zip(*found))
        if not len(corner):
            break
        dist, nearest = tree.query(pred)
        ok = dist <= reach
        taken = np.zeros(len(detections), bool) if logits is None else logits < config.min_logit
        taken[detection_of[known]] = True
        ok &= ~taken[nearest]
        ok[ok] &= ~_nearer_one(tree, detections, origin[ok], nearest[ok])
        new = _agreed(corner[ok], nearest[ok])
        if not new:
            break
        for c, d in new.items():
            detection_of[c] = d
    return detection_of


def _agreed(corner: np.ndarray, detection: np.ndarray) -> dict[int, int]:
    """corner -> detection where every prediction of the corner found the same detection and no other corner's
    found it."""
    pairs = np.unique(np.column_stack([corner, detection]), axis=0)
    corners, per_corner = np.unique(pairs[:, 0], return_counts=True)
    detections, per_detection = np.unique(pairs[:, 1], return_counts=True)
    single_corner = set(corners[per_corner == 1].tolist())
    single_detection = set(detections[per_detection == 1].tolist())
    return {int(c): int(d) for c, d in pairs if c in single_corner and d in single_detection}


# ---------------------------------------------------------------------------------------------------- the stage

def grow_corner_labels(images, corners, labels, config: GrowConfig):
    """Task: suit_labels grown over the grid (``quads`` 0 on the grown corners)."""
    import xarray as xr

    cells = images["cells"].values
    edges = cell_edges(cells)
    x, y = labels["x"].values.copy(), labels["y"].values.copy()
    named = labels["quads"].values.copy()
    for v in range(x.shape[0]):
        for f in range(x.shape[1]):
            det = np.column_stack([corners["x"].values[v, f], corners["y"].values[v, f]])
            real = np.isfinite(det).all(axis=1)
            det = det[real]
            detection_of = _detection_indices(det, x[v, f], y[v, f])
            grown = grow_labels(det, detection_of, cells, config, edges, corners["logit"].values[v, f][real])
            new = (grown >= 0) & (detection_of < 0)
            x[v, f, new], y[v, f, new] = det[grown[new], 0], det[grown[new], 1]
            named[v, f, new] = 0
    dims = ("view", "frame", "corner")
    return xr.Dataset({"x": (dims, x), "y": (dims, y), "quads": (dims, named)},
                      coords={"view": labels["view"].values, "frame": labels["frame"].values,
                              "corner": labels["corner"].values})


def _detection_indices(detections: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The detection at each labelled corner's position (labels are detections' positions), -1 where unlabelled."""
    out = np.full(len(x), -1, np.int64)
    hit = np.isfinite(x)
    if hit.any() and len(detections):
        dist, idx = cKDTree(detections).query(np.column_stack([x[hit], y[hit]]))
        assert (dist < 1e-3).all(), "a label is not at a detection"
        out[hit] = idx
    return out
