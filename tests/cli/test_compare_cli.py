"""`mocapflow compare` on a joint take filmed by DeepMoCap, UUO and the suit: every system's joints scored against
the same truth frames, and the comparison's page drawn in a real headless browser."""

from __future__ import annotations

import re

import numpy as np
import xarray as xr

from browser import run_browser
from conftest import last_json, mocapflow, read_artifacts
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.compare import compare_plan
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.suit import joints as suit_joints
from studio_catalogs import JOINT_CATALOG

SYSTEMS = ("deepmocap", "uuo", "suit")


def _by_partition(root) -> dict:
    return {pid: arrays for (pid, _), arrays in read_artifacts(root).items()}


def test_every_system_is_scored_on_the_same_truth_frames_and_shown_side_by_side(tmp_path):
    (tmp_path / "catalog.yaml").write_text(JOINT_CATALOG)
    proc = mocapflow("compare", "--json", "--out", "page", cwd=tmp_path, timeout=1200)
    figures = last_json(proc)
    assert figures["compare_takes"] == 1 and figures["compare_frames"] == 10  # 30 fps and 10 fps meet 10 times
    # measured MPJPE: DeepMoCap 52.3 mm, UUO 17.1 mm (the catalog's exact prior), the suit 12.4 mm; each bound about
    # a quarter above its own system's figure, so a regression of any one system fails here, not only a collapse
    bounds_mm = {"deepmocap": 65.0, "uuo": 22.0, "suit": 16.0}
    for system in SYSTEMS:
        assert 0 < figures[f"compare_{system}_mpjpe_mm"] < bounds_mm[system], figures
        assert figures[f"compare_{system}_cpu_s_per_s"] > 0
        assert figures[f"compare_{system}_completeness"] == 1.0, figures  # measured: every joint on every frame
    assert "compare_deepmocap_surface_mm" not in figures
    assert figures["compare_suit_surface_mm"] < 2, figures  # measured 1.3 mm: the filled corners on their truth
    assert figures["compare_uuo_surface_mm"] < 25, figures  # measured 19.2 mm: the solved skin on the true skin

    catalog = load_catalog(tmp_path / "catalog.yaml")
    result = compare_plan(catalog, build_plan(catalog), Store(catalog.root))
    take = result["takes"]["squat"]
    np.testing.assert_allclose(take["times"], np.arange(10) / 10.0)
    stored = _by_partition(tmp_path / "storage")
    truths = {"deepmocap": stored["frames/squat.dmc"]["gt_joints"][::3],  # every third 30 fps frame
              "uuo": stored["markers/squat.uuo"]["gt_joints"][::3], "suit": stored["images/squat.suit"]["gt_joints"]}
    for system, truth in truths.items():  # each system's own stored truth at the instants compared: one truth
        assert truth.shape == (10, 20, 3)
        np.testing.assert_allclose(take["truth"], truth, atol=2e-3, err_msg=system)
    assert not np.allclose(stored["frames/squat.dmc"]["gt_joints"][1], take["truth"][1], atol=2e-3)  # not frame 1

    poses = xr.open_zarr(next((tmp_path / "storage" / "poses").glob("*/data.zarr")), consolidated=False)
    order = [[str(j) for j in poses["joint"].values].index(j) for j in JOINT_NAMES]
    filled = xr.open_zarr(next((tmp_path / "storage" / "filled").glob("*/data.zarr")), consolidated=False)
    images = stored["images/squat.suit"]
    body = mesh_body(Phenotype(**filled.attrs["phenotype"]))  # the subject as the suit's filling fitted it
    rest = suit_joints.rest_corners(body.vertices, body.faces, images["corner_face"], images["corner_bary"])
    rest_joints = body.rest_heads[body.joint_bones()]
    solved = {"deepmocap": poses["position"].values[::3][:, order],
              "uuo": stored["solve/squat.uuo"]["joints"][::3],
              "suit": suit_joints.joints_from_corners(  # the joints its filled corners carry, every 10 fps frame
                  filled["position"].transpose("frame", "corner", "xyz").values.astype(np.float64), rest,
                  rest_joints, suit_joints.joint_neighbourhoods(rest, rest_joints))}
    assert sorted(solved) == sorted(SYSTEMS) == sorted(take["systems"])  # every system compared is checked
    assert take["truth_gap_mm"] < 2
    for system, joints in solved.items():  # the scored joints are the system's own output at those frames
        assert joints.shape == (10, 20, 3) and np.isfinite(joints).all(), system
        np.testing.assert_allclose(take["systems"][system]["joints"], joints, atol=1e-6, err_msg=system)
        error = np.linalg.norm(joints - truths[system], axis=-1) * 1000
        np.testing.assert_allclose(take["systems"][system]["error_mm"], error, rtol=1e-5, atol=1e-3)
        np.testing.assert_allclose(take["systems"][system]["mpjpe_mm"], figures[f"compare_{system}_mpjpe_mm"],
                                   rtol=1e-9)
    surface = stored["filled/squat.suit"]["position"] - stored["images/squat.suit"]["gt_corners"]
    np.testing.assert_allclose(take["systems"]["suit"]["surface_mm"],
                               np.median(1000 * np.median(np.linalg.norm(surface, axis=-1), axis=1)), rtol=1e-6)

    for name in ("compare_parts.png", "compare_error_squat.png", "compare.html"):
        assert f"wrote page/{name}" in proc.stdout
    page = tmp_path / "page" / "compare.html"
    dom = run_browser(page, tmp_path, "--dump-dom")
    assert dom.returncode == 0, dom.stderr[-2000:]
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert 'data-take="squat"' in body and 'data-frames="10"' in body, body
    for system in SYSTEMS:  # one canvas per system, each drawn (floor grid, truth, its joints)
        assert int(re.search(rf'data-painted-{system}="(\d+)"', body).group(1)) > 2000, body
    assert "deepmocap: " in dom.stdout and "mm MPJPE at 0.00 s" in dom.stdout
