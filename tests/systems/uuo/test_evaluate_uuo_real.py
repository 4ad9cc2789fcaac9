"""Scoring an unlabelled solve of a recorded take against its labelled reference: the labelling's consistency."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.systems.uuo.evaluate import label_consistency


def test_consistency_counts_the_frames_of_each_label_on_its_majority_part():
    seen = np.ones((10, 4, 3))
    seen[6:, 0] = np.nan  # LASI's first fragment: frames 0-5 (6 frames)
    seen[:6, 1] = np.nan  # its second fragment: frames 6-9 (4 frames)
    seen[5:, 3] = np.nan  # C7: frames 0-4
    parts = np.array(["hips", "left_thigh", "hips", ""])
    out = label_consistency(["LASI", "LASI", "RASI", "C7"], parts, seen, {"LASI": "hips", "RASI": "torso", "C7": "torso"})
    assert out["LASI"] == {"frames": 10, "majority": "hips", "fragments": 2, "consistent": 0.6, "agrees": 0.6}
    assert out["RASI"]["consistent"] == 1.0 and out["RASI"]["agrees"] == 0.0
    assert out["C7"] == {"frames": 5, "majority": "", "fragments": 1, "consistent": 0.0, "agrees": 0.0}
    assert pytest.approx(np.mean([r["consistent"] for r in out.values()])) == (0.6 + 1.0 + 0.0) / 3


def test_a_solve_turned_round_or_with_its_sides_swapped_is_counted_against_the_reference():
    import xarray as xr
    from scipy.spatial.transform import Rotation

    from mocapflow.systems.uuo.evaluate import over_takes, score_against_reference
    from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES
    from mocapflow.tasks.shared.solver_body import BodyFit
    from mocapflow.tasks.uuo import solve

    frames, labels = 4, ["LKNE", "RKNE", "LANK", "RANK"]
    markers = xr.Dataset(coords={"frame": np.arange(frames), "marker": np.array(labels, dtype=object)},
                         attrs={"fps": 100.0})
    phenotype = {k: 0.5 for k in PHENOTYPE_NAMES}
    body, solver = solve._bodies(phenotype)
    rest = BodyFit(np.broadcast_to(np.eye(3), (frames, len(body.bone_names), 3, 3)).copy(),
                   np.broadcast_to(body.rest_heads[0], (frames, 3)).copy(), np.full(6, 0.5))
    names = list(body.bone_names)
    vertex = np.array([np.flatnonzero(body.vertex_bone == names.index(b))[0]
                       for b in ("lowerleg01.L", "lowerleg01.R", "foot.L", "foot.R")])

    def solved(fit, vertices, yaw=0.0):
        return solve.body_dataset(markers, body, solver, fit, vertices, np.zeros(4), {},
                                  {"yaw_deg": yaw, "chamfer": 0.0, "parts": ["body"]})

    reference = solved(rest, vertex)
    positions = np.repeat(reference["joints"].values[:, 13:14].astype(np.float64), 4, axis=1)  # any samples
    same = score_against_reference(solved(rest, vertex), reference, labels, positions, positions)
    assert (same["turned"], same["mirrored"], same["mpjpe_mm"]) == (0.0, 0.0, 0.0) and same["agreement"] == 1.0
    half = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    turned_local = rest.local.copy()
    turned_local[:, 0] = half
    turned = score_against_reference(solved(BodyFit(turned_local, rest.root, rest.phenotype), vertex), reference,
                                     labels, positions, positions)
    assert turned["turned"] == 1.0 and turned["facing_error_deg"] == pytest.approx(180.0)
    swapped = score_against_reference(solved(rest, vertex[[1, 0, 3, 2]]), reference, labels, positions, positions)
    assert swapped["mirrored"] == 1.0 and swapped["turned"] == 0.0 and swapped["agreement"] == 0.0
    summary = over_takes([same, turned, swapped])
    assert (summary["turned_takes"], summary["mirrored_takes"], summary["too_close_takes"], summary["takes"]) == \
        (1, 1, 0, 3)
    assert summary["agreement"] == 1.0 and summary["mpjpe_mm"] == 0.0  # medians over the three takes
    assert "turned" not in summary and "turned_p90" not in summary  # counted, never a median
