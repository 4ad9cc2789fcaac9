"""The harsh studio's frame beside the plain one: tape, clothing and the Kinect v2's artefacts switched on.

    python docs/make_harsh_figure.py     # writes docs/studio/harsh_frame.png (from the repository root)

One frame of the held-out take cmu_jumping_jacks as benchmarks/catalog.yaml films it (top) and as
benchmarks/catalog_harsh.yaml does (bottom): colorized depth (black: no depth), IR, and the IR round one strap
enlarged. On the right, the reflector set as DeepMoCap's Figure 2 draws it (straps orange, patches blue), from the
take's ground truth: the paper is stored as text only here, so its figure cannot be cropped.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.systems.deepmocap.film import StudioReader
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES, STRAPS

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "studio" / "harsh_frame.png"
FRAME = 2
ZOOM = 5
ORANGE, BLUE = (0, 140, 255), (255, 120, 0)  # BGR: Figure 2's strap and patch colours


def render(catalog: str):
    cat = load_catalog(ROOT / "benchmarks" / catalog)
    dataset = cat.datasets["heldout"]
    seq = next(s for s in StudioReader.discover(cat, dataset) if s.id == "cmu_jumping_jacks")
    return StudioReader.read(dataset, seq, FRAME, FRAME + 1)


def label(img: np.ndarray, text: str, y: int = 18) -> np.ndarray:
    cv2.putText(img, text, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def panels(ds, v: int, box, title: str) -> np.ndarray:
    depth = ds.depth.values[v, 0].astype(np.float32)
    col = cv2.applyColorMap(np.clip((depth - 1000) / 3000 * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)
    col[depth == 0] = 0
    ir = cv2.cvtColor(np.clip(ds.ir.values[v, 0] / 64000 * 765, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    y0, y1, x0, x1 = box
    # the zoom shows IR on a log scale, so that tape below saturation stands out from tape at it
    raw = ds.ir.values[v, 0, y0:y1, x0:x1].astype(np.float32)
    zoom = np.clip(np.log1p(raw) / np.log1p(65535.0) * 255, 0, 255).astype(np.uint8)
    zoom = cv2.applyColorMap(zoom, cv2.COLORMAP_INFERNO)
    zoom = cv2.resize(zoom, None, fx=ZOOM, fy=ZOOM, interpolation=cv2.INTER_NEAREST)
    zoom = cv2.copyMakeBorder(zoom, 0, max(col.shape[0] - zoom.shape[0], 0), 0, 0, cv2.BORDER_CONSTANT)
    cv2.rectangle(ir, (x0, y0), (x1, y1), (0, 255, 255), 1)
    return np.hstack([label(col, f"{title}: depth"), label(ir, "IR"), label(zoom, "IR round a strap (log)")])


def suit(ds, v: int, height: int) -> np.ndarray:
    """The reflector set drawn on the view's body silhouette, straps orange and patches blue (DeepMoCap Fig. 2)."""
    body = ds.gt_body.values[v, 0]
    img = np.zeros(body.shape + (3,), np.uint8)
    img[body] = 70
    for name, (x, y), seen in zip(REFLECTOR_NAMES, ds.gt_reflectors2d.values[v, 0], ds.gt_visible.values[v, 0]):
        colour = ORANGE if name in STRAPS else BLUE
        cv2.circle(img, (int(round(x)), int(round(y))), 5, colour, -1 if seen else 1, cv2.LINE_AA)
    label(img, "reflector set (cf. DeepMoCap Fig. 2)")
    label(img, "straps orange, patches blue", 38)
    label(img, "hollow: hidden in this view", 58)
    pad = height - img.shape[0]
    return cv2.copyMakeBorder(img, 0, pad, 0, 0, cv2.BORDER_CONSTANT)


def main() -> None:
    plain, harsh = render("catalog.yaml"), render("catalog_harsh.yaml")
    v = int(np.argmax(harsh.gt_pixels.values[:, 0].sum(axis=-1)))
    strap = REFLECTOR_NAMES.index("R_ELBOW")
    x, y = harsh.gt_reflectors2d.values[v, 0, strap]
    h, w = harsh.depth.shape[-2:]
    half = 40
    cy, cx = int(np.clip(y, half, h - half)), int(np.clip(x, half, w - half))
    box = (cy - half, cy + half, cx - half, cx + half)
    rows = np.vstack([panels(plain, v, box, "plain"), panels(harsh, v, box, "harsh")])
    figure = np.hstack([rows, suit(harsh, v, rows.shape[0])])
    OUT.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(OUT), figure)
    print(f"wrote {OUT} ({figure.shape[1]} x {figure.shape[0]}), view {v}")


if __name__ == "__main__":
    main()
