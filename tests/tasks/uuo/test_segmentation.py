"""UUO stage 1, rigid segmentation: markers on one bone group together, markers on different bones do not."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.mesh_body import PARTS, part_of_bone
from mocapflow.tasks.uuo import takes as uuo
from mocapflow.tasks.deepmocap.film.synth import build_rig
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.uuo import segmentation as seg


def two_bones(n_frames=60, rng=None):
    """Three markers on each of two bones turning differently about a shared joint, 0.5 mm of noise."""
    rng = rng or np.random.default_rng(0)
    t = np.linspace(0, 2 * np.pi, n_frames)
    upper = Rotation.from_rotvec(np.outer(0.6 * np.sin(t), [1, 0, 0])).as_matrix()
    lower = Rotation.from_rotvec(np.outer(1.2 * np.sin(t + 1), [0, 1, 0])).as_matrix() @ upper
    a = np.array([[0.03, 0.0, -0.1], [-0.03, 0.02, -0.2], [0.0, -0.03, -0.25]])
    b = np.array([[0.03, 0.0, -0.35], [0.0, 0.03, -0.45], [-0.02, -0.03, -0.5]])
    pos = np.concatenate([np.einsum("fij,mj->fmi", upper, a), np.einsum("fij,mj->fmi", lower, b)], axis=1)
    return pos + rng.normal(0, 0.0005, pos.shape)


def test_markers_on_two_bones_make_two_groups_and_a_lone_fragment_its_own():
    pos = two_bones()
    groups = seg.segment(pos, seg.SegmentConfig())
    assert len(set(groups[:3])) == 1 and len(set(groups[3:])) == 1 and groups[0] != groups[3]
    # one marker of the first bone hidden half the time: still with its bone; a 5-frame fragment: alone
    pos = np.concatenate([pos, pos[:, :1]], axis=1)
    pos[:30, 1] = np.nan
    pos[5:, 6] = np.nan
    groups = seg.segment(pos, seg.SegmentConfig())
    assert groups[1] == groups[0] and groups[6] not in set(groups[:6])
    spread = seg.distance_spread(pos, 10, 1.0)
    assert spread[0, 2] < 0.002 and spread[0, 3] > 0.01 and spread[0, 6] == 1.0


def test_markers_on_the_mesh_body_group_by_what_moves_rigidly_together():
    rig = build_rig(SequenceSpec("jumping_jack", frames=45, seed=14, body="mesh", views=1, variation=1.0))
    layout = uuo.layout(rig.body, np.random.default_rng(2), 40)
    paths = uuo.marker_paths(rig.body, layout, rig.take.posed.vertices[:45])
    rec = uuo.capture(paths, uuo.MarkerFaults.clean(), np.random.default_rng(3))
    groups = seg.segment(rec.positions, seg.SegmentConfig())
    truth = 1000 * seg.distance_spread(paths[:, rec.source], 10, 1.0)  # mm, without the capture's noise
    same = groups[:, None] == groups[None, :]
    assert np.median(truth[same]) < 3.0  # a group rides one bone
    assert not (same & (truth > 20.0)).any()  # markers that move apart are never grouped
    assert 6 <= groups.max() + 1 <= 30
    part_of = {b: part_of_bone(n) for b, n in enumerate(rig.body.bone_names)}
    part = np.array([part_of[rig.body.vertex_bone[rig.body.faces[f, 0]]] for f in layout.faces])[rec.source]
    limbs = {p for p in PARTS if p.startswith(("left_", "right_")) and PARTS[p] == (p,)}
    for g in np.unique(groups):  # no group mixes the left and the right side
        assert len({p.split("_")[0] for p in part[groups == g] if p in limbs}) <= 1
    trunk = groups[part == "torso"]
    assert np.bincount(trunk).max() >= 0.8 * len(trunk)  # the trunk moves as one


def test_bad_settings_are_refused():
    with pytest.raises(seg.SegmentationError, match="threshold_mm"):
        seg.SegmentConfig(threshold_mm=0)
