"""DeepMoCap's reflectors as the tape they are: 2-inch retro-reflective tape, unevenly bright, flaring.

The paper's reflector set is cut from the off-the-shelf 2-inch (5.08 cm) reflective tape of protective clothing
(Chatzitofis et al. 2019, §3.1): straps wound round the limbs, seen from every side, and patches stuck on the
trunk, head and hands, seen from one side. With a sequence's ``tape: true`` the mesh studio
(tasks/deepmocap/film/mesh_synth.py) draws each tape per pixel from its rest-pose frame (mesh_reflectors.MeshPlacement):

- **size**: a strap is the band of its limb's skin within half the tape's width of the strap's plane, a patch the
  rectangle ``TAPE_WIDTH`` across by ``PATCH_LENGTH`` along its segment, so a tape's image is its real size at the
  camera's distance (a 5.08 cm band at 2 m is fx 0.0508 / 2, about 9 px wide for the studio's Kinect v2 intrinsics),
  not the faces it happens to cover;
- **uneven saturation**: a tape's infrared return is that of a retro-reflector (``tape_ir``): independent of the
  albedo, falling with the entrance angle, and a gain that varies per reflector (a piece of tape's wear and cut)
  and along the tape (bead coverage, creases where it bends round a limb), so parts of a tape seen obliquely or
  where it is dull stay below saturation and keep their depth;
- **flare** (``flare``): the saturated pixels spread into their neighbours by a radius that varies per reflector
  and grows with how far the tape overflows the sensor, with a glow round them.

Everything here is a pure function of arrays and the take's seeded ``TapeLayout``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocapflow.tasks.shared.reflectors import TAPE_WIDTH

# The paper gives the tape's width (2 inch) but not how long a patch is cut; 3 inches (a rectangle 1.5 times as long
# as wide) is an assumption, long side along the segment.
PATCH_LENGTH = 0.0762
# A retro-reflector's return at normal incidence, in IR counts at 1 m: twice the sensor's saturation (render.IR_REFLECTOR,
# 64000) at 2.5 m, so tape facing a sensor 2-3 m away saturates (DeepMoCap §3.2: reflector regions have "clearly
# distinguishable" IR values, Figures 3-4) and tape seen beyond about 45 degrees, or dull, falls below saturation (an
# assumption of the level; the paper gives no counts).
TAPE_IR_1M = 2.0 * 64000.0 * 2.5**2
# Glass-bead tape keeps most of its retro-reflection to 30-40 degrees of entrance angle and loses it towards 70-80
# (ASTM E810 / D4956 grade it at entrance angles -4 and +30 degrees); cos^ENTRANCE_POWER gives 0.75 at 30, 0.25 at 60
# and 0.03 at 80 degrees, a fit to that shape, not to one tape's data sheet.
ENTRANCE_POWER = 2.0
GAIN_SPREAD = 0.25  # per reflector: log-normal sigma of a piece's gain (wear, dirt, cut); an assumption
ALONG_SPREAD = 0.35  # along the tape: the gain's relative swing (bead coverage, creases); an assumption
ALONG_WAVELENGTHS_M = (0.03, 0.08)  # its two wavelengths along the tape: creases a few cm apart; an assumption
TYPICAL_OVERFLOW = 2.0  # a new tape facing a sensor 2.5 m away (TAPE_IR_1M)
FLARE_RANGE = (0.5, 1.5)  # per reflector: its flare radius is ir_bloom_px times a factor drawn in this range
FLARE_MIN_PX = 1  # a saturated tape flares at least this much even with ir_bloom_px 0 (a Kinect v2 blooms, §3.2)


class TapeError(ValueError):
    """A tape layout that cannot be drawn."""


@dataclass(frozen=True)
class TapeLayout:
    """The take's tapes in rest-pose coordinates of the mesh, with their seeded appearance."""

    kind: np.ndarray  # (reflector,) bool: True for a strap
    centre: np.ndarray  # (reflector, 3) rest pose: a patch's surface point, a strap's point on its limb's axis
    frame: np.ndarray  # (reflector, 3, 3) rows across, along, out
    half: np.ndarray  # (reflector, 3) half sizes across, along, out, metres
    gain: np.ndarray  # (reflector,) the piece's gain (1 = a new tape)
    phase: np.ndarray  # (reflector, 2) phases of the gain's swing along the tape
    flare: np.ndarray  # (reflector,) its flare's factor on ir_bloom_px


def tape_layout(placements, rng: np.random.Generator) -> TapeLayout:
    """The tapes of mesh ``placements`` (mesh_reflectors.MeshPlacement), their appearance drawn from ``rng``."""
    if any(p.centre is None or p.frame is None for p in placements):
        raise TapeError("a placement has no tape frame; place the reflectors with mesh_reflectors.place_on_mesh")
    strap = np.array([p.kind == "strap" for p in placements])
    n = len(placements)
    half = np.where(strap[:, None], [TAPE_WIDTH / 2, TAPE_WIDTH / 2, TAPE_WIDTH / 2],
                    [TAPE_WIDTH / 2, PATCH_LENGTH / 2, TAPE_WIDTH / 2])
    # a strap's "across" is its width along the limb: its half sizes are (any, half width, any)
    gain = np.exp(rng.normal(0.0, GAIN_SPREAD, n))
    phase = rng.uniform(0.0, 2 * np.pi, (n, 2))
    flare = rng.uniform(*FLARE_RANGE, n)
    return TapeLayout(strap, np.stack([p.centre for p in placements]), np.stack([p.frame for p in placements]),
                      half, gain, phase, flare)


def label(layout: TapeLayout, candidate: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """The tape under each surface point (-1 for none): ``candidate`` (n,) its face's candidate tape
    (mesh_reflectors.tape_faces), ``rest`` (n, 3) the point in the rest pose.  -> (n,) int8"""
    out = np.full(len(candidate), -1, np.int8)
    sel = np.flatnonzero(candidate >= 0)
    if not len(sel):
        return out
    r = candidate[sel].astype(np.int64)
    rel = np.einsum("nij,nj->ni", layout.frame[r], rest[sel] - layout.centre[r])  # across, along, out
    inside = np.abs(rel[:, 1]) <= layout.half[r, 1]
    patch = ~layout.kind[r]
    inside &= ~patch | ((np.abs(rel[:, 0]) <= layout.half[r, 0]) & (np.abs(rel[:, 2]) <= layout.half[r, 2]))
    out[sel[inside]] = r[inside]
    return out


def along_tape(layout: TapeLayout, rid: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Each tape point's coordinate along the tape's length, metres: round its limb for a strap (arc length), along
    its segment for a patch.  rid (n,) >= 0, rest (n, 3) -> (n,)"""
    rel = np.einsum("nij,nj->ni", layout.frame[rid], rest - layout.centre[rid])
    arc = np.arctan2(rel[:, 2], rel[:, 0]) * np.hypot(rel[:, 0], rel[:, 2])
    return np.where(layout.kind[rid], arc, rel[:, 1])


def tape_ir(layout: TapeLayout, rid: np.ndarray, rest: np.ndarray, t: np.ndarray, cos: np.ndarray) -> np.ndarray:
    """Unclipped IR counts of tape points: the retro-reflector's return TAPE_IR_1M at distance ``t`` (m, the inverse
    square of the active illumination), entrance angle ``cos`` and the gain of the piece and along it.
    rid (n,) >= 0, rest (n, 3), t (n,), cos (n,) -> (n,)"""
    s = along_tape(layout, rid, rest)
    phase = layout.phase[rid]
    swing = (0.6 * np.sin(2 * np.pi * s / ALONG_WAVELENGTHS_M[0] + phase[:, 0])
             + 0.4 * np.sin(2 * np.pi * s / ALONG_WAVELENGTHS_M[1] + phase[:, 1]))
    gain = layout.gain[rid] * (1.0 + ALONG_SPREAD * swing)
    return TAPE_IR_1M * gain * np.clip(cos, 0.0, 1.0) ** ENTRANCE_POWER / np.maximum(t, 0.3) ** 2


def flare(saturated: np.ndarray, rid: np.ndarray, ir: np.ndarray, layout: TapeLayout, bloom_px: int,
          saturation: float) -> tuple[np.ndarray, np.ndarray]:
    """The pixels a sensor saturates round saturated tape, and the glow beside them.

    Each reflector's saturated pixels (``saturated`` (y, x) bool, ``rid`` (y, x) int8) spread by a disc of radius
    ``bloom_px`` times its flare factor times the square root of how far its brightest pixel overflows
    ``saturation`` (``ir`` (y, x) unclipped counts) relative to TYPICAL_OVERFLOW, at least FLARE_MIN_PX: a stray-light
    halo grows with the light that overflows (an assumption of its shape), and a tape at the typical overflow flares
    ``bloom_px`` on average, as the plain studio's reflectors do; the glow is a Gaussian of that radius's half.
    -> hot (y, x) bool, glow (y, x) float32 in [0, 1]"""
    hot = saturated.copy()
    glow = np.zeros(saturated.shape, np.float32)
    h, w = saturated.shape
    for r in np.unique(rid[saturated]):
        mine = saturated & (rid == r)
        overflow = float(ir[mine].max()) / saturation
        radius = max(FLARE_MIN_PX, int(round(bloom_px * layout.flare[r] * np.sqrt(np.clip(overflow / TYPICAL_OVERFLOW,
                                                                                            0.25, 2.0)))))
        ys, xs = np.nonzero(mine)
        pad = 3 * radius + 3
        y0, y1, x0, x1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, h), max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)
        crop = mine[y0:y1, x0:x1].astype(np.uint8)
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        hot[y0:y1, x0:x1] |= cv2.dilate(crop, disc) > 0
        halo = cv2.GaussianBlur(crop.astype(np.float32), (0, 0), max(0.5 * radius, 0.8))
        glow[y0:y1, x0:x1] = np.maximum(glow[y0:y1, x0:x1], halo)
    return hot, glow
