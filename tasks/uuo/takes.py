"""Unlabelled marker takes on the mesh body (UUO, Milef et al. 2024, §4 and appendix E.3): markers stuck anywhere.

A ``MarkerLayout`` is a set of points on the skin, given as (face, barycentric) and 9.5 mm off the surface
along its normal, spread uniformly by area over the whole body or one part (the paper's partial layouts: a
leg, an arm, a shoulder). ``marker_paths`` tracks them through a skinned take. ``capture`` then records them
the way an optical system does when nobody labels its output (``record`` does both, counting the cameras):

- each sample jittered (0.5-1 mm);
- occlusion (``occlusion``, on by default): a marker is lost on every frame fewer than two of the studio's eight
  optical cameras (``optical_cameras``, a ring round the capture area) see it past the body, as a marker system
  needs two rays to triangulate; where the count hovers at two the marker flickers in and out;
- breaks (``break_per_s``): a trajectory lost for one frame, as trackers lose one at the edge of visibility or
  where two markers pass close;
- with ``fragment`` (default), a marker seen again after any loss comes back under a new trajectory id, so
  occlusion's flicker and the breaks leave short fragments, as raw optical data has them;
- optionally, hidden runs of ``gap_frames`` started at random (``dropout``);
- ghosts (``ghosts_per_s``): short-lived spurious trajectories near the body, each riding near a true marker;
- the ids in an order that says nothing.

``source`` keeps, per id, the true marker it follows (-1 for a ghost): the ground truth a labelling is scored
against. ``MarkerFaults.clean()`` records every marker on every frame under one id each, without ghosts.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.mesh_body import MeshBody, random_surface_points
from mocapflow.tasks.studio.mesh_render import surface_points

MARKER_OFFSET_M = 0.0095  # a 9.5 mm marker's centre above the skin
GHOST_NEAR_M = 0.05  # a ghost rides at least this far from its true marker (closer, a tracker takes it for the marker)


class MarkerTakeError(ValueError):
    """Capture settings a marker take cannot use."""


@dataclass(frozen=True)
class MarkerLayout:
    faces: np.ndarray  # (marker,) face of each marker's skin point
    bary: np.ndarray  # (marker, 2) barycentric (u, v) on that face
    offset_m: float = MARKER_OFFSET_M
    part: str = "body"


@dataclass(frozen=True)
class MarkerFaults:
    """What goes wrong while recording (UUO appendix E.3); by default, what an optical system's raw data has.

    The rates are per second of take, so a longer take has proportionally more ghosts and breaks. Their defaults
    are estimates of raw, uncleaned optical data, not measurements (docs/studio.md, the marker takes): a couple of
    ghost trajectories a second, living 0.1-0.5 s at 30 frames/s, and one break in ten seconds per marker on top
    of the occlusion's own losses.
    """

    jitter_mm: tuple[float, float] = (0.5, 1.0)  # each marker's noise sigma, drawn in this range
    occlusion: bool = True  # a marker seen by fewer than ``min_cameras`` of the optical cameras is lost
    min_cameras: int = 2  # (an optical system triangulates a marker from two cameras or more)
    break_per_s: float = 0.1  # per marker and second: its trajectory is lost for one frame, then goes on
    fragment: bool = True  # a marker seen again after any loss comes back under a new id
    ghosts_per_s: float = 2.0  # ghost trajectories per second of take, each near a true marker
    ghost_frames: tuple[int, int] = (3, 15)  # how long a ghost lives
    ghost_reach_m: float = 0.3  # how far from its true marker a ghost rides (at least 5 cm)
    dropout: float = 0.0  # per-frame probability that a seen marker starts a hidden run
    gap_frames: int = 10  # frames a hidden run lasts

    def __post_init__(self):
        lo, hi = self.jitter_mm
        if not 0 <= lo <= hi:
            raise MarkerTakeError(f"jitter_mm must be a range 0 <= low <= high, got {self.jitter_mm}")
        if not 0 <= self.dropout < 1:
            raise MarkerTakeError(f"dropout is a per-frame probability in [0, 1), got {self.dropout}")
        if self.min_cameras < 1:
            raise MarkerTakeError(f"min_cameras must be >= 1 (a marker is triangulated from cameras), got "
                                  f"{self.min_cameras}")
        if not (self.ghosts_per_s >= 0 and self.break_per_s >= 0):  # (NaN refused too)
            raise MarkerTakeError(f"ghosts_per_s ({self.ghosts_per_s}) and break_per_s ({self.break_per_s}) are "
                                  f"rates per second, >= 0")
        if self.gap_frames < 1 or not 1 <= self.ghost_frames[0] <= self.ghost_frames[1]:
            raise MarkerTakeError(f"gap_frames ({self.gap_frames}) and ghost_frames ({self.ghost_frames}) must be "
                                  f">= 1, ghost_frames a range low <= high")
        if not self.ghost_reach_m >= GHOST_NEAR_M:
            raise MarkerTakeError(f"ghost_reach_m must be >= {GHOST_NEAR_M} m (a ghost rides at least that far from "
                                  f"its marker), got {self.ghost_reach_m}")

    @classmethod
    def clean(cls, **changes) -> MarkerFaults:
        """Jitter only (with ``changes``): every marker seen on every frame under one id, no ghost."""
        return cls(**{"occlusion": False, "break_per_s": 0.0, "ghosts_per_s": 0.0, **changes})


@dataclass(frozen=True)
class CapturedMarkers:
    positions: np.ndarray  # (frame, id, 3) metres, NaN where the id has no sample
    source: np.ndarray  # (id,) the true marker each id follows, -1 for a ghost
    truth: np.ndarray  # (frame, marker, 3) every true marker's centre, never hidden


def layout(body: MeshBody, rng: np.random.Generator, count: int, part: str = "body",
           offset_m: float = MARKER_OFFSET_M) -> MarkerLayout:
    """``count`` markers spread uniformly by area over ``part``'s skin (mesh_body.PARTS)."""
    faces, bary = random_surface_points(body, rng, count, part)
    return MarkerLayout(faces, bary, offset_m, part)


def marker_paths(body: MeshBody, markers: MarkerLayout, vertices: np.ndarray) -> np.ndarray:
    """Each marker's centre on every posed mesh: vertices (frame, vertex, 3) -> (frame, marker, 3)."""
    return np.stack([surface_points(v, body.faces, markers.faces, markers.bary, markers.offset_m)[0]
                     for v in vertices])


def optical_cameras(count: int = 8, radius_m: float = 3.5, heights_m: tuple[float, float] = (0.8, 2.4),
                    centre: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The studio's optical mocap cameras: ``count`` centres on a ring around the capture area, their heights
    alternating low and high, as marker systems are set up.  -> (camera, 3) metres"""
    angles = 2 * np.pi * np.arange(count) / count
    heights = np.where(np.arange(count) % 2 == 0, heights_m[0], heights_m[1])
    return np.stack([centre[0] + radius_m * np.cos(angles), centre[1] + radius_m * np.sin(angles), heights], 1)


def cameras_seeing(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, cameras: np.ndarray,
                   tolerance_m: float = 2e-3) -> np.ndarray:
    """How many cameras see each marker: the body hides no part of the line from the camera to the marker.
    vertices (frame, vertex, 3), faces (face, 3), points (frame, marker, 3), cameras (camera, 3) -> (frame, marker)

    One mesh refitted frame after frame and one ray query per camera and marker (sight_lines.py): a 300-frame
    take of 40 markers and 8 cameras in well under a second."""
    from mocapflow.tasks.uuo import sight_lines

    return sight_lines.cameras_seeing(vertices, faces, points, cameras, tolerance_m)


def record(body: MeshBody, markers: MarkerLayout, vertices: np.ndarray, faults: MarkerFaults,
           rng: np.random.Generator, fps: float, cameras: np.ndarray | None = None) -> CapturedMarkers:
    """A take's markers recorded under ``faults``: their paths on the posed meshes (frame, vertex, 3), with
    ``faults.occlusion`` the cameras seeing them counted (``optical_cameras()`` unless ``cameras`` are given), then
    captured at ``fps`` frames a second."""
    paths = marker_paths(body, markers, vertices)
    seen_by = cameras_seeing(vertices, body.faces, paths, optical_cameras() if cameras is None else cameras) \
        if faults.occlusion else None
    return capture(paths, faults, rng, seen_by, fps=fps)


def capture(truth: np.ndarray, faults: MarkerFaults, rng: np.random.Generator,
            cameras_seen: np.ndarray | None = None, *, fps: float | None = None) -> CapturedMarkers:
    """The unlabelled recording of true marker paths (frame, marker, 3) under ``faults``; with
    ``faults.occlusion``, ``cameras_seen`` (frame, marker) counts the cameras seeing each marker (cameras_seeing);
    with rates (``break_per_s``, ``ghosts_per_s``), ``fps`` is the take's frame rate."""
    n_frames, n_markers, _ = truth.shape
    if (faults.break_per_s > 0 or faults.ghosts_per_s > 0) and not (fps is not None and fps > 0):
        raise MarkerTakeError(f"break_per_s and ghosts_per_s are rates per second: capture needs the take's frame "
                              f"rate (fps > 0), got fps={fps}")
    sigma = rng.uniform(*faults.jitter_mm, n_markers) / 1000.0
    seen = _visibility(n_frames, n_markers, faults, rng)  # (frame, marker)
    if faults.occlusion:
        if cameras_seen is None or cameras_seen.shape != (n_frames, n_markers):
            raise MarkerTakeError(f"occlusion needs how many cameras see each marker per frame, ({n_frames}, "
                                  f"{n_markers}); got {None if cameras_seen is None else cameras_seen.shape} "
                                  f"(cameras_seeing, or record; occlusion=False for the all-visible take)")
        seen &= cameras_seen >= faults.min_cameras
    noisy = truth + rng.standard_normal(truth.shape) * sigma[None, :, None]
    if faults.break_per_s > 0:
        seen &= ~_breaks(n_frames, n_markers, faults.break_per_s / fps, rng)
    columns, source = [], []
    for m in range(n_markers):
        for start, stop in _runs(seen[:, m]) if faults.fragment else [(0, n_frames)]:
            column = np.full((n_frames, 3), np.nan)
            keep = np.zeros(n_frames, bool)
            keep[start:stop] = seen[start:stop, m]
            column[keep] = noisy[keep, m]
            columns.append(column)
            source.append(m)
    if faults.ghosts_per_s > 0 and n_markers:
        for _ in range(ghost_count(faults.ghosts_per_s * n_frames / fps, rng)):
            columns.append(_ghost(truth, faults, rng))
            source.append(-1)
    order = rng.permutation(len(columns))  # ids carry no label
    positions = np.stack(columns, axis=1)[:, order] if columns else np.zeros((n_frames, 0, 3))
    return CapturedMarkers(positions, np.asarray(source, np.int64)[order], truth)


def ghost_count(expected: float, rng: np.random.Generator) -> int:
    """The ghosts of a take expected to have ``expected`` (rate x length): its whole part, and one more with the
    probability of its fraction, so that the count follows the take's length at the rate, never more than one off."""
    expected = round(expected, 9)  # 1.25 ghosts/s x 0.8 s is one ghost, not 0.9999999
    whole = int(np.floor(expected))
    return whole + int(rng.random() < expected - whole)


def _visibility(n_frames: int, n_markers: int, faults: MarkerFaults, rng: np.random.Generator) -> np.ndarray:
    """(frame, marker) bool: False inside hidden runs of ``gap_frames`` started with probability ``dropout``."""
    starts = rng.random((n_frames, n_markers)) < faults.dropout
    seen = np.ones((n_frames, n_markers), bool)
    for f, m in zip(*np.nonzero(starts)):
        if seen[f, m]:  # a run starts only on a frame where the marker is seen
            seen[f:f + faults.gap_frames, m] = False
    return seen


def _breaks(n_frames: int, n_markers: int, per_frame: float, rng: np.random.Generator) -> np.ndarray:
    """(frame, marker) bool: the frames a trajectory breaks on, each with probability ``per_frame``; never the first
    or the last frame (a break there would cut nothing off)."""
    lost = rng.random((n_frames, n_markers)) < per_frame
    lost[:1] = lost[-1:] = False
    return lost


def _runs(seen: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True."""
    edges = np.diff(np.concatenate([[0], seen.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def _ghost(truth: np.ndarray, faults: MarkerFaults, rng: np.random.Generator) -> np.ndarray:
    """A spurious point living a few frames near a random true marker (5 cm to ``ghost_reach_m`` from it), riding
    along with it as a reflection on the body does and drifting slowly off.  # (frame, 3)"""
    n_frames = truth.shape[0]
    life = int(rng.integers(faults.ghost_frames[0], faults.ghost_frames[1] + 1))
    start = int(rng.integers(0, max(n_frames - life, 0) + 1))
    near = int(rng.integers(truth.shape[1]))
    direction = rng.standard_normal(3)
    offset = direction / np.linalg.norm(direction) * rng.uniform(GHOST_NEAR_M, faults.ghost_reach_m)
    column = np.full((n_frames, 3), np.nan)
    stop = min(start + life, n_frames)
    column[start:stop] = truth[start:stop, near] + offset + np.cumsum(rng.normal(0, 0.002, (stop - start, 3)), axis=0)
    return column


def marker_dataset(body: MeshBody, markers: MarkerLayout, captured: CapturedMarkers, take, fps: float,
                   start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of a captured take as raw_markers with its ground truth: per trajectory its true
    marker's skin point and path, the body's joints and what reproduces its mesh (``take``: mesh_motion.MeshTake)."""
    n = stop - start
    real = captured.source >= 0
    src = np.where(real, captured.source, 0)
    path = captured.truth[start:stop][:, src].astype(np.float32)
    path[:, ~real] = np.nan
    bary = np.where(real[:, None], markers.bary[src], np.nan)
    quats = Rotation.from_matrix(take.rotations[start:stop].reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    data = {
        "position": (("frame", "marker", "xyz"), captured.positions[start:stop].astype(np.float32)),
        "timestamp": (("frame",), np.arange(start, stop) / fps),
        "gt_source": (("marker",), captured.source.astype(np.int64)),
        "gt_face": (("marker",), np.where(real, markers.faces[src], -1).astype(np.int64)),
        "gt_bary": (("marker", "uv"), bary),
        "gt_path": (("frame", "marker", "xyz"), path),
        "gt_joints": (("frame", "joint", "xyz"), take.posed.heads[start:stop][:, body.joint_bones()].astype(np.float32)),
        "gt_bone_rotations": (("frame", "bone", "quat"), quats),
        "gt_root": (("frame", "xyz"), take.root[start:stop]),
    }
    ids = np.array([f"m{i:03d}" for i in range(len(captured.source))], dtype=object)
    return xr.Dataset(data, coords={"frame": np.arange(start, stop, dtype=np.int64), "marker": ids,
                                    "xyz": np.array(["x", "y", "z"], dtype=object),
                                    "uv": np.array(["u", "v"], dtype=object),
                                    "joint": np.array(JOINT_NAMES, dtype=object),
                                    "bone": np.array(body.bone_names, dtype=object),
                                    "quat": np.array(["x", "y", "z", "w"], dtype=object)},
                      attrs={"fps": float(fps), "length_unit": "m", "up_axis": "Z", "marker_part": markers.part,
                             "marker_count": int(len(markers.faces)), "marker_offset_m": markers.offset_m,
                             "phenotype": asdict(body.phenotype)})
