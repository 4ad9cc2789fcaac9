"""The mesh body: Anny, a parametric human mesh (MakeHuman-based, PyTorch), posed in the studio's world.

Anny's own frame is Z up, the body facing -Y with its left side at +X; the studio's world
(tasks/shared/body.py) is Z up, facing +Y, left side at -X. ``FACING`` (a half turn about Z) takes
the one to the other, so every array here is in the studio's world, metres.

A body is a ``Phenotype`` (Anny's six parameters in [0, 1]); ``mesh_body`` evaluates its rest mesh
once (A-pose: vertices, triangles, per-corner UVs, the 104 bones' rest heads and orientations).
``pose_mesh`` skins it (linear blend skinning) from each bone's world rotation relative to its rest
orientation and the root's position: Anny's 'world-orient' parameterization, in which every bone's
head follows its parent. ``JOINT_BONES`` names the bone whose head is each of the 20 template
joints, so every system is scored on the same joints.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import asdict, dataclass

import numpy as np

from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.cache import BoundedCache

PHENOTYPE_NAMES = ("gender", "age", "muscle", "weight", "height", "proportions")
FACING = np.diag([-1.0, -1.0, 1.0])  # Anny's frame -> the studio's world (a half turn about Z)
HEIGHT_RANGE_M = (1.50, 2.00)
POSE_BATCH = 64  # frames skinned per call
ADULT_AGE = (0.72, 0.83)  # Anny's age scale: 0.67 ~ 16 years, 0.77 ~ 18, 0.83 ~ 64 (its shape calibration)

# The bone whose rest head is each template joint (tasks/shared/body.py JOINTS), for shared ground truth.
JOINT_BONES = {
    "Hips": "root", "SpineBase": "spine05", "Neck": "neck01", "Head": "head",
    "LeftShoulder": "upperarm01.L", "LeftElbow": "lowerarm01.L", "LeftWrist": "wrist.L", "LeftHand": "finger3-1.L",
    "RightShoulder": "upperarm01.R", "RightElbow": "lowerarm01.R", "RightWrist": "wrist.R", "RightHand": "finger3-1.R",
    "LeftHip": "upperleg01.L", "LeftKnee": "lowerleg01.L", "LeftAnkle": "foot.L", "LeftFoot": "toe3-1.L",
    "RightHip": "upperleg01.R", "RightKnee": "lowerleg01.R", "RightAnkle": "foot.R", "RightFoot": "toe3-1.R",
}
assert tuple(JOINT_BONES) == JOINT_NAMES

# Body parts for surface-point layouts, from the fine parts a bone belongs to (``part_of_bone``).
_SIDES = {"left": ".L", "right": ".R"}
_FINE = ("head", "torso", "hips") + tuple(f"{side}_{limb}" for side in _SIDES for limb in
                                         ("upper_arm", "forearm", "hand", "thigh", "shank", "foot"))
PARTS = {name: (name,) for name in _FINE}
for _side in _SIDES:
    PARTS[f"{_side}_arm"] = tuple(f"{_side}_{limb}" for limb in ("upper_arm", "forearm", "hand"))
    PARTS[f"{_side}_leg"] = tuple(f"{_side}_{limb}" for limb in ("thigh", "shank", "foot"))
PARTS["body"] = _FINE
# UUO's shoulder layouts (Milef et al. 2024, Table 5: spine3, collar, shoulder, elbow): the upper arm and forearm
# with the shoulder girdle's bones, which the fine parts count as torso.
PART_BONES = {f"{side}_shoulder": (f"clavicle{suffix}", f"shoulder01{suffix}") for side, suffix in _SIDES.items()}
for _side in _SIDES:
    PARTS[f"{_side}_shoulder"] = (f"{_side}_upper_arm", f"{_side}_forearm")
_LIMB_BONES = (("upperarm", "upper_arm"), ("lowerarm", "forearm"), ("wrist", "hand"), ("finger", "hand"),
               ("metacarpal", "hand"), ("upperleg", "thigh"), ("lowerleg", "shank"), ("foot", "foot"), ("toe", "foot"))
_SKIN_EXCLUDED = ("tongue", "mouth_cavity", "eye_cavity.L", "eye_cavity.R", "eye_back.L", "eye_back.R")

_MODELS: BoundedCache[str, object] = BoundedCache(1)


def part_of_bone(name: str) -> str:
    """The fine part (``_FINE``) a bone's vertices belong to."""
    if name.startswith(("neck", "head", "eye")):
        return "head"
    if name.startswith(("root", "pelvis")):
        return "hips"
    side = next((s for s, suffix in _SIDES.items() if name.endswith(suffix)), None)
    limb = next((part for prefix, part in _LIMB_BONES if name.startswith(prefix)), None)
    return f"{side}_{limb}" if side and limb else "torso"  # spine, clavicles, shoulders


def part_sides(parts) -> np.ndarray:
    """The side of each fine part: 1 left, -1 right, 0 neither (torso, head, hips, no part).  (n,) names -> (n,)"""
    return np.array([1 if p.startswith("left") else -1 if p.startswith("right") else 0 for p in parts], dtype=int)


class MeshBodyError(ValueError):
    """A phenotype or pose the mesh body cannot take."""


@dataclass(frozen=True)
class Phenotype:
    """Anny's phenotype parameters, each in [0, 1] (gender 0 male, 1 female; age 0.5 is a teenager)."""

    gender: float = 0.5
    age: float = 0.77
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5

    def __post_init__(self):
        for name, value in asdict(self).items():
            if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
                raise MeshBodyError(f"phenotype {name} = {value!r} is outside Anny's range [0, 1]; "
                                    "give a number between 0 and 1")


@dataclass(frozen=True)
class MeshBody:
    """One subject's rest mesh in the studio's world (A-pose, feet at z = 0)."""

    phenotype: Phenotype
    vertices: np.ndarray  # (vertex, 3) rest positions, metres
    faces: np.ndarray  # (face, 3) int32 vertex indices, counter-clockwise seen from outside
    uv: np.ndarray  # (face, 3, 2) float32 texture coordinates per face corner, in [0, 1]
    bone_names: tuple[str, ...]
    bone_parents: np.ndarray  # (bone,) parent index, -1 for the root; parents come first
    rest_heads: np.ndarray  # (bone, 3) rest head of every bone
    rest_frames: np.ndarray  # (bone, 3, 3) rest orientation of every bone (Anny's, in the studio's world)
    vertex_bone: np.ndarray  # (vertex,) the bone with the largest skinning weight
    skin: np.ndarray  # (face,) bool: outer skin (not the eyes' backs, the mouth or the tongue)

    @property
    def height(self) -> float:
        return float(np.ptp(self.vertices[:, 2]))

    def bone(self, name: str) -> int:
        try:
            return self.bone_names.index(name)
        except ValueError:
            raise MeshBodyError(f"Anny has no bone {name!r}; bones are {', '.join(self.bone_names)}") from None

    def descendants(self, name: str) -> np.ndarray:
        """Indices of a bone and every bone below it.  # (bone,)"""
        inside = np.zeros(len(self.bone_names), bool)
        inside[self.bone(name)] = True
        for b, parent in enumerate(self.bone_parents):  # parents come first
            inside[b] |= parent >= 0 and inside[parent]
        return np.flatnonzero(inside)

    def part_faces(self, part: str) -> np.ndarray:
        """Skin faces of a named part (PARTS), by the bone that moves their vertices most.  # (face,) bool"""
        if part not in PARTS:
            raise MeshBodyError(f"unknown body part {part!r}; parts are {', '.join(PARTS)}")
        extra = PART_BONES.get(part, ())
        bones = np.array([part_of_bone(n) in PARTS[part] or n in extra for n in self.bone_names])
        return self.skin & bones[self.vertex_bone[self.faces]].all(axis=1)

    def joint_bones(self) -> np.ndarray:
        """Index of the bone at each template joint, in JOINT_NAMES order.  # (joint,)"""
        return np.array([self.bone(JOINT_BONES[j]) for j in JOINT_NAMES])


@dataclass(frozen=True)
class PosedMesh:
    vertices: np.ndarray  # (frame, vertex, 3) float64
    heads: np.ndarray  # (frame, bone, 3) posed bone heads
    frames: np.ndarray  # (frame, bone, 3, 3) posed bone orientations


def anny_model():
    """The Anny model (default 104-bone rig, triangles, float64), built once per process.

    Anny builds its model data on first use and caches it (``ANNY_CACHE_DIR``, default ``~/.cache/anny``, about
    0.8 GB; about a minute the first time), and compiles its skinning kernel once (``WARP_CACHE_PATH``).
    """
    def build():
        warp_ready()  # here, not in Anny's import
        import anny
        import torch

        model = anny.Anny(pose_parameterization="world-orient").to(dtype=torch.float64)
        model.requires_grad_(False)
        return model

    return _MODELS.get_or_make("anny", build)


def warp_ready() -> None:
    """Warp initialized for the house (Anny's skinning, the studio's sight lines): its banner off the console and,
    on a machine without a GPU, its CUDA driver warning dropped; nothing once it is."""
    import warp

    warp.config.log_level = warp.LOG_ERROR
    with _without_cuda_driver_warning():
        warp.init()


CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"  # warp's native line on a machine without one


@contextmanager
def _without_cuda_driver_warning():
    """Hold what native code writes to stderr (file descriptor 2) while the block runs, then write it back except
    warp's line saying no CUDA driver was found (expected on a CPU machine; Anny skins on the CPU there). Any other
    line, a real error among them, still reaches stderr."""
    import os
    import sys
    import tempfile

    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            text = held.read().decode(errors="replace")
        kept = [line for line in text.splitlines(keepends=True) if CUDA_DRIVER_WARNING not in line]
        if kept:
            os.write(2, "".join(kept).encode())


@contextmanager
def _one_torch_thread():
    """Anny's sums run in one thread, so a body is the same to the last bit whatever a process's thread count
    (torch splits its reductions by thread, and the studio's output must not depend on where it was rendered)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _rest(phenotype: Phenotype) -> dict:
    import torch

    model = anny_model()
    with torch.no_grad(), _one_torch_thread():
        out = model(phenotype_kwargs={k: torch.tensor([v], dtype=torch.float64) for k, v in asdict(phenotype).items()})
    return {k: v[0].numpy() for k, v in out.items() if k.startswith("rest_")}


def _rest_height(phenotype: Phenotype) -> float:
    return float(np.ptp(_rest(phenotype)["rest_vertices"][:, 2]))


HEIGHT_STEPS = 6  # secant steps at most
HEIGHT_TOLERANCE_M = 1e-6


def phenotype_for_height(height_m: float, base: Phenotype) -> Phenotype:
    """``base`` with Anny's height parameter set so that the rest mesh stands ``height_m`` tall (to a micrometre).

    The rest mesh is piecewise linear in the height parameter (blend shapes between anchor values) and its height
    the spread of its vertices, so the line through the two ends is only a start: secant steps finish it.
    """
    def tall(h: float) -> float:
        return _rest_height(Phenotype(**{**asdict(base), "height": h}))

    lo, hi = tall(0.0), tall(1.0)
    value = (height_m - lo) / (hi - lo)
    if not 0.0 <= value <= 1.0:
        raise MeshBodyError(f"a body {height_m:.3f} m tall is outside what this phenotype reaches "
                            f"({lo:.3f}-{hi:.3f} m); choose a height in that range or another gender or age")
    slope, error = hi - lo, tall(value) - height_m
    for _ in range(HEIGHT_STEPS):
        if abs(error) < HEIGHT_TOLERANCE_M:
            break
        step = float(np.clip(value - error / slope, 0.0, 1.0))
        new_error = tall(step) - height_m
        if step != value and new_error != error:
            slope = (new_error - error) / (step - value)
        value, error = step, new_error
    return Phenotype(**{**asdict(base), "height": float(value)})


def random_phenotype(rng: np.random.Generator, height_m: float | None = None) -> Phenotype:
    """An adult of any gender, build and proportions, ``height_m`` tall (drawn from 1.50-2.00 m when None)."""
    base = Phenotype(gender=float(rng.uniform(0, 1)), age=float(rng.uniform(*ADULT_AGE)),
                     muscle=float(rng.uniform(0.2, 0.8)), weight=float(rng.uniform(0.2, 0.8)),
                     proportions=float(rng.uniform(0.2, 0.8)))
    height = float(rng.uniform(*HEIGHT_RANGE_M)) if height_m is None else float(height_m)
    if not HEIGHT_RANGE_M[0] <= height <= HEIGHT_RANGE_M[1]:
        raise MeshBodyError(f"subject height {height} m is outside the studio's {HEIGHT_RANGE_M[0]}-"
                            f"{HEIGHT_RANGE_M[1]} m; choose one inside")
    return phenotype_for_height(height, base)


def mesh_body(phenotype: Phenotype) -> MeshBody:
    """The rest mesh of ``phenotype`` in the studio's world, standing on z = 0."""
    model = anny_model()
    rest = _rest(phenotype)
    lift = np.array([0.0, 0.0, -rest["rest_vertices"][:, 2].min()])
    poses = rest["rest_bone_poses"]  # (bone, 4, 4) in Anny's frame
    uv = model.texture_coordinates.numpy()[model.face_texture_coordinate_indices.numpy()]
    from anny.face_segmentation import get_face_segmentation_mask

    weights, bones = model.vertex_bone_weights.numpy(), model.vertex_bone_indices.numpy()
    return MeshBody(
        phenotype=phenotype,
        vertices=rest["rest_vertices"] @ FACING.T + lift,
        faces=model.faces.numpy().astype(np.int32),
        uv=uv.astype(np.float32),
        bone_names=tuple(model.bone_labels),
        bone_parents=np.asarray(model.bone_parents, dtype=np.int64),
        rest_heads=poses[:, :3, 3] @ FACING.T + lift,
        rest_frames=FACING @ poses[:, :3, :3],
        vertex_bone=bones[np.arange(len(bones)), weights.argmax(axis=1)],
        skin=~get_face_segmentation_mask(model, list(_SKIN_EXCLUDED)).numpy(),
    )


def pose_mesh(body: MeshBody, rotations: np.ndarray, root: np.ndarray) -> PosedMesh:
    """Skin ``body``: each bone turned by ``rotations`` from its rest orientation, the root's head at ``root``.

    rotations: (frame, bone, 3, 3) world rotation of each bone relative to its rest orientation (rest-pose
    geometry -> posed geometry); root: (frame, 3) world position of the root bone's head. Bone heads follow
    their parents, so only the root's position is free.
    """
    import torch

    n_bones = len(body.bone_names)
    if rotations.ndim != 4 or rotations.shape[1:] != (n_bones, 3, 3) or root.shape != (rotations.shape[0], 3):
        raise MeshBodyError(f"pose_mesh takes rotations (frame, {n_bones}, 3, 3) and root (frame, 3), got "
                            f"{rotations.shape} and {root.shape}")
    model = anny_model()
    rest = _rest(body.phenotype)
    lift = body.rest_heads[0] - rest["rest_bone_poses"][0, :3, 3] @ FACING.T
    # 'world-orient': D_c = [M_c R_c | root], R_c the rest orientation, both in Anny's frame. M_c is given in the
    # studio's world, so in Anny's frame it is FACING^T M_c FACING; the result is mapped back by FACING.
    native = FACING.T @ rotations @ FACING @ rest["rest_bone_poses"][:, :3, :3]
    delta = np.zeros(rotations.shape[:2] + (4, 4))
    delta[..., :3, :3] = native
    delta[..., 3, 3] = 1.0
    delta[:, 0, :3, 3] = (root - lift) @ FACING  # the root head, in Anny's frame before the lift
    phenotype = {k: torch.tensor([v], dtype=torch.float64) for k, v in asdict(body.phenotype).items()}
    vertices, poses = [], []
    with torch.no_grad(), _one_torch_thread():
        for start in range(0, len(delta), POSE_BATCH):  # bounded memory for long takes
            out = model(pose_parameters=torch.from_numpy(delta[start:start + POSE_BATCH]), phenotype_kwargs=phenotype)
            vertices.append(out["vertices"].numpy())
            poses.append(out["bone_poses"].numpy())
    vertices, poses = np.concatenate(vertices), np.concatenate(poses)
    return PosedMesh(vertices=vertices @ FACING.T + lift,
                     heads=poses[..., :3, 3] @ FACING.T + lift,
                     frames=FACING @ poses[..., :3, :3])


def random_surface_points(body: MeshBody, rng: np.random.Generator, count: int,
                          part: str = "body") -> tuple[np.ndarray, np.ndarray]:
    """``count`` points spread uniformly by area over a part's skin on the rest mesh: face (n,) int, barycentric
    (n, 2) (the point is (1-u-v) V0 + u V1 + v V2)."""
    if count < 0:
        raise MeshBodyError(f"surface point count must be >= 0, got {count}")
    faces = np.flatnonzero(body.part_faces(part))
    v0, v1, v2 = (body.vertices[body.faces[faces, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(v1 - v0, v2 - v0), axis=1)
    chosen = faces[rng.choice(len(faces), size=count, p=area / area.sum())]
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)  # uniform over the triangle
    return chosen, np.column_stack([s * (1 - r2), s * r2])
