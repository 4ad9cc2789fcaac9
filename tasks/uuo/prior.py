"""The monocular body prior of UUO (Milef et al. 2024, §3.3): a rough body per frame, as a video estimator gives.

UUO starts from a body estimated from monocular video (HMR 2.0 in the paper), whose poses and proportions are
roughly right but whose global translation, size and root orientation are not (§3.3, appendix B: mostly a
single yaw offset). Implementations of the stage ``prior``:

- ``simulated_prior``: the studio's truth degraded the way such an estimator errs. ``form: mild`` (the first
  form): every articulated joint's local rotation (SMPL's joints on Anny's rig, PRIOR_BONES) off by a smooth,
  temporally correlated random rotation; the whole body turned by one yaw offset, scaled by one factor, moved by
  one translation and by a slow drift (monocular depth); a few frames lost (tracking failures, held by the
  nearest kept frame and marked invalid); the phenotype off by a little. ``form: realistic`` (the default) adds
  the errors a real monocular estimate makes in correlated ways (``monocular_errors``): every other bone off by a
  smaller smooth rotation, limbs flipped in depth and held for a while, a slow lean of the upper body, per-frame
  jitter. Its error is stored three ways: ``aligned_mpjpe_mm`` after what part matching estimates (one rotation,
  a translation per frame; realistic about 130 mm on the studio's 90-frame exercises, mild about 79),
  ``registered_mpjpe_mm`` after one rigid registration with scale of the take (the paper's measure of HMR2.0+RR,
  132-150 mm there; realistic about 280 mm, docs/uuo.md), and ``pa_mpjpe_mm`` per frame
  (benchmarks/uuo_prior_calibration.py prints all three);
- ``no_prior``: markers only (the paper's marker-only rows): a neutral body in its rest pose;
- ``file_prior``: a monocular estimate a user brings (any method), as the 20 template joints per frame
  (tasks/shared/body.py JOINT_NAMES, metres, Z up; NaN rows for lost frames), read by systems/uuo/prior_files.py.
  Anny's rig is fitted to them (``fit_joints``): the SMPL-like bones of PRIOR_BONES turn, the others follow
  their parents; the phenotype's height is set from the joints' limb lengths;
- ``reference_prior``: ``simulated_prior``'s degradation applied to a solved body (a recorded take's labelled
  reference) instead of the studio's truth.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass

import numpy as np
import xarray as xr
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.kinematics import forward_kinematics, local_rotations, rigid_fit, world_rotations
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, MeshBody, Phenotype, mesh_body, phenotype_for_height, \
    pose_mesh


def nearest_kept(valid: np.ndarray) -> np.ndarray:
    """Each frame's nearest kept frame (itself where kept): what a lost frame of a prior holds.  (frame,) bool ->
    (frame,) frame indices"""
    kept = np.flatnonzero(valid)
    return kept[np.abs(np.arange(len(valid))[:, None] - kept[None]).argmin(axis=1)]


class PriorError(ValueError):
    """A prior that cannot be made from the given take or settings."""


PRIOR_FORMS = ("realistic", "mild")


@dataclass(frozen=True)
class SimulatedPriorConfig:
    """``form: realistic`` (the default) adds the correlated errors of a real monocular estimate to ``mild`` (the
    project's first form: independent smooth rotation errors of the SMPL-like joints only); the realistic terms
    (``other_rotation_deg`` .. ``jitter_deg``) are ignored by ``mild``. Calibrated on the studio's procedural
    exercises (benchmarks/uuo_prior_calibration.py): realistic about 130 mm MPJPE after one rotation and a
    translation per frame (what part matching removes), the target set for it from HMR2.0+RR's 132-150 mm."""

    form: str = "realistic"  # realistic | mild
    rotation_deg: float = 6.5  # std of each articulated joint's rotation error (PRIOR_BONES): PA-MPJPE about 54 mm
    correlation_s: float = 0.4  # how long an error lasts (Gaussian smoothing of the error curves)
    drift_m: float = 0.13  # std of a slow error of the body's position (monocular depth, drift): RR about 140 mm (mild)
    drift_s: float = 1.0  # how long a drift lasts
    yaw_deg: float = 180.0  # the root's yaw offset is drawn in [-yaw_deg, yaw_deg]
    scale_range: tuple[float, float] = (0.85, 1.15)  # one size factor for the take
    translation_m: float = 1.0  # one offset of that size, in a random direction
    lost: float = 0.02  # per-frame probability that tracking fails for a frame
    phenotype_noise: float = 0.1  # std of the phenotype parameters' error (clipped to [0, 1])
    other_rotation_deg: float = 3.0  # realistic: std of the other bones' smooth error (every bone degraded)
    flip_per_s: float = 0.3  # realistic: rate per limb bone of depth flips (the limb swung through the view axis)
    flip_deg: tuple[float, float] = (30.0, 55.0)  # ... each flip's angle, drawn in this range ...
    flip_s: tuple[float, float] = (0.4, 1.2)  # ... and held this long (ramped in and out over 0.1 s)
    lean_deg: float = 5.0  # realistic: std of a systematic lean of the upper body, varying slowly (lean_s)
    lean_s: float = 2.0
    jitter_deg: float = 1.5  # realistic: std of a per-frame rotation jitter of every articulated joint
    seed: int = 0  # mixed with each take's own key (take_key): one seed gives every take of a catalog its own errors

    def __post_init__(self):
        lo, hi = self.scale_range
        if self.form not in PRIOR_FORMS:
            raise PriorError(f"simulated prior form {self.form!r} is unknown; use one of {list(PRIOR_FORMS)}")
        if self.rotation_deg < 0 or self.correlation_s <= 0 or not 0 < lo <= hi or not 0 <= self.lost < 1 \
                or self.drift_m < 0 or self.drift_s <= 0:
            raise PriorError(f"simulated prior settings out of range: rotation_deg {self.rotation_deg} >= 0, "
                             f"correlation_s {self.correlation_s} > 0, 0 < scale_range {self.scale_range}, "
                             f"lost {self.lost} in [0, 1), drift_m {self.drift_m} >= 0, drift_s {self.drift_s} > 0")
        if min(self.other_rotation_deg, self.flip_per_s, self.lean_deg, self.jitter_deg) < 0 or self.lean_s <= 0 \
                or not 0 <= self.flip_deg[0] <= self.flip_deg[1] or not 0 < self.flip_s[0] <= self.flip_s[1]:
            raise PriorError(f"realistic prior settings out of range: other_rotation_deg, flip_per_s, lean_deg, "
                             f"jitter_deg >= 0, lean_s > 0, flip_deg and flip_s ranges low <= high (got {self})")


# The articulated joints a monocular estimator has (SMPL's, on Anny's rig); the bones between them follow their
# parents, so an error is not multiplied by the number of vertebrae a rig happens to have.
PRIOR_BONES = frozenset(("root", "spine05", "spine03", "spine01", "neck01", "head") + tuple(
    f"{bone}.{side}" for side in "LR" for bone in ("clavicle", "upperarm01", "lowerarm01", "wrist", "upperleg01",
                                                   "lowerleg01", "foot")))


def _smooth_noise(rng: np.random.Generator, shape: tuple, sigma_frames: float) -> np.ndarray:
    """Noise smoothed over the first axis (frames) by a Gaussian of ``sigma_frames``, of unit variance in
    expectation: scaled by the filter's own gain (the root of its squared weights), not by the take's spread, so
    a take shorter than the smoothing keeps its stated size (a per-take normalisation blew a nearly constant
    curve up to tens of standard deviations)."""
    noise = rng.standard_normal(shape)
    if shape[0] > 1:
        noise = gaussian_filter1d(noise, sigma_frames, axis=0, mode="nearest")
        impulse = np.zeros(8 * int(np.ceil(sigma_frames)) + 1)
        impulse[len(impulse) // 2] = 1.0
        noise /= np.sqrt((gaussian_filter1d(impulse, sigma_frames, mode="constant") ** 2).sum())
    return noise


def take_key(phenotype: dict, root: np.ndarray) -> int:
    """A number that tells takes apart (the subject's phenotype and where the body starts), mixed into the prior's
    seed: each take of a catalog gets errors of its own, and the same take always the same ones."""
    values = np.array([float(phenotype[k]) for k in sorted(phenotype)] + [float(v) for v in np.asarray(root)[0]])
    return int.from_bytes(hashlib.sha256(np.round(values, 9).tobytes()).digest()[:8], "little")


def degrade(body: MeshBody, rotations: np.ndarray, root: np.ndarray, fps: float, config: SimulatedPriorConfig,
            key: int) -> dict:
    """The prior's bone rotations (frame, bone, 3, 3), root (frame, 3), validity (frame,) and phenotype; the draws
    come from ``config.seed`` and the take's ``key`` (take_key)."""
    rng = np.random.default_rng([config.seed, key])
    n, n_bones = rotations.shape[:2]
    noise = _smooth_noise(rng, (n, n_bones, 3), config.correlation_s * fps)
    noise *= np.radians(config.rotation_deg) / np.sqrt(3)
    noise[:, [b not in PRIOR_BONES for b in body.bone_names]] = 0.0  # the other bones follow their parents
    local = local_rotations(rotations, body.bone_parents)
    local = Rotation.from_rotvec(noise.reshape(-1, 3)).as_matrix().reshape(n, n_bones, 3, 3) @ local
    if config.form == "realistic":  # a stream of its own: the mild terms draw the same with or without it
        local = monocular_errors(body, local, fps, config, np.random.default_rng([config.seed, key, 7]))
    yaw = Rotation.from_euler("z", rng.uniform(-config.yaw_deg, config.yaw_deg), degrees=True).as_matrix()
    local[:, 0] = yaw @ local[:, 0]  # the root's world orientation, turned by one yaw for the take
    world = world_rotations(local, body.bone_parents)
    scale = rng.uniform(*config.scale_range)
    direction = rng.standard_normal(3)
    offset = direction / np.linalg.norm(direction) * config.translation_m
    centre = root.mean(axis=0)
    drift = _smooth_noise(rng, (n, 3), config.drift_s * fps) * config.drift_m / np.sqrt(3)
    prior_root = (root - centre) @ yaw.T * scale + centre + offset + drift
    valid = rng.random(n) >= config.lost
    if not valid.any():
        valid[int(rng.integers(n))] = True
    nearest = nearest_kept(valid)  # lost frames hold the nearest kept
    values = np.clip(np.array(list(asdict(body.phenotype).values()))
                     + rng.normal(0, config.phenotype_noise, 6), 0.0, 1.0)
    return {"rotations": world[nearest], "root": prior_root[nearest], "valid": valid, "scale": scale,
            "phenotype": Phenotype(**dict(zip(asdict(body.phenotype), map(float, values))))}


# The limb bones whose direction a monocular estimate can get wrong in depth, each with the bone its segment
# ends at (a flip swings the segment through the view axis).
FLIP_BONES = tuple((f"{bone}.{side}", f"{end}.{side}") for side in "LR" for bone, end in (
    ("upperarm01", "lowerarm01"), ("lowerarm01", "wrist"), ("upperleg01", "lowerleg01"), ("lowerleg01", "foot")))


def _held_events(rng: np.random.Generator, n: int, fps: float, rate_per_s: float, hold_s: tuple[float, float],
                 ramp_s: float = 0.1) -> np.ndarray:
    """(frame,) weight in [0, 1]: events starting at ``rate_per_s`` (Poisson), each held ``hold_s`` and ramped."""
    weight = np.zeros(n)
    t = np.arange(n) / max(fps, 1e-9)
    for start in np.flatnonzero(rng.random(n) < rate_per_s / max(fps, 1e-9)):
        hold = rng.uniform(*hold_s)
        s = t - t[start]
        up = np.clip(s / ramp_s, 0, 1) * np.clip((hold - s) / ramp_s, 0, 1)
        weight = np.maximum(weight, np.where((s >= 0) & (s <= hold), 0.5 - 0.5 * np.cos(np.pi * up), 0.0))
    return weight


def _world_turn(local: np.ndarray, parents: np.ndarray, bone: int, turn: np.ndarray) -> np.ndarray:
    """Local rotations with ``bone`` turned by ``turn`` (frame, 3, 3) in world axes (its children follow)."""
    world = world_rotations(local, parents)
    out = local.copy()
    parent = world[:, parents[bone]] if parents[bone] >= 0 else np.broadcast_to(np.eye(3), turn.shape)
    out[:, bone] = np.swapaxes(parent, -1, -2) @ turn @ world[:, bone]
    return out


def monocular_errors(body: MeshBody, local: np.ndarray, fps: float, config: SimulatedPriorConfig,
                     rng: np.random.Generator) -> np.ndarray:
    """The realistic prior's correlated errors on local rotations (frame, bone, 3, 3): the other bones' smooth
    error (every bone degraded), depth flips of the limbs held for a while (the segment swung about the axis
    across it and the camera's view, toward its mirror image in depth), a slow lean of the upper body, and
    per-frame jitter of the articulated joints."""
    n, n_bones = local.shape[:2]
    parents = body.bone_parents
    other = np.array([b not in PRIOR_BONES for b in body.bone_names])
    noise = _smooth_noise(rng, (n, n_bones, 3), config.correlation_s * fps) * np.radians(config.other_rotation_deg)
    noise[:, ~other] = rng.standard_normal((n, (~other).sum(), 3)) * np.radians(config.jitter_deg)
    local = Rotation.from_rotvec(noise.reshape(-1, 3) / np.sqrt(3)).as_matrix().reshape(local.shape) @ local
    view = np.array([*Rotation.from_euler("z", rng.uniform(0, 360), degrees=True).apply([1.0, 0, 0])[:2], 0.0])
    offsets = body.rest_heads - np.where(parents[:, None] >= 0, body.rest_heads[np.maximum(parents, 0)], 0.0)
    for bone_name, end_name in FLIP_BONES:
        weight = _held_events(rng, n, fps, config.flip_per_s, config.flip_s)
        if not weight.any():
            continue
        bone, end = body.bone(bone_name), body.bone(end_name)
        heads = forward_kinematics(local, np.zeros((n, 3)), offsets, parents)[1]
        segment = heads[:, end] - heads[:, bone]
        axis = np.cross(segment, view)
        axis /= np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-9)
        toward = -np.sign(segment @ view + 1e-12)  # toward the mirror image in depth
        angle = np.radians(rng.uniform(*config.flip_deg)) * weight * toward
        local = _world_turn(local, parents, bone, Rotation.from_rotvec(axis * angle[:, None]).as_matrix())
    lean_axis = _smooth_noise(rng, (n, 2), config.lean_s * fps) * 0.5 + rng.standard_normal(2)  # a bias that drifts
    lean = np.concatenate([lean_axis, np.zeros((n, 1))], axis=1) * np.radians(config.lean_deg) / np.sqrt(2)
    return _world_turn(local, parents, body.bone("spine05"), Rotation.from_rotvec(lean).as_matrix())


@dataclass(frozen=True)
class NoPriorConfig:
    phenotype: Phenotype = Phenotype()  # the neutral body's shape (Anny's middle values, an adult)


def no_prior(markers: xr.Dataset, config: NoPriorConfig) -> xr.Dataset:
    """Stage ``prior`` (none): markers only. A neutral body in its rest pose on every frame at the origin; the
    solver's part matching places and turns it (the paper's marker-only baselines)."""
    body = mesh_body(config.phenotype)
    n, n_bones = markers.sizes["frame"], len(body.bone_names)
    root = np.broadcast_to(body.rest_heads[0], (n, 3)).copy()
    joints = np.broadcast_to(body.rest_heads[body.joint_bones()], (n, len(JOINT_NAMES), 3)).astype(np.float32)
    quats = np.broadcast_to(np.array([0.0, 0.0, 0.0, 1.0]), (n, n_bones, 4)).copy()
    return xr.Dataset(
        {"bone_rotation": (("frame", "bone", "quat"), quats), "root": (("frame", "xyz"), root),
         "joints": (("frame", "joint", "xyz"), joints), "valid": (("frame",), np.ones(n, bool))},
        coords={"frame": markers["frame"].values, "bone": np.array(body.bone_names, dtype=object),
                "joint": np.array(JOINT_NAMES, dtype=object), "xyz": np.array(["x", "y", "z"], dtype=object),
                "quat": np.array(["x", "y", "z", "w"], dtype=object)},
        attrs={"fps": float(markers.attrs.get("fps", 0.0)), "phenotype": asdict(config.phenotype), "source": "none"})


def registered_mpjpe(joints: np.ndarray, truth: np.ndarray) -> float:
    """MPJPE (m) after one rigid registration with scale of all frames' joints onto the truth (HMR2.0+RR's
    measure).  (frame, joint, 3) x 2 -> float"""
    a, b = joints.reshape(-1, 3), truth.reshape(-1, 3)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    s = np.sqrt(((b - cb) ** 2).sum() / ((a - ca) ** 2).sum())
    rot, trans = rigid_fit((a - ca) * s + ca, b)
    return float(np.linalg.norm(((a - ca) * s + ca) @ rot.T + trans - b, axis=1).mean())


def aligned_mpjpe(joints: np.ndarray, truth: np.ndarray) -> float:
    """MPJPE (m) after what part matching itself estimates: one rotation for the take and a translation per frame
    (no scale). The error a solver started from the placed prior must remove.  (frame, joint, 3) x 2 -> float"""
    a = joints - joints.mean(axis=1, keepdims=True)
    b = truth - truth.mean(axis=1, keepdims=True)
    rot, _ = rigid_fit(a.reshape(-1, 3), b.reshape(-1, 3))
    a = a - a.reshape(-1, 3).mean(0)
    return float(np.linalg.norm(a @ rot.T - b, axis=-1).mean())


def procrustes_mpjpe(joints: np.ndarray, truth: np.ndarray) -> float:
    """PA-MPJPE (m): MPJPE after a rigid registration with scale of each frame on its own (the articulated error).
    (frame, joint, 3) x 2 -> float"""
    return float(np.mean([registered_mpjpe(j[None], t[None]) for j, t in zip(joints, truth)]))


def simulated_prior(markers: xr.Dataset, config: SimulatedPriorConfig) -> xr.Dataset:
    """Stage ``prior`` (simulated): a studio take's true body, degraded like a monocular estimate."""
    missing = [k for k in ("gt_bone_rotations", "gt_root", "gt_joints") if k not in markers] + \
        ([] if "phenotype" in markers.attrs else ["phenotype attribute"])
    if missing:
        raise PriorError(f"a simulated prior degrades the studio's truth, and these markers lack {missing}; use "
                         "prior: file (a monocular estimate you bring) or prior: none on recorded markers")
    return degraded_body(markers["frame"].values, markers.attrs["phenotype"], markers["gt_bone_rotations"].values,
                     markers["gt_root"].values, markers["gt_joints"].values, float(markers.attrs["fps"]), config,
                     "simulated")


def reference_prior(markers: xr.Dataset, reference: xr.Dataset, config: SimulatedPriorConfig) -> xr.Dataset:
    """Stage ``prior`` (simulated from a reference): a solved body (uuo_body, e.g. the labelled solve of a
    recorded take) degraded like a monocular estimate, as ``simulated_prior`` degrades the studio's truth."""
    if reference.sizes["frame"] != markers.sizes["frame"]:
        raise PriorError(f"the reference body has {reference.sizes['frame']} frames and the markers "
                         f"{markers.sizes['frame']}; solve the reference on the same take")
    fps = float(markers.attrs.get("fps", reference.attrs.get("fps", 0.0)))
    return degraded_body(markers["frame"].values, reference.attrs["phenotype"], reference["bone_rotation"].values,
                     reference["root"].values, reference["joints"].values, fps, config, "reference")


def degraded_body(frames: np.ndarray, phenotype: dict, quats: np.ndarray, root: np.ndarray, truth_joints: np.ndarray,
                  fps: float, config: SimulatedPriorConfig, source: str) -> xr.Dataset:
    """A body (bone quaternions (frame, bone, 4), root (frame, 3)) degraded by ``degrade``, as a body_prior."""
    body = mesh_body(Phenotype(**phenotype))
    rotations = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(quats.shape[:2] + (3, 3))
    out = degrade(body, rotations, root, fps, config, take_key(phenotype, root))
    prior_body = mesh_body(out["phenotype"])
    posed = pose_mesh(prior_body, out["rotations"], out["root"])
    joints = posed.heads[:, prior_body.joint_bones()]
    truth = truth_joints.astype(np.float64)
    valid = out["valid"]
    return prior_dataset(frames, body, out["rotations"], out["root"], joints, valid, fps, out["phenotype"], source,
                         registered_mpjpe_mm=1000.0 * registered_mpjpe(joints[valid], truth[valid]),
                         pa_mpjpe_mm=1000.0 * procrustes_mpjpe(joints[valid], truth[valid]),
                         aligned_mpjpe_mm=1000.0 * aligned_mpjpe(joints[valid], truth[valid]), form=config.form)


def prior_dataset(frames: np.ndarray, body: MeshBody, rotations: np.ndarray, root: np.ndarray, joints: np.ndarray,
                  valid: np.ndarray, fps: float, phenotype: Phenotype, source: str, **attrs) -> xr.Dataset:
    """A body_prior dataset.  rotations (frame, bone, 3, 3) world, root (frame, 3), joints (frame, joint, 3)"""
    quats = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat().reshape(rotations.shape[:2] + (4,))
    return xr.Dataset(
        {"bone_rotation": (("frame", "bone", "quat"), quats), "root": (("frame", "xyz"), root),
         "joints": (("frame", "joint", "xyz"), joints.astype(np.float32)), "valid": (("frame",), valid)},
        coords={"frame": frames, "bone": np.array(body.bone_names, dtype=object),
                "joint": np.array(JOINT_NAMES, dtype=object), "xyz": np.array(["x", "y", "z"], dtype=object),
                "quat": np.array(["x", "y", "z", "w"], dtype=object)},
        attrs={"fps": fps, "phenotype": asdict(phenotype), "source": source, **attrs})


@dataclass(frozen=True)
class FilePriorConfig:
    phenotype: Phenotype = Phenotype()  # the body's shape; its height is set from the joints' limb lengths
    iterations: int = 150  # L-BFGS iterations of the joint fit
    pose_weight: float = 1e-3  # E_Theta (Eq. 5) toward the rest pose: fixes the twists joints cannot tell
    follow_weight: float = 1.0  # on the rotation of bones outside PRIOR_BONES: they follow their parents

    def __post_init__(self):
        if self.iterations < 1 or min(self.pose_weight, self.follow_weight) < 0:
            raise PriorError(f"file prior settings out of range: iterations >= 1, weights >= 0 (got {self})")


# Template joints that fix the trunk's orientation (the root's start on each frame) and the limb chains whose
# summed lengths give the body's size.
_TRUNK = ("Hips", "SpineBase", "Neck", "LeftShoulder", "RightShoulder", "LeftHip", "RightHip")
_CHAINS = (("Hips", "SpineBase", "Neck", "Head"), ("LeftHip", "LeftKnee", "LeftAnkle"),
           ("RightHip", "RightKnee", "RightAnkle"), ("LeftShoulder", "LeftElbow", "LeftWrist"),
           ("RightShoulder", "RightElbow", "RightWrist"))


def _chain_length(joints: np.ndarray) -> float:
    """Summed segment lengths of _CHAINS, median over frames.  (frame, joint, 3) -> m"""
    index = {n: i for i, n in enumerate(JOINT_NAMES)}
    total = sum(np.linalg.norm(joints[:, index[b]] - joints[:, index[a]], axis=-1)
                for chain in _CHAINS for a, b in zip(chain, chain[1:]))
    return float(np.median(total))


def _sized(joints: np.ndarray, base: Phenotype) -> Phenotype:
    """``base`` with the height whose rest joints' chain lengths match the joints'."""
    rest = mesh_body(base)
    ratio = _chain_length(joints) / _chain_length(rest.rest_heads[rest.joint_bones()][None])
    lo, hi = (float(np.ptp(mesh_body(Phenotype(**{**asdict(base), "height": h})).vertices[:, 2])) for h in (0.0, 1.0))
    return phenotype_for_height(float(np.clip(rest.height * ratio, lo + 1e-3, hi - 1e-3)), base)


def fit_joints(joints: np.ndarray, config: FilePriorConfig):
    """Anny's rig fitted to template joints: (MeshBody, SolverBody, BodyFit).  joints (frame, joint, 3), finite"""
    import torch

    from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody
    from mocapflow.tasks.uuo.fitting import Fit, minimize

    body = mesh_body(_sized(joints, config.phenotype))
    valid = np.ones(joints.shape[0], bool)
    solver = SolverBody(body)
    n = joints.shape[0]
    trunk = [JOINT_NAMES.index(j) for j in _TRUNK]
    rest_joints = body.rest_heads[body.joint_bones()]
    local = np.broadcast_to(np.eye(3), (n, len(body.bone_names), 3, 3)).copy()
    for f in range(n):  # the rest body turned onto each frame's trunk (Kabsch)
        local[f, 0] = rigid_fit(rest_joints[trunk], joints[f, trunk])[0]
    start = BodyFit(local, joints[:, JOINT_NAMES.index("Hips")].astype(np.float64),
                    np.array([asdict(body.phenotype)[k] for k in PHENOTYPE_NAMES]))  # the root's head is Hips
    fit = Fit(solver, start, start, valid)
    target = torch.from_numpy(np.nan_to_num(joints.astype(np.float64)))
    weight = torch.from_numpy(valid.astype(np.float64))[:, None]
    bones = torch.from_numpy(body.joint_bones())
    seen_names = np.array(body.bone_names)[solver.seen_bones]
    follow = torch.from_numpy(np.array([name not in PRIOR_BONES for name in seen_names]))

    with torch.no_grad():  # the shape stays the sized one: the rest skeleton once, only the pose is fitted
        _, rest_heads = solver.rest(torch.from_numpy(start.phenotype))

    def energy():
        local_now = fit.local()
        heads = solver.kinematics(local_now, fit.root, rest_heads)[1]
        d2 = ((heads[:, bones] - target) ** 2).sum(-1)  # (frame, joint)
        e_joints = (d2 * weight).sum() / (weight.sum() * len(JOINT_NAMES)).clamp_min(1.0)
        return (e_joints + config.pose_weight * fit.pose_prior(local_now)
                + config.follow_weight * (fit.delta[:, follow] ** 2).sum(-1).mean())

    minimize(fit.parameters(shape=False), energy, config.iterations)
    return body, solver, fit.result()


def file_prior(markers: xr.Dataset, config: FilePriorConfig) -> xr.Dataset:
    """Stage ``prior`` (file): a monocular estimate brought as template joints per frame (``prior_joints`` of the
    markers, read from the take's prior file), Anny fitted to them; lost frames (NaN) hold the nearest kept."""
    if "prior_joints" not in markers:
        raise PriorError("a file prior needs the take's prior file (the markers have no prior_joints); give the "
                         "markers dataset a 'prior' folder with one file per take, or use prior: simulated or none")
    joints = markers["prior_joints"].transpose("frame", "joint", "xyz").values.astype(np.float64)
    if [str(j) for j in markers["joint"].values] != list(JOINT_NAMES):
        raise PriorError(f"prior joints {list(markers['joint'].values)} are not the template's {list(JOINT_NAMES)}")
    if not np.isfinite(joints).all(axis=(1, 2)).any():
        raise PriorError("every frame of the prior is lost (NaN); a prior needs at least one estimated frame")
    return joints_prior(markers["frame"].values, joints, float(markers.attrs.get("fps", 0.0)), config, "file")


def joints_prior(frames: np.ndarray, joints: np.ndarray, fps: float, config: FilePriorConfig, source: str) -> xr.Dataset:
    """A body_prior of Anny fitted to template joints per frame (frame, joint, 3) (a prior file's, a monocular
    estimator's); lost frames (NaN) hold the nearest kept one and are marked invalid."""
    from mocapflow.tasks.shared.solver_body import posed_heads

    valid = np.isfinite(joints).all(axis=(1, 2))
    kept = np.flatnonzero(valid)
    nearest = np.searchsorted(kept, nearest_kept(valid))  # lost frames hold the nearest kept (an index into kept)
    body, solver, fitted = fit_joints(joints[kept], config)
    out = posed_heads(solver, fitted)[nearest][:, body.joint_bones()]
    local, root = fitted.local[nearest], fitted.root[nearest]
    phenotype = Phenotype(**dict(zip(PHENOTYPE_NAMES, map(float, fitted.phenotype))))
    error = np.linalg.norm(out[valid] - joints[valid], axis=-1).mean()
    return prior_dataset(frames, body, world_rotations(local, body.bone_parents), root, out, valid, fps, phenotype,
                         source, fit_error_mm=1000.0 * float(error))
