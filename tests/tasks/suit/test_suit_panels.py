"""The suit's sewing pattern: ten panels where a tailor would cut them, each flattened with little stretch, packed
into one print without overlap, the body's up pointing up the print."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.suit import panels as sp
from mocapflow.tasks.shared.flatten import stretch
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body


@pytest.fixture(scope="module")
def body():
    return mesh_body(Phenotype())


@pytest.fixture(scope="module")
def lay(body):
    return sp.layout(body, 0.031, 28, 2048)


def test_panels_are_cut_where_a_tailor_would_cut_them(body, lay):
    centre = np.array([body.vertices[body.faces[lay.panel == p]].mean(axis=(0, 1)) for p in range(len(sp.PANELS))])
    name = dict(zip(sp.PANELS, centre))
    assert set(np.unique(lay.panel)) == set(range(-1, len(sp.PANELS)))
    for region in sp.REGIONS:
        assert name[f"{region}_front"][1] > name[f"{region}_back"][1]  # the body faces +Y
    for limb in ("sleeve", "leg"):
        assert name[f"left_{limb}_front"][0] < -0.05 < 0.05 < name[f"right_{limb}_front"][0]  # facing +Y, up +Z: left is -X
    assert name["left_sleeve_front"][2] > name["left_leg_front"][2] + 0.5
    off = lay.panel < 0
    head = body.vertices[body.faces[off]].mean(axis=1)[:, 2] > 1.6
    assert head.any()  # the head is bare
    assert not (lay.panel[~body.skin] >= 0).any()  # only the skin is dressed


def test_each_panel_is_flat_with_little_stretch_at_one_scale(body, lay):
    per_metre = 28 / (0.031 * 2048)
    for p, name in enumerate(sp.PANELS):
        faces = np.flatnonzero(lay.panel == p)
        used, local = np.unique(body.faces[faces], return_inverse=True)
        local = local.reshape(-1, 3)
        uv = np.zeros((len(used), 2))
        uv[local.ravel()] = lay.uv[faces].reshape(-1, 2) / per_metre
        s = np.sqrt(stretch(body.vertices[used].astype(float), local, uv))  # linear stretch per face
        assert (s > 0).all(), name  # no face turned over: the print reads from outside
        assert 0.85 < np.percentile(s, 1) and np.percentile(s, 99) < 1.15, name


def test_panels_do_not_overlap_in_the_print_and_the_body_points_up_it(body, lay):
    box = np.array([[lay.uv[lay.panel == p].reshape(-1, 2).min(axis=0), lay.uv[lay.panel == p].reshape(-1, 2).max(axis=0)]
                    for p in range(len(sp.PANELS))])  # (panel, lo/hi, uv)
    gap = 2 * 28 / 2048
    for a in range(len(box)):
        for b in range(a + 1, len(box)):
            apart = (box[a, 0] >= box[b, 1] + gap - 1e-9) | (box[b, 0] >= box[a, 1] + gap - 1e-9)
            assert apart.any(), (sp.PANELS[a], sp.PANELS[b])
    assert (box >= 0).all() and (box <= 1).all()
    for p in (sp.PANELS.index("torso_front"), sp.PANELS.index("left_leg_back")):
        faces = np.flatnonzero(lay.panel == p)
        z = body.vertices[body.faces[faces]][..., 2].ravel()
        v = lay.uv[faces][..., 1].ravel()
        assert np.corrcoef(z, v)[0, 1] > 0.95  # up the body is up the print


def test_a_print_too_small_for_the_panels_is_refused(body):
    with pytest.raises(sp.PanelError, match="do not fit"):
        sp.layout(body, 0.02, 40, 2048)
