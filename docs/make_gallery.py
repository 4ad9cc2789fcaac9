"""Render the gallery under docs/: the studio (docs/studio/: colorized depth with reflectors black, IR and
reflector ids for three views of a few exercises, one of them also with ir_bloom_px 3, and a retargeted CMU
clip) and the input stages (docs/stages/: the FCN's inputs I_CD and I_F for three views, as in DeepMoCap's Figure 4).

    python docs/make_gallery.py
"""

from __future__ import annotations

from pathlib import Path


import cv2
import numpy as np

from mocapflow.formats.bvh import parse_bvh
from mocapflow.tasks.deepmocap.flow import DisConfig, PrimalDualConfig, dis
from mocapflow.tasks.deepmocap.masks import MaskConfig, masks
from mocapflow.tasks.deepmocap.pdflow import primal_dual
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec

OUT = Path(__file__).resolve().parent / "studio"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "motions"


def colorize_depth(depth: np.ndarray, near=1500, far=3500) -> np.ndarray:
    """JET over [near, far] mm; invalid depth (reflectors, holes, out of range) black."""
    scaled = np.clip((depth.astype(np.float32) - near) / (far - near) * 255, 0, 255).astype(np.uint8)
    img = cv2.applyColorMap(255 - scaled, cv2.COLORMAP_JET)
    img[depth == 0] = 0
    return img


def panel(ds, frame: int) -> np.ndarray:
    rows = []
    for v in range(ds.sizes["view"]):
        depth = ds.depth.values[v, frame]
        ir = cv2.cvtColor(np.clip(ds.ir.values[v, frame] / 3000.0 * 255, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        rid = ds.gt_reflector_id.values[v, frame]
        ids = np.zeros_like(ir)
        on = rid >= 0
        ids[on] = cv2.applyColorMap((rid[on] * 9 + 10).astype(np.uint8).reshape(-1, 1), cv2.COLORMAP_HSV).reshape(-1, 3)
        for r, (u, w) in enumerate(ds.gt_reflectors2d.values[v, frame]):
            if ds.gt_visible.values[v, frame, r]:
                cv2.circle(ids, (int(round(u)), int(round(w))), 2, (255, 255, 255), -1)
        row = np.hstack([colorize_depth(depth), ir, ids])
        cv2.putText(row, str(ds.view.values[v]), (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1)
        rows.append(row)
    return np.vstack(rows)


def stages_panel(name: str, spec: SequenceSpec, frame: int) -> None:
    """Per view: I_CD (masks stage), I_F from dis, I_F from primal_dual, and the true flow, colorized alike."""
    ds = synthesize(build_rig(spec), frame - 1, frame + 1)
    cd = masks(ds, MaskConfig()).colorized_depth.values[:, 1]
    flows = [dis(ds, DisConfig()), primal_dual(ds, PrimalDualConfig())]
    scale = DisConfig().color_scale_m
    truth = np.clip(128 + 127 * ds.gt_scene_flow_prev.values[:, 1].astype(np.float32) / scale, 0, 255).astype(np.uint8)
    truth[~ds.gt_body.values[:, 1]] = 128
    rows = []
    for v in range(ds.sizes["view"]):
        tiles = [cd[v]] + [f.colorized_flow.values[v, 1] for f in flows] + [truth[v]]
        row = np.hstack([t[..., ::-1] for t in tiles])  # RGB -> BGR for OpenCV
        for k, label in enumerate(("I_CD", "I_F dis", "I_F primal_dual", "true flow")):
            cv2.putText(row, label, (8 + 512 * k, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1)
        rows.append(row)
    (OUT.parent / "stages").mkdir(exist_ok=True)
    path = OUT.parent / "stages" / f"{name}.png"
    cv2.imwrite(str(path), cv2.resize(np.vstack(rows), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    print("wrote", path)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    shots = [("jumping_jack", SequenceSpec("jumping_jack", frames=16, seed=2, subject_height=1.8), None, 12),
             ("kick_box_kicking", SequenceSpec("kick_box_kicking", frames=24, seed=3, subject_height=1.74), None, 20),
             ("classic_squat", SequenceSpec("classic_squat", frames=40, seed=4, subject_height=1.62), None, 28),
             ("kick_box_kicking_bloom3",  # the same frame with regions the size of a real Kinect v2's
              SequenceSpec("kick_box_kicking", frames=24, seed=3, subject_height=1.74, ir_bloom_px=3), None, 20)]
    clip = SHARED / "cmu_14_14_jumping_jacks.bvh"
    if clip.exists():
        shots.append(("cmu_jumping_jacks", SequenceSpec("bvh", frames=40, seed=7, random_layout=True),
                      parse_bvh(clip.read_text()), 30))
    for name, spec, motion_clip, frame in shots:
        ds = synthesize(build_rig(spec, motion_clip), frame, frame + 1)
        img = panel(ds, 0)
        cv2.imwrite(str(OUT / f"{name}.png"), cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
        print("wrote", OUT / f"{name}.png")
    stages_panel("kick_box_kicking", SequenceSpec("kick_box_kicking", frames=24, seed=3, subject_height=1.74), 20)


if __name__ == "__main__":
    main()
