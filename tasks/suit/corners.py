"""The corner detector (Chen et al. 2021, §3.1 "Corner detector", §4.1 "Corner Detector", §6 "CornerdetNet"): every
checkerboard-like corner of a grey image, with sub-pixel accuracy.

The image is a grid of 8 x 8 cells, each holding at most one corner. ``CornerdetNet`` sees a cell with 6-pixel
margins (a 20 x 20 crop) and gives a presence logit and the corner's position, normalised to [0, 1]^2 in the cell.
The network is fully convolutional with a receptive field of exactly 20 x 20 pixels at a stride of 8, so one pass
over an image padded by 6 pixels gives every cell's output at once, identical to running it on each cell's crop.

``detect_corners`` runs it on the cells whose crop has any contrast (the dark background and flat skin are skipped
by a cheap morphological prefilter; the network sees tiles of cells around the rest), keeps the cells over the
threshold, merges detections closer than 3 px (the higher logit stays) and refines each by averaging the positions
found on crops randomly shifted around it (Fig. 6b; each re-crop also turned or flipped exactly, which decorrelates
the network's errors), all in global pixel coordinates: pixel (x, y) integer is that pixel's centre, so a cell
(row i, column j) spans x in [8j - 0.5, 8j + 7.5). Merging runs again after refinement, which can pull a stray
detection onto a corner already found.

``corner_samples`` cuts training crops from an image with known corners: positives with their sub-pixel targets,
negatives near corners, on edges (seams, glyphs, the silhouette) and on flat areas (background, skin);
``train_cornerdet`` trains with Adam on the loss of §3.1 (cross entropy + 200 x squared position error on
positives), augmenting each batch with exact quarter turns and flips (the corners are rotation invariant),
contrast, brightness, gamma, noise and blur (§4.2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    import torch
    from torch import nn

    from mocapflow.tasks.suit.networks import CornerdetNet

from mocapflow.tasks.suit.augment import Augment, Fitted, adam_cosine, augment_crops, dihedral, fit, seeded
from mocapflow.tasks.suit.crop_pool import CropPool
from mocapflow.tasks.suit.net_configs import CornerError, CornerNetConfig

CELL = 8  # §3.1, Chen et al. 2021: cells of 8 x 8 pixels
MARGIN = 6  # each side of a cell, so a crop is 20 x 20
CROP = CELL + 2 * MARGIN
CELL_LO = MARGIN - 0.5  # the cell's extent in crop coordinates (pixel centres), [5.5, 13.5)


# ---------------------------------------------------------------------------------------------------- the network

def check_net(net: nn.Module) -> None:
    """A network in evaluation mode, else a CornerError: in training mode batch normalisation would use each batch's
    statistics and a cell's output would depend on the other cells run with it."""
    from torch import nn

    if not isinstance(net, nn.Module):
        raise CornerError(f"net must be a torch module (CornerdetNet), got {type(net).__name__}")
    if net.training:
        raise CornerError("net is in training mode; call net.eval() before detecting corners")


def crop_outputs(net: nn.Module, crops: np.ndarray, batch: int = 1024) -> np.ndarray:
    """The network on single crops, in batches.  crops (n, 20, 20) uint8 -> (n, 3) float32 (logit, u, v)"""
    import torch

    check_net(net)
    out = np.zeros((len(crops), 3), np.float32)
    with torch.inference_mode():
        for s in range(0, len(crops), batch):
            x = torch.from_numpy(crops[s:s + batch]).float().div_(255.0)[:, None]  # (b, 1, 20, 20)
            out[s:s + batch] = net(x)[:, :, 0, 0].numpy()
    return out


# ------------------------------------------------------------------------------------------------------ inference

@dataclass(frozen=True)
class DetectConfig:
    threshold: float = 0.0  # presence logit a cell must exceed
    cluster_px: float = 3.0  # §3.1 "Corner Clustering": of two detections closer than this, the lower logit goes
    recrops: int = 4  # §3.1 "Refinement", Fig. 6b: re-crops per detection whose positions are averaged (0: none)
    recrop_margin_px: float = 1.0  # a re-crop keeps the detection at least this far inside its central cell
    min_contrast: int = 40  # grey levels (max - min) a cell's 20 x 20 crop needs to be looked at; 0 looks everywhere
    tile_cells: int = 8  # the network runs on tiles of this many cells square around the cells with contrast
    batch_tiles: int = 8  # tiles per network call (small batches keep the activations in cache)
    seed: int = 0  # the re-crops' random shifts and turns

    def __post_init__(self):
        if self.cluster_px < 0 or self.recrops < 0 or not 0 <= self.recrop_margin_px < CELL / 2:
            raise CornerError(f"cluster_px ({self.cluster_px}) and recrops ({self.recrops}) must be >= 0 and "
                              f"recrop_margin_px ({self.recrop_margin_px}) in [0, {CELL / 2})")
        if self.tile_cells < 1 or self.batch_tiles < 1 or not 0 <= self.min_contrast <= 255:
            raise CornerError(f"tile_cells ({self.tile_cells}) and batch_tiles ({self.batch_tiles}) must be >= 1 and "
                              f"min_contrast ({self.min_contrast}) in [0, 255] grey levels")


@dataclass(frozen=True)
class Corners:
    """Detected corners of one image."""

    xy: np.ndarray  # (corner, 2) float (x, y), pixel centres at integers
    logit: np.ndarray  # (corner,) presence logit of the cell that found it


@dataclass(frozen=True)
class CellOutputs:
    """The network's output on every cell of an image; cells the prefilter skipped have logit -inf."""

    logit: np.ndarray  # (row, col) float32
    xy: np.ndarray  # (row, col, 2) float32 the cell's corner (x, y) in image pixels


def check_image(image: np.ndarray, name: str = "image") -> None:
    """A grey uint8 image at least one crop (20 x 20) large, else a CornerError naming the fix."""
    if not isinstance(image, np.ndarray):
        raise CornerError(f"{name} must be a numpy array (y, x) of uint8 grey levels, got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] in (3, 4):
        raise CornerError(f"{name} has shape {image.shape}: a colour image; convert it to grey first "
                          "(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))")
    if image.ndim != 2:
        raise CornerError(f"{name} must be 2-D (y, x) grey, got shape {image.shape}")
    if image.dtype != np.uint8:
        raise CornerError(f"{name} has dtype {image.dtype}; the detector reads 8-bit grey levels: convert it, e.g. "
                          "np.clip(image * 255, 0, 255).astype(np.uint8) for [0, 1] floats")
    if min(image.shape) < CROP:
        raise CornerError(f"{name} is {image.shape[1]} x {image.shape[0]} px; the detector needs at least "
                          f"{CROP} x {CROP} (one cell with its margins): use a larger image or pad it")


def cell_outputs(image: np.ndarray, net: nn.Module, config: DetectConfig = DetectConfig()) -> CellOutputs:
    """The network on every cell whose crop has contrast, as one fully convolutional pass per tile of cells.
    image (y, x) uint8 -> CellOutputs with (ceil(y / 8), ceil(x / 8)) cells."""
    import torch

    check_image(image)
    check_net(net)
    t = config.tile_cells
    h, w = -(-image.shape[0] // CELL), -(-image.shape[1] // CELL)
    ty, tx = -(-h // t), -(-w // t)
    padded = _pad(image, ty * t * CELL + 2 * MARGIN, tx * t * CELL + 2 * MARGIN)
    look = np.zeros((ty * t, tx * t), bool)
    look[:h, :w] = _contrast_cells(padded, h, w) >= config.min_contrast  # (row, col)
    tiles = np.argwhere(look.reshape(ty, t, tx, t).any(axis=(1, 3)))  # (tile, 2) tile row, col
    side = t * CELL + 2 * MARGIN
    windows = np.lib.stride_tricks.sliding_window_view(padded, (side, side))[::t * CELL, ::t * CELL]
    out = np.zeros((ty, tx, 3, t, t), np.float32)
    with torch.inference_mode():
        for s in range(0, len(tiles), config.batch_tiles):
            chunk = tiles[s:s + config.batch_tiles]
            x = torch.from_numpy(windows[chunk[:, 0], chunk[:, 1]]).float().div_(255.0)[:, None]  # (b, 1, side, side)
            out[chunk[:, 0], chunk[:, 1]] = net(x).numpy()  # (b, 3, t, t)
    grid = out.transpose(0, 3, 1, 4, 2).reshape(ty * t, tx * t, 3)[:h, :w]  # (row, col, 3)
    logit = np.where(look[:h, :w], grid[..., 0], -np.inf).astype(np.float32)
    rows, cols = np.mgrid[0:h, 0:w]
    xy = np.stack([CELL * cols - 0.5 + CELL * grid[..., 1], CELL * rows - 0.5 + CELL * grid[..., 2]], axis=-1)
    return CellOutputs(logit, xy.astype(np.float32))


def detect_corners(image: np.ndarray, net: nn.Module, config: DetectConfig = DetectConfig()) -> Corners:
    """Every corner of a grey image: cells over the threshold, clustered, refined (§3.1, Chen et al. 2021) and
    clustered again (refinement may pull a stray detection onto a corner already found).
    image (y, x) uint8 -> Corners, highest logit first"""
    cells = cell_outputs(image, net, config)
    hit = cells.logit > config.threshold
    xy, logit = cells.xy[hit].astype(np.float64), cells.logit[hit]  # (n, 2), (n,)
    keep = cluster_corners(xy, logit, config.cluster_px)
    xy, logit = xy[keep], logit[keep]
    if config.recrops and len(xy):
        xy = refine_corners(image, xy, net, config)
        keep = np.sort(cluster_corners(xy, logit, config.cluster_px))  # refining can pull two onto one corner
        xy, logit = xy[keep], logit[keep]
    return Corners(xy, logit)


def cluster_corners(xy: np.ndarray, logit: np.ndarray, radius: float) -> np.ndarray:
    """§3.1 "Corner Clustering", Chen et al. 2021: of any two detections closer than ``radius`` the lower logit is
    discarded, greedily from the highest logit down.  xy (n, 2), logit (n,) -> kept indices (m,), highest first."""
    order = np.argsort(-np.asarray(logit), kind="stable")
    if len(order) < 2 or radius <= 0:
        return order
    pairs = cKDTree(xy).query_pairs(radius, output_type="ndarray")  # (pair, 2) closer than radius (<=)
    d = np.linalg.norm(xy[pairs[:, 0]] - xy[pairs[:, 1]], axis=1)
    pairs = pairs[d < radius]
    neighbours = [[] for _ in range(len(xy))]
    for a, b in pairs:
        neighbours[a].append(b)
        neighbours[b].append(a)
    gone = np.zeros(len(xy), bool)
    kept = []
    for i in order:
        if not gone[i]:
            kept.append(i)
            gone[neighbours[i]] = True
    return np.array(kept, dtype=np.int64)


def refine_corners(image: np.ndarray, xy: np.ndarray, net: nn.Module, config: DetectConfig) -> np.ndarray:
    """§3.1 "Refinement", Fig. 6b, Chen et al. 2021: each corner re-found on ``config.recrops`` crops shifted at
    random so that it lies anywhere in their central cell (``recrop_margin_px`` inside), each crop also given a
    random exact quarter turn or flip (undone on the answer), the positions averaged in global pixel coordinates.
    xy (n, 2) -> (n, 2)"""
    check_image(image)
    rng = np.random.default_rng([config.seed, 61])
    n, k = len(xy), config.recrops
    lo, hi = CELL_LO + config.recrop_margin_px, CELL_LO + CELL - config.recrop_margin_px
    place = rng.uniform(lo, hi, (n, k, 2))  # (n, k, 2) where the corner should sit in the re-crop
    origin = np.rint(xy[:, None, :] - place).astype(np.int64)  # (n, k, 2) re-crop's pixel (0, 0) in the image, x y
    padded = _pad(image, image.shape[0] + 2 * CROP, image.shape[1] + 2 * CROP, CROP)
    origin[..., 0] = np.clip(origin[..., 0], -CROP, image.shape[1])
    origin[..., 1] = np.clip(origin[..., 1], -CROP, image.shape[0])
    windows = np.lib.stride_tricks.sliding_window_view(padded, (CROP, CROP))
    crops = windows[origin[..., 1].ravel() + CROP, origin[..., 0].ravel() + CROP]  # (n k, 20, 20)
    turn = rng.integers(0, 8, n * k)  # (n k,) bit 0: transpose, 1: flip x, 2: flip y
    found = _undo_turns(crop_outputs(net, _turn_crops(crops, turn))[:, 1:], turn).reshape(n, k, 2)
    return (origin + CELL_LO + CELL * found).mean(axis=1)


def _turn_crops(crops: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Exact quarter turns / flips of square crops: transpose, then flip x, then flip y, as ``turn``'s bits say.
    (n, s, s), (n,) -> (n, s, s)"""
    out = np.where((turn & 1).astype(bool)[:, None, None], crops.transpose(0, 2, 1), crops)
    out = np.where((turn & 2).astype(bool)[:, None, None], out[:, :, ::-1], out)
    return np.ascontiguousarray(np.where((turn & 4).astype(bool)[:, None, None], out[:, ::-1, :], out))


def _undo_turns(uv: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Cell coordinates found on turned crops, back in the crops' own frame (the cell is central, so a flip is
    u -> 1 - u and a transpose swaps u and v).  (n, 2), (n,) -> (n, 2)"""
    u, v = uv[:, 0].copy(), uv[:, 1].copy()
    v = np.where(turn & 4, 1 - v, v)
    u = np.where(turn & 2, 1 - u, u)
    return np.where((turn & 1).astype(bool)[:, None], np.column_stack([v, u]), np.column_stack([u, v]))


def _pad(image: np.ndarray, height: int, width: int, margin: int = MARGIN) -> np.ndarray:
    """The image with ``margin`` replicated pixels before it and enough after it to be height x width."""
    return cv2.copyMakeBorder(image, margin, height - image.shape[0] - margin, margin,
                              width - image.shape[1] - margin, cv2.BORDER_REPLICATE)


def _contrast_cells(padded: np.ndarray, h: int, w: int) -> np.ndarray:
    """max - min grey level of every cell's 20 x 20 crop of the padded image.  -> (h, w) int"""
    kernel = np.ones((CROP, CROP), np.uint8)
    hi = cv2.dilate(padded, kernel, anchor=(0, 0))[:CELL * h:CELL, :CELL * w:CELL]  # max over [8i, 8i + 20)
    lo = cv2.erode(padded, kernel, anchor=(0, 0))[:CELL * h:CELL, :CELL * w:CELL]
    return hi.astype(np.int16) - lo.astype(np.int16)


# ------------------------------------------------------------------------------------------------------- samples

@dataclass(frozen=True)
class SampleConfig:
    """Training crops of one image (§4.1, Chen et al. 2021: 20 x 20 crops, positive iff a corner lies in the
    central 8 x 8)."""

    per_corner: int = 4  # positive crops per usable corner, the corner anywhere in the central cell
    negatives: float = 2.0  # negative crops per positive crop
    near_share: float = 0.4  # of the negatives: centred 6-16 px from a corner (the suit around its corners)
    edge_share: float = 0.4  # with contrast anywhere else (glyphs, seams, the silhouette, skin and hair edges)
    # the rest: anywhere (the background, flat skin and suit)
    min_spacing_px: float = 12.0  # a usable corner has no other visible corner closer (grazing views squeeze them)
    ignore_px: float = 1.0  # a crop with a corner this close outside its cell is neither positive nor negative
    rotate: float = 0.5  # share of crops turned by a random angle (bilinear); the rest are cut exactly
    min_contrast: int = 40  # as DetectConfig.min_contrast: what the edge negatives need

    def __post_init__(self):
        if self.per_corner < 1 or self.negatives < 0 or not 0 <= self.rotate <= 1:
            raise CornerError(f"per_corner ({self.per_corner}) must be >= 1, negatives ({self.negatives}) >= 0 and "
                              f"rotate ({self.rotate}) in [0, 1]")
        if self.near_share < 0 or self.edge_share < 0 or self.near_share + self.edge_share > 1:
            raise CornerError(f"near_share ({self.near_share}) and edge_share ({self.edge_share}) are shares of the "
                              "negatives: each >= 0, together <= 1")


SAMPLE_KINDS = ("positive", "near", "edge", "any")  # how a crop was drawn: a positive or one of three negatives


@dataclass(frozen=True)
class CornerSamples:
    """Training crops: the image inside each crop, whether a corner lies in its central cell, and where."""

    crops: np.ndarray  # (n, 20, 20) uint8
    present: np.ndarray  # (n,) bool
    position: np.ndarray  # (n, 2) float32 the corner's (x, y) normalised in the central cell (0 where absent)
    kind: np.ndarray  # (n,) int8 index into SAMPLE_KINDS

    def __len__(self) -> int:
        return len(self.crops)


def concat_samples(parts: list[CornerSamples]) -> CornerSamples:
    """The samples of several images as one set."""
    if not parts:
        raise CornerError("no samples to join: pass at least one CornerSamples")
    return CornerSamples(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                           ("crops", "present", "position", "kind")))


def usable_corners(corners2d: np.ndarray, visible: np.ndarray, min_spacing_px: float) -> np.ndarray:
    """Visible corners with no other visible corner closer than ``min_spacing_px``: at most one per cell, and not
    squeezed by a grazing view.  corners2d (corner, 2), visible (corner,) -> (corner,) bool"""
    out = np.zeros(len(corners2d), bool)
    idx = np.flatnonzero(visible)
    if len(idx) == 1:
        out[idx] = True
    elif len(idx) > 1:
        d, _ = cKDTree(corners2d[idx]).query(corners2d[idx], k=2)
        out[idx] = d[:, 1] >= min_spacing_px
    return out


def corner_samples(image: np.ndarray, corners2d: np.ndarray, visible: np.ndarray, config: SampleConfig,
                   rng: np.random.Generator, positive: np.ndarray | None = None) -> CornerSamples:
    """Training crops of one grey image with known corners (§4.1, Chen et al. 2021).

    image (y, x) uint8; corners2d (corner, 2) true (x, y); visible (corner,) bool: every corner the image shows
    (negatives keep clear of all of them); positive (corner,) bool or None: the corners allowed as positives
    (default all visible ones). Positives are the allowed corners :func:`usable_corners` keeps, each cut
    ``per_corner`` times anywhere in the central cell; a crop holding any other visible corner in its cell or
    within ``ignore_px`` of it is not drawn as a negative.
    """
    check_image(image)
    corners2d = np.asarray(corners2d, np.float64)
    visible = np.asarray(visible, bool)
    if corners2d.ndim != 2 or corners2d.shape[1] != 2 or visible.shape != corners2d.shape[:1]:
        raise CornerError(f"corners2d must be (corner, 2) and visible (corner,), got {corners2d.shape} and "
                          f"{visible.shape}")
    shown = visible & np.isfinite(corners2d).all(axis=1)
    allowed = shown if positive is None else shown & np.asarray(positive, bool)
    good = np.flatnonzero(allowed & usable_corners(corners2d, shown, config.min_spacing_px))
    pos = _positive_crops(image, corners2d[good], config, rng)
    neg = _negative_crops(image, corners2d[shown], int(round(config.negatives * len(pos))), config, rng)
    return concat_samples([pos, neg])


def _affine(centre_img: np.ndarray, centre_crop: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Crop -> image affines turning by ``angle`` about a point: image = c_img + R (crop - c_crop).
    (n, 2), (n, 2), (n,) -> (n, 2, 3)"""
    c, s = np.cos(angle), np.sin(angle)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (n, 2, 2)
    shift = centre_img - np.einsum("nij,nj->ni", rot, centre_crop)
    return np.concatenate([rot, shift[..., None]], axis=-1)


def _turns(n: int, config: SampleConfig, rng: np.random.Generator) -> np.ndarray:
    """A random angle for a ``rotate`` share of n crops, 0 (an exact cut) for the rest.  -> (n,)"""
    turn = rng.random(n) < config.rotate
    return np.where(turn, rng.uniform(0, 2 * np.pi, n), 0.0)


def _cut(image: np.ndarray, affines: np.ndarray) -> np.ndarray:
    """20 x 20 crops through crop -> image affines (exact copies where the affine is an integer shift).
    (n, 2, 3) -> (n, 20, 20) uint8"""
    out = np.empty((len(affines), CROP, CROP), np.uint8)
    for i, m in enumerate(affines):
        out[i] = cv2.warpAffine(image, m, (CROP, CROP), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
    return out


def _positive_crops(image: np.ndarray, corners: np.ndarray, config: SampleConfig, rng: np.random.Generator
                    ) -> CornerSamples:
    """``per_corner`` crops of each corner, the corner uniformly anywhere in the central cell: exact cuts (an
    integer shift, the corner's fraction kept) or turned about the corner.  corners (n, 2)"""
    anchor = np.repeat(corners, config.per_corner, axis=0)  # (n k, 2)
    angle = _turns(len(anchor), config, rng)
    frac = anchor - CELL_LO - np.floor(anchor - CELL_LO)  # the corner's place within its pixel, [0, 1)
    exact = CELL_LO + frac + rng.integers(0, CELL, anchor.shape)  # integer origins, uniform over the cell
    place = np.where((angle == 0)[:, None], exact, rng.uniform(CELL_LO, CELL_LO + CELL, anchor.shape))
    place = np.clip(place, CELL_LO, np.nextafter(CELL_LO + CELL, 0))  # (n k, 2) in the cell
    return CornerSamples(_cut(image, _affine(anchor, place, angle)), np.ones(len(anchor), bool),
                         ((place - CELL_LO) / CELL).astype(np.float32), np.zeros(len(anchor), np.int8))


def _negative_crops(image: np.ndarray, corners: np.ndarray, count: int, config: SampleConfig,
                    rng: np.random.Generator) -> CornerSamples:
    """``count`` crops with no corner in (or within ``ignore_px`` of) the central cell, drawn near corners, on
    edges and anywhere in the shares of ``config``.  corners (m, 2) every visible corner."""
    n_near = int(round(count * config.near_share)) if len(corners) else 0
    n_edge = int(round(count * config.edge_share))
    wanted = {1: n_near, 2: n_edge, 3: count - n_near - n_edge}
    tree = cKDTree(corners) if len(corners) else None
    parts = []
    for kind, n in wanted.items():
        if n <= 0:
            continue
        centres = np.rint(_negative_centres(image, corners, kind, 4 * n, config, rng))  # (4n, 2) candidates
        # crop pixel (10, 10) on an integer centre: integer shifts where not turned
        affines = _affine(centres, np.full(centres.shape, CROP // 2), _turns(len(centres), config, rng))
        affines = affines[_clear(affines, tree, config.ignore_px)][:n]
        parts.append(CornerSamples(_cut(image, affines), np.zeros(len(affines), bool),
                                   np.zeros((len(affines), 2), np.float32), np.full(len(affines), kind, np.int8)))
    if not parts:
        return CornerSamples(np.zeros((0, CROP, CROP), np.uint8), np.zeros(0, bool), np.zeros((0, 2), np.float32),
                             np.zeros(0, np.int8))
    return concat_samples(parts)


def _negative_centres(image: np.ndarray, corners: np.ndarray, kind: int, n: int, config: SampleConfig,
                      rng: np.random.Generator) -> np.ndarray:
    """Candidate crop centres (image x, y): 6-16 px from a corner (kind 1), on pixels whose surrounding 20 x 20
    has contrast (2), anywhere (3).  -> (n, 2)"""
    h, w = image.shape
    if kind == 1:
        base = corners[rng.integers(len(corners), size=n)]
        angle, radius = rng.uniform(0, 2 * np.pi, n), rng.uniform(6.0, 16.0, n)
        return base + radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    if kind == 2:
        kernel = np.ones((CROP, CROP), np.uint8)
        contrast = cv2.dilate(image, kernel).astype(np.int16) - cv2.erode(image, kernel)
        where = np.flatnonzero(contrast >= config.min_contrast)
        if len(where):
            pick = where[rng.integers(len(where), size=n)]
            return np.column_stack([pick % w, pick // w]).astype(np.float64)
    return np.column_stack([rng.uniform(0, w - 1, n), rng.uniform(0, h - 1, n)])


def _clear(affines: np.ndarray, tree: cKDTree | None, ignore_px: float) -> np.ndarray:
    """Whether each crop's central cell, grown by ``ignore_px``, holds no corner.  affines (n, 2, 3) -> (n,) bool"""
    if tree is None:
        return np.ones(len(affines), bool)
    centre = affines[:, :, 2] + np.einsum("nij,j->ni", affines[:, :, :2], np.full(2, CROP / 2 - 0.5))
    reach = (CELL / 2 + ignore_px) * np.sqrt(2) + 1e-6
    near = tree.query_ball_point(centre, reach)
    inv = np.linalg.inv(affines[:, :, :2])
    out = np.ones(len(affines), bool)
    data = tree.data
    for i, idx in enumerate(near):
        if idx:
            at = (data[idx] - affines[i, :, 2]) @ inv[i].T  # (k, 2) in crop coordinates
            grown = (at >= CELL_LO - ignore_px) & (at < CELL_LO + CELL + ignore_px)
            out[i] = not grown.all(axis=1).any()
    return out


# ------------------------------------------------------------------------------------------------------ training

@dataclass(frozen=True)
class TrainConfig:
    net: CornerNetConfig = CornerNetConfig()
    augment: Augment = Augment()
    iterations: int = 20000
    batch: int = 128
    learning_rate: float = 3e-3  # Adam; cosine decay to 1 % over the iterations
    position_weight: float = 200.0  # λ of §3.1, Chen et al. 2021

    def __post_init__(self):
        if self.iterations < 1 or self.batch < 2 or self.learning_rate <= 0 or self.position_weight < 0:
            raise CornerError(f"iterations ({self.iterations}) >= 1, batch ({self.batch}) >= 2, learning_rate "
                              f"({self.learning_rate}) > 0 and position_weight ({self.position_weight}) >= 0 needed")


def cornerdet_loss(out: torch.Tensor, present: torch.Tensor, position: torch.Tensor, weight: float) -> torch.Tensor:
    """§3.1, Chen et al. 2021: cross entropy on presence + λ c ||p* - p||^2 on the cells with a corner.
    out (n, 3) (logit, u, v), present (n,) float 0/1, position (n, 2) -> scalar"""
    from torch.nn import functional as F

    ce = F.binary_cross_entropy_with_logits(out[:, 0], present, reduction="none")
    sq = ((out[:, 1:] - position) ** 2).sum(dim=1)
    return (ce + weight * present * sq).mean()


def train_cornerdet(samples: CornerSamples | CropPool, config: TrainConfig = TrainConfig(), seed: int = 0,
                    checkpoint=None, checkpoint_every: int = 500,
                    start: CornerdetNet | None = None) -> tuple[CornerdetNet, Fitted]:
    """CornerdetNet trained with Adam on ``samples`` (in memory, or a pool streaming them), batches drawn and
    augmented from ``seed`` (deterministic for a seed and a torch thread count); checkpointed and resumable with a
    ``checkpoint`` (augment.fit); from the weights of ``start`` (fine-tuning; of ``config.net``'s architecture)
    or from scratch.  -> the network (eval mode, CPU), its losses and seconds"""
    import torch
    from mocapflow.tasks.suit.networks import CornerdetNet

    pool = samples if isinstance(samples, CropPool) else CropPool.in_memory(
        {"crops": samples.crops, "present": samples.present, "position": samples.position})
    positives = pool.count("present")
    if len(pool) < config.batch or not positives or positives == len(pool):
        raise CornerError(f"training needs at least one batch ({config.batch}) of crops with both positives and "
                          f"negatives; got {len(pool)} crops, {positives} positive")
    gen, rng, device = seeded(seed, 17)
    if start is not None and start.config != config.net:
        raise CornerError(f"the network to start from is {start.config}, the training's {config.net}; set the "
                          "training's net to the file's architecture or train from scratch (init: \"\")")
    net = (CornerdetNet(config.net) if start is None else start).to(device)
    opt, sched = adam_cosine(list(net.parameters()), config.learning_rate, config.iterations)

    def batch_loss():
        b = pool.draw(rng, config.batch)
        x, p = dihedral(torch.from_numpy(b["crops"]).float().div_(255.0)[:, None],
                        torch.from_numpy(b["position"].astype(np.float32)), gen)
        x = augment_crops(x, config.augment, gen)
        present = torch.from_numpy(b["present"].astype(np.float32))
        return cornerdet_loss(net(x.to(device))[:, :, 0, 0], present.to(device), p.to(device), config.position_weight)

    fitted = fit({"net": net}, batch_loss, optimizer=opt, schedule=sched, iterations=config.iterations, pool=pool,
                 streams=(gen, rng), device=device, checkpoint=checkpoint, checkpoint_every=checkpoint_every)
    return net, fitted


# ---------------------------------------------------------------------------------------------------- the stage

@dataclass(frozen=True)
class FindCornersConfig:
    detect: DetectConfig = DetectConfig()
    capacity: int = 4096  # most detections kept per image (the artifact's padding), highest logit first
    weights: str = ""  # a CornerdetNet file; empty: the packaged one


def cornerdet_from_weights(weights: dict) -> CornerdetNet:
    """The network a weights file holds ({"architecture", "state"}, tasks/shared/weights.py), in eval mode."""
    from mocapflow.tasks.suit.networks import CornerdetNet

    arch = weights["architecture"]
    net = CornerdetNet(CornerNetConfig(widths=tuple(arch["widths"]), hidden=int(arch["hidden"]),
                                       batch_norm=bool(arch.get("batch_norm", True))))
    net.load_state_dict(weights["state"])
    return net.eval()


def find_corners(images, config: FindCornersConfig, weights: dict):
    """Task: suit_corners of every view and frame of suit_images (§3.1)."""
    import torch

    import xarray as xr

    from mocapflow.tasks.suit.networks import for_inference

    net = for_inference(cornerdet_from_weights(weights))  # the same outputs to float rounding, 17-24 % faster
    views, frames = images["view"].values, images["frame"].values
    shape = (len(views), len(frames), config.capacity)
    x, y, logit = (np.full(shape, np.nan, np.float32) for _ in range(3))
    torch.set_num_threads(1)
    for v in range(len(views)):
        for f in range(len(frames)):
            found = detect_corners(images["image"].values[v, f], net, config.detect)
            order = np.argsort(-found.logit, kind="stable")[:config.capacity]
            n = len(order)
            x[v, f, :n], y[v, f, :n] = found.xy[order, 0], found.xy[order, 1]
            logit[v, f, :n] = found.logit[order]
    dims = ("view", "frame", "detection")
    return xr.Dataset({"x": (dims, x), "y": (dims, y), "logit": (dims, logit)},
                      coords={"view": views, "frame": frames})
