"""PLY meshes (ASCII): a suit's corners as vertices and its squares as faces, each vertex saying whether it was
observed."""

from __future__ import annotations

import numpy as np


def ply_text(position: np.ndarray, observed: np.ndarray, cells: np.ndarray) -> str:
    """One frame of the filled suit: position (corner, 3) m, observed (corner,), cells (cell, 4) counter-clockwise
    in uv -> ASCII PLY with the cells split into two triangles each."""
    tris = np.concatenate([cells[:, [0, 1, 2]], cells[:, [0, 2, 3]]])
    lines = ["ply", "format ascii 1.0", "comment mocapflow: the filled checkerboard suit, metres, Z up",
             f"element vertex {len(position)}", "property float x", "property float y", "property float z",
             "property uchar observed", f"element face {len(tris)}", "property list uchar int vertex_indices",
             "end_header"]
    lines += [f"{x:.6f} {y:.6f} {z:.6f} {int(o)}" for (x, y, z), o in zip(position, observed)]
    lines += [f"3 {a} {b} {c}" for a, b, c in tris]
    return "\n".join(lines) + "\n"
