"""Poses as bodies: Anny fitted to the labelled 3D reflectors, the shape calibrated per take (beyond DeepMoCap §3.5,
which poses a template skeleton; the template stays as ``solve_poses``).

Every reflector has a place on Anny's rest mesh (tasks/deepmocap/reflector_places.py: a patch's centre on the
skin, a strap's limb centre as a blend of its band's vertices), so its posed position is a function of the pose and
the phenotype, and the house's body fit (tasks/shared/place_fit: key frames, the phenotype once per take, every
frame; Levenberg-Marquardt on tasks/shared/body_fit) puts the body on the smoothed markers, each weighted by its
confidence. The places are the nominal ones; a subject's reflectors sit a few centimetres elsewhere, so after a
first fit each reflector's place is calibrated to the take (``calibrate_places``): its observations unposed into the
fitted rest body by its place's skinning, their median taken, and the place moved there (the convex blend of
three nearby vertices nearest it: for a patch of the skin's, for a strap of its limb's); the body is then fitted
again with the calibrated places from the phenotype found, ``calibration_rounds`` times.

The joints are read from the fitted body: the heads of the bones at the 20 template joints (as the studio's truth
and UUO's joints are). Per frame also where the fitted body puts each reflector, and the RMS distance of the observed
reflectors from it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import xarray as xr
from scipy.optimize import nnls
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from mocapflow.tasks.deepmocap.reflector_places import PLACES
from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, Phenotype
from mocapflow.tasks.shared.place_fit import (PlacedBody, PlaceFitConfig, PlaceFitError, fit_places,
                                              phenotype_vector, reference_body)
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody

PLACE_NAMES = tuple(p[0] for p in PLACES)


class BodyPoseError(ValueError):
    """Markers or settings the body fit of the reflectors cannot use."""


@dataclass(frozen=True)
class BodyPoseConfig:
    # chosen on the realistic validation split by benchmarks/body_tune.py
    fit: PlaceFitConfig = field(default_factory=lambda: PlaceFitConfig(point_sigma_m=0.01, pose_sigma_rad=0.5,
                                                                       min_points=8, chunk=64))
    min_confidence: float = 0.05  # markers below it are left out of the fit
    calibration_rounds: int = 1  # each reflector's place calibrated to the take, the body fitted again, so many times
    calibration_frames: int = 60  # frames (evenly spread) whose observations calibrate the places
    min_observations: int = 5  # fewer: a reflector keeps its nominal place

    def __post_init__(self):
        if not 0.0 <= self.min_confidence <= 1.0 or self.calibration_rounds < 0 or self.calibration_frames < 1 \
                or self.min_observations < 1:
            raise BodyPoseError(f"body pose settings out of range: min_confidence in [0, 1], calibration_rounds >= 0, "
                                f"calibration_frames and min_observations >= 1 (got {self})")


def nominal_places(names) -> lm.Places:
    """The nominal places of the reflectors ``names`` on Anny's rest mesh."""
    index = {name: i for i, name in enumerate(PLACE_NAMES)}
    missing = [str(n) for n in names if str(n) not in index]
    if missing:
        raise BodyPoseError(f"reflectors {', '.join(missing)} have no place on the body; the places are "
                            f"DeepMoCap's 26 ({', '.join(PLACE_NAMES)})")
    rows = [PLACES[index[str(n)]] for n in names]
    return lm.Places(np.array([r[2] for r in rows], np.int64), np.array([r[3] for r in rows], np.float64))


def _skinning(body: SolverBody, fit: BodyFit, weights: np.ndarray, frames: np.ndarray):
    """Per frame and place, the blended transform of its skinning: x_posed = B x_rest + c.
    weights (place, bone) -> B (frame, place, 3, 3), c (frame, place, 3)"""
    import torch

    _, rest_heads = body.rest_fixed(fit.phenotype)
    with torch.no_grad():
        rots, heads = body.kinematics(torch.from_numpy(fit.local[frames]), torch.from_numpy(fit.root[frames]),
                                      rest_heads)
        dense = torch.from_numpy(weights)
        blend = torch.einsum("pk,fkij->fpij", dense, rots)
        carried = (rots @ rest_heads[..., None])[..., 0] - heads  # (frame, bone, 3)
        shift = -torch.einsum("pk,fki->fpi", dense, carried)
    return blend.numpy(), shift.numpy()


def calibrated_places(body: SolverBody, placed, points: np.ndarray, places: lm.Places, kinds: list[str],
                      config: BodyPoseConfig) -> lm.Places:
    """Each reflector's place moved to the median of its observations unposed into the fitted rest body (see the
    module's text).  points (frame, place, 3) NaN where left out."""
    fitted = np.flatnonzero(placed.fitted)
    frames = fitted[np.unique(np.linspace(0, len(fitted) - 1, min(config.calibration_frames, len(fitted)))
                              .round().astype(int))]
    blend, shift = _skinning(body, placed.fit, placed.weights, frames)
    rest = np.linalg.solve(blend, (points[frames] - shift)[..., None])[..., 0]  # (frame, place, 3), NaN stays
    rest_vertices = body.rest_fixed(placed.fit.phenotype)[0].numpy()
    skin = np.unique(body.body.faces[body.body.skin])
    tree = cKDTree(rest_vertices[skin])
    vertices, weights = places.vertices.copy(), places.blend.copy()
    for r in range(rest.shape[1]):
        seen = np.isfinite(rest[:, r]).all(-1)
        if seen.sum() < config.min_observations:
            continue
        target = np.median(rest[seen, r], axis=0)
        candidates = skin[tree.query(target, k=12)[1]] if kinds[r] == "patch" else \
            _near_vertices(rest_vertices, places.vertices[r], target)
        vertices[r], weights[r] = nearest_blend(rest_vertices, candidates, target)
    return lm.Places(vertices, weights)


def _near_vertices(rest_vertices: np.ndarray, triple: np.ndarray, target: np.ndarray) -> np.ndarray:
    """A strap's candidates: the 24 vertices nearest its calibrated centre within 8 cm, nearest first."""
    d = np.linalg.norm(rest_vertices - target, axis=1)
    near = np.flatnonzero(d < 0.08)
    return near[np.argsort(d[near])][:24] if len(near) >= 3 else triple


def nearest_blend(rest_vertices: np.ndarray, candidates: np.ndarray, target: np.ndarray):
    """Of triples of ``candidates``, the convex blend (weights >= 0, sum 1) nearest ``target``."""
    best = (np.inf, None, None)
    for i in range(len(candidates)):
        for j in range(i + 1, len(candidates)):
            for k in range(j + 1, len(candidates)):
                triple = candidates[[i, j, k]]
                a = np.vstack([rest_vertices[triple].T, 100.0 * np.ones(3)])  # the sum held at 1 by a heavy row
                w, _ = nnls(a, np.append(target, 100.0))
                w = w / w.sum()
                miss = np.linalg.norm(w @ rest_vertices[triple] - target)
                if miss < best[0]:
                    best = (miss, triple, w)
    return best[1], best[2]


def _fit(body: SolverBody, points: np.ndarray, confidence: np.ndarray, places: lm.Places, config: BodyPoseConfig):
    try:
        return fit_places(body, points, places, config.fit, confidence)
    except PlaceFitError as e:
        raise BodyPoseError(f"the reflectors cannot pose the body: {e}") from e


def fit_body_poses(markers: xr.Dataset, config: BodyPoseConfig) -> xr.Dataset:
    """Anny fitted to a take's labelled 3D reflectors (see the module's text)."""
    names = [str(n) for n in markers["reflector"].values]
    points = markers["position"].transpose("frame", "reflector", "xyz").values.astype(np.float64)
    confidence = markers["confidence"].transpose("frame", "reflector").values.astype(np.float64)
    use = np.isfinite(points).all(-1) & (np.nan_to_num(confidence) >= config.min_confidence) & (confidence > 0)
    confidence = np.where(use, confidence, 0.0)
    points = np.where(use[..., None], points, np.nan)
    body = reference_body()
    places = nominal_places(names)
    if not (use.sum(1) >= config.fit.min_points).any():  # nothing to pose by: every frame unfitted, not an error
        return _dataset(markers, body, _unfitted(body, len(points), len(names)), places, points, names)
    placed = _fit(body, points, confidence, places, config)
    kinds = [PLACES[PLACE_NAMES.index(n)][1] for n in names]
    for _ in range(config.calibration_rounds):
        places = calibrated_places(body, placed, points, places, kinds, config)
        start = Phenotype(**dict(zip(PHENOTYPE_NAMES, np.clip(placed.fit.phenotype, 0.0, 1.0).tolist())))
        placed = _fit(body, points, confidence, places, replace(config, fit=replace(config.fit, start=start)))
    return _dataset(markers, body, placed, places, points, names)


def _unfitted(body: SolverBody, frames: int, count: int) -> PlacedBody:
    """A take no frame of which has ``min_points`` reflectors: the rest body at the default phenotype, NaN-placed."""
    fit = BodyFit(np.tile(np.eye(3), (frames, body.n_bones, 1, 1)), np.full((frames, 3), np.nan),
                  phenotype_vector(Phenotype()))
    return PlacedBody(fit, np.zeros((count, body.n_bones)), np.zeros(frames, bool))


def _dataset(markers: xr.Dataset, body: SolverBody, placed, places: lm.Places, points: np.ndarray,
             names: list[str]) -> xr.Dataset:
    import torch

    fit = placed.fit
    rest_vertices, rest_heads = body.rest_fixed(fit.phenotype)
    with torch.no_grad():
        rots, heads = body.kinematics(torch.from_numpy(fit.local), torch.from_numpy(fit.root), rest_heads)
    rest_points = (torch.from_numpy(places.blend)[..., None] * rest_vertices[torch.from_numpy(places.vertices)]).sum(1)
    on_body = body.skin_dense(rots, heads, rest_points, rest_heads, torch.from_numpy(placed.weights)).numpy()
    joints = heads.numpy()[:, body.body.joint_bones()]
    miss = np.linalg.norm(on_body - points, axis=-1)  # NaN where not observed
    seen = np.isfinite(miss)
    rms = np.sqrt(np.nansum(miss ** 2, axis=1) / np.maximum(seen.sum(1), 1))
    quat = Rotation.from_matrix(rots.numpy().reshape(-1, 3, 3)).as_quat().reshape(rots.shape[:2] + (4,))
    frame = markers["frame"].values
    return xr.Dataset(
        {"position": (("frame", "joint", "xyz"), joints.astype(np.float32)),
         "bone_rotation": (("frame", "bone", "quat"), quat),
         "root": (("frame", "xyz"), fit.root.astype(np.float64)),
         "reflector_position": (("frame", "reflector", "xyz"), on_body.astype(np.float32)),
         "rms_error": (("frame",), np.where(seen.any(1), rms, np.nan).astype(np.float32)),
         "reflectors": (("frame",), seen.sum(1).astype(np.int16)),
         "fitted": (("frame",), placed.fitted),
         "shape": (("phenotype",), np.asarray(fit.phenotype, np.float64))},
        coords={"frame": frame, "joint": list(JOINT_NAMES), "bone": list(body.body.bone_names),
                "reflector": names, "xyz": ["x", "y", "z"], "quat": ["x", "y", "z", "w"],
                "phenotype": list(PHENOTYPE_NAMES)},
        attrs={"length_unit": "m", "up_axis": "Z", "fps": float(markers.attrs["fps"])},
    )
