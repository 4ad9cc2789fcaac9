"""Ray-cast rendering of the studio: Kinect-v2-like depth and IR, reflector ids and scene flow.

Rays through every (undistorted) pixel hit the body primitives (capsules, ellipsoids), a floor
(z = 0) and a cylindrical room wall; the nearest hit wins, so limbs occlude each other. Only the
pixels inside a primitive's projected bounding sphere are tested. Depth is the camera z of the
hit in millimetres with Kinect-like artifacts (range-dependent noise, mm quantization, 0 where
invalid: reflector pixels, out of range, grazing angles; flying pixels and dropouts at silhouette
edges). IR falls off with distance and incidence, retro-reflectors saturate (DeepMoCap §3.2,
Figures 3-4: reflector regions have zero depth and clearly distinguishable IR values).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import xarray as xr

from mocapflow.schemas.raw import make_raw_sequence
from mocapflow.tasks.shared.body import JOINT_NAMES, Primitive
from mocapflow.tasks.shared.cameras import Camera
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES, Placement, label_hits

RANGE_M = (0.5, 4.5)  # Kinect v2 operating range
GRAZING_COS = 0.12  # below this incidence cosine the sensor returns no depth
ROOM_RADIUS = 4.2
ALBEDO = {"body": 0.65, "floor": 0.35, "wall": 0.5}
IR_GAIN = 24000.0  # counts for albedo 1 at 1 m, normal incidence
IR_REFLECTOR = 64000.0


@dataclass(frozen=True)
class View:
    """Per-camera constants: rays and the static room (computed once per camera)."""

    cam: Camera
    rays: np.ndarray  # (y, x, 3) unit, camera frame
    bg_t: np.ndarray  # (y, x) ray length to floor or wall
    bg_cos: np.ndarray  # (y, x) incidence cosine
    bg_albedo: np.ndarray  # (y, x)
    R: np.ndarray  # world -> camera rotation
    t: np.ndarray  # world -> camera translation


def prepare_view(cam: Camera) -> View:
    rays = cam.pixel_rays()
    w2c = cam.world_to_cam
    R, t = w2c[:3, :3], w2c[:3, 3]
    d = rays @ R  # world ray directions (y, x, 3)
    o = cam.cam_to_world[:3, 3]
    t_floor = np.where(d[..., 2] < -1e-6, -o[2] / np.minimum(d[..., 2], -1e-6), np.inf)
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = o[0] * d[..., 0] + o[1] * d[..., 1]
    c = o[0] ** 2 + o[1] ** 2 - ROOM_RADIUS**2
    t_wall = (-b + np.sqrt(np.maximum(b * b - a * c, 0))) / np.maximum(a, 1e-12)
    floor = t_floor < t_wall
    bg_t = np.where(floor, t_floor, t_wall)
    hit = o + d * bg_t[..., None]
    wall_n = -np.concatenate([hit[..., :2], np.zeros_like(hit[..., :1])], axis=-1) / ROOM_RADIUS
    normal = np.where(floor[..., None], np.array([0.0, 0.0, 1.0]), wall_n)
    bg_cos = np.abs(np.einsum("yxi,yxi->yx", normal, d))
    albedo = np.where(floor, ALBEDO["floor"], ALBEDO["wall"])
    return View(cam, rays, bg_t, bg_cos, albedo, R, t)


@dataclass(frozen=True)
class Pose:
    """World joint rotations (joint, 3, 3) and positions (joint, 3) at one instant."""

    rot: np.ndarray
    pos: np.ndarray


@dataclass(frozen=True)
class Frame:
    """One rendered view-frame."""

    depth: np.ndarray  # (y, x) uint16 mm
    ir: np.ndarray  # (y, x) uint16
    reflector_id: np.ndarray  # (y, x) int8, -1 none
    body: np.ndarray  # (y, x) bool, the body is the visible surface
    scene_flow: np.ndarray  # (y, x, 3) float32 m, camera frame: motion of the visible surface to the next frame
    scene_flow_prev: np.ndarray  # (y, x, 3) float32 m, camera frame: its motion from the previous frame
    pixels: np.ndarray  # (26,) int32 visible pixels per reflector


class FrameStack:
    """A region's rendered frames, view by view, and the raw-sequence Dataset they make with their ground truth."""

    def __init__(self, n_views: int, n_frames: int, shape: tuple[int, int], n_reflectors: int):
        h, w = shape
        self.depth = np.zeros((n_views, n_frames, h, w), np.uint16)
        self.ir = np.zeros_like(self.depth)
        self.rid = np.zeros((n_views, n_frames, h, w), np.int8)
        self.flow = np.zeros((n_views, n_frames, h, w, 3), np.float16)
        self.flow_prev = np.zeros_like(self.flow)
        self.body = np.zeros((n_views, n_frames, h, w), bool)
        self.pixels = np.zeros((n_views, n_frames, n_reflectors), np.int32)

    def put(self, v: int, i: int, frame: Frame) -> None:
        self.depth[v, i], self.ir[v, i], self.rid[v, i], self.body[v, i], self.pixels[v, i] = (
            frame.depth, frame.ir, frame.reflector_id, frame.body, frame.pixels)
        self.flow[v, i], self.flow_prev[v, i] = frame.scene_flow, frame.scene_flow_prev

    def dataset(self, views: tuple[View, ...], fps: float, start: int, reflectors3d: np.ndarray, joints: np.ndarray,
                joint_quats: np.ndarray, extra: dict | None = None) -> xr.Dataset:
        """The raw sequence of frames [start, start + n): reflectors3d (frame, 26, 3), joints (frame, 20, 3) and
        joint_quats (frame, 20, 4) of the truth, ``extra`` more ground-truth variables."""
        n = reflectors3d.shape[0]
        uv = np.stack([view.cam.project(reflectors3d.reshape(-1, 3))[0].reshape(n, -1, 2) for view in views])
        gt = {
            "gt_joints": (("frame", "joint", "xyz"), joints.astype(np.float32)),
            "gt_joint_rotations": (("frame", "joint", "quat"), joint_quats.astype(np.float32)),
            **(extra or {}),
            "gt_reflectors": (("frame", "reflector", "xyz"), reflectors3d.astype(np.float32)),
            "gt_reflectors2d": (("view", "frame", "reflector", "uv"), uv.astype(np.float32)),
            "gt_visible": (("view", "frame", "reflector"), self.pixels > 0),
            "gt_pixels": (("view", "frame", "reflector"), self.pixels),
            "gt_reflector_id": (("view", "frame", "y", "x"), self.rid),
            "gt_body": (("view", "frame", "y", "x"), self.body),
            "gt_scene_flow": (("view", "frame", "y", "x", "xyz"), self.flow),
            "gt_scene_flow_prev": (("view", "frame", "y", "x", "xyz"), self.flow_prev),
        }
        ds = make_raw_sequence(self.depth, self.ir, {view.cam.name: view.cam.as_dict() for view in views}, fps,
                               start, gt)
        return ds.assign_coords(joint=np.array(JOINT_NAMES, dtype=object),
                                reflector=np.array(REFLECTOR_NAMES, dtype=object),
                                xyz=np.array(["x", "y", "z"], dtype=object), uv=np.array(["u", "v"], dtype=object),
                                quat=np.array(["x", "y", "z", "w"], dtype=object))


def render(view: View, prims: tuple[Primitive, ...], placements: tuple[Placement, ...],
           pose: Pose, prev: Pose, nxt: Pose, rng: np.random.Generator, noise: float = 1.0, *,
           bloom_px: int = 0) -> Frame:
    """Render one view at one frame; ``prev``/``nxt`` are the poses one frame before and after. ``bloom_px``: the
    sensor's saturation spreads this many pixels round each reflector (IR saturated, no depth there)."""
    rot, pos = pose.rot, pose.pos
    h, w = view.bg_t.shape
    t_buf = view.bg_t.copy()
    prim_buf = np.full((h, w), -1, dtype=np.int16)
    normal_buf = np.zeros((h, w, 3))
    local_buf = np.zeros((h, w, 3))
    centres, radii = _bounds(view, prims, rot, pos)
    boxes = _boxes(view.cam, centres, radii)
    for k, prim in enumerate(prims):
        box = boxes[k]
        if box is None:
            continue
        y0, y1, x0, x1 = box
        d = view.rays[y0:y1, x0:x1].reshape(-1, 3)
        cam_rot = view.R @ rot[prim.joint]  # joint frame -> camera
        cam_pos = view.R @ pos[prim.joint] + view.t
        t, n = _intersect(prim, cam_rot, cam_pos, d)
        cur = t_buf[y0:y1, x0:x1].reshape(-1)
        win = t < cur
        if not win.any():
            continue
        idx = np.flatnonzero(win)
        yy, xx = np.divmod(idx, x1 - x0)
        yy, xx = yy + y0, xx + x0
        t_buf[yy, xx] = t[idx]
        prim_buf[yy, xx] = k
        normal_buf[yy, xx] = n[idx]
        local_buf[yy, xx] = (d[idx] * t[idx, None] - cam_pos) @ cam_rot  # hit point in the joint frame
    return _sensor(view, prims, placements, t_buf, prim_buf, normal_buf, local_buf, pose, prev, nxt, rng, noise,
                   bloom_px)


def _bounds(view, prims, rot, pos):
    centres, radii = np.zeros((len(prims), 3)), np.zeros(len(prims))
    for k, prim in enumerate(prims):
        if prim.kind == "capsule":
            mid, r = (prim.a + prim.b) / 2, np.linalg.norm(prim.b - prim.a) / 2 + prim.radii[0]
        else:
            mid, r = prim.a, prim.radii.max()
        centres[k] = rot[prim.joint] @ mid + pos[prim.joint]
        radii[k] = r
    return centres, radii


def _boxes(cam: Camera, centres: np.ndarray, radii: np.ndarray):
    """Pixel boxes (y0, y1, x0, x1) holding each bounding sphere's image, or None when out of view."""
    pc = centres @ cam.world_to_cam[:3, :3].T + cam.world_to_cam[:3, 3]
    uv, _ = cv2.projectPoints(pc.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, np.asarray(cam.dist))
    uv = uv.reshape(-1, 2)
    out = []
    for (u, v), z, r in zip(uv, pc[:, 2], radii):
        if z + r <= RANGE_M[0] * 0.5:
            out.append(None)
            continue
        if z - r <= 0.05:
            out.append((0, cam.height, 0, cam.width))
            continue
        extent = 1.3 * max(cam.fx, cam.fy) * r / (z - r) + 4  # margin for lens distortion
        box = (int(max(0, v - extent)), int(min(cam.height, v + extent + 1)),
               int(max(0, u - extent)), int(min(cam.width, u + extent + 1)))
        out.append(box if box[0] < box[1] and box[2] < box[3] else None)
    return out


def _intersect(prim: Primitive, cam_rot: np.ndarray, cam_pos: np.ndarray, d: np.ndarray):
    """Ray length (inf on a miss) and unit normal for rays ``d`` (n, 3) from the camera centre."""
    if prim.kind == "capsule":
        return _capsule(cam_rot @ prim.a + cam_pos, cam_rot @ prim.b + cam_pos, prim.radii[0], d)
    return _ellipsoid(cam_rot @ prim.a + cam_pos, cam_rot, prim.radii, d)


def _capsule(A, B, r, d):
    """Ray-capsule intersection (Quilez's closed form) for rays from the origin."""
    ba, oa = B - A, -A
    baba, baoa, oaoa = ba @ ba, ba @ oa, oa @ oa
    bard, rdoa = d @ ba, d @ oa
    a = baba - bard * bard
    b = baba * rdoa - baoa * bard
    c = baba * oaoa - baoa * baoa - r * r * baba
    h = b * b - a * c
    t = np.full(d.shape[0], np.inf)
    normal = np.zeros_like(d)
    ok = h >= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        tb = (-b - np.sqrt(np.where(ok, h, 0))) / a
        y = baoa + tb * bard
    body = ok & (y > 0) & (y < baba) & (tb > 0)
    t[body] = tb[body]
    p = d[body] * tb[body, None]
    normal[body] = (p - A - np.outer(y[body] / baba, ba)) / r
    caps = ok & ~body
    if caps.any():
        cap_centre = np.where((y[caps] <= 0)[:, None], A, B)  # (m, 3)
        oc = -cap_centre
        bc = np.einsum("ij,ij->i", d[caps], oc)
        hc = bc * bc - (np.einsum("ij,ij->i", oc, oc) - r * r)
        tc = -bc - np.sqrt(np.maximum(hc, 0))
        good = (hc >= 0) & (tc > 0)
        idx = np.flatnonzero(caps)[good]
        t[idx] = tc[good]
        normal[idx] = (d[idx] * tc[good, None] - cap_centre[good]) / r
    return t, normal


def _ellipsoid(C, Q, radii, d):
    """Ray-ellipsoid intersection; ``Q`` holds the ellipsoid axes (camera frame) in its columns."""
    o = (-C @ Q) / radii
    dl = (d @ Q) / radii
    a = np.einsum("ij,ij->i", dl, dl)
    b = dl @ o
    c = o @ o - 1.0
    h = b * b - a * c
    t = np.full(d.shape[0], np.inf)
    ok = h >= 0
    tt = (-b[ok] - np.sqrt(h[ok])) / a[ok]
    good = tt > 0
    idx = np.flatnonzero(ok)[good]
    t[idx] = tt[good]
    q = o + dl[idx] * t[idx, None]  # on the unit sphere
    n = (q / radii) @ Q.T
    normal = np.zeros_like(d)
    normal[idx] = n / np.linalg.norm(n, axis=1, keepdims=True)
    return t, normal


def saturated(reflector: np.ndarray, bloom_px: int) -> np.ndarray:
    """The pixels a time-of-flight sensor saturates: the retro-reflectors' own and, with ``bloom_px`` > 0, a disc of that
    radius round them (a real Kinect v2's reflector regions measure 100-400 px, the tape alone a few dozen).
    (y, x) bool -> (y, x) bool"""
    if bloom_px <= 0:
        return reflector
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * bloom_px + 1, 2 * bloom_px + 1))
    return cv2.dilate(reflector.astype(np.uint8), disc) > 0


def _sensor(view, prims, placements, t_buf, prim_buf, normal_buf, local_buf, pose, prev, nxt, rng, noise,
            bloom_px=0) -> Frame:
    body = prim_buf >= 0
    rid = np.full(prim_buf.shape, -1, dtype=np.int8)
    for k, prim in enumerate(prims):
        on = prim_buf == k
        if on.any() and any(p.prim == k for p in placements):
            rid[on] = label_hits(placements, prim, k, local_buf[on])
    reflector = rid >= 0
    cos = np.where(body, np.abs(np.einsum("yxi,yxi->yx", normal_buf, view.rays)), view.bg_cos)
    z = t_buf * view.rays[..., 2]
    flow = _scene_flow(view, prims, prim_buf, local_buf, pose, nxt)
    flow_prev = -_scene_flow(view, prims, prim_buf, local_buf, pose, prev)
    hot = saturated(reflector, bloom_px)
    depth = kinect_depth(z, cos, hot, rng, noise)
    albedo = view.bg_albedo.copy()
    albedo[body] = ALBEDO["body"] * cloth_texture(prim_buf[body], local_buf[body])
    ir = kinect_ir(t_buf, cos, albedo, hot, rng, noise)
    pixels = np.bincount(rid[reflector].astype(np.int64), minlength=len(placements)).astype(np.int32)
    return Frame(depth, ir, rid, body, flow, flow_prev, pixels)


_SCALES = np.array([[20.0, 33.0], [8.0, 12.5], [3.3, 5.0]])  # cycles per metre: fine, medium, coarse bands
_WAVES = np.random.default_rng(20190601).normal(size=(32, 6, 3))  # per primitive: two plane waves per band
_WAVES /= np.linalg.norm(_WAVES, axis=2, keepdims=True)
_WAVES *= np.random.default_rng(7).uniform(_SCALES[:, :1], _SCALES[:, 1:], (32, 3, 2)).reshape(32, 6, 1)
_PHASES = np.random.default_rng(11).uniform(0, 2 * np.pi, (32, 6))


def cloth_texture(prim: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Albedo factor (about 0.75-1.25) of a cloth-like pattern fixed to each primitive's surface.

    prim (n,) primitive index, local (n, 3) surface points in the joint frame -> (n,)
    Three bands of plane waves (periods about 4, 10 and 25 cm), like the multi-scale texture of
    clothing (weave, folds, seams); it moves with the body.
    """
    arg = 2 * np.pi * np.einsum("nkj,nj->nk", _WAVES[prim], local) + _PHASES[prim]  # (n, 6)
    s = np.sin(arg)
    return 1.0 + 0.25 * (0.3 * s[:, 0] * s[:, 1] + 0.35 * s[:, 2] * s[:, 3] + 0.35 * s[:, 4] * s[:, 5])


def _scene_flow(view, prims, prim_buf, local_buf, pose: Pose, other: Pose):
    """Camera-frame 3D motion of the visible surface from ``pose`` to ``other`` (static background: 0)."""
    flow = np.zeros(prim_buf.shape + (3,), dtype=np.float32)
    body = prim_buf >= 0
    if body.any():
        joints = np.array([p.joint for p in prims])[prim_buf[body]]
        p = local_buf[body]
        moved = np.einsum("nij,nj->ni", other.rot[joints] - pose.rot[joints], p) + other.pos[joints] - pose.pos[joints]
        flow[body] = moved @ view.R.T
    return flow


def kinect_depth(z, cos, reflector, rng, noise) -> np.ndarray:
    """Kinect-like depth in mm: noise, edge artifacts, quantization, 0 where invalid."""
    sigma = noise * (0.0006 + 0.00035 * z**2)  # axial noise grows with range
    noisy = z + rng.standard_normal(z.shape) * sigma
    zmax = cv2.dilate(z.astype(np.float32), np.ones((3, 3), np.uint8))
    zmin = cv2.erode(z.astype(np.float32), np.ones((3, 3), np.uint8))
    edge = (zmax - zmin) > 0.08
    if noise > 0:
        u = rng.random(z.shape)
        drop = edge & (u < 0.4 * min(noise, 1.0))
        flying = edge & ~drop & (u < 0.7 * min(noise, 1.0))
        noisy = np.where(flying, z + (zmax - z) * rng.random(z.shape), noisy)  # mixed fg/bg returns
    else:
        drop = np.zeros_like(edge)
    valid = (z >= RANGE_M[0]) & (z <= RANGE_M[1]) & (cos >= GRAZING_COS) & ~reflector & ~drop
    mm = np.rint(noisy * 1000.0)
    return np.where(valid, np.clip(mm, 1, 65535), 0).astype(np.uint16)


def kinect_ir(t, cos, albedo, reflector, rng, noise, *, override=None, glow=None) -> np.ndarray:
    """Active-IR intensity: albedo * cos / d^2, saturated retro-reflectors with a little bloom, sensor noise.
    ``override`` (y, x): counts that replace the Lambertian return where not NaN (unsaturated tape, tasks/deepmocap/film/tape.py);
    ``glow`` (y, x) in [0, 1]: the bloom's shape, instead of a 1-pixel Gaussian round ``reflector``."""
    ir = IR_GAIN * albedo * cos / np.maximum(t, 0.3) ** 2
    if override is not None:
        ir = np.where(np.isnan(override), ir, override)
    bloom = cv2.GaussianBlur(reflector.astype(np.float32), (0, 0), 1.0) if glow is None else glow
    ir = np.where(reflector, IR_REFLECTOR, ir + 0.5 * IR_REFLECTOR * bloom)
    ir = ir + noise * rng.standard_normal(ir.shape) * (15.0 + 0.01 * ir)
    return np.clip(np.rint(ir), 0, 65535).astype(np.uint16)
