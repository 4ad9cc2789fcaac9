"""A joint hierarchy's motion as a BVH file holds it: the structure the file readers fill and the kernels read.

formats/bvh.py parses BVH text into a :class:`BVHClip`, formats/asf_amc.py reads an ASF skeleton and an AMC take
straight into one; the studio's retargeting onto the template (tasks/studio/retarget.py) takes it from there.
Joints come after their parents; an End Site is a joint named ``<parent>_End`` without channels. Each joint's
channels (``Xposition`` ... ``Zrotation``) are columns of ``data`` in joint order; rotation channels compose in
the order listed, in degrees; a joint's position channels replace its offset, frame by frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.kinematics import forward_kinematics


class BVHError(ValueError):
    """A BVH text (or a clip read into the same structure) that cannot be parsed or retargeted."""


@dataclass(frozen=True)
class BVHClip:
    names: tuple[str, ...]  # joints and end sites ("<parent>_End")
    parents: np.ndarray
    offsets: np.ndarray  # (joint, 3)
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    data: np.ndarray  # (frame, channel)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def forward_kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (frame, joint, 3, 3) and positions (frame, joint, 3), in the file's axes and units."""
        n = self.data.shape[0]
        local = np.tile(np.eye(3), (n, len(self.names), 1, 1))  # (frame, joint, 3, 3)
        translation = np.tile(self.offsets, (n, 1, 1))  # (frame, joint, 3): the offset, or the position channels
        col = 0
        for j, chans in enumerate(self.channels):
            values = self.data[:, col:col + len(chans)]
            col += len(chans)
            for k, chan in enumerate(chans):
                axis = chan[0].lower()
                if chan.endswith("rotation"):
                    local[:, j] = local[:, j] @ Rotation.from_euler(axis, values[:, k:k + 1], degrees=True).as_matrix()
                else:
                    translation[:, j, "xyz".index(axis)] = values[:, k]
        root = int(np.flatnonzero(self.parents < 0)[0])
        return forward_kinematics(local, translation[:, root], translation, self.parents)


def rest_positions(clip: BVHClip) -> np.ndarray:
    """Every joint's position with all rotations at zero, the root at its OFFSET, in the file's axes and units."""
    rest = np.zeros((len(clip.names), 3))  # (joint, 3); parents come before their children in a BVH
    for j, parent in enumerate(clip.parents):
        rest[j] = clip.offsets[j] + (rest[parent] if parent >= 0 else 0)
    return rest
