"""The suit's pattern (Chen et al. 2021, §3 "Suit", Fig. 2c and 8b): a checkerboard on the body, each white square
with a unique two-letter code, each corner's identity a (code, quad vertex) key.

The suit is sewn from flat panels (tasks/suit/panels.py: torso, sleeves and legs, a front and a back each; a
unitard without head, hands or feet), printed side by side with a checkerboard of squares ``square_m`` wide on the
rest body, ``square_texels`` texels in the print. A white square that lies wholly on one panel and whose four
corners make a sound square on the rest body (each edge within ``size_band`` of ``square_m``) gets a code from the
25-character alphabet (the paper's; 625 codes at most); its corners are the suit's corners. A corner's keys are
(code, k) for every coded square it belongs to, k = 0..3 its place in the square's quad, clockwise from the top-left
as the code reads upright (Fig. 8b): a corner between two coded squares has two keys. The grid squares (black and
white) whose four corners all exist form the corner mesh the hole filling smooths over.

The pattern is data: the print's texture coordinates of every face, the corners' texture coordinates, their
rest-body faces and barycentric coordinates, the squares' codes and corners. ``texture`` prints it (squares and
glyphs) for the studio's cameras.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from mocapflow.tasks.shared.mesh_body import MeshBody
from mocapflow.tasks.suit.panels import layout

ALPHABET = "1234567ABCDEFGJKLMPQRTUVY"  # §3, Chen et al. 2021: symbols whose upright orientation is unambiguous
MAX_CODES = len(ALPHABET) ** 2
WHITE, BLACK, BARE = 0.85, 0.06, 0.45  # albedo of the white and black squares and of what the suit leaves bare


class PatternError(ValueError):
    """A suit pattern that cannot be made."""


@dataclass(frozen=True)
class SuitSize:
    """A suit: its squares' width on the rest body and in the print (a different print, a different size)."""

    name: str
    square_m: float
    square_texels: int
    seed: int = 0  # which code goes on which square
    size_band: float = 1.2  # each rest edge of a coded square within square_m / size_band .. square_m * size_band

    @property
    def square_uv(self) -> float:
        """A square's width in texture coordinates."""
        return self.square_texels / TEXELS


# About 1,400 and 1,100 corners on the default body, like the paper's medium (1,487) and small (1,119) suits; a
# millimetre of cloth a texel, like the cameras' pixels. Squares are whole texels of the 2,048-texel print (and of
# any print 2,048 * 2^k wide), so every square edge falls on a texel boundary and the printed corner is exactly the
# nominal one.
TEXELS = 2048
SUITS = {"medium": SuitSize("medium", 0.031, 28, seed=1),
         "small": SuitSize("small", 0.035, 31, seed=2)}


@dataclass(frozen=True)
class Suit:
    """A printed suit on one body's UV layout."""

    size: SuitSize
    face_uv: np.ndarray  # (face, 3, 2) float32 the print's texture coordinates of every face of the body
    face_panel: np.ndarray  # (face,) int the panel (panels.PANELS) of each face, -1 off the suit
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


def make_suit(body: MeshBody, size: SuitSize) -> Suit:
    """Sew ``size`` for a body: its panels laid out flat (panels.layout), the checkerboard printed on them."""
    if not 8 <= size.square_texels <= TEXELS // 16 or not 0.01 <= size.square_m <= 0.1:
        raise PatternError(f"suit {size.name!r}: a square of {size.square_m} m and {size.square_texels} texels; give "
                           f"0.01-0.1 m and 8-{TEXELS // 16} texels of the {TEXELS}-texel print")
    lay = layout(body, size.square_m, size.square_texels, TEXELS)
    suit_faces = np.flatnonzero(lay.panel >= 0)
    s = size.square_uv
    across, up = lay.squares
    gi, gj = np.meshgrid(np.arange(across + 1), np.arange(up + 1), indexing="ij")
    grid = np.column_stack([gi.ravel(), gj.ravel()])  # every grid point of the print
    face, bary = locate(lay.uv, suit_faces, grid * s)
    inside = face >= 0
    index = {tuple(g): n for n, g in enumerate(grid)}
    # A white square (i + j even) counts when it lies wholly on one panel's print, with a texel to spare all round.
    white = [(i, j) for i, j in grid if (i + j) % 2 == 0]
    on_panel = _on_one_panel(lay.uv, lay.panel, np.array(white), size.square_texels)
    rest = _rest_points(body.vertices, body.faces, face, bary)
    squares = []
    for (i, j), ok in zip(white, on_panel):
        # Quad vertex 0..3: clockwise as the code reads upright (v up): top-left, top-right, bottom-right, bottom-left.
        quad = [index.get((i, j + 1)), index.get((i + 1, j + 1)), index.get((i + 1, j)), index.get((i, j))]
        if ok and all(q is not None and inside[q] for q in quad) and _sound(rest[quad], size):
            squares.append(quad)
    if len(squares) > MAX_CODES:
        raise PatternError(f"suit {size.name!r}: {len(squares)} coded squares but only {MAX_CODES} two-letter codes; "
                           "make square_m larger")
    if not squares:
        raise PatternError(f"suit {size.name!r}: no square fits on the suit's panels; make square_m smaller")
    used = np.unique(np.array(squares).ravel())
    renumber = np.full(len(grid), -1)
    renumber[used] = np.arange(len(used))
    square_corners = renumber[np.array(squares)]
    rng = np.random.default_rng([size.seed, 2021])
    pool = [a + b for a in ALPHABET for b in ALPHABET]
    codes = tuple(pool[k] for k in rng.permutation(MAX_CODES)[:len(squares)])
    return Suit(size, lay.uv.astype(np.float32), lay.panel, codes, square_corners, grid[used], grid[used] * s,
                face[used], bary[used], _cells(grid[used]))


def panel_mask(uv: np.ndarray, face_panel: np.ndarray, resolution: int) -> np.ndarray:
    """The print's texels, row 0 at v = 1: the panel that covers each (-1: bare cloth).  -> (res, res) int16"""
    mask = np.full((resolution, resolution), -1, np.int16)
    for f in np.flatnonzero(face_panel >= 0):
        poly = np.round(np.column_stack([uv[f, :, 0], 1 - uv[f, :, 1]]) * resolution * 4).astype(np.int32)
        cv2.fillPoly(mask, [poly], int(face_panel[f]), lineType=cv2.LINE_8, shift=2)
    return mask


def _on_one_panel(uv: np.ndarray, face_panel: np.ndarray, squares: np.ndarray, texels: int) -> np.ndarray:
    """Whether each grid square (i, j) of ``texels`` texels lies on one panel's print, one texel of margin round it.
    squares (n, 2) -> (n,) bool"""
    mask = np.pad(panel_mask(uv, face_panel, TEXELS), texels + 1, constant_values=-1)
    out = np.zeros(len(squares), bool)
    for n, (i, j) in enumerate(squares):
        col, row = i * texels + texels + 1, TEXELS - (j + 1) * texels + texels + 1  # the square's top-left texel
        patch = mask[row - 1:row + texels + 1, col - 1:col + texels + 1]
        out[n] = patch.min() >= 0 and patch.min() == patch.max()
    return out


def _rest_points(vertices, faces, face, bary) -> np.ndarray:
    """Rest positions of located texture points (NaN where unlocated).  -> (n, 3)"""
    tri = vertices[faces[np.maximum(face, 0)]]  # (n, 3, 3)
    p = (1 - bary[:, :1] - bary[:, 1:]) * tri[:, 0] + bary[:, :1] * tri[:, 1] + bary[:, 1:] * tri[:, 2]
    p[face < 0] = np.nan
    return p


def _sound(quad: np.ndarray, size: SuitSize) -> bool:
    """A square that keeps its size on the rest body: every edge within the size band of the nominal square."""
    edges = np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1)
    return bool(edges.min() >= size.square_m / size.size_band and edges.max() <= size.square_m * size.size_band)


def _cells(grid: np.ndarray) -> np.ndarray:
    """Grid squares whose four corners are all suit corners, counter-clockwise in uv.  grid (corner, 2) -> (cell, 4)"""
    index = {tuple(g): n for n, g in enumerate(grid)}
    out = []
    for i, j in grid:
        quad = [index.get((i, j)), index.get((i + 1, j)), index.get((i + 1, j + 1)), index.get((i, j + 1))]
        if all(q is not None for q in quad):
            out.append(quad)
    return np.array(out, np.int64).reshape(-1, 4)


def texture(suit: Suit, resolution: int = TEXELS) -> np.ndarray:
    """The printed suit as an albedo texture (resolution, resolution) float32 in [0, 1], row 0 at v = 1.

    On the suit's panels the checkerboard (white where i + j is even) with each coded square's two characters in
    black, upright with v up; elsewhere bare skin.
    """
    s = suit.size.square_uv
    chart = panel_mask(suit.face_uv, suit.face_panel, resolution) + 1
    cu = (np.arange(resolution) + 0.5) / resolution
    i = np.floor(cu / s).astype(int)
    j = np.floor((1 - cu) / s).astype(int)  # row r is v = 1 - (r + 0.5) / resolution
    board = np.where((i[None, :] + j[:, None]) % 2 == 0, level(WHITE), level(BLACK)).astype(np.uint8)
    image = np.where(chart > 0, board, np.uint8(level(BARE)))
    px = s * resolution  # a square's width in texels
    for code, quad in zip(suit.codes, suit.square_corners):
        gi, gj = suit.corner_grid[quad[3]]  # bottom-left corner of the square
        print_code(image, code, gi * s * resolution, (1 - gj * s) * resolution, px)
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
