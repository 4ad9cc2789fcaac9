"""Every reading checked against the print (beyond Chen et al. 2021, who trust RecogNet alone): the suit's print —
its checkerboard and each coded square's glyph pair (tasks/suit/pattern.py ``print_code``) — is known
exactly, so what the networks and the growth claim can be compared with what the print shows there.

*Codes* (``verify_codes``). Each accepted quad is rectified onto the canonical square of ``square_px`` pixels by
the homography of its four corners (vertex 0 top-left, clockwise; Hartley and Zisserman 2004, §4.1, the 4-point
DLT: ``cv2.getPerspectiveTransform``) and compared with every code the suit prints, in the four rotations, rendered
at the same size: the normalised cross-correlation (NCC; Lewis 1995) over the square's inside, glyphs and white.
A crop of rotation r is the upright code turned r quarter turns counter-clockwise (tasks/suit/codes.py), so each
template is ``np.rot90(upright, r)``. The body's curvature moves the glyphs 1-3 px from where the corners'
homography puts them, so the NCC is the best over shifts of up to ``shift_px``: every (code, rotation) at half size
first, then the ``candidates`` best and the network's reading at full size. The network's reading is kept when the
print agrees — it scores at least ``agree_ncc`` and best of all (code, rotation) pairs by ``agree_margin`` — and
replaced by the print's best when that one is decisive: at least ``correct_ncc`` and ``correct_margin`` above the
second best (the quad keeps RecogNet's confidence, which orders label_corners' redundancy check). Anything else is
refused (``accepted`` False, code and rotation -1), so the output has read_codes' schema and label_corners takes
it unchanged.

*Corners* (``verify_labels``). A label names a corner of the suit's grid; the print says what surrounds it: the
four grid squares meeting there, black or white, and the glyph pair of every coded one among them. The squares'
grid coordinates come from ``cells`` (counter-clockwise in the print's uv, vertex 0 at (i, j)). A homography from
the grid to the image is fitted (least squares, ``cv2.findHomography``) to the *other* labelled corners within
two squares of it and moved so that the corner lands on the label; the image is rectified onto a canonical
window of those four squares (plus a search margin) and the print's window, rendered at the same size, is slid
over it (its masked NCC's best: ``min_ncc``), then the print's corner alone, half a square each way (the
X-junction and the glyphs' near halves; ``min_centre_ncc``), whose best shift says where the print's corner lies:
a label farther than ``max_offset_px`` from it is dropped. A corner hidden behind another limb, or named at a
false detection or at the next corner one square on (where the checker's colours swap), fails. Squares whose
content the print does not fix (an uncoded white square, a black one at a seam) are masked out. By default only
grown labels (``quads`` 0) are checked; with fewer than three labelled neighbours a label cannot be checked and is
dropped.

Both are pure functions of arrays; the stages wrap them per view and frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from mocapflow.tasks.suit.pattern import BLACK, SUITS, WHITE, level, print_code


class VerifyError(ValueError):
    """Settings or inputs the print check cannot use."""


@dataclass(frozen=True)
class PrintCanvas:
    """How the print and the image are compared: both at ``square_px`` pixels a square, blurred alike, the image
    slid up to ``shift_px`` each way over the print (the body's curvature moves a square's glyphs 1-3 px off
    where its corners' homography puts them)."""

    square_px: int = 32  # the canonical square's side (the studio's squares are 10-50 px)
    blur: float = 0.7  # Gaussian sigma on both, canonical px (the print's pre-filter and the camera's defocus)
    texels: int = 0  # a square of the print in texels (0: the suit's own, from the images' ``suit``, else 32)
    inner: float = 0.12  # share of the square trimmed off each side before a code's NCC (its edges meet black)
    shift_px: int = 4  # the glyphs searched this far each way (canonical px; even)
    candidates: int = 16  # codes x rotations scored finely, the best of a coarse pass at half size

    def __post_init__(self):
        if not 16 <= self.square_px <= 128 or self.square_px % 4 or self.blur < 0 or not 0 <= self.inner < 0.4 \
                or self.texels < 0 or self.shift_px < 0 or self.shift_px % 2 or self.candidates < 2:
            raise VerifyError(f"canvas: square_px {self.square_px} (give a multiple of 4 in 16-128), blur {self.blur} "
                              f"(>= 0), inner {self.inner} (0-0.4), texels {self.texels} (>= 0), shift_px "
                              f"{self.shift_px} (even, >= 0), candidates {self.candidates} (>= 2) out of range")


@dataclass(frozen=True)
class VerifyCodesConfig:
    # decided on the tuning split of training takes (benchmarks/suit_verify_tune.py on
    # benchmarks/suit_verify_tuning.yaml; docs/suit.md), with VerifyLabelsConfig's thresholds
    canvas: PrintCanvas = field(default_factory=PrintCanvas)
    agree_ncc: float = 0.65  # the network's reading kept when the print scores it at least this, best of all ...
    agree_margin: float = 0.005  # ... and this much above every other (code, rotation)
    correct: bool = True  # a decisive print replaces the network's reading (False: refused instead)
    correct_ncc: float = 0.75  # the print's best taken when at least this ...
    correct_margin: float = 0.05  # ... and this much above the second best

    def __post_init__(self):
        if not (-1 <= self.agree_ncc <= 1 and -1 <= self.correct_ncc <= 1 and self.agree_margin >= 0
                and self.correct_margin >= 0):
            raise VerifyError(f"verify_codes: agree_ncc {self.agree_ncc} and correct_ncc {self.correct_ncc} are NCCs "
                              f"(-1..1); agree_margin {self.agree_margin} and correct_margin {self.correct_margin} "
                              "must be >= 0")


@dataclass(frozen=True)
class VerifyLabelsConfig:
    # decided with VerifyCodesConfig's on the tuning split (benchmarks/suit_verify_tune.py; docs/suit.md)
    canvas: PrintCanvas = field(default_factory=PrintCanvas)
    min_ncc: float = 0.3  # the print's four squares must match the image at least this well (masked NCC, best shift)
    min_centre_ncc: float = 0.75  # ... and the print's corner (half a square each way) this well
    max_offset_px: float = 4.0  # the label within this of where the print's corner fits best (image px)
    search: float = 0.3  # share of a square the print's four squares are slid each way around the label
    centre_px: int = 4  # canonical px the print's corner is slid each way
    reach: int = 2  # labelled corners within this many squares fit the homography
    check_read: bool = False  # also check labels named by read quads (``quads`` >= 1), not only grown ones

    def __post_init__(self):
        if not (-1 <= self.min_ncc <= 1 and -1 <= self.min_centre_ncc <= 1 and self.max_offset_px > 0
                and 0 < self.search <= 0.5 and 1 <= self.reach <= 3
                and 1 <= self.centre_px <= self.search * self.canvas.square_px):
            raise VerifyError(f"verify_labels: min_ncc {self.min_ncc} and min_centre_ncc {self.min_centre_ncc} "
                              f"(-1..1), max_offset_px {self.max_offset_px} (> 0), search {self.search} (0-0.5 of a "
                              f"square), reach {self.reach} (1-3 squares), centre_px {self.centre_px} (1 to search x "
                              "square_px)")


# ------------------------------------------------------------------------------------------------- the print

def print_texels(suit: str, canvas: PrintCanvas) -> int:
    """Texels a square of the print: the canvas's, else the named suit's, else 32."""
    if canvas.texels:
        return canvas.texels
    return SUITS[suit].square_texels if suit in SUITS else 32


def _to_canvas(tex: np.ndarray, size: tuple[int, int], blur: float) -> np.ndarray:
    """A print rendered in texels resized to the canvas (``size`` = (width, height)) and blurred.  -> float32"""
    out = cv2.resize(tex.astype(np.float32), size, interpolation=cv2.INTER_AREA if size[0] < tex.shape[1]
                     else cv2.INTER_LINEAR)
    return cv2.GaussianBlur(out, (0, 0), blur) if blur > 0 else out


@lru_cache(maxsize=8)
def code_templates(codes: tuple[str, ...], texels: int, square_px: int, blur: float) -> np.ndarray:
    """Each code's white square with its glyph pair as the print has it (``print_code``), at ``square_px``, in the
    four rotations of RecogNet (np.rot90 by r: the crop of a quad of rotation r).  -> (code, 4, s, s) float32"""
    out = np.empty((len(codes), 4, square_px, square_px), np.float32)
    for n, code in enumerate(codes):
        tex = np.full((texels, texels), level(WHITE), np.uint8)
        print_code(tex, code, 0, texels, texels)
        upright = _to_canvas(tex, (square_px, square_px), blur)
        for r in range(4):
            out[n, r] = np.rot90(upright, r)
    return out


def _unit(x: np.ndarray) -> np.ndarray:
    """Rows zero-mean and unit-norm (NCC as a dot product; a flat row stays 0).  x (n, d) -> (n, d)"""
    x = x.astype(np.float32) - x.mean(axis=1, keepdims=True, dtype=np.float32)
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    return np.where(norm > 1e-6, x / np.maximum(norm, 1e-6), 0.0).astype(np.float32)


# --------------------------------------------------------------------------------------------------- codes

def rectify_quads(image: np.ndarray, points: np.ndarray, canvas: PrintCanvas = PrintCanvas()) -> np.ndarray:
    """Each quad's square rectified onto the canonical square by its homography (vertex 0 top-left, clockwise; the
    corners on the square's pixel edges) with ``shift_px`` of its surroundings each way, warped at twice the size
    and averaged down, then blurred.  image (y, x) uint8, points (q, 4, 2) -> (q, s + 2 m, s + 2 m) float32, the
    square at [m, m + s)"""
    if image.ndim != 2:
        raise VerifyError(f"rectify_quads needs a grey (y, x) image, got shape {image.shape}")
    s, m = canvas.square_px, canvas.shift_px
    big, side = 2 * s, s + 2 * m
    dst = np.array([(-0.5, -0.5), (big - 0.5, -0.5), (big - 0.5, big - 0.5), (-0.5, big - 0.5)], np.float32) + 2 * m
    grey = image.astype(np.float32)
    out = np.empty((len(points), side, side), np.float32)
    for i, quad in enumerate(np.asarray(points, np.float32)):
        h = cv2.getPerspectiveTransform(dst, quad)  # canvas -> image (Hartley and Zisserman 2004, §4.1)
        warped = cv2.warpPerspective(grey, h, (2 * side, 2 * side), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_REPLICATE)
        small = cv2.resize(warped, (side, side), interpolation=cv2.INTER_AREA)
        out[i] = cv2.GaussianBlur(small, (0, 0), canvas.blur) if canvas.blur > 0 else small
    return out


@dataclass(frozen=True)
class CodeCheck:
    code: np.ndarray  # (q,) int the suit's square (index into ``codes``) whose code stands, -1 refused
    rotation: np.ndarray  # (q,) int8, -1 refused
    verdict: np.ndarray  # (q,) int8: 1 kept (print agrees), 2 corrected (print decisive), 0 refused
    read_ncc: np.ndarray  # (q,) float32 the print's NCC of the network's reading (-1: a code the suit lacks)
    best_ncc: np.ndarray  # (q,) the best (code, rotation)'s
    margin: np.ndarray  # (q,) best minus the second best


def _half(x: np.ndarray) -> np.ndarray:
    """Images (..., h, w) averaged down to half size."""
    flat = x.reshape(-1, *x.shape[-2:])
    out = np.stack([cv2.resize(a, (a.shape[1] // 2, a.shape[0] // 2), interpolation=cv2.INTER_AREA) for a in flat])
    return out.reshape(*x.shape[:-2], *out.shape[-2:])


def _coarse(patches: np.ndarray, templates: np.ndarray, canvas: PrintCanvas) -> np.ndarray:
    """Each patch's NCC with every template at half size, the best over shifts of up to ``shift_px`` (whole coarse
    pixels).  patches (q, s + 2m, s + 2m), templates (code, 4, s, s) -> (q, code * 4)"""
    s, m = canvas.square_px // 2, canvas.shift_px // 2
    lo = int(round(canvas.inner * s))
    n = s - 2 * lo
    t = _unit(_half(templates)[..., lo:s - lo, lo:s - lo].reshape(-1, n * n))
    windows = np.lib.stride_tricks.sliding_window_view(_half(patches), (n, n), axis=(1, 2))[:, lo:lo + 2 * m + 1,
                                                                                              lo:lo + 2 * m + 1]
    q, shifts = len(patches), (2 * m + 1) ** 2
    w = _unit(windows.reshape(q * shifts, n * n))
    return (w @ t.T).reshape(q, shifts, -1).max(axis=1)


def _fine(patch: np.ndarray, templates: np.ndarray, which: np.ndarray, canvas: PrintCanvas) -> np.ndarray:
    """The patch's NCC with the templates ``which`` (code * 4 + rotation) at full size, the best over shifts of up
    to ``shift_px``.  -> (len(which),)"""
    s, m = canvas.square_px, canvas.shift_px
    lo = int(round(canvas.inner * s))
    out = np.empty(len(which), np.float32)
    for k, c in enumerate(which):
        t = np.ascontiguousarray(templates[c // 4, c % 4, lo:s - lo, lo:s - lo])
        out[k] = cv2.matchTemplate(patch, t, cv2.TM_CCOEFF_NORMED)[lo:lo + 2 * m + 1, lo:lo + 2 * m + 1].max()
    return out


def check_codes(patches: np.ndarray, read_square: np.ndarray, read_rotation: np.ndarray, templates: np.ndarray,
                config: VerifyCodesConfig = VerifyCodesConfig()) -> CodeCheck:
    """The print's verdict on each reading.

    patches (q, s + 2m, s + 2m) from ``rectify_quads``; read_square (q,) the suit's square of the code the network
    read (-1: not printed on this suit), read_rotation (q,); templates (square, 4, s, s) from ``code_templates``.
    Every (code, rotation) is scored at half size first (the NCC's best over shifts); the ``candidates`` best and
    the network's reading are scored at full size, and decide."""
    canvas = config.canvas
    q, m = len(patches), len(templates)
    side = canvas.square_px + 2 * canvas.shift_px
    if templates.shape[2:] != (canvas.square_px,) * 2 or patches.shape[1:] != (side, side):
        raise VerifyError(f"templates of {templates.shape[2:]} px and patches of {patches.shape[1:]} px: render both "
                          f"with the canvas (square_px {canvas.square_px}, shift_px {canvas.shift_px})")
    refused = np.full(q, -1.0, np.float32)
    if not q or m < 2:
        return CodeCheck(np.full(q, -1), np.full(q, -1, np.int8), np.zeros(q, np.int8), refused, refused, refused * 0)
    coarse = _coarse(patches, templates, canvas)
    k = min(canvas.candidates, m * 4)
    top = np.argpartition(-coarse, k - 1, axis=1)[:, :k]
    read_at = np.where(read_square >= 0, read_square * 4 + np.asarray(read_rotation, np.int64) % 4, -1)
    pick, verdict = np.full(q, -1), np.zeros(q, np.int8)
    read_ncc, best_ncc, margin = refused.copy(), refused.copy(), np.zeros(q, np.float32)
    for i in range(q):
        which = np.unique(np.append(top[i], read_at[i]) if read_at[i] >= 0 else top[i])
        score = _fine(patches[i], templates, which, canvas)
        order = np.argsort(-score)
        best, second = score[order[0]], score[order[1]]
        best_ncc[i], margin[i] = best, best - second
        if read_at[i] >= 0:
            read_ncc[i] = score[np.searchsorted(which, read_at[i])]
            other = second if which[order[0]] == read_at[i] else best
            if which[order[0]] == read_at[i] and read_ncc[i] >= config.agree_ncc \
                    and read_ncc[i] - other >= config.agree_margin:
                pick[i], verdict[i] = read_at[i], 1
                continue
        if config.correct and best >= config.correct_ncc and best - second >= config.correct_margin:
            pick[i], verdict[i] = which[order[0]], 2
    return CodeCheck(np.where(pick >= 0, pick // 4, -1), np.where(pick >= 0, pick % 4, -1).astype(np.int8), verdict,
                     read_ncc, best_ncc, margin)


# ------------------------------------------------------------------------------------------------- corners

C_OFF = np.array([(0, 0), (1, 0), (1, 1), (0, 1)])  # a cell's vertex p in grid (i, j) from its vertex 0 (ccw in uv)


@dataclass(frozen=True)
class Grid:
    """The suit's corners on its print's grid, from ``cells`` alone: per connected piece of the grid, integer (i, j)
    up to the piece's own offset."""

    piece: np.ndarray  # (corner,) int the connected piece of cells, -1 in none
    ij: np.ndarray  # (corner, 2) int grid coordinates within the piece
    corner_at: dict  # (piece, i, j) -> corner
    cell_at: dict  # (piece, i, j) of a cell's vertex 0 -> cell
    square_at: dict  # (piece, i, j) of a coded square's vertex 0 -> the square (index into codes)


def suit_grid(cells: np.ndarray, square_corners: np.ndarray, n_corners: int) -> Grid:
    """Grid coordinates of every corner by a walk over the cells (each cell's vertices at (i, j) + C_OFF).
    cells (cell, 4) counter-clockwise in uv from the lower-left; square_corners (square, 4) clockwise from the
    upright top-left (vertex k = 3 the lower-left)."""
    piece = np.full(n_corners, -1, np.int64)
    ij = np.zeros((n_corners, 2), np.int64)
    of_corner: list[list[int]] = [[] for _ in range(n_corners)]
    for n, row in enumerate(cells.tolist()):
        for c in row:
            of_corner[c].append(n)
    seen = np.zeros(len(cells), bool)
    pieces = 0
    for start in range(len(cells)):
        if seen[start]:
            continue
        seen[start] = True
        piece[cells[start, 0]], ij[cells[start, 0]] = pieces, (0, 0)
        stack = [start]
        while stack:
            n = stack.pop()
            row = cells[n]
            known = next(p for p in range(4) if piece[row[p]] == pieces)
            origin = ij[row[known]] - C_OFF[known]
            for p in range(4):
                c = row[p]
                if piece[c] < 0:
                    piece[c], ij[c] = pieces, origin + C_OFF[p]
                    stack.extend(m for m in of_corner[c] if not seen[m])
                    seen[[m for m in of_corner[c]]] = True
        pieces += 1
    corner_at = {(int(piece[c]), int(ij[c, 0]), int(ij[c, 1])): c for c in np.flatnonzero(piece >= 0)}
    cell_at = {(int(piece[r[0]]), *map(int, ij[r[0]])): n for n, r in enumerate(cells)}
    square_at = {(int(piece[r[3]]), *map(int, ij[r[3]])): s for s, r in enumerate(square_corners) if piece[r[3]] >= 0}
    return Grid(piece, ij, corner_at, cell_at, square_at)


def window_print(grid: Grid, corner: int, codes: tuple[str, ...], texels: int, square_px: int, blur: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """What the print shows around ``corner``: the four grid squares meeting there, upright (v up), at
    ``square_px`` a square, and the mask of what it fixes: coded squares (white, their glyph pair) and black
    squares of the grid; an uncoded white square or a square off the grid is masked out.
    -> template (2s, 2s) float32, mask (2s, 2s) float32 (1 / 0)"""
    k, (i, j) = int(grid.piece[corner]), grid.ij[corner]
    tex = np.full((2 * texels, 2 * texels), 128, np.uint8)
    known = np.zeros((2, 2), bool)
    coded = {(a, b): grid.square_at.get((k, int(i + a), int(j + b))) for a in (-1, 0) for b in (-1, 0)}
    parity = next(((a + b) % 2 for (a, b), s in coded.items() if s is not None), None)
    for (a, b), s in coded.items():
        col, row = a + 1, -b  # the square (i + a, j + b) in the upright window: v = j + b + 1 at its top
        block = (slice(row * texels, (row + 1) * texels), slice(col * texels, (col + 1) * texels))
        if s is not None:
            tex[block] = level(WHITE)
            print_code(tex, codes[s], col * texels, (row + 1) * texels, texels)
            known[row, col] = True
        elif parity is not None and (a + b) % 2 != parity and (k, int(i + a), int(j + b)) in grid.cell_at:
            tex[block] = level(BLACK)
            known[row, col] = True
    size = (2 * square_px, 2 * square_px)
    mask = cv2.resize(known.astype(np.float32), size, interpolation=cv2.INTER_NEAREST)
    return _to_canvas(tex, size, blur), mask


def grid_homography(grid: Grid, corner: int, xy: np.ndarray, labelled: np.ndarray, reach: int) -> np.ndarray | None:
    """Grid (i, j) relative to ``corner`` -> image, fitted by least squares to the other labelled corners of its
    piece within ``reach`` squares: a homography (the DLT, Hartley and Zisserman 2004, §4.1) where six or more span
    three rows and three columns of the grid, otherwise an affine map where three or more span two of each (fewer
    fix no plane: None).  xy (corner, 2), labelled (corner,) bool -> (3, 3) or None"""
    k, (i, j) = int(grid.piece[corner]), grid.ij[corner]
    src, dst = [], []
    for a in range(-reach, reach + 1):
        for b in range(-reach, reach + 1):
            c = grid.corner_at.get((k, int(i + a), int(j + b)))
            if c is not None and c != corner and labelled[c]:
                src.append((a, b))
                dst.append(xy[c])
    src_a, dst_a = np.asarray(src, np.float64).reshape(-1, 2), np.asarray(dst, np.float64).reshape(-1, 2)
    spread = min(len(np.unique(src_a[:, 0])), len(np.unique(src_a[:, 1])))
    if len(src) >= 6 and spread >= 3:
        h, _ = cv2.findHomography(src_a, dst_a, 0)
        if h is not None and abs(h[2, 2]) > 1e-9:
            return h / h[2, 2]
    if len(src) < 3 or spread < 2:
        return None
    design = np.column_stack([src_a, np.ones(len(src_a))])
    affine, _, rank, _ = np.linalg.lstsq(design, dst_a, rcond=None)
    return np.vstack([affine.T, (0, 0, 1)]) if rank == 3 else None


@dataclass(frozen=True)
class CornerCheck:
    ncc: float  # the print's four squares against the image, best over shifts of ``search`` (-1: not checked)
    centre_ncc: float  # the print's corner (half a square each way) against the image, best over small shifts
    offset_px: float  # the label's distance to where the print's corner fits best in the image (inf: not checked)


def _masked_ncc(window: np.ndarray, template: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The masked NCC (Lewis 1995) of ``template`` at every shift inside ``window``: sum t p / (|t| sqrt(sum_mask
    p^2 - (sum_mask p)^2 / n)) with t zero-mean over the mask; 0 where the window is flat (under 2 grey levels)."""
    n = float(mask.sum())
    t = (template - (template * mask).sum() / max(n, 1.0)) * mask
    t_norm = float(np.sqrt((t * t).sum()))
    if n < 16 or t_norm < 1e-6:
        return np.zeros((window.shape[0] - template.shape[0] + 1, window.shape[1] - template.shape[1] + 1), np.float32)
    num = cv2.matchTemplate(window, t.astype(np.float32), cv2.TM_CCORR)
    s1 = cv2.matchTemplate(window, mask, cv2.TM_CCORR)
    s2 = cv2.matchTemplate(window * window, mask, cv2.TM_CCORR)
    var = s2 - s1 * s1 / n  # the window's masked variance x n at each shift
    return np.where(var > 4.0 * n, num / (t_norm * np.sqrt(np.maximum(var, 1e-6))), 0.0)


def check_corner(image: np.ndarray, label_xy: np.ndarray, h: np.ndarray, template: np.ndarray, mask: np.ndarray,
                 config: VerifyLabelsConfig = VerifyLabelsConfig()) -> CornerCheck:
    """The print placed at the label: ``h`` (grid offsets from the corner -> image) moved so that the corner lands
    on the label, the image rectified onto the print's window around it (plus the search margin), and the print's
    four squares slid over it (their NCC's best within ``search``); then the print's corner alone (half a square
    each way: the X-junction and the glyphs' near halves) slid within ``centre_px``, whose best says where the
    print's corner lies.  image (y, x), label_xy (2,), template and mask (2s, 2s) from ``window_print``."""
    s = config.canvas.square_px
    m = int(round(config.search * s))
    size = 2 * s + 2 * m
    p0 = h @ np.array([0.0, 0.0, 1.0])
    h = np.array([[1, 0, label_xy[0] - p0[0] / p0[2]], [0, 1, label_xy[1] - p0[1] / p0[2]], [0, 0, 1]]) @ h
    # canvas pixel (x, y) -> grid offset (u, v): the window spans u, v in [-1 - search, 1 + search], v up
    to_grid = np.array([[1 / s, 0, 0.5 / s - 1 - m / s], [0, -1 / s, 1 + m / s - 0.5 / s], [0, 0, 1]])
    up = np.array([[0.5, 0, -0.25], [0, 0.5, -0.25], [0, 0, 1]])  # a pixel of the 2x canvas -> the canvas
    big = cv2.warpPerspective(image.astype(np.float32), h @ to_grid @ up, (2 * size, 2 * size),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    win = cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA)
    if config.canvas.blur > 0:
        win = cv2.GaussianBlur(win, (0, 0), config.canvas.blur)
    mask = mask.astype(np.float32)
    if mask.sum() < 0.2 * mask.size:
        return CornerCheck(-1.0, -1.0, np.inf)
    whole = float(_masked_ncc(win, template, mask).max())
    r, q = config.centre_px, s // 2  # the centre: the template's [q, 3q), the window's around m + s
    centre = _masked_ncc(win[m + q - r:m + 3 * q + r, m + q - r:m + 3 * q + r], template[q:3 * q, q:3 * q],
                         mask[q:3 * q, q:3 * q])
    y0, x0 = np.unravel_index(int(np.argmax(centre)), centre.shape)
    dx, dy = _peak(centre[y0, max(x0 - 1, 0):x0 + 2], x0), _peak(centre[max(y0 - 1, 0):y0 + 2, x0], y0)
    g = to_grid @ np.array([m + s - 0.5 + x0 - r + dx, m + s - 0.5 + y0 - r + dy, 1.0])
    p = h @ g
    return CornerCheck(whole, float(centre[y0, x0]), float(np.linalg.norm(p[:2] / p[2] - label_xy)))


def _peak(values: np.ndarray, at: int) -> float:
    """Sub-pixel offset of a peak from the parabola through it and its neighbours (0 at an edge)."""
    if len(values) != 3:
        return 0.0
    a, b, c = (float(v) for v in values)
    d = a - 2 * b + c
    return float(np.clip(0.5 * (a - c) / d, -0.5, 0.5)) if d < -1e-9 else 0.0


def check_labels(image: np.ndarray, xy: np.ndarray, check: np.ndarray, grid: Grid, codes: tuple[str, ...],
                 texels: int, config: VerifyLabelsConfig = VerifyLabelsConfig()) -> tuple[np.ndarray, np.ndarray]:
    """One image's labels against the print.  xy (corner, 2) labelled pixels (NaN unlabelled), check (corner,)
    bool the labels to check.  -> keep (corner,) bool (unchecked labels kept); scores (corner, 3) float32: the
    four squares' NCC, the corner's NCC and the label's distance to the print's corner in px (NaN unchecked; -1,
    -1, inf where the print could not be placed: too few labelled neighbours)"""
    labelled = np.isfinite(xy).all(axis=1)
    keep = labelled.copy()
    scores = np.full((len(xy), 3), np.nan, np.float32)
    s, blur = config.canvas.square_px, config.canvas.blur
    for c in np.flatnonzero(check & labelled):
        h = grid_homography(grid, int(c), xy, labelled, config.reach) if grid.piece[c] >= 0 else None
        got = CornerCheck(-1.0, -1.0, np.inf) if h is None else \
            check_corner(image, xy[c], h, *window_print(grid, int(c), codes, texels, s, blur), config)
        scores[c] = got.ncc, got.centre_ncc, got.offset_px
        keep[c] = got.ncc >= config.min_ncc and got.centre_ncc >= config.min_centre_ncc \
            and got.offset_px <= config.max_offset_px
    return keep, scores


# ---------------------------------------------------------------------------------------------------- the stages

def verify_codes(images, corners, quads, codes, config: VerifyCodesConfig):
    """Task: suit_codes with every reading checked against the print (kept, corrected or refused)."""
    import xarray as xr

    from mocapflow.tasks.suit.codes import code_index

    printed = tuple(str(c) for c in images["code"].values)
    square_of = np.full(625, -1, np.int64)
    square_of[[code_index(c) for c in printed]] = np.arange(len(printed))
    numbers = np.array([code_index(c) for c in printed], np.int16)
    canvas = config.canvas
    templates = code_templates(printed, print_texels(str(images.attrs.get("suit", "")), canvas), canvas.square_px,
                               float(canvas.blur))
    accepted, rotation = codes["accepted"].values.copy(), codes["rotation"].values.copy()
    code, confidence = codes["code"].values.copy(), codes["confidence"].values
    for v in range(accepted.shape[0]):
        for f in range(accepted.shape[1]):
            idx = np.flatnonzero(accepted[v, f])
            if not len(idx):
                continue
            det = quads["detections"].values[v, f][idx]
            xy = np.column_stack([corners["x"].values[v, f], corners["y"].values[v, f]])
            patches = rectify_quads(images["image"].values[v, f], xy[det], canvas)
            read = code[v, f, idx].astype(np.int64)
            got = check_codes(patches, np.where(read >= 0, square_of[np.clip(read, 0, 624)], -1),
                              rotation[v, f, idx], templates, config)
            ok = got.verdict > 0
            accepted[v, f, idx] = ok
            rotation[v, f, idx] = np.where(ok, got.rotation, -1)
            code[v, f, idx] = np.where(ok, numbers[np.maximum(got.code, 0)], -1)
    dims = ("view", "frame", "quad")
    return xr.Dataset({"accepted": (dims, accepted), "rotation": (dims, rotation), "code": (dims, code),
                       "confidence": (dims, confidence)}, coords={"view": codes["view"].values,
                                                                  "frame": codes["frame"].values})


def verify_labels(images, labels, config: VerifyLabelsConfig):
    """Task: suit_labels with the labels the print does not confirm dropped (grown ones, or all)."""
    import xarray as xr

    printed = tuple(str(c) for c in images["code"].values)
    grid = suit_grid(images["cells"].values, images["square_corners"].values, labels.sizes["corner"])
    texels = print_texels(str(images.attrs.get("suit", "")), config.canvas)
    x, y = labels["x"].values.copy(), labels["y"].values.copy()
    named = labels["quads"].values.copy()
    views = [str(v) for v in images["view"].values]
    frames = images["frame"].values.tolist()
    for v, view in enumerate(labels["view"].values):
        for f, frame in enumerate(labels["frame"].values):
            image = images["image"].values[views.index(str(view)), frames.index(frame)]
            xy = np.column_stack([x[v, f], y[v, f]]).astype(np.float64)
            check = np.ones(len(xy), bool) if config.check_read else named[v, f] == 0
            keep, _ = check_labels(image, xy, check, grid, printed, texels, config)
            drop = np.isfinite(xy).all(axis=1) & ~keep
            x[v, f, drop], y[v, f, drop], named[v, f, drop] = np.nan, np.nan, 0
    dims = ("view", "frame", "corner")
    return xr.Dataset({"x": (dims, x), "y": (dims, y), "quads": (dims, named)},
                      coords={"view": labels["view"].values, "frame": labels["frame"].values,
                              "corner": labels["corner"].values})
