"""Mesh studio benchmark: render and posing times on one core, retargeting quality per CMU clip, first-use cost.

    taskset -c 0 python benchmarks/mesh_studio.py [--frames 30] [--clips DIR] [--cold]

- render: per view-frame, after each camera's setup, the Embree scene of each frame shared by its views
  (its build time divided among them): the Kinect-like sensor at 512x424 (depth, IR, reflector ids, scene
  flow, noise; three views of the mesh studio) and a 1280x720 grey camera (lit, textured, noise; three views);
- pose: skinning the mesh per frame, in takes of ``--frames`` frames, and the whole retargeting per frame;
- retargeting quality, per clip of ``--clips`` at its own frame rate: the angle between each mapped mesh bone
  and the source BVH bone it follows (median and 95th percentile over bones and frames); foot skating, the
  horizontal speed of each ankle over the source's stance frames (its toe within 2 cm of its lowest), for the
  mesh and for the source (scaled to the mesh's leg length); and the mesh sole's height over the floor in
  those frames (median);
- ``--cold``: the first use in a fresh process with empty Anny and warp caches (model data built, kernel
  compiled), against a warm one.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

from mocapflow.formats.bvh import parse_bvh  # noqa: E402
from mocapflow.tasks.shared.body import Subject  # noqa: E402
from mocapflow.tasks.shared.cameras import Camera  # noqa: E402
from mocapflow.tasks.shared.mesh_body import mesh_body, pose_mesh, random_phenotype  # noqa: E402
from mocapflow.tasks.studio import mesh_motion, mesh_render, retarget  # noqa: E402
from mocapflow.tasks.shared.cameras import look_at  # noqa: E402
from mocapflow.tasks.deepmocap.film.mesh_synth import view_frame  # noqa: E402
from mocapflow.tasks.deepmocap.film.synth import build_rig  # noqa: E402
from mocapflow.tasks.studio.spec import SequenceSpec

ROOT = Path(__file__).resolve().parents[1]
CONTACT_M = 0.02  # a source foot whose toe is within this height of its lowest is on the floor


def kinect_times(frames: int) -> list[float]:
    rig = build_rig(SequenceSpec("jumping_jack", frames=frames, seed=1, body="mesh", random_layout=True))
    out = []
    for f in range(frames):
        t0 = time.perf_counter()
        scene = mesh_render.MeshScene(rig.take.posed.vertices[f], rig.body.faces)
        normals = mesh_render.vertex_normals(rig.take.posed.vertices[f], rig.body.faces)
        shared = (time.perf_counter() - t0) / len(rig.views)
        for v, view in enumerate(rig.views):
            t0 = time.perf_counter()
            view_frame(rig, view, scene, f, normals, np.random.default_rng([1, v, f]))
            out.append(shared + time.perf_counter() - t0)
    return out


def grey_times(frames: int) -> list[float]:
    rig = build_rig(SequenceSpec("kick_box_kicking", frames=frames, seed=2, body="mesh"))
    cams = [Camera(f"grey{i}", 1000.0, 1000.0, 639.5, 359.5, (-0.08, 0.02, 0.0, 0.0, 0.0),
                   look_at((3.2 * np.cos(a), 3.2 * np.sin(a), 1.4), (0.0, 0.0, 1.0)), 1280, 720)
            for i, a in enumerate(np.radians([90, 210, 330]))]
    rays = [c.pixel_rays() for c in cams]
    yy, xx = np.mgrid[0:1024, 0:1024]
    texture = np.where(((yy // 64) + (xx // 64)) % 2 == 0, 0.85, 0.15)
    out = []
    for f in range(frames):
        verts = rig.take.posed.vertices[f]
        t0 = time.perf_counter()
        scene = mesh_render.MeshScene(verts, rig.body.faces)
        shared = (time.perf_counter() - t0) / len(cams)
        for i, (cam, r) in enumerate(zip(cams, rays)):
            t0 = time.perf_counter()
            hits = mesh_render.cast_view(scene, cam, r)
            rad = mesh_render.radiance(hits, verts, rig.body.faces, rig.body.uv, texture, mesh_render.Lighting())
            mesh_render.grey_image(rad, np.random.default_rng([f, i]))
            out.append(shared + time.perf_counter() - t0)
    return out


def pose_times(frames: int) -> tuple[float, float]:
    body = mesh_body(random_phenotype(np.random.default_rng(3)))
    rig = build_rig(SequenceSpec("jumping_jack", frames=frames - 1, seed=3, body="mesh"))
    skin, whole = [], []
    for _ in range(5):
        t0 = time.perf_counter()
        pose_mesh(body, rig.take.rotations, rig.take.root)
        skin.append((time.perf_counter() - t0) / frames)
        t0 = time.perf_counter()
        mesh_motion.retarget(rig.body, rig.subject, rig.motion)
        whole.append((time.perf_counter() - t0) / frames)
    return statistics.median(skin), statistics.median(whole)


def retarget_quality(path: Path, seed: int) -> dict:
    clip = parse_bvh(path.read_text())
    body = mesh_body(random_phenotype(np.random.default_rng([seed, 2])))
    subject = Subject(height=body.height)  # the template that performs the clip, as in the mesh studio
    motion = retarget.retarget(clip, subject, fps=clip.fps)
    take = mesh_motion.retarget(body, subject, motion)
    source = retarget.world_positions(clip)
    index = {n: i for i, n in enumerate(clip.names)}
    mapping = retarget.joint_map(clip)
    angles = []
    for bone, (joint, end_bone, _) in mesh_motion.SEGMENTS.items():
        m = mapping.get(joint)
        if end_bone is None or not isinstance(m, tuple):
            continue  # a segment that inherits its rotation (the clavicles and the neck) follows no BVH bone
        mesh_dir = take.posed.heads[:, body.bone(end_bone)] - take.posed.heads[:, body.bone(bone)]
        src_dir = source[:, index[m[2]]] - source[:, index[m[1]]]
        cos = np.einsum("fi,fi->f", mesh_dir, src_dir) / np.linalg.norm(mesh_dir, axis=1) / np.linalg.norm(src_dir, axis=1)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    angles = np.concatenate(angles)
    scale = leg_length(take.posed.heads, body) / leg_length_source(source, index, mapping)
    skate_mesh, skate_src, float_cm = [], [], []
    for side, s in (("Left", "L"), ("Right", "R")):
        ankle, toe = (source[:, index[mapping[f"{side}Ankle"][k]]] * scale for k in (1, 2))
        down = toe[:, 2] <= toe[:, 2].min() + CONTACT_M  # the source's stance frames
        both = down[1:] & down[:-1]
        skate_src.append(speed(ankle, both, clip.fps))
        skate_mesh.append(speed(take.posed.heads[:, body.bone(f"foot.{s}")], both, clip.fps))
        float_cm.append(100 * np.median(take.posed.vertices[down][:, feet(body, s), 2].min(axis=1)))
    return {"frames": take.root.shape[0], "angle_median": float(np.median(angles)),
            "angle_p95": float(np.percentile(angles, 95)), "skate_mesh": float(np.mean(skate_mesh)),
            "skate_source": float(np.mean(skate_src)), "float_cm": float(np.mean(float_cm))}


def feet(body, side: str) -> np.ndarray:
    return np.flatnonzero(np.isin(body.vertex_bone, [i for i, n in enumerate(body.bone_names)
                                                     if n.startswith(("foot", "toe")) and n.endswith(side)]))


def leg_length(heads, body) -> float:
    h, k, a = (heads[0, body.bone(n)] for n in ("upperleg01.L", "lowerleg01.L", "foot.L"))
    return float(np.linalg.norm(k - h) + np.linalg.norm(a - k))


def leg_length_source(pos, index, mapping) -> float:
    h, k, a = (pos[0, index[mapping[j][1]]] for j in ("LeftHip", "LeftKnee", "LeftAnkle"))
    return float(np.linalg.norm(k - h) + np.linalg.norm(a - k))


def speed(ankle: np.ndarray, pairs: np.ndarray, fps: float) -> float:
    """Mean horizontal speed (cm/s) of ``ankle`` (frame, 3) over the frame pairs ``pairs`` (frame - 1,) marks."""
    step = np.linalg.norm(np.diff(ankle[:, :2], axis=0), axis=1)[pairs]
    return float(100 * fps * step.mean()) if len(step) else float("nan")


def cold_start() -> tuple[float, float]:
    code = ("import time; t=time.perf_counter(); import numpy as np; "
            "from mocapflow.tasks.shared.mesh_body import mesh_body, pose_mesh, Phenotype; b=mesh_body(Phenotype()); "
            "pose_mesh(b, np.tile(np.eye(3), (1, 104, 1, 1)), b.rest_heads[:1]); print(time.perf_counter()-t)")
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "ANNY_CACHE_DIR": f"{tmp}/anny", "WARP_CACHE_PATH": f"{tmp}/warp"}
        for _ in range(2):  # the first run builds both caches, the second finds them
            out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            times.append(float(out.stdout.strip().splitlines()[-1]))
    return times[0], times[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--clips", type=Path, default=ROOT.parent / "shared" / "data" / "motions")
    parser.add_argument("--cold", action="store_true")
    args = parser.parse_args()
    k = kinect_times(args.frames)
    g = grey_times(args.frames)
    print(f"render per view-frame, one core: 512x424 depth+IR {1e3 * statistics.median(k):.1f} ms "
          f"(p90 {1e3 * np.percentile(k, 90):.1f}, {len(k)} view-frames); 1280x720 grey "
          f"{1e3 * statistics.median(g):.1f} ms (p90 {1e3 * np.percentile(g, 90):.1f}, {len(g)} view-frames)")
    skin, whole = pose_times(args.frames)
    print(f"pose per frame ({args.frames}-frame takes, median of 5): skinning {1e3 * skin:.2f} ms, "
          f"retargeting and skinning {1e3 * whole:.2f} ms")
    print("clip | frames | bone angle to the source median / p95 (deg) | stance ankle speed mesh / source (cm/s) | "
          "stance sole height (cm)")
    for seed, path in enumerate(sorted(args.clips.glob("*.bvh"))):
        q = retarget_quality(path, 9100 + seed)
        print(f"{path.stem} | {q['frames']} | {q['angle_median']:.2f} / {q['angle_p95']:.2f} | "
              f"{q['skate_mesh']:.1f} / {q['skate_source']:.1f} | {q['float_cm']:.1f}")
    if args.cold:
        cold, warm = cold_start()
        print(f"first use in a fresh process with empty caches: {cold:.1f} s; again with the caches: {warm:.1f} s")


if __name__ == "__main__":
    main()
