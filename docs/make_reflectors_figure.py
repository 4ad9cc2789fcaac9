"""Figures of the 2D reflector estimation on the held-out split (run `mocapflow evaluate --catalog
benchmarks/capsule.yaml` first, so the artifacts exist):

- docs/stages/reflectors2d.png: accepted estimates (coloured, labelled) and ground truth (white rings)
  on I_CD of the three views, with the summed confidence maps of each view below;
- docs/stages/fcn_training_loss.png: the training loss of the committed weights.

    python docs/make_reflectors_figure.py [SEQUENCE] [FRAME]
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.schemas import get_schema

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "stages"


def _open(store, plan, stage, pid, schema):
    return store.open(stage, plan.items[pid].key, get_schema(schema))


def overlay(sequence: str, frame: int) -> np.ndarray:
    catalog = load_catalog(ROOT / "benchmarks" / "capsule.yaml", ())
    plan, store = build_plan(catalog, sequence), Store(catalog.root)
    raw = _open(store, plan, "frames", f"frames/{sequence}", "raw_sequence")
    columns = []
    for view in raw["view"].values:
        m = _open(store, plan, "masks", f"masks/{sequence}/{view}", "reflector_masks").sel(view=view, frame=frame)
        est = _open(store, plan, "reflectors2d", f"reflectors2d/{sequence}/{view}", "reflectors2d").sel(view=view, frame=frame)
        heat = _open(store, plan, "heatmaps", f"heatmaps/{sequence}/{view}", "heatmaps").sel(view=view, frame=frame)
        image = np.ascontiguousarray(m["colorized_depth"].values[..., ::-1])
        gt = raw.sel(view=view, frame=frame)
        for (u, v), px in zip(gt["gt_reflectors2d"].values, gt["gt_pixels"].values):
            if px >= 5:
                cv2.circle(image, (int(round(u)), int(round(v))), 7, (255, 255, 255), 1, cv2.LINE_AA)
        for r, name in enumerate(est["reflector"].values):
            x, y = float(est["x"][r]), float(est["y"][r])
            if np.isfinite(x):
                colour = tuple(int(c) for c in cv2.applyColorMap(np.uint8([[r * 255 // 25]]), cv2.COLORMAP_HSV)[0, 0])
                cv2.circle(image, (int(round(x)), int(round(y))), 3, colour, -1, cv2.LINE_AA)
                cv2.putText(image, str(name).lower(), (int(x) + 5, int(y) - 3), cv2.FONT_HERSHEY_PLAIN, 0.6, colour, 1)
        columns.append(np.vstack([image, _heat_panel(heat, image.shape)]))
    return np.hstack(columns)


def _heat_panel(heat, shape) -> np.ndarray:
    """The summed confidence maps warped back onto the image grid."""
    summed = np.clip(heat["confidence"].values.astype(np.float32).sum(0), 0, 1)  # (hy, hx)
    stride = int(heat.attrs["stride"])
    to_image = heat["crop"].values.reshape(2, 3)
    cells_to_crop = np.array([[stride, 0, (stride - 1) / 2], [0, stride, (stride - 1) / 2], [0, 0, 1.0]])
    m = to_image @ cells_to_crop
    warped = cv2.warpAffine((summed * 255).astype(np.uint8), m, (shape[1], shape[0]), flags=cv2.INTER_LINEAR)
    return cv2.applyColorMap(warped, cv2.COLORMAP_INFERNO)


def loss_curve(width: int = 640, height: int = 320) -> np.ndarray:
    catalog = load_catalog(ROOT / "training" / "catalog.yaml", ())
    item = build_plan(catalog).items["weights/train"]
    loss = Store(catalog.root).open("weights", item.key, get_schema("fcn_weights"))["loss"].values
    smooth = np.convolve(loss, np.ones(25) / 25, mode="valid")
    image = np.full((height, width, 3), 255, np.uint8)
    logs = np.log10(smooth)
    lo, hi = logs.min(), logs.max()
    pts = np.stack([np.linspace(40, width - 10, len(smooth)), height - 30 - (logs - lo) / (hi - lo) * (height - 60)], 1)
    cv2.polylines(image, [pts.astype(np.int32)], False, (160, 60, 20), 2, cv2.LINE_AA)
    cv2.putText(image, f"training loss (log scale, {smooth[0]:.0f} -> {smooth[-1]:.0f}) over {len(loss)} iterations",
                (40, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return image


def main() -> None:
    sequence = sys.argv[1] if len(sys.argv) > 1 else "cmu_jumping_jacks"
    frame = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    OUT.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(OUT / "reflectors2d.png"), overlay(sequence, frame))
    cv2.imwrite(str(OUT / "fcn_training_loss.png"), loss_curve())


if __name__ == "__main__":
    main()
