"""CornerdetNet (tasks/suit/corners.py) trained on studio renders and measured on held-out ones.

    taskset -c 0 python benchmarks/suit_corners.py [--cache DIR] [--weights /tmp/cornerdet.pt] [--overlay PNG]
    taskset -c 0 python benchmarks/suit_corners.py --load /tmp/cornerdet.pt     # score saved weights only

Training: the procedural exercises, seeds < 9000, the "small" suit, 6 views x 2 frames of 5 takes. Held out: the
CMU walk, seed 9001, the "medium" suit, 8 views x 2 frames (and 4 zoomed-in views, for timing a frame the body
fills more of). Renders are cached as .npz under --cache. Prints one JSON line: how the network was trained
(wall and CPU seconds, settings), detection rates of readable and of visible true corners (a detection within
1.5 px), false detections per image, localisation error (mean, p99) of the detected readable corners, and ms per
megapixel of ``detect_corners`` on one thread (CPU time of the process, and wall time).

Truth. The texture prints square edges on texel boundaries, up to half a texel (about 0.35 px, more where the UV
layout is stretched) from a corner's exact texture coordinate; the truth here is where the printed pattern puts
each corner, and the error against the nominal corners (``film``'s corners2d) is reported beside it. Positives are
the readable suit corners. Besides the suit's corners (those of coded squares) the image shows other X-junctions of
the printed board: corners of uncoded squares, squares meeting across UV seams, other charts sharing the texture.
They are found from the renderer's per-pixel texture coordinates (:func:`seen_junctions`); training keeps its
negatives clear of them, and false detections are counted both against the suit's visible corners alone and
against every X-junction the image shows.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from mocapflow.formats.bvh import parse_bvh  # noqa: E402
from mocapflow.tasks.shared import mesh_body as mb  # noqa: E402
from mocapflow.tasks.suit import takes as st  # noqa: E402
from mocapflow.tasks.deepmocap.film import synth  # noqa: E402
from mocapflow.tasks.studio.spec import SequenceSpec  # noqa: E402
from mocapflow.tasks.studio.mesh_render import (NO_HIT, MeshScene, cast_view, interpolate,  # noqa: E402
                                                 surface_points, visibility)
from mocapflow.tasks.suit import corners as co  # noqa: E402
from mocapflow.tasks.suit import networks  # noqa: E402
from mocapflow.tasks.suit import pattern as pt  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MOTIONS = Path(os.environ.get("MOCAPFLOW_MOTIONS", ROOT.parent / "shared" / "data" / "motions"))
# (motion, seed, camera ring radius m): procedural exercises, seeds < 9000, the small suit
TRAIN = (("classic_squat", 101, 2.6), ("jumping_jack", 102, 3.0), ("forward_lunge_left_right", 103, 3.4),
         ("side_reaches", 104, 2.8), ("kick_box_kicking", 105, 3.2))
TEST = ("cmu_12_01_walk.bvh", 9001, 3.0)  # held out: a CMU clip, a held-out subject, the medium suit
TEST_FRAMES = range(40, 90, 25)  # the walk crosses the ring's centre (its ends leave most views)
TRAIN_FRAMES = range(10, 60, 25)
CLOSE_VIEW_M, CLOSE_FRAMES = 1.6, range(65, 66)  # timing: four views of the walk zoomed in (the body fills more)
MATCH_PX = 1.5


def printed_grid(suit: pt.Suit, body: mb.MeshBody, texture_px: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Where the texture prints every checkerboard corner of the suit's chart: the suit's corners first (in its
    order), then the X-junctions of uncoded squares. -> face (n,), bary (n, 2), the number of suit corners"""
    chart = np.flatnonzero(suit.face_panel >= 0)
    s, off = suit.size.square_uv, np.zeros(2)
    lo, hi = suit.face_uv[chart].reshape(-1, 2).min(axis=0), suit.face_uv[chart].reshape(-1, 2).max(axis=0)
    i0, j0 = np.floor((lo - off) / s).astype(int)
    i1, j1 = np.ceil((hi - off) / s).astype(int)
    gi, gj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
    grid = np.column_stack([gi.ravel(), gj.ravel()])
    uv = grid * s + off  # exact grid points
    probes = np.array([(0.0, 0.0), (0.3, 0.3), (-0.3, 0.3), (0.3, -0.3), (-0.3, -0.3)]) * s
    pf, _ = pt.locate(suit.face_uv, chart, (uv[:, None] + probes[None]).reshape(-1, 2))
    junction = (pf.reshape(len(uv), len(probes)) >= 0).all(axis=1)  # four printed squares around the point
    index = {tuple(g): n for n, g in enumerate(grid)}
    suit_idx = np.array([index[tuple(g)] for g in suit.corner_grid])
    extra = np.setdiff1d(np.flatnonzero(junction), suit_idx)
    order = np.concatenate([suit_idx, extra])
    # texture column c is coloured at u = (c + 0.5) / t, row r at v = 1 - (r + 0.5) / t; bilinear look-ups put the
    # printed edge midway between the last texel of one colour and the first of the other
    u_p = np.ceil(uv[order, 0] * texture_px - 0.5) / texture_px
    t_p = np.floor((1 - uv[order, 1]) * texture_px - 0.5) + 0.5
    v_p = 1 - (t_p + 0.5) / texture_px
    face, bary = pt.locate(suit.face_uv, chart, np.column_stack([u_p, v_p]))
    return face, bary, len(suit_idx)


def printed_board(texture: np.ndarray) -> np.ndarray:
    """Texels printed with the board (not bare skin); the blurred edges between squares, grey like the bare skin,
    count through their neighbours.  (t, t) -> (t, t) bool"""
    board = (np.abs(texture - pt.BARE) > 0.15).astype(np.uint8)
    return cv2.dilate(board, np.ones((5, 5), np.uint8)) > 0


RING = np.array([(0, 3), (1, 3), (2, 2), (3, 1), (3, 0), (3, -1), (2, -2), (1, -3), (0, -3), (-1, -3), (-2, -2),
                 (-3, -1), (-3, 0), (-3, 1), (-2, 2), (-1, 3)])  # 16 pixels on a circle of radius 3 (dx, dy)


def seen_junctions(rig: st.SuitRig, scene: MeshScene, v: int, board_texels: np.ndarray) -> tuple[np.ndarray, float]:
    """Every X-junction the printed board shows in the image, a suit corner or not (uncoded squares, squares meeting
    across a UV seam, other charts sharing the texture): pixels around which a ring of radius 3 px sees the board's
    square colours (glyphs aside, noise-free) change exactly four times: a disc around each junction, whose centre
    is returned. -> (k, 2) (x, y), within about half a pixel of a junction, and the share of pixels the body covers"""
    hits = cast_view(scene, rig.cameras[v], rig.rays[v])
    hit = hits.face != NO_HIT
    uv = np.zeros(hit.shape + (2,))
    uv[hit] = interpolate(rig.suit.face_uv, hits.face[hit], hits.bary[hit])
    t = rig.texture.shape[0]
    board = hit & board_texels[np.clip(np.rint((1 - uv[..., 1]) * t - 0.5).astype(int), 0, t - 1),
                               np.clip(np.rint(uv[..., 0] * t - 0.5).astype(int), 0, t - 1)]
    sq = np.floor(uv / rig.suit.size.square_uv).astype(np.int64)
    colour = np.pad(np.where(board, sq.sum(axis=-1) % 2, -1).astype(np.int8), 3, constant_values=-1)
    h, w = hit.shape
    ring = np.stack([colour[3 + dy:3 + dy + h, 3 + dx:3 + dx + w] for dx, dy in RING])  # (16, y, x)
    changes = (ring != np.roll(ring, 1, axis=0)).sum(axis=0)
    near = ((ring >= 0).all(axis=0) & (changes == 4)).astype(np.uint8)  # a disc of radius ~3 around each junction
    _, _, stats, centres = cv2.connectedComponentsWithStats(near, connectivity=8)
    return centres[1:][stats[1:, cv2.CC_STAT_AREA] >= 5], float(hit.mean())  # the discs' centres


def render_take(motion: str, seed: int, radius: float, suit_name: str, frames: range, cameras: int,
                cache: Path, view_height_m: float = st.SuitCameras.view_height_m) -> dict:
    """Images and truth of one take (cached): printed corners2d/visible (suit's then uncoded squares'),
    the nominal corners2d/visible/readable of the suit's corners."""
    path = cache / f"{Path(motion).stem}_{seed}_{suit_name}_{cameras}_{radius}_{frames.start}_{frames.stop}_" \
                   f"{frames.step}_{view_height_m}_v4.npz"
    if path.exists():
        return dict(np.load(path))
    ref = mb.mesh_body(mb.Phenotype())
    suit = pt.make_suit(ref, pt.SUITS[suit_name])
    if motion.endswith(".bvh"):
        spec = SequenceSpec(motion="bvh", body="mesh", frames=frames.stop, views=1, seed=seed)
        rig0 = synth.build_rig(spec, parse_bvh((MOTIONS / motion).read_text()))
    else:
        rig0 = synth.build_rig(SequenceSpec(motion=motion, body="mesh", frames=frames.stop, views=1, seed=seed))
    ring = st.SuitCameras(count=cameras, radius=radius, view_height_m=view_height_m)
    rig = st.suit_rig(rig0.body, suit, ring, st.SuitLook(), seed=seed)
    verts = rig0.take.posed.vertices
    out = st.film(rig, verts, frames)
    face, bary, n_suit = printed_grid(suit, ref, rig.look.texture_px)
    ok = face >= 0
    nv, nf = out.image.shape[:2]
    xy = np.full((nv, nf, len(face), 2), np.nan)
    seen = np.zeros((nv, nf, len(face)), bool)
    junctions, count, coverage = [], np.zeros((nv, nf), np.int64), np.zeros((nv, nf))
    board_texels = printed_board(rig.texture)
    for i, f in enumerate(frames):
        scene = MeshScene(verts[f], rig.body.faces)
        points, normals = surface_points(verts[f], rig.body.faces, face[ok], bary[ok])
        for v, cam in enumerate(rig.cameras):
            xy[v, i, ok], seen[v, i, ok] = visibility(scene, cam, points, normals)
            found, coverage[v, i] = seen_junctions(rig, scene, v, board_texels)
            junctions.append(found)
            count[v, i] = len(found)
    data = {"image": out.image, "corners2d": xy, "visible": seen, "n_suit": np.array(n_suit),
            "nominal2d": out.corners2d, "nominal_visible": out.visible, "readable": out.readable,
            "junctions": np.concatenate(junctions), "junction_count": count, "coverage": coverage}
    cache.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **data)
    return data


def junctions_of(take: dict, v: int, i: int) -> np.ndarray:
    """The seen junctions of view v, frame i (stored frame by frame, view by view).  -> (k, 2)"""
    nv = take["junction_count"].shape[0]
    order = take["junction_count"].T.ravel()  # frame-major, as rendered
    k = i * nv + v
    start = int(order[:k].sum())
    return take["junctions"][start:start + int(order[k])]


def image_truth(take: dict, v: int, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Every corner the image shows: the printed corners (visible or not) and the seen junctions no printed corner
    accounts for (within 1.5 px). -> corners2d (n, 2), visible (n,)"""
    xy, seen = take["corners2d"][v, i], take["visible"][v, i]
    junctions = junctions_of(take, v, i)
    if seen.any() and len(junctions):
        junctions = junctions[cKDTree(xy[seen]).query(junctions)[0] > MATCH_PX]
    return np.concatenate([xy, junctions]), np.concatenate([seen, np.ones(len(junctions), bool)])


def training_samples(cache: Path, config: co.SampleConfig, cameras: int, frames: range, positives: str
                     ) -> co.CornerSamples:
    """Crops of every training view-frame; positives: the readable suit corners (or any visible corner)."""
    rng = np.random.default_rng(2021)
    parts = []
    for motion, seed, radius in TRAIN:
        take = render_take(motion, seed, radius, "small", frames, cameras, cache)
        n_suit = int(take["n_suit"])
        for v in range(take["image"].shape[0]):
            for i in range(take["image"].shape[1]):
                xy, seen = image_truth(take, v, i)
                allowed = np.zeros(len(xy), bool)  # positives: the suit's corners, readable or visible
                allowed[:n_suit] = take["readable"][v, i] if positives == "readable" else seen[:n_suit]
                parts.append(co.corner_samples(take["image"][v, i], xy, seen, config, rng, positive=allowed))
    return co.concat_samples(parts)


def _distance(truth: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Each point's distance to the nearest truth point (inf without any).  -> (n,)"""
    if not len(truth) or not len(points):
        return np.full(len(points), np.inf)
    return cKDTree(truth).query(points)[0]


def score(dets: list[co.Corners], take: dict) -> dict:
    """Detection rates, false detections and localisation errors over every held-out view-frame."""
    n_suit = int(take["n_suit"])
    tallies = {k: [] for k in ("readable_hit", "visible_hit", "err_printed", "err_nominal", "false_suit", "false_all")}
    k = 0
    for v in range(take["image"].shape[0]):
        for i in range(take["image"].shape[1]):
            det = dets[k]
            k += 1
            xy, seen = take["corners2d"][v, i], take["visible"][v, i]
            readable = take["readable"][v, i] & seen[:n_suit]
            tree = cKDTree(det.xy) if len(det.xy) else None
            d, j = tree.query(np.nan_to_num(xy[:n_suit], nan=-1e6)) if tree else (np.full(n_suit, np.inf), None)
            hit = d <= MATCH_PX
            tallies["readable_hit"].append(hit[readable])
            tallies["visible_hit"].append(hit[seen[:n_suit]])
            good = readable & hit
            tallies["err_printed"].append(d[good])
            tallies["err_nominal"].append(np.linalg.norm(det.xy[j[good]] - take["nominal2d"][v, i][good], axis=1)
                                          if tree else np.zeros(0))
            near_suit = _distance(xy[:n_suit][seen[:n_suit]], det.xy) <= MATCH_PX
            near_any = ((_distance(xy[seen], det.xy) <= MATCH_PX)
                        | (_distance(junctions_of(take, v, i), det.xy) <= MATCH_PX))
            tallies["false_suit"].append(int((~near_suit).sum()))
            tallies["false_all"].append(int((~near_any).sum()))
    cat = {k: np.concatenate(x) if k not in ("false_suit", "false_all") else np.array(x) for k, x in tallies.items()}
    return {"images": k, "readable_corners": int(cat["readable_hit"].size),
            "readable_detected": float(cat["readable_hit"].mean()), "visible_corners": int(cat["visible_hit"].size),
            "visible_detected": float(cat["visible_hit"].mean()),
            "false_per_image_vs_suit_corners": float(cat["false_suit"].mean()),
            "false_per_image_vs_all_seen_corners": float(cat["false_all"].mean()),
            "error_px_mean": float(cat["err_printed"].mean()),
            "error_px_p99": float(np.percentile(cat["err_printed"], 99)),
            "error_px_mean_vs_nominal": float(cat["err_nominal"].mean()),
            "error_px_p99_vs_nominal": float(np.percentile(cat["err_nominal"], 99))}


def timing(images: np.ndarray, net: torch.nn.Module, config: co.DetectConfig, runs: int) -> dict:
    """ms per megapixel of detect_corners per image, the fastest of ``runs``: CPU time of this process (what one
    core spends, whatever else the machine runs) and wall time. -> medians and maxima over the images"""
    cpu, wall = [], []
    for img in images:
        co.detect_corners(img, net, config)
        c, w = [], []
        for _ in range(runs):
            t, p = time.perf_counter(), time.process_time()
            co.detect_corners(img, net, config)
            c.append(time.process_time() - p)
            w.append(time.perf_counter() - t)
        cpu.append(1000 * min(c) / (img.size / 1e6))
        wall.append(1000 * min(w) / (img.size / 1e6))
    return {"ms_per_mp_cpu": statistics.median(cpu), "ms_per_mp_cpu_max": max(cpu),
            "ms_per_mp_wall": statistics.median(wall), "ms_per_mp_wall_max": max(wall)}


def write_overlay(path: Path, image: np.ndarray, det: co.Corners, truth: np.ndarray, seen: np.ndarray) -> None:
    """Detections (green crosses) and visible true corners (red circles) on a 300 x 300 crop around the middle of
    the visible corners, magnified 3x."""
    cx, cy = np.median(truth[seen], axis=0).astype(int)
    y0, x0 = max(cy - 150, 0), max(cx - 150, 0)
    s = 3
    crop = cv2.resize(image[y0:y0 + 300, x0:x0 + 300], None, fx=s, fy=s, interpolation=cv2.INTER_NEAREST)
    col = cv2.cvtColor(crop, cv2.COLOR_GRAY2BGR)

    def at(p):
        return int(round(((p[0] - x0) + 0.5) * s * 16 - 8)), int(round(((p[1] - y0) + 0.5) * s * 16 - 8))

    for p in truth[seen]:
        cv2.circle(col, at(p), 5 * 16, (0, 0, 255), 1, cv2.LINE_AA, shift=4)
    for p in det.xy:
        x, y = at(p)
        cv2.line(col, (x - 64, y), (x + 64, y), (0, 255, 0), 1, cv2.LINE_AA, shift=4)
        cv2.line(col, (x, y - 64), (x, y + 64), (0, 255, 0), 1, cv2.LINE_AA, shift=4)
    cv2.imwrite(str(path), col)


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=Path("/tmp/suit_corners_cache"), help="rendered takes (.npz)")
    parser.add_argument("--weights", type=Path, default=Path("/tmp/cornerdet.pt"), help="trained state_dict out")
    parser.add_argument("--load", type=Path, help="skip training: score these weights")
    parser.add_argument("--overlay", type=Path, default=Path("/tmp/cornerdet_overlay.png"))
    parser.add_argument("--iterations", type=int, default=co.TrainConfig.iterations)
    parser.add_argument("--batch", type=int, default=co.TrainConfig.batch)
    parser.add_argument("--learning-rate", type=float, default=co.TrainConfig.learning_rate)
    parser.add_argument("--train-cameras", type=int, default=6)
    parser.add_argument("--test-cameras", type=int, default=8)
    parser.add_argument("--recrops", type=int, default=co.DetectConfig.recrops)
    parser.add_argument("--threshold", type=float, default=co.DetectConfig.threshold)
    parser.add_argument("--timing-runs", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--positives", choices=("readable", "visible"), default="readable",
                        help="which true corners are positives (the others are neither positive nor negative)")
    return parser.parse_args()


def trained(args: argparse.Namespace) -> tuple[torch.nn.Module, dict]:
    """The network (trained here, or loaded) and how it was trained."""
    train = co.TrainConfig(iterations=args.iterations, batch=args.batch, learning_rate=args.learning_rate)
    if args.load:
        net = networks.CornerdetNet(train.net)
        net.load_state_dict(torch.load(args.load, weights_only=True))
        return net.eval(), {"weights": str(args.load), "widths": train.net.widths, "hidden": train.net.hidden}
    t0 = time.perf_counter()
    samples = training_samples(args.cache, co.SampleConfig(), args.train_cameras, TRAIN_FRAMES, args.positives)
    t_samples = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    net, _ = co.train_cornerdet(samples, train, seed=args.seed)
    t_train, cpu_train = time.perf_counter() - t0, time.process_time() - c0
    torch.save(net.state_dict(), args.weights)
    return net, {"weights": str(args.weights), "train_seconds": round(t_train, 1),
                 "train_cpu_seconds": round(cpu_train, 1), "sample_seconds": round(t_samples, 1),
                 "train_crops": len(samples), "train_positives": int(samples.present.sum()),
                 "positives": args.positives, "iterations": train.iterations, "batch": train.batch,
                 "learning_rate": train.learning_rate, "position_weight": train.position_weight,
                 "widths": train.net.widths, "hidden": train.net.hidden}


def main() -> None:
    args = arguments()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    net, how = trained(args)
    motion, seed, radius = TEST
    take = render_take(motion, seed, radius, "medium", TEST_FRAMES, args.test_cameras, args.cache)
    detect = co.DetectConfig(recrops=args.recrops, threshold=args.threshold)
    images = take["image"].reshape(-1, *take["image"].shape[2:])
    dets = [co.detect_corners(img, net, detect) for img in images]
    figures = score(dets, take)
    figures.update(timing(images, net, detect, args.timing_runs))
    figures["coverage_median"] = float(np.median(take["coverage"])) if "coverage" in take else None
    close = render_take(motion, seed, radius, "medium", CLOSE_FRAMES, 4, args.cache, CLOSE_VIEW_M)
    closeup = timing(close["image"].reshape(-1, *close["image"].shape[2:]), net, detect, args.timing_runs)
    figures.update({f"closeup_{k}": x for k, x in closeup.items()})
    figures["closeup_coverage_median"] = float(np.median(close["coverage"]))
    k = int(np.argmax([len(d.xy) for d in dets]))
    v, i = divmod(k, take["image"].shape[1])
    write_overlay(args.overlay, images[k], dets[k], take["corners2d"][v, i], take["visible"][v, i])
    print(json.dumps({**how, "recrops": detect.recrops, "threshold": detect.threshold,
                      "threads": torch.get_num_threads(), "overlay": str(args.overlay),
                      **{k: round(x, 4) if isinstance(x, float) else x for k, x in figures.items()}}))


if __name__ == "__main__":
    main()
