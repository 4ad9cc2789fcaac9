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


def far_corners(cells: np.ndarray, edges: dict | None = None) -> np.ndarray:
    """For each cell's edge i (its corners i, i + 1), the two far corners of the cell across it: the one beside
    corner i, then the one beside corner i + 1; -1 where no cell lies across (the grid's border).
    cells (cell, 4) counter-clockwise -> (cell, 4, 2) int64"""
    edges = cell_edges(cells) if edges is None else edges
    out = np.full((len(cells), 4, 2), -1, np.int64)
    for pair in edges.values():
        for cell, i in pair:
            across = [(n, j) for n, j in pair if n != cell]
            if not across:
                continue
            n, j = across[0]  # the edge is the neighbour's corners j, j + 1 (q, p when both run counter-clockwise)
            ring = cells[n]
            q = cells[cell][(i + 1) % 4]
            out[cell, i] = ((ring[(j + 2) % 4], ring[(j + 3) % 4]) if ring[j] == q
                            else (ring[(j + 3) % 4], ring[(j + 2) % 4]))
    return out


def _extensions(cells: np.ndarray, far: np.ndarray, xy: np.ndarray, known: np.ndarray, radius: float):
    """(corner, predicted xy, search radius px, origin: the labelled corner it continues from) of the far corners
    of the neighbours of every fully labelled cell: across edge p q (corners i, i + 1), the corner beside p at
    2 p - s and the one beside q at 2 q - r (s, r the cell's corners behind p, q)."""
    full = np.flatnonzero(known[cells].all(axis=1))
    c, target = cells[full], far[full]  # (m, 4), (m, 4, 2)
    turn = (np.arange(4)[:, None] + np.arange(4)[None, :]) % 4  # [i, k]: corner i + k
    p, q, r, s = (c[:, turn[:, k]] for k in range(4))  # (m, 4) each, edge i's p q and the two behind them
    near, behind = np.stack([p, q], axis=-1), np.stack([s, r], axis=-1)  # (m, 4, 2)
    side = np.repeat(np.linalg.norm(xy[p] - xy[q], axis=-1)[..., None], 2, axis=-1)
    ok = target >= 0
    ok[ok] = ~known[target[ok]]
    if not ok.any():
        return _nothing()
    near = near[ok]
    return target[ok], 2 * xy[near] - xy[behind[ok]], radius * side[ok], xy[near]


def _nearer_one(tree: cKDTree, detections: np.ndarray, origin: np.ndarray, found: np.ndarray) -> np.ndarray:
    """Per extension, whether another detection lies between its origin and the detection it found (nearer the
    origin, within 30 degrees of that direction): the next corner is nearer than one square (a foreshortened
    square), and what was found may be the corner after it."""
    out = np.zeros(len(origin), bool)
    rows = np.flatnonzero(np.isfinite(origin).all(axis=1))
    if not len(rows):
        return out
    start, hit = origin[rows], found[rows]
    ray = detections[hit] - start
    length = np.linalg.norm(ray, axis=1)
    near = tree.query_ball_point(start, 0.8 * length)
    owner = np.repeat(np.arange(len(rows)), [len(n) for n in near])
    if not len(owner):
        return out
    other = np.concatenate(near).astype(np.int64)
    step = detections[other] - start[owner]
    with np.errstate(divide="ignore", invalid="ignore"):
        along = np.einsum("ij,ij->i", step, ray[owner]) / length[owner]
    between = (other != hit[owner]) & (0.15 * length[owner] < along) \
        & (along > np.cos(np.radians(30)) * np.linalg.norm(step, axis=1))
    out[rows[owner[between]]] = True
    return out


def grow_labels(detections: np.ndarray, detection_of: np.ndarray, cells: np.ndarray, config: GrowConfig = GrowConfig(),
                far: np.ndarray | None = None, logits: np.ndarray | None = None) -> np.ndarray:
    """One image's labels grown over the grid.

    detections (n, 2) every detection's (x, y); detection_of (corner,) the detection labelled each suit corner
    (-1 none); cells (cell, 4) the grid's squares; far their :func:`far_corners` (computed when not given: once
    per suit is enough); logits (n,) CornerdetNet's, for ``min_logit``.
    -> detection_of with the grown labels added (corner,)"""
    detection_of = detection_of.copy()
    if not len(detections):
        return detection_of
    far = far_corners(cells) if far is None else far
    tree = cKDTree(detections)
    for _ in range(config.rounds):
        known = detection_of >= 0
        xy = np.full((len(detection_of), 2), np.nan)
        xy[known] = detections[detection_of[known]]
        found = [_completions(cells, xy, known, config.complete_radius)]
        if config.extend:
            found.append(_extensions(cells, far, xy, known, config.extend_radius))
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
    far = far_corners(cells)
    x, y = labels["x"].values.copy(), labels["y"].values.copy()
    named = labels["quads"].values.copy()
    for v in range(x.shape[0]):
        for f in range(x.shape[1]):
            det = np.column_stack([corners["x"].values[v, f], corners["y"].values[v, f]])
            real = np.isfinite(det).all(axis=1)
            det = det[real]
            detection_of = _detection_indices(det, x[v, f], y[v, f])
            grown = grow_labels(det, detection_of, cells, config, far, corners["logit"].values[v, f][real])
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
