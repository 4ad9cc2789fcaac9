"""A colour video of a take, as a monocular estimator sees it: one camera, the mesh body shaded with skin.

The body is ray cast (tasks/studio/mesh_render.py), lit by the studio's lights (Lambert, two directional lights
and an ambient term), coloured with one skin albedo, set before a plain grey background, with sensor noise and
8-bit quantization. What this makes easier than a real video: no clothes, hair or texture on the skin, a plain
background, no motion blur, one person always whole in view of a still camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.cameras import Camera
from mocapflow.tasks.shared.cameras import look_at
from mocapflow.tasks.studio.mesh_render import Lighting, MeshScene, cast_view, radiance


class VideoError(ValueError):
    """A video setting out of range."""


@dataclass(frozen=True)
class VideoSpec:
    """The video camera: image size, horizontal field of view, where it stands (azimuth around the capture
    centre, 90 degrees = in front of the subject's start, distance and height) and what the body looks like."""

    width: int = 640
    height: int = 480
    fov_deg: float = 60.0
    azimuth_deg: float = 90.0
    distance_m: float = 4.0
    height_m: float = 1.3
    target_height_m: float = 0.9
    skin: tuple[float, float, float] = (0.80, 0.60, 0.48)
    background: tuple[float, float, float] = (0.42, 0.44, 0.47)
    noise: float = 2.0  # std of the sensor noise, 8-bit levels

    def __post_init__(self):
        if not (16 <= self.width <= 4096 and 16 <= self.height <= 4096 and 10.0 <= self.fov_deg <= 150.0
                and self.distance_m > 0.5 and self.noise >= 0):
            raise VideoError(f"video settings out of range: width and height 16-4096 px, fov_deg 10-150, "
                             f"distance_m > 0.5, noise >= 0 (got {self})")

    def camera(self) -> Camera:
        a = np.radians(self.azimuth_deg)
        position = [self.distance_m * np.cos(a), self.distance_m * np.sin(a), self.height_m]
        f = (self.width / 2) / np.tan(np.radians(self.fov_deg / 2))
        return Camera("video", float(f), float(f), (self.width - 1) / 2, (self.height - 1) / 2, (0.0,) * 5,
                      look_at(position, [0.0, 0.0, self.target_height_m]), self.width, self.height)


def film(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, spec: VideoSpec,
         rng: np.random.Generator) -> np.ndarray:
    """Colour frames of a posed mesh: vertices (frame, vertex, 3) -> (frame, y, x, rgb) uint8."""
    cam = spec.camera()
    rays = cam.pixel_rays()
    white = np.ones((4, 4), np.float32)  # one albedo over the whole skin
    skin, background = np.asarray(spec.skin, np.float32), np.asarray(spec.background, np.float32)
    out = np.empty((len(vertices), spec.height, spec.width, 3), np.uint8)
    for k, v in enumerate(vertices):
        hits = cast_view(MeshScene(v, faces), cam, rays)
        shade = radiance(hits, v, faces, uv, white, Lighting(background=0.0))
        body = hits.face >= 0
        rgb = np.where(body[..., None], shade[..., None] * skin, background) * 255.0
        rgb += spec.noise * rng.standard_normal(rgb.shape)
        out[k] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    return out
