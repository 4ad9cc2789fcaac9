"""Render the studio gallery under docs/studio/: colorized depth (reflectors black, DeepMoCap Fig. 4 style),
IR and reflector ids for three views of a few exercises and a retargeted CMU clip.

    python docs/make_gallery.py
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mocapflow.tasks.studio.synth import SequenceSpec, build_rig, synthesize

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


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    shots = [("jumping_jack", SequenceSpec("jumping_jack", frames=16, seed=2, subject_height=1.8), None, 12),
             ("kick_box_kicking", SequenceSpec("kick_box_kicking", frames=24, seed=3, subject_height=1.74), None, 20),
             ("classic_squat", SequenceSpec("classic_squat", frames=40, seed=4, subject_height=1.62), None, 28)]
    clip = SHARED / "cmu_14_14_jumping_jacks.bvh"
    if clip.exists():
        shots.append(("cmu_jumping_jacks", SequenceSpec("bvh", frames=40, seed=7, random_layout=True),
                      clip.read_text(), 30))
    for name, spec, text, frame in shots:
        ds = synthesize(build_rig(spec, text), frame, frame + 1)
        img = panel(ds, 0)
        cv2.imwrite(str(OUT / f"{name}.png"), cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
        print("wrote", OUT / f"{name}.png")


if __name__ == "__main__":
    main()
