"""Suit hole-filling probe (Chen et al. 2021, §5, Eq. 8): the window solve's time and the filled corners' error.

    taskset -c 0 python benchmarks/suit_fill.py [--frames 150] [--spacing 0.0145] [--hidden 0.3] [--runs 3]
                                                [--noise-mm 0.5] [--seed 3] [--no-kkt]

The suit is a checkerboard printed on Anny's texture map: a corner wherever a grid of ``--spacing`` (texture units)
falls on the suit's skin (trunk, arms and legs), a cell wherever a grid square's four corners exist and its edges are
short on the body (about 1,500 corners at the default).

1. Timing: one window of ``--frames`` frames on that corner mesh, a random smooth displacement field, ``--hidden`` of
   the points hidden at random; the reduced solve and the KKT system (median of ``--runs``), and their largest
   difference.
2. Error: Anny (default phenotype) moved by a smooth random motion, the corners skinned with Anny's mesh, plus a
   few millimetres of smooth non-articulated motion along the skin's normal and ``--noise-mm`` of triangulation
   noise; ``--hidden`` of the points hidden by occluders (patches of the suit, each for a run of frames). The body
   is fitted to the observed corners (tasks/suit/body_fit, timed), their displacements unposed, filled (Eq. 8) and
   reposed; the hidden corners' error against the truth (median and 95th percentile, mm), beside the body model
   alone (zero displacement), over all hidden points, those whose hidden run lies inside the take and those whose
   run reaches its first or last frame (there Eq. 8 extrapolates in time). Points the fill leaves unfilled fall
   back to the body model.

Prints one JSON line. Run it on one core (``taskset -c 0``); torch is held to one thread.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

SUIT_PARTS = ("torso", "hips", "left_upper_arm", "left_forearm", "right_upper_arm", "right_forearm", "left_thigh",
              "left_shank", "right_thigh", "right_shank")
LIMBS = ("upperarm", "lowerarm", "wrist", "upperleg", "lowerleg", "foot")


def grid_points(body, spacing: float) -> dict:
    """Grid node (i, j) -> (face, u, v) where the texture grid of ``spacing`` falls on a suit face."""
    faces = np.flatnonzero(np.logical_or.reduce([body.part_faces(p) for p in SUIT_PARTS]))
    found = {}
    for f, t in zip(faces, body.uv[faces].astype(np.float64)):
        lo, hi = np.floor(t.min(0) / spacing).astype(int), np.floor(t.max(0) / spacing).astype(int)
        gi, gj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        g = np.column_stack([gi.ravel(), gj.ravel()])
        e1, e2, d = t[1] - t[0], t[2] - t[0], g * spacing - t[0]
        det = e1[0] * e2[1] - e1[1] * e2[0]
        if abs(det) < 1e-14:
            continue
        u = (d[:, 0] * e2[1] - d[:, 1] * e2[0]) / det
        v = (e1[0] * d[:, 1] - e1[1] * d[:, 0]) / det
        for k in np.flatnonzero((u >= 0) & (v >= 0) & (u + v <= 1)):
            found.setdefault(tuple(g[k]), (f, u[k], v[k]))
    return found


def suit_layout(body, spacing: float):
    """Corners (face, barycentric), their rest positions and the cells.  -> (c,), (c, 2), (c, 3), (cell, 4)"""
    found = grid_points(body, spacing)
    keys = sorted(found)
    index = {k: n for n, k in enumerate(keys)}
    face = np.array([found[k][0] for k in keys])
    bary = np.array([found[k][1:] for k in keys])
    rest = on_mesh(body.vertices, body.faces, face, bary)
    cells = np.array([[index[c] for c in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))] for i, j in keys
                      if all(c in index for c in ((i + 1, j), (i + 1, j + 1), (i, j + 1)))])
    edges = np.linalg.norm(rest[cells] - rest[np.roll(cells, -1, 1)], axis=-1)
    return face, bary, rest, cells[(edges < 2.0 * np.median(edges)).all(1)]  # squares across a texture seam out


def on_mesh(vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Points (1-u-v) V0 + u V1 + v V2 on a mesh; vertices (..., vertex, 3) -> (..., point, 3)"""
    w = np.column_stack([1.0 - bary.sum(1), bary])
    return (vertices[..., faces[face], :] * w[:, :, None]).sum(-2)


def smooth_field(rest: np.ndarray, frames: int, rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """Sum of three travelling waves, about 20-60 cm and 40-120 frames long.  -> (frame, corner, 3)"""
    t = np.arange(frames)[:, None]
    out = np.zeros((frames, len(rest), 3))
    for _ in range(3):
        k = rng.normal(size=3)
        k *= 2 * np.pi / rng.uniform(0.2, 0.6) / np.linalg.norm(k)
        phase = 2 * np.pi * t / rng.uniform(40, 120) + rest @ k + rng.uniform(0, 2 * np.pi)
        out += amplitude * np.sin(phase)[..., None] * rng.normal(size=3) / np.sqrt(3)
    return out


class Clock:
    """Wall and CPU seconds of a block (CPU time is the steadier figure on a shared machine)."""

    def __enter__(self):
        self.start = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.seconds = (time.perf_counter() - self.start[0], time.process_time() - self.start[1])


def time_windows(rest: np.ndarray, cells: np.ndarray, args, rng: np.random.Generator) -> dict:
    from mocapflow.tasks.suit.fill import FillConfig, cotangent_laplacian, solve_window

    lap = cotangent_laplacian(rest, cells)
    field = smooth_field(rest, args.frames, rng, 0.003)
    field[rng.random(field.shape[:2]) < args.hidden] = np.nan
    out, results = {}, {}
    for method in ("reduced",) + (() if args.no_kkt else ("kkt",)):
        times = []
        for _ in range(args.runs):
            with Clock() as clock:
                results[method] = solve_window(field, lap, FillConfig(method=method))
            times.append(clock.seconds)
        out[f"window_{method}_s"], out[f"window_{method}_cpu_s"] = (round(float(x), 3) for x in np.median(times, 0))
    if "kkt" in results:
        out["kkt_vs_reduced_max_m"] = float(np.nanmax(np.abs(results["kkt"] - results["reduced"])))
    return out


def smooth_motion(solver, frames: int, rng: np.random.Generator):
    """Local rotations (frame, bone, 3, 3) and root heads (frame, 3): every seen bone swinging smoothly (limbs up
    to ~0.5 rad, the spine and neck less), the root turning and wandering."""
    from mocapflow.tasks.shared.kinematics import rodrigues

    t = np.arange(frames)[:, None, None] / 30.0  # seconds at 30 fps
    names = solver.body.bone_names
    amplitude = np.array([0.35 if n.startswith(LIMBS) else 0.08 for n in names])[:, None] * solver.seen_bones[:, None]
    rotvec = np.zeros((frames, len(names), 3))
    for _ in range(2):
        rate = rng.uniform(0.2, 0.8, (len(names), 1))  # Hz
        phase = rng.uniform(0, 2 * np.pi, (len(names), 1))
        rotvec += amplitude * rng.normal(size=(len(names), 3)) * np.sin(2 * np.pi * rate * t + phase)
    rotvec[:, 0] = [0.0, 0.0, 1.0] * (0.8 * np.sin(2 * np.pi * 0.1 * t[:, 0]))  # the root turns about z
    root = solver.body.rest_heads[0] + 0.3 * np.sin(2 * np.pi * np.array([0.07, 0.05, 0.0]) * t[:, 0])
    return rodrigues(rotvec), root


def occluded(rest: np.ndarray, frames: int, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Patches of the suit (6-15 cm) hidden for runs of 10-60 frames, added until ``fraction`` is hidden, and 1 % at
    random.  -> (frame, corner) bool"""
    hidden = rng.random((frames, len(rest))) < 0.01
    while hidden.mean() < fraction:
        centre, radius = rest[rng.integers(len(rest))], rng.uniform(0.06, 0.15)
        start, length = rng.integers(-30, frames), rng.integers(10, 61)
        hidden[max(start, 0):max(start + length, 0), np.linalg.norm(rest - centre, axis=1) < radius] = True
    return hidden


def at_ends(hidden: np.ndarray) -> np.ndarray:
    """Hidden points whose run of hidden frames reaches the take's first or last frame (the fill extrapolates
    there).  hidden (frame, corner) -> (frame, corner) bool"""
    from_start = np.logical_and.accumulate(hidden, axis=0)
    to_end = np.logical_and.accumulate(hidden[::-1], axis=0)[::-1]
    return from_start | to_end


def synthetic_take(body, solver, face, bary, cells, args, rng: np.random.Generator) -> dict:
    from mocapflow.tasks.shared import mesh_body as mb
    from mocapflow.tasks.shared.kinematics import world_rotations
    from mocapflow.tasks.suit.body_fit import fit_body
    from mocapflow.tasks.suit.fill import cotangent_laplacian, fill_sequence, repose, skinning_transforms, unpose

    local, root = smooth_motion(solver, args.frames, rng)
    posed = mb.pose_mesh(body, world_rotations(local, body.bone_parents), root).vertices
    corners = on_mesh(posed, body.faces, face, bary)  # (frame, corner, 3)
    v = posed[:, body.faces[face]]
    normal = np.cross(v[..., 1, :] - v[..., 0, :], v[..., 2, :] - v[..., 0, :])
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    flesh = smooth_field(on_mesh(body.vertices, body.faces, face, bary), args.frames, rng, 0.004)
    truth = corners + (flesh * normal).sum(-1, keepdims=True) * normal  # non-articulated: along the skin's normal
    hidden = occluded(on_mesh(body.vertices, body.faces, face, bary), args.frames, args.hidden, rng)
    observed = np.where(hidden[..., None], np.nan, truth + rng.normal(0, args.noise_mm / 1000.0, truth.shape))
    with Clock() as fit_clock:
        suit = fit_body(solver, observed, face, bary)
    transforms = skinning_transforms(suit.weights, suit.bone_transforms)
    with Clock() as fill_clock:
        filled, _ = fill_sequence(unpose(observed, transforms) - suit.rest, cotangent_laplacian(suit.rest, cells))
    unfilled = np.isnan(filled).any(-1)
    result = repose(suit.rest + np.nan_to_num(filled), transforms)
    body_only = repose(np.broadcast_to(suit.rest, truth.shape), transforms)
    ends = at_ends(hidden)
    err = {f"{name}{part}": 1000 * np.linalg.norm(x - truth, axis=-1)[sel] for name, x in
           (("fill", result), ("body", body_only)) for part, sel in (("", hidden), ("_inside", hidden & ~ends),
                                                                    ("_at_ends", ends))}
    return {"fit_s": round(fit_clock.seconds[0], 2), "fit_cpu_s": round(fit_clock.seconds[1], 2),
            "fill_s": round(fill_clock.seconds[0], 2), "fill_cpu_s": round(fill_clock.seconds[1], 2),
            "hidden_share": round(float(hidden.mean()), 3), "at_ends_share": round(float(ends.mean()), 3),
            "unfilled_share": round(float(unfilled[hidden].mean()), 4), "borrowed_frames": int(suit.borrowed.sum()),
            **{f"{k}_median_mm": round(float(np.median(e)), 2) for k, e in err.items()},
            **{f"{k}_p95_mm": round(float(np.percentile(e, 95)), 2) for k, e in err.items()},
            "observed_fit_median_mm": round(float(np.median(1000 * np.linalg.norm(body_only - truth,
                                                                                  axis=-1)[~hidden])), 2)}


def main() -> None:
    import torch

    from mocapflow.tasks.shared import mesh_body as mb
    from mocapflow.tasks.shared.solver_body import SolverBody

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--spacing", type=float, default=0.0145, help="suit grid spacing in texture units")
    ap.add_argument("--hidden", type=float, default=0.3)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--noise-mm", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--no-kkt", action="store_true", help="time the reduced solve only")
    args = ap.parse_args()
    torch.set_num_threads(1)
    body = mb.mesh_body(mb.Phenotype())
    face, bary, rest, cells = suit_layout(body, args.spacing)
    rng = np.random.default_rng(args.seed)
    out = {"frames": args.frames, "corners": len(rest), "cells": len(cells)}
    out.update(time_windows(rest, cells, args, rng))
    out.update(synthetic_take(body, SolverBody(body), face, bary, cells, args, rng))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
