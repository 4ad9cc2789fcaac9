"""The suit's sewing pattern: the body cut into panels a tailor could print flat and sew (Chen et al. 2021, §3
"Suit": the suit is printed on fabric and sewn, so its squares are nearly one size on the body).

A unitard without head, hands or feet in ten panels: the torso (with the hips), each sleeve (upper arm and
forearm) and each leg (thigh and shank), every one cut into a front and a back half along the sides, as tights and
two-piece sleeves are. A vertex belongs to the part of the bone that moves it most; it is on the front when it lies
ahead (+Y, the body faces +Y) of the middle of its part's cross-section, taken in 2 cm slices along the part's
axis (up for the torso and legs, shoulder to wrist for the sleeves). Each panel is flattened as rigidly as possible
(tasks/shared/flatten.py), turned so that the body's up (a sleeve's shoulder) points up the print, and the panels
are packed side by side into one print, a whole number of squares apart, at one scale: ``square_texels`` texels
for ``square_m`` metres of cloth.

``layout`` returns the print's texture coordinates for every face of the body (faces off the suit share one bare
texel at the print's corner) and which panel covers each face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from mocapflow.tasks.shared.flatten import arap, lscm
from mocapflow.tasks.shared.mesh_body import MeshBody, part_of_bone

REGIONS = {"torso": ("torso", "hips"),
           "left_sleeve": ("left_upper_arm", "left_forearm"), "right_sleeve": ("right_upper_arm", "right_forearm"),
           "left_leg": ("left_thigh", "left_shank"), "right_leg": ("right_thigh", "right_shank")}
PANELS = tuple(f"{region}_{half}" for region in REGIONS for half in ("front", "back"))
SLICE_M = 0.02  # the cross-sections that find a part's middle
FORWARD = np.array([0.0, 1.0, 0.0])
UP = np.array([0.0, 0.0, 1.0])
GAP = 2  # bare squares between panels in the print


class PanelError(ValueError):
    """A sewing pattern that cannot be laid out."""


@dataclass(frozen=True)
class Layout:
    """The panels printed side by side."""

    uv: np.ndarray  # (face, 3, 2) texture coordinates of every face of the body, in [0, 1]
    panel: np.ndarray  # (face,) int index into PANELS, -1 off the suit
    squares: tuple[int, int]  # the print's size in squares (across, up)


def cut(body: MeshBody) -> np.ndarray:
    """The panel of every face: index into PANELS, -1 where the suit does not cover.  -> (face,)"""
    part = np.array([part_of_bone(name) for name in body.bone_names])[body.vertex_bone]  # (vertex,)
    vertex_panel = np.full(len(body.vertices), -1)
    for r, (region, parts) in enumerate(REGIONS.items()):
        inside = np.flatnonzero(np.isin(part, parts))
        front = _ahead_of_middle(body.vertices[inside], _axis(body, region))
        vertex_panel[inside] = 2 * r + np.where(front, 0, 1)
    labels = vertex_panel[body.faces]  # (face, 3)
    face_panel = np.where((labels[:, 0] == labels[:, 1]) | (labels[:, 0] == labels[:, 2]), labels[:, 0], labels[:, 1])
    face_panel[~body.skin] = -1
    face_panel = _smooth_seams(body.faces, face_panel)
    for p in range(len(PANELS)):  # a panel is one piece of cloth: its largest connected piece
        faces = np.flatnonzero(face_panel == p)
        if len(faces):
            piece = _pieces(body.faces[faces])
            face_panel[faces[piece != np.argmax(np.bincount(piece))]] = -1
    return face_panel


def flat_panel(body: MeshBody, faces: np.ndarray, up: np.ndarray, iterations: int = 40) -> np.ndarray:
    """One panel flattened in metres, the body's ``up`` pointing up (+v) the print, its lower-left at the origin.
    faces (n,) face indices -> (n, 3, 2)"""
    used, local = np.unique(body.faces[faces], return_inverse=True)
    local = local.reshape(-1, 3)
    points = body.vertices[used].astype(np.float64)
    uv = arap(points, local, lscm(points, local), iterations)
    # The direction up the body, as seen in the plane: the least-squares gradient of height along ``up``.
    design = np.column_stack([uv, np.ones(len(uv))])
    grad = np.linalg.lstsq(design, points @ up, rcond=None)[0][:2]
    angle = np.pi / 2 - np.arctan2(grad[1], grad[0])
    c, s = np.cos(angle), np.sin(angle)
    uv = uv @ np.array([[c, s], [-s, c]])
    uv -= uv.min(axis=0)
    return uv[local]


def layout(body: MeshBody, square_m: float, square_texels: int, texels: int) -> Layout:
    """Every panel flattened and packed into a print ``texels`` wide, ``square_texels`` texels to ``square_m``
    metres, each panel's lower-left on a whole square and two squares of bare cloth between panels (so that no grid
    square of the print joins two panels)."""
    panel = cut(body)
    per_metre = square_texels / (square_m * texels)  # print units per metre
    across = texels // square_texels
    uv = np.full((len(body.faces), 3, 2), 0.5 * square_texels / texels)  # off the suit: the bare corner square
    flats = {p: flat_panel(body, np.flatnonzero(panel == p), _axis(body, PANELS[p].rsplit("_", 1)[0]))
             for p in range(len(PANELS)) if (panel == p).any()}
    sizes = {p: np.ceil(f.reshape(-1, 2).max(axis=0) / square_m).astype(int) for p, f in flats.items()}
    shelves: list[list[int]] = []  # [row, next free column] of each shelf, bare squares around the print's edge too
    top = GAP
    for p in sorted(flats, key=lambda q: -sizes[q][1]):  # first fit, tallest first: a panel fits any shelf's height
        w, h = sizes[p]
        shelf = next((s for s in shelves if s[1] + w + GAP <= across), None)
        if shelf is None:
            shelf, top = [top, GAP], top + h + GAP
            shelves.append(shelf)
        if shelf[1] + w + GAP > across or top > across:
            raise PanelError(f"the suit's panels do not fit a print of {across} x {across} squares of "
                             f"{square_texels} texels; make square_m larger or square_texels smaller")
        uv[panel == p] = flats[p] * per_metre + np.array(shelf[::-1]) * square_texels / texels
        shelf[1] += w + GAP
    return Layout(uv, panel, (across, top))


def _axis(body: MeshBody, region: str) -> np.ndarray:
    """A region's long axis, pointing up the body: up for the torso and legs, wrist to shoulder for a sleeve."""
    if region.endswith("sleeve"):
        suffix = ".L" if region.startswith("left") else ".R"
        d = body.rest_heads[body.bone("upperarm01" + suffix)] - body.rest_heads[body.bone("wrist" + suffix)]
        return d / np.linalg.norm(d)
    return UP


def _ahead_of_middle(points: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Whether each point lies ahead (+Y) of its 2 cm slice's middle along ``axis``.  (n, 3) -> (n,) bool"""
    forward = FORWARD - (FORWARD @ axis) * axis
    forward /= np.linalg.norm(forward)
    along, ahead = points @ axis, points @ forward
    slices = np.floor((along - along.min()) / SLICE_M).astype(int)
    lo = np.full(slices.max() + 1, np.inf)
    hi = np.full(slices.max() + 1, -np.inf)
    np.minimum.at(lo, slices, ahead)
    np.maximum.at(hi, slices, ahead)
    return ahead > 0.5 * (lo[slices] + hi[slices])


def _smooth_seams(faces: np.ndarray, label: np.ndarray, rounds: int = 4) -> np.ndarray:
    """A face whose edge neighbours mostly (two of three) belong to another panel joins it: the seams follow the
    mesh's edges without spikes.  faces (face, 3), label (face,) -> (face,)"""
    neighbours = _edge_neighbours(faces)  # (face, 3), -1 on the mesh's own boundary
    label = label.copy()
    for _ in range(rounds):
        n = np.where(neighbours >= 0, label[np.maximum(neighbours, 0)], -2)  # (face, 3)
        agree = (n[:, :1] == n[:, 1:2]) | (n[:, :1] == n[:, 2:])
        major = np.where(agree[:, 0], n[:, 0], np.where(n[:, 1] == n[:, 2], n[:, 1], -2))
        switch = (major != -2) & (major != label) & (label >= 0) & (major >= 0)
        if not switch.any():
            break
        label[switch] = major[switch]
    return label


def _edge_neighbours(faces: np.ndarray) -> np.ndarray:
    """The face across each edge (corner k to k + 1) of every face, -1 where none.  -> (face, 3)"""
    edges = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    _, edge_id, count = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    edge_id = edge_id.ravel()
    order = np.argsort(edge_id, kind="stable")
    first = np.searchsorted(edge_id[order], edge_id)  # the first half-edge of each edge, in sorted order
    half = np.arange(len(edge_id))
    mate = np.where(order[first] == half, order[np.minimum(first + 1, len(half) - 1)], order[first])
    mate = np.where(count[edge_id] == 2, mate, -1)
    return np.where(mate >= 0, mate // 3, -1).reshape(-1, 3)


def _pieces(faces: np.ndarray) -> np.ndarray:
    """Connected piece of every face, faces joined where they share an edge.  (n, 3) -> (n,) int"""
    neighbours = _edge_neighbours(faces)
    face, across = np.nonzero(neighbours >= 0)
    adjacency = sparse.coo_matrix((np.ones(len(face)), (face, neighbours[face, across])), (len(faces), len(faces)))
    return csgraph.connected_components(adjacency, directed=False)[1]
