"""Corner labels (Chen et al. 2021, §3.2 "Corner labelling"): each accepted quad's code and rotation name its four
detections; the redundancy check keeps a detection only where every quad naming it agrees.

An accepted quad whose code the suit does not print is dropped, and so is every quad of a code read twice in one
image (one of the two is wrong, and nothing says which). Quad vertex i of a quad of rotation r is the square's
corner (i + r) mod 4 (tasks/suit/codes.py), i.e. the suit's corner ``square_corners[square, (i + r) % 4]``.
The redundancy check (§3.2: two quads naming one corner must agree) takes the quads most confident first and
leaves out any that disagrees with those taken: a detection named as another corner, or a corner named at another
detection. A corner shared by two coded squares is named twice when both are read (``quads`` = 2); a quad that
agrees with no other needs a confident reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LabelConfig:
    drop_repeated_codes: bool = True  # a code read on two quads of one image: drop both
    solo_confidence: float = 1.0  # a quad sharing no corner with another kept quad stays above this confidence
    # (1: never; on held-out studio takes 0.98 kept 7 % more right labels and 13 wrong ones per 2,000)


def corner_labels(quads: np.ndarray, rotation: np.ndarray, code: np.ndarray, confidence: np.ndarray,
                  square_of_code: dict[int, int], square_corners: np.ndarray, n_corners: int,
                  config: LabelConfig = LabelConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Labels of one image's detections.

    quads (q, 4) detection indices of the accepted quads, rotation (q,), code (q,) code indices, confidence (q,);
    square_of_code: code index -> the suit's square; square_corners (square, 4).
    -> detection of each suit corner (n_corners,) int (-1 unlabelled), quads naming it (n_corners,) int

    Quads are taken most confident first; one that names a detection or a corner otherwise than the quads already
    taken disagrees with them and is left out (§3.2: two quads naming one corner must agree). A quad that shares no
    corner with another taken quad has nothing to agree with and stays only when read above ``solo_confidence``.
    """
    keep = np.array([int(c) in square_of_code for c in code], bool)
    if config.drop_repeated_codes and keep.any():
        codes, counts = np.unique(code[keep], return_counts=True)
        keep &= ~np.isin(code, codes[counts > 1])
    order = np.flatnonzero(keep)[np.argsort(-confidence[keep], kind="stable")]
    corner_of: dict[int, int] = {}  # detection -> corner, of the quads taken
    detection_of: dict[int, int] = {}  # corner -> detection
    taken = []
    for q in order:
        names = square_corners[square_of_code[int(code[q])], (np.arange(4) + int(rotation[q])) % 4]
        pairs = list(zip(quads[q].tolist(), names.tolist()))
        if all(corner_of.get(d, c) == c and detection_of.get(c, d) == d for d, c in pairs):
            for d, c in pairs:
                corner_of[d], detection_of[c] = c, d
            taken.append((q, names))
    named = np.zeros(n_corners, np.int64)
    for _, names in taken:
        named[names] += 1
    detection = np.full(n_corners, -1, np.int64)
    for q, names in taken:
        if (named[names] > 1).any() or confidence[q] > config.solo_confidence:
            detection[names] = quads[q]
    return detection, np.where(detection >= 0, named, 0)


# ---------------------------------------------------------------------------------------------------- the stage

def label_corners(images, corners, quads, codes, config: LabelConfig):
    """Task: suit_labels of every view and frame: the suit's corners at their detections (§3.2)."""
    import xarray as xr

    from mocapflow.tasks.suit.codes import code_index

    square_corners = images["square_corners"].values
    square_of_code = {code_index(str(c)): s for s, c in enumerate(images["code"].values)}
    n_corners = images.sizes["corner"]
    views, frames = corners["view"].values, corners["frame"].values  # images bring the pattern only
    x = np.full((len(views), len(frames), n_corners), np.nan, np.float32)
    y, named = x.copy(), np.zeros(x.shape, np.int8)
    for v in range(len(views)):
        for f in range(len(frames)):
            ok = codes["accepted"].values[v, f]
            det, count = corner_labels(quads["detections"].values[v, f][ok], codes["rotation"].values[v, f][ok],
                                       codes["code"].values[v, f][ok], codes["confidence"].values[v, f][ok],
                                       square_of_code, square_corners, n_corners, config)
            hit = det >= 0
            x[v, f, hit] = corners["x"].values[v, f][det[hit]]
            y[v, f, hit] = corners["y"].values[v, f][det[hit]]
            named[v, f] = np.minimum(count, 127)
    dims = ("view", "frame", "corner")
    return xr.Dataset({"x": (dims, x), "y": (dims, y), "quads": (dims, named)},
                      coords={"view": views, "frame": frames, "corner": images["corner"].values})
