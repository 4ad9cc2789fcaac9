"""UUO's accuracy measures (Milef et al. 2024, §4.1): MPJPE, MPJVE, V2V and m2s, against the studio's truth.

- MPJPE: mean distance of the 20 template joints to the true ones (all frames);
- MPJVE: mean error of the joints' velocity, the difference of adjacent poses (the paper's definition), per frame;
- V2V: mean distance of the solved mesh's vertices to the true mesh's (the same topology: Anny's);
- m2s: mean distance from each real marker sample (every frame) to the solved body's skin. A marker sits 9.5 mm above the
  skin, so the truth itself scores about 9.5 mm (``m2s_truth``).
A partial layout is also scored on its part's joints (PART_JOINTS, the paper's Table 5 parts).

Two failures the averages hide are counted per take: a body solved turned around (``facing_error_deg``: the
solved hips face away from the true ones) and a body solved mirrored (``side_swaps``: markers of one side of the
body labelled on the other).
"""

from __future__ import annotations

import numpy as np

from mocapflow.tasks.shared.mesh_body import part_sides

PART_JOINTS = {  # Milef et al. 2024, Table 5, on the template's joints
    "left_leg": ("LeftHip", "LeftKnee", "LeftAnkle", "LeftFoot"),
    "right_leg": ("RightHip", "RightKnee", "RightAnkle", "RightFoot"),
    "left_arm": ("LeftShoulder", "LeftElbow", "LeftWrist"),
    "right_arm": ("RightShoulder", "RightElbow", "RightWrist"),
    "left_shoulder": ("Neck", "LeftShoulder", "LeftElbow"),
    "right_shoulder": ("Neck", "RightShoulder", "RightElbow"),
}


def mpjpe(joints: np.ndarray, truth: np.ndarray) -> float:
    """(frame, joint, 3) x 2 -> m"""
    return float(np.linalg.norm(joints - truth, axis=-1).mean())


def mpjve(joints: np.ndarray, truth: np.ndarray) -> float:
    """Velocity error on adjacent frames, m per frame.  (frame, joint, 3) x 2 -> m"""
    if len(joints) < 2:
        return float("nan")
    return float(np.linalg.norm(np.diff(joints, axis=0) - np.diff(truth, axis=0), axis=-1).mean())


def v2v(vertices: np.ndarray, truth: np.ndarray) -> float:
    """(frame, vertex, 3) x 2 -> m"""
    return float(np.linalg.norm(vertices - truth, axis=-1).mean())


def incident_faces(faces: np.ndarray, n_vertices: int) -> list[np.ndarray]:
    """The faces around each vertex.  (face, 3) -> [vertex] of (k,) face indices"""
    order = np.argsort(faces.ravel(), kind="stable")
    bounds = np.searchsorted(faces.ravel()[order], np.arange(n_vertices + 1))
    return [order[bounds[v]:bounds[v + 1]] // 3 for v in range(n_vertices)]


def surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, incident: list[np.ndarray],
                     neighbours: int = 4) -> np.ndarray:
    """Distance from each point to a triangle mesh: exact over the faces around its ``neighbours`` closest vertices
    (the closest point of a body mesh lies there).  points (n, 3), vertices (vertex, 3), faces (face, 3) -> (n,)"""
    import trimesh
    from scipy.spatial import cKDTree

    if not len(points):
        return np.zeros(0)
    near = cKDTree(vertices).query(points, k=neighbours)[1]  # (n, k)
    best = np.full(len(points), np.inf)
    for i, row in enumerate(near):
        cand = np.unique(np.concatenate([incident[v] for v in row]).astype(np.int64))
        closest = trimesh.triangles.closest_point(vertices[faces[cand]], np.repeat(points[i:i + 1], len(cand), 0))
        best[i] = np.linalg.norm(closest - points[i], axis=1).min()
    return best


def m2s(markers: np.ndarray, vertices: np.ndarray, faces: np.ndarray, frames: int | None = None) -> float:
    """Mean marker-to-skin distance over every frame (or up to ``frames`` evenly spaced ones).
    markers (frame, marker, 3) NaN where unseen, vertices (frame, vertex, 3) -> m"""
    count = len(markers) if frames is None else min(frames, len(markers))
    chosen = np.linspace(0, len(markers) - 1, count).astype(int)
    incident = incident_faces(faces, vertices.shape[1])
    out = [surface_distance(markers[f][np.isfinite(markers[f]).all(-1)], vertices[f], faces, incident)
           for f in chosen]
    out = np.concatenate(out) if out else np.zeros(0)
    return float(out.mean()) if len(out) else float("nan")


TURNED_DEG = 90.0  # a solve whose facing is off by more than this on the median frame is turned around
MIRRORED_SHARE = 0.5  # a solve that puts more than this share of its sided labels on the other side is mirrored


def facing(joints: np.ndarray, names) -> np.ndarray:
    """Each frame's facing (the horizontal normal of the hips' left-right axis, Z up), radians.
    joints (frame, joint, 3) in the order of ``names``"""
    names = list(names)
    across = joints[:, names.index("LeftHip"), :2] - joints[:, names.index("RightHip"), :2]
    return np.arctan2(-across[:, 0], across[:, 1])  # forward = across x up: (across_y, -across_x)


def facing_error_deg(joints: np.ndarray, truth: np.ndarray, names: list[str]) -> float:
    """Median over frames of the angle between the solved and the true facing, degrees: the horizontal direction
    normal to the hips' left-right axis (Z up). About 180 for a body solved turned around.
    joints, truth (frame, joint, 3) in the order of ``names`` (the template's JOINT_NAMES)"""
    diff = np.angle(np.exp(1j * (facing(joints, names) - facing(truth, names))))
    return float(np.degrees(np.median(np.abs(diff))))


def side_swaps(true_parts: np.ndarray, got_parts: np.ndarray) -> tuple[int, int]:
    """(labels on the other side, sided labels): of the markers whose true part is on one side of the body and
    that got a part, how many got a part of the other side.  true_parts, got_parts (marker,) part names, "" none"""
    t, g = part_sides(true_parts), part_sides(got_parts)
    sided = (t != 0) & (np.asarray(got_parts) != "")
    return int((sided & (g == -t)).sum()), int(sided.sum())
