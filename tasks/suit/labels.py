"""Corner labels (Chen et al. 2021, §3.2 "Corner labelling"): each accepted quad's code and rotation name its four
detections; the redundancy check keeps a detection only where every quad naming it agrees.

An accepted quad whose code the suit does not print is dropped, and so is every quad of a code read twice in one
image (one of the two is wrong, and nothing says which). Quad vertex i of a quad of rotation r is the square's
corner (i + r) mod 4 (tasks/suit/codes.py), i.e. the suit's corner ``square_corners[square, (i + r) % 4]``. A
detection named as two different corners, or a corner named at two different detections, discards every quad
involved: two quads naming one corner must agree (§3.2), and which of them misread is unknown. A corner shared by two coded squares is named twice when both are
read, which is the redundancy the check uses (``quads`` = 2).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LabelConfig:
    drop_repeated_codes: bool = True  # a code read on two quads of one image: drop both


def corner_labels(quads: np.ndarray, rotation: np.ndarray, code: np.ndarray, square_of_code: dict[int, int],
                  square_corners: np.ndarray, n_corners: int, config: LabelConfig = LabelConfig()
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Labels of one image's detections.

    quads (q, 4) detection indices of the accepted quads, rotation (q,), code (q,) code indices;
    square_of_code: code index -> the suit's square; square_corners (square, 4).
    -> detection of each suit corner (n_corners,) int (-1 unlabelled), quads naming it (n_corners,) int
    """
    keep = np.array([int(c) in square_of_code for c in code], bool)
    if config.drop_repeated_codes and keep.any():
        codes, counts = np.unique(code[keep], return_counts=True)
        keep &= ~np.isin(code, codes[counts > 1])
    quads, rotation, code = quads[keep], rotation[keep], code[keep]
    named_as = np.array([[square_corners[square_of_code[int(c)], (i + int(r)) % 4] for i in range(4)]
                         for r, c in zip(rotation, code)], np.int64).reshape(-1, 4)  # (q, 4) corner of each vertex
    det_corners: dict[int, set[int]] = defaultdict(set)  # detection -> corners it is named as
    corner_dets: dict[int, set[int]] = defaultdict(set)  # corner -> detections named as it
    for row, names in zip(quads, named_as):
        for d, c in zip(row, names):
            det_corners[int(d)].add(int(c))
            corner_dets[int(c)].add(int(d))
    # A quad naming any detection or corner that another quad names otherwise disagrees: every quad involved goes
    # (which one read wrong is unknown, and a wrong label costs more than a missing one).
    bad_dets = {d for d, cs in det_corners.items() if len(cs) > 1}
    bad_corners = {c for c, ds in corner_dets.items() if len(ds) > 1}
    good = np.array([not (bad_dets & set(row.tolist()) or bad_corners & set(names.tolist()))
                     for row, names in zip(quads, named_as)], bool)
    detection = np.full(n_corners, -1, np.int64)
    named = np.zeros(n_corners, np.int64)
    for row, names in zip(quads[good], named_as[good]):
        detection[names] = row
        np.add.at(named, names, 1)
    return detection, np.where(detection >= 0, named, 0)


# ---------------------------------------------------------------------------------------------------- the stage

def label_corners(images, corners, quads, codes, config: LabelConfig):
    """Task: suit_labels of every view and frame: the suit's corners at their detections (§3.2)."""
    import xarray as xr

    from mocapflow.tasks.suit.codes import code_index

    square_corners = images["square_corners"].values
    square_of_code = {code_index(str(c)): s for s, c in enumerate(images["code"].values)}
    n_corners = images.sizes["corner"]
    views, frames = images["view"].values, images["frame"].values
    x = np.full((len(views), len(frames), n_corners), np.nan, np.float32)
    y, named = x.copy(), np.zeros(x.shape, np.int8)
    for v in range(len(views)):
        for f in range(len(frames)):
            ok = codes["accepted"].values[v, f]
            det, count = corner_labels(quads["detections"].values[v, f][ok], codes["rotation"].values[v, f][ok],
                                       codes["code"].values[v, f][ok], square_of_code, square_corners, n_corners,
                                       config)
            hit = det >= 0
            x[v, f, hit] = corners["x"].values[v, f][det[hit]]
            y[v, f, hit] = corners["y"].values[v, f][det[hit]]
            named[v, f] = np.minimum(count, 127)
    dims = ("view", "frame", "corner")
    return xr.Dataset({"x": (dims, x), "y": (dims, y), "quads": (dims, named)},
                      coords={"view": views, "frame": frames, "corner": images["corner"].values})
