"""Figures of the mesh studio: the Kinect-like sensors on the Anny body, and grey cameras with surface markers.

    python docs/make_mesh_figures.py     # writes docs/studio/mesh_kinect.png and docs/studio/mesh_grey.png
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mocapflow.tasks.shared.cameras import Camera
from mocapflow.tasks.shared.mesh_body import random_surface_points
from mocapflow.tasks.studio import mesh_render
from mocapflow.tasks.shared.cameras import look_at
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec

OUT = Path(__file__).resolve().parent / "studio"


def kinect_panel() -> np.ndarray:
    rig = build_rig(SequenceSpec("kick_box_kicking", frames=24, seed=4, body="mesh", random_layout=True))
    ds = synthesize(rig, 14, 15)
    rows = []
    for v in range(ds.sizes["view"]):
        depth = ds.depth.values[v, 0].astype(np.float32)
        col = cv2.applyColorMap(np.clip((depth - 1000) / 3000 * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)
        col[depth == 0] = 0  # reflectors (and invalid pixels) are black, as in DeepMoCap Fig. 4
        ir = cv2.cvtColor(np.clip(ds.ir.values[v, 0] / 64000 * 765, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        ids = np.zeros_like(col)
        rid = ds.gt_reflector_id.values[v, 0]
        ids[rid >= 0] = cv2.applyColorMap((rid[rid >= 0].astype(np.uint8) * 9).reshape(-1, 1), cv2.COLORMAP_HSV)[:, 0]
        ids[(rid < 0) & ds.gt_body.values[v, 0]] = 60
        for (x, y), seen in zip(ds.gt_reflectors2d.values[v, 0], ds.gt_visible.values[v, 0]):
            if seen:
                cv2.circle(ids, (int(round(x)), int(round(y))), 3, (255, 255, 255), 1)
        rows.append(np.hstack([col, ir, ids]))
    return np.vstack(rows)


def grey_panel() -> np.ndarray:
    rig = build_rig(SequenceSpec("side_reaches", frames=30, seed=6, body="mesh"))
    body, f = rig.body, 20
    verts = rig.take.posed.vertices[f]
    yy, xx = np.mgrid[0:1024, 0:1024]
    texture = np.where(((yy // 64) + (xx // 64)) % 2 == 0, 0.85, 0.2)
    faces, bary = random_surface_points(body, np.random.default_rng(0), 40, "right_arm")
    points, normals = mesh_render.surface_points(verts, body.faces, faces, bary, 0.0095)  # markers 9.5 mm off the skin
    scene = mesh_render.MeshScene(verts, body.faces)
    panels = []
    for a in (100, 20, 260):
        position = (3.0 * np.cos(np.radians(a)), 3.0 * np.sin(np.radians(a)), 1.5)
        cam = Camera("grey", 800.0, 800.0, 639.5, 359.5, (-0.08, 0.02, 0.0, 0.0, 0.0), look_at(position, (0, 0, 1.0)),
                     1280, 720)
        hits = mesh_render.cast_view(scene, cam, cam.pixel_rays())
        image = mesh_render.grey_image(mesh_render.radiance(hits, verts, body.faces, body.uv, texture,
                                                            mesh_render.Lighting()), np.random.default_rng(a))
        panel = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        xy, visible = mesh_render.visibility(scene, cam, points, normals)
        for (x, y), seen in zip(xy, visible):
            colour = (0, 220, 0) if seen else (0, 0, 255)
            cv2.circle(panel, (int(round(x)), int(round(y))), 5, colour, -1 if seen else 1)
        panels.append(panel[:, 340:940])
    return np.hstack(panels)


def main() -> None:
    OUT.mkdir(exist_ok=True)
    cv2.imwrite(str(OUT / "mesh_kinect.png"), cv2.resize(kinect_panel(), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    cv2.imwrite(str(OUT / "mesh_grey.png"), cv2.resize(grey_panel(), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))


if __name__ == "__main__":
    main()
