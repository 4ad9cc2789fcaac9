"""The suit's pattern (Chen et al. 2021, §3 "Suit", Fig. 2c and 8b): a checkerboard on the body, each white square
with a unique two-letter code, each corner's identity a (code, quad vertex) key.

The suit is the body's largest UV chart (torso, arms and legs: a unitard without head, hands or feet) printed with
a checkerboard of squares ``square_uv`` wide in texture space, its grid shifted by ``offset_uv``. A white square
that lies wholly inside the chart and whose four corners make a sound quadrilateral on the rest body gets a code
from the 25-character alphabet (the paper's; 625 codes at most); its corners are the suit's corners. A corner's
keys are (code, k) for every coded square it belongs to, k = 0..3 its place in the square's quad, clockwise from
the top-left as the code reads upright (Fig. 8b): a corner between two coded squares has two keys. The grid
squares (black and white) whose four corners all exist form the corner mesh the hole filling smooths over.

The pattern is data: the corners' texture coordinates, their rest-body faces and barycentric coordinates, the
squares' codes and corners. ``texture`` prints it (squares and glyphs) for the studio's cameras.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

ALPHABET = "1234567ABCDEFGJKLMPQRTUVY"  # §3, Chen et al. 2021: symbols whose upright orientation is unambiguous
MAX_CODES = len(ALPHABET) ** 2
WHITE, BLACK, BARE = 0.85, 0.06, 0.45  # albedo of the white and black squares and of what the suit leaves bare


class PatternError(ValueError):
    """A suit pattern that cannot be made."""


@dataclass(frozen=True)
class SuitSize:
    """A suit: its squares' width in texture space and its grid's shift (a different print, a different size)."""

    name: str
    square_uv: float
    offset_uv: tuple[float, float] = (0.0, 0.0)
    seed: int = 0  # which code goes on which square
    max_aspect: float = 3.0  # a coded square's longest rest edge over its shortest, at most
    min_edge_m: float = 0.012  # and its shortest rest edge, at least


# About 1,350 and 1,100 corners on the default body, like the paper's medium (1,487) and small (1,119) suits.
# Squares and shifts are whole texels of a 2,048-texel print (and of any print 2,048 * 2^k wide), so every square
# edge falls on a texel boundary and the printed corner is exactly the nominal one.
TEXELS = 2048
SUITS = {"medium": SuitSize("medium", 33 / TEXELS, (6 / TEXELS, 4 / TEXELS), seed=1),
         "small": SuitSize("small", 36 / TEXELS, (22 / TEXELS, 14 / TEXELS), seed=2)}


@dataclass(frozen=True)
class Suit:
    """A printed suit on one body's UV layout."""

    size: SuitSize
    codes: tuple[str, ...]  # (square,) two-letter code of each coded white square
    square_corners: np.ndarray  # (square, 4) corner index of quad vertex k = 0..3, clockwise from the upright top-left
    corner_grid: np.ndarray  # (corner, 2) int grid indices (i along u, j along v)
    corner_uv: np.ndarray  # (corner, 2) texture coordinates
    corner_face: np.ndarray  # (corner,) int face of the body's mesh under the corner
    corner_bary: np.ndarray  # (corner, 2) barycentric (u, v) on that face
    cells: np.ndarray  # (cell, 4) corner indices of every grid square whose corners all exist, counter-clockwise in uv

    @property
    def n_corners(self) -> int:
        return len(self.corner_uv)

    @cached_property
    def keys(self) -> dict[tuple[str, int], int]:
        """(code, quad vertex) -> corner index."""
        return {(code, k): int(c) for code, row in zip(self.codes, self.square_corners) for k, c in enumerate(row)}

    @cached_property
    def code_index(self) -> dict[str, int]:
        return {code: i for i, code in enumerate(self.codes)}

    def corner_keys(self) -> list[list[tuple[str, int]]]:
        """Every corner's keys: one per coded square it belongs to (two where two coded squares meet)."""
        out: list[list[tuple[str, int]]] = [[] for _ in range(self.n_corners)]
        for key, c in self.keys.items():
            out[c].append(key)
        return out


def uv_charts(uv: np.ndarray) -> np.ndarray:
    """Chart (connected piece of the UV layout) of every face: faces sharing a UV point share a chart.
    uv (face, 3, 2) -> (face,) int, chart 0 the one with the most faces."""
    key = np.round(uv.reshape(-1, 2) * 1e6).astype(np.int64)
    _, point = np.unique(key[:, 0] * 10_000_019 + key[:, 1], return_inverse=True)
    point = point.reshape(-1, 3)
    rows, cols = point.ravel(), np.roll(point, 1, axis=1).ravel()
    n = int(point.max()) + 1
    _, label = csgraph.connected_components(sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), (n, n)),
                                            directed=False)
    face_chart = label[point[:, 0]]
    order = np.argsort(-np.bincount(face_chart))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[face_chart]


def locate(uv: np.ndarray, faces: np.ndarray, points: np.ndarray, resolution: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """The face under each texture point and its barycentric coordinates, among ``faces``.

    uv (face, 3, 2), faces (m,) candidate face indices, points (n, 2) -> face (n,) (-1 where none covers the point),
    bary (n, 2). A raster of the candidates' faces proposes up to nine faces per point; the one whose barycentric
    coordinates are least negative wins, and counts when they are all >= -1e-9.
    """
    raster = np.full((resolution, resolution), -1, np.int32)
    for f in faces:
        poly = np.round(np.column_stack([uv[f, :, 0], 1 - uv[f, :, 1]]) * resolution * 4).astype(np.int32)
        cv2.fillPoly(raster, [poly], int(f), lineType=cv2.LINE_8, shift=2)
    col = np.clip((points[:, 0] * resolution).astype(int), 1, resolution - 2)
    row = np.clip(((1 - points[:, 1]) * resolution).astype(int), 1, resolution - 2)
    shifts = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
    cand = raster[row[:, None] + shifts[:, 0], col[:, None] + shifts[:, 1]]  # (n, 9)
    tri = uv[np.maximum(cand, 0)]  # (n, 9, 3, 2)
    e1, e2 = tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]
    d = points[:, None, :] - tri[..., 0, :]
    det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
    det = np.where(np.abs(det) < 1e-18, 1e-18, det)
    bu = (d[..., 0] * e2[..., 1] - d[..., 1] * e2[..., 0]) / det
    bv = (e1[..., 0] * d[..., 1] - e1[..., 1] * d[..., 0]) / det
    worst = np.minimum(np.minimum(bu, bv), 1 - bu - bv)
    worst = np.where(cand >= 0, worst, -np.inf)
    best = np.argmax(worst, axis=1)
    pick = np.arange(len(points))
    found = worst[pick, best] >= -1e-9
    face = np.where(found, cand[pick, best], -1)
    return face, np.column_stack([bu[pick, best], bv[pick, best]])


def make_suit(uv: np.ndarray, vertices: np.ndarray, faces: np.ndarray, skin: np.ndarray, size: SuitSize) -> Suit:
    """Print ``size`` on a body's largest UV chart.  uv (face, 3, 2), vertices (vertex, 3) rest, faces (face, 3),
    skin (face,) bool."""
    if not 0.005 <= size.square_uv <= 0.1:
        raise PatternError(f"suit {size.name!r}: square_uv {size.square_uv} is outside [0.005, 0.1]; a square is a "
                           "fraction of the texture's width")
    chart = np.flatnonzero((uv_charts(uv) == 0) & skin)
    lo, hi = uv[chart].reshape(-1, 2).min(axis=0), uv[chart].reshape(-1, 2).max(axis=0)
    s, off = size.square_uv, np.asarray(size.offset_uv, float)
    i0, j0 = np.floor((lo - off) / s).astype(int)
    i1, j1 = np.ceil((hi - off) / s).astype(int)
    gi, gj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
    grid = np.column_stack([gi.ravel(), gj.ravel()])  # every grid point over the chart
    face, bary = locate(uv, chart, grid * s + off)
    inside = face >= 0
    index = {tuple(g): n for n, g in enumerate(grid)}
    # A white square (i + j even) counts when its corners, its centre and its edges' midpoints lie on the chart.
    white = [(i, j) for i, j in grid if (i + j) % 2 == 0]
    probes = np.array([(0.5, 0.5), (0.5, 0), (1, 0.5), (0.5, 1), (0, 0.5), (0.25, 0.25), (0.75, 0.75),
                       (0.25, 0.75), (0.75, 0.25)])
    wq = np.array(white, float)
    pf, _ = locate(uv, chart, ((wq[:, None, :] + probes[None]) * s + off).reshape(-1, 2))
    probes_in = (pf.reshape(len(white), len(probes)) >= 0).all(axis=1)
    rest = _rest_points(vertices, faces, face, bary)
    squares = []
    for (i, j), ok in zip(white, probes_in):
        # Quad vertex 0..3: clockwise as the code reads upright (v up): top-left, top-right, bottom-right, bottom-left.
        quad = [index.get((i, j + 1)), index.get((i + 1, j + 1)), index.get((i + 1, j)), index.get((i, j))]
        if ok and all(q is not None and inside[q] for q in quad) and _sound(rest[quad], size):
            squares.append(quad)
    if len(squares) > MAX_CODES:
        raise PatternError(f"suit {size.name!r}: {len(squares)} coded squares but only {MAX_CODES} two-letter codes; "
                           "make square_uv larger")
    if not squares:
        raise PatternError(f"suit {size.name!r}: no square fits on the body's UV layout; make square_uv smaller")
    used = np.unique(np.array(squares).ravel())
    renumber = np.full(len(grid), -1)
    renumber[used] = np.arange(len(used))
    square_corners = renumber[np.array(squares)]
    rng = np.random.default_rng([size.seed, 2021])
    pool = [a + b for a in ALPHABET for b in ALPHABET]
    codes = tuple(pool[k] for k in rng.permutation(MAX_CODES)[:len(squares)])
    return Suit(size, codes, square_corners, grid[used], grid[used] * s + off, face[used], bary[used],
                _cells(grid[used]))


def _rest_points(vertices, faces, face, bary) -> np.ndarray:
    """Rest positions of located texture points (NaN where unlocated).  -> (n, 3)"""
    tri = vertices[faces[np.maximum(face, 0)]]  # (n, 3, 3)
    p = (1 - bary[:, :1] - bary[:, 1:]) * tri[:, 0] + bary[:, :1] * tri[:, 1] + bary[:, 1:] * tri[:, 2]
    p[face < 0] = np.nan
    return p


def _sound(quad: np.ndarray, size: SuitSize) -> bool:
    """A printable square on the rest body: no edge too short, no edge far longer than another."""
    edges = np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1)
    return bool(edges.min() >= size.min_edge_m and edges.max() <= size.max_aspect * edges.min())


def _cells(grid: np.ndarray) -> np.ndarray:
    """Grid squares whose four corners are all suit corners, counter-clockwise in uv.  grid (corner, 2) -> (cell, 4)"""
    index = {tuple(g): n for n, g in enumerate(grid)}
    out = []
    for i, j in grid:
        quad = [index.get((i, j)), index.get((i + 1, j)), index.get((i + 1, j + 1)), index.get((i, j + 1))]
        if all(q is not None for q in quad):
            out.append(quad)
    return np.array(out, np.int64).reshape(-1, 4)


def texture(suit: Suit, uv: np.ndarray, faces_in_chart: np.ndarray, resolution: int = 4096) -> np.ndarray:
    """The printed suit as an albedo texture (resolution, resolution) float32 in [0, 1], row 0 at v = 1.

    Inside the suit's chart the checkerboard (white where i + j is even) with each coded square's two characters
    in black, upright with v up; elsewhere bare skin.
    """
    s, off = suit.size.square_uv, np.asarray(suit.size.offset_uv, float)
    chart = np.zeros((resolution, resolution), np.uint8)
    for f in faces_in_chart:
        poly = np.round(np.column_stack([uv[f, :, 0], 1 - uv[f, :, 1]]) * resolution * 4).astype(np.int32)
        cv2.fillPoly(chart, [poly], 1, lineType=cv2.LINE_8, shift=2)
    cu = (np.arange(resolution) + 0.5) / resolution
    i = np.floor((cu - off[0]) / s).astype(int)
    j = np.floor(((1 - cu) - off[1]) / s).astype(int)  # row r is v = 1 - (r + 0.5) / resolution
    board = np.where((i[None, :] + j[:, None]) % 2 == 0, level(WHITE), level(BLACK)).astype(np.uint8)
    image = np.where(chart > 0, board, np.uint8(level(BARE)))
    px = s * resolution  # a square's width in texels
    for code, quad in zip(suit.codes, suit.square_corners):
        gi, gj = suit.corner_grid[quad[3]]  # bottom-left corner of the square
        print_code(image, code, (gi * s + off[0]) * resolution, (1 - (gj * s + off[1])) * resolution, px)
    return image.astype(np.float32) / 255.0


def print_code(image: np.ndarray, code: str, left: float, bottom: float, px: float) -> None:
    """Print ``code`` upright in black on the white square of side ``px`` whose bottom-left corner is at column
    ``left``, row ``bottom`` of ``image`` (uint8, rows grow downwards), in place: half a square tall, centred."""
    thick = max(1, int(round(0.08 * px)))
    scale = _font_scale(code, px, thick)
    (w, h), _ = cv2.getTextSize(code, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    x, y = left + (px - w) / 2, bottom - (px - h) / 2  # the text's baseline
    cv2.putText(image, code, (int(round(x)), int(round(y))), cv2.FONT_HERSHEY_SIMPLEX, scale, level(BLACK), thick,
                cv2.LINE_AA)


def _font_scale(code: str, px: float, thick: int) -> float:
    """The font scale at which ``code`` is half a square tall and at most 80 % of it wide."""
    scale = cv2.getFontScaleFromHeight(cv2.FONT_HERSHEY_SIMPLEX, int(round(0.5 * px)), thick)
    (w, _), _ = cv2.getTextSize(code, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    return scale * min(1.0, 0.8 * px / max(w, 1))


def level(albedo: float) -> int:
    return int(round(albedo * 255))
