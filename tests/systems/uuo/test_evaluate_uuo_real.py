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
