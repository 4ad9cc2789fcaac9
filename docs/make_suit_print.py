"""The suit's print and the suit worn: the flat print of both sizes, and the medium suit on three subjects seen from
the front and the back (rest pose, the studio's grey cameras and lights, no noise).

    python docs/make_suit_print.py     # writes docs/suit/print_medium.png, print_small.png, worn.png
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mocapflow.tasks.suit import pattern as pt
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body, random_phenotype
from mocapflow.tasks.suit import takes as st

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "suit"
PNG = [cv2.IMWRITE_PNG_COMPRESSION, 9]
SUBJECTS = (1, 2, 3)  # seeds of random_phenotype
CAMERAS = st.SuitCameras(count=2, width=600, height=1000, radius=3.0, heights=(1.2, 1.2), view_height_m=2.0,
                         distortion=0.0)
LOOK = st.SuitLook(noise=0.0, blur_px=(0.3, 0.3), light=(1.0, 1.0))


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    ref = mesh_body(Phenotype())
    suits = {name: pt.make_suit(ref, size) for name, size in pt.SUITS.items()}
    for name, suit in suits.items():
        print_ = (pt.texture(suit) * 255).astype(np.uint8)
        cv2.imwrite(str(OUT / f"print_{name}.png"), cv2.resize(print_, (1024, 1024), interpolation=cv2.INTER_AREA),
                    PNG)
    tiles = []
    for seed in SUBJECTS:
        body = mesh_body(random_phenotype(np.random.default_rng(seed)))
        rig = st.suit_rig(body, suits["medium"], CAMERAS, LOOK, seed)
        shot = st.film(rig, body.vertices[None].astype(np.float64), range(1))
        tiles.extend(shot.image[:, 0])  # front, then back
    cv2.imwrite(str(OUT / "worn.png"), np.concatenate(tiles, axis=1), PNG)


if __name__ == "__main__":
    main()
