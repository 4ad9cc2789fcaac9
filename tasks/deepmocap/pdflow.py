"""Primal-dual RGB-D scene flow (PD-Flow; Jaimez, Souiai, Gonzalez-Jimenez, Cremers, ICRA 2015), IR as intensity.

Written from the paper (not from its GPL code). The unknowns are the image motion (u, v) in pixels
and the depth change w (metres) of every reference pixel towards the other frame. The energy,
linearized around the current estimate (u0, v0) at each warp of a coarse-to-fine pyramid, is

    E = sum_p  |rho_I| / n_p + mu * m_p * |rho_Z|  +  lambda_uv * g_p * (|grad u| + |grad v|)  +  lambda_w * g_p * |grad w|
    rho_I = I_o(p + u0) + grad I_o(p + u0) . (u - u0) - I_r(p)                 (intensity constancy)
    rho_Z = Z_o(p + u0) + grad Z_o(p + u0) . (u - u0) - Z_r(p) - w             (range-flow constraint)
    n_p   = sqrt(|grad I_o(p + u0)|^2 + eps^2)                                  (constraint normalization)

with m_p = 0 where either depth is invalid (holes never drive the motion; the TV term fills them)
and g_p = 1 / (1 + |grad Z_r| / z_edge) so that motion may change at depth edges. Dividing the
intensity residual by the gradient magnitude (constraint normalization, Zimmer, Bruhn & Weickert,
IJCV 2011) measures it in pixels of displacement, so the faint cloth texture of a thin limb counts
as much as a strong silhouette edge; without it, thin limbs moving along their axis are pulled
towards their surroundings' motion. It is solved by
the first-order primal-dual algorithm of Chambolle & Pock with diagonal preconditioning (Pock &
Chambolle, ICCV 2011). torch runs it on the CPU, or on a GPU when one is given.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
import xarray as xr

from mocapflow.tasks.deepmocap.flow import PrimalDualConfig, flow_sequence, lift_points


def _grad(f: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward differences with a zero last row/column.  (y, x) -> 2 x (y, x)"""
    return F.pad(f[:, 1:] - f[:, :-1], (0, 1)), F.pad(f[1:] - f[:-1], (0, 0, 0, 1))


def _div(px: torch.Tensor, py: torch.Tensor) -> torch.Tensor:
    """Negative adjoint of _grad."""
    return px - F.pad(px[:, :-1], (1, 0)) + py - F.pad(py[:-1], (0, 0, 1, 0))


def _central(f: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Central differences, zero on the border.  (y, x) -> 2 x (y, x)"""
    return F.pad((f[:, 2:] - f[:, :-2]) / 2, (1, 1)), F.pad((f[2:] - f[:-2]) / 2, (0, 0, 1, 1))


def _smooth_depth_mask(z: torch.Tensor, m: torch.Tensor, max_step: float) -> torch.Tensor:
    """1 where the central depth differences are defined: both neighbours valid and no step above ``max_step``.

    The linearized range-flow constraint only holds on smooth surfaces, not across holes or silhouettes.
    """
    ok = m.clone()
    for a, b in ((z[:, 2:], z[:, :-2]), (z[2:], z[:-2])):
        mask_a = (a > 0) & (b > 0) & ((a - b).abs() <= 2 * max_step)
        pad = (1, 1) if a.shape[0] == z.shape[0] else (0, 0, 1, 1)
        ok = ok * F.pad(mask_a.to(z.dtype), pad)
    return ok


def _edge_weight(z: torch.Tensor, m: torch.Tensor, z_edge: float) -> torch.Tensor:
    """Regularization weight g = 1 / (1 + |grad Z| / z_edge), the gradient taken between valid neighbours only."""
    gzx, gzy = _grad(z)
    both_x = F.pad(m[:, 1:] * m[:, :-1], (0, 1))
    both_y = F.pad(m[1:] * m[:-1], (0, 0, 0, 1))
    return 1.0 / (1.0 + torch.sqrt((gzx * both_x) ** 2 + (gzy * both_y) ** 2) / z_edge)


def _down(f: torch.Tensor, size) -> torch.Tensor:
    return F.interpolate(f[None, None], size=size, mode="area")[0, 0]


def _up(f: torch.Tensor, size) -> torch.Tensor:
    return F.interpolate(f[None, None], size=size, mode="bilinear", align_corners=True)[0, 0]


def _warp(fields: list[torch.Tensor], u: torch.Tensor, v: torch.Tensor) -> list[torch.Tensor]:
    """Each field sampled at p + (u, v), bilinearly (borders clamped)."""
    h, w = u.shape
    ys, xs = torch.meshgrid(torch.arange(h, device=u.device, dtype=u.dtype),
                            torch.arange(w, device=u.device, dtype=u.dtype), indexing="ij")
    grid = torch.stack([2 * (xs + u) / max(w - 1, 1) - 1, 2 * (ys + v) / max(h - 1, 1) - 1], dim=-1)[None]
    stack = torch.stack(fields)[None]
    out = F.grid_sample(stack, grid, mode="bilinear", padding_mode="border", align_corners=True)[0]
    return list(out)


def _reduce(i, z, m, size):
    """Intensity, depth (averaged over valid pixels only) and validity at a smaller ``size``."""
    mm = _down(m, size)
    zz = torch.where(mm > 0, _down(z * m, size) / mm.clamp_min(1e-6), torch.zeros_like(mm))
    return _down(i, size), zz, (mm > 0.74).to(i.dtype)


def _pyramid(i, z, m, min_width: int, factor: float = 0.5):
    levels = [(i, z, m)]
    while round(levels[-1][0].shape[1] * factor) >= min_width:
        h, w = levels[-1][0].shape
        levels.append(_reduce(*levels[-1], (max(1, round(h * factor)), round(w * factor))))
    return levels


def pd_flow(i_ref: np.ndarray, i_oth: np.ndarray, z_ref: np.ndarray, z_oth: np.ndarray, config: PrimalDualConfig,
            device: str = "cpu", *, min_width: int = 32,
            pyramid_factor: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scene flow from the reference to the other frame at the reference pixels.

    i_* (y, x) intensities in [0, 1]; z_* (y, x) depth in metres, 0 invalid.
    Returns u, v (pixels) and w (metres), each (y, x) float32 at full resolution.
    """
    dev = torch.device(device)
    finest_level = config.finest_level
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32, device=dev)  # noqa: E731
    full = (t(i_ref), t(z_ref), t(z_ref > 0)), (t(i_oth), t(z_oth), t(z_oth > 0))
    if finest_level > 0:  # the working resolution: halve finest_level times
        size = (i_ref.shape[0] >> finest_level, i_ref.shape[1] >> finest_level)
        full = tuple(_reduce(*frame, size) for frame in full)
    ref = _pyramid(*full[0], min_width, pyramid_factor)
    oth = _pyramid(*full[1], min_width, pyramid_factor)
    u = v = w = None
    for level in range(len(ref) - 1, -1, -1):
        (ir, zr, mr), (io, zo, mo) = ref[level], oth[level]
        if u is None:
            u, v, w = (torch.zeros_like(ir) for _ in range(3))
        else:
            scale = ir.shape[1] / u.shape[1]
            u, v, w = _up(u, ir.shape) * scale, _up(v, ir.shape) * scale, _up(w, ir.shape)
        g = _edge_weight(zr, mr, config.z_edge)
        for _ in range(config.warps):
            u, v, w = _solve((ir, zr, mr), (io, zo, mo), (u, v, w), g, config)
    size = i_ref.shape
    scale = size[1] / u.shape[1]
    u, v, w = _up(u, size) * scale, _up(v, size) * scale, _up(w, size)
    return u.cpu().numpy(), v.cpu().numpy(), w.cpu().numpy()


def _solve(ref, oth, start, g, config: PrimalDualConfig):
    """One warp: preconditioned Chambolle-Pock on the linearized energy. ``ref`` and ``oth``: each frame's
    (intensity, depth, validity) at this level; ``start``: the current (u, v, w); ``g``: the edge weight."""
    (ir, zr, mr), (io, zo, mo), (u0, v0, w0) = ref, oth, start
    mu, normalize_eps = config.mu, config.normalize_eps
    gix, giy = _central(io)
    smooth = _smooth_depth_mask(zo * mo, mo, max_step=0.03)
    gzx, gzy = _central(zo * mo)
    iw, ixw, iyw, zw, zxw, zyw, mw = _warp([io, gix, giy, zo * mo, gzx * smooth, gzy * smooth, smooth], u0, v0)
    m = mr * (mw > 0.99) * ((zw - zr - w0).abs() <= config.max_depth_jump)
    a_z = mu * m
    if normalize_eps > 0:  # constraint normalization: the intensity residual in pixels of displacement
        scale = 1.0 / torch.sqrt(ixw**2 + iyw**2 + normalize_eps**2)
        iw, ixw, iyw, ir = iw * scale, ixw * scale, iyw * scale, ir * scale
    it = iw - ixw * u0 - iyw * v0 - ir  # rho_I = it + ixw * u + iyw * v
    zt = zw - zxw * u0 - zyw * v0 - zr  # rho_Z = zt + zxw * u + zyw * v - w
    eps = 1e-6
    tau_u = 1.0 / (4.0 + ixw.abs() + a_z * zxw.abs() + eps)  # Eq. (10), Pock & Chambolle 2011
    tau_v = 1.0 / (4.0 + iyw.abs() + a_z * zyw.abs() + eps)
    tau_w = 1.0 / (4.0 + a_z + eps)
    sigma_i = 1.0 / (ixw.abs() + iyw.abs() + eps)
    sigma_z = 1.0 / (a_z * (zxw.abs() + zyw.abs() + 1.0) + eps)
    bound_uv, bound_w = config.lambda_uv * g, config.lambda_w * g
    u, v, w = u0.clone(), v0.clone(), w0.clone()
    ub, vb, wb = u.clone(), v.clone(), w.clone()
    pu = [torch.zeros_like(u), torch.zeros_like(u)]
    pv = [torch.zeros_like(u), torch.zeros_like(u)]
    pw = [torch.zeros_like(u), torch.zeros_like(u)]
    qi, qz = torch.zeros_like(u), torch.zeros_like(u)
    for _ in range(config.iterations):
        for p, field, bound in ((pu, ub, bound_uv), (pv, vb, bound_uv), (pw, wb, bound_w)):
            gx, gy = _grad(field)
            p[0] = p[0] + 0.5 * gx
            p[1] = p[1] + 0.5 * gy
            shrink = torch.clamp(torch.sqrt(p[0] ** 2 + p[1] ** 2) / bound.clamp_min(eps), min=1.0)
            p[0], p[1] = p[0] / shrink, p[1] / shrink
        qi = torch.clamp(qi + sigma_i * (it + ixw * ub + iyw * vb), -1.0, 1.0)
        qz = torch.clamp(qz + sigma_z * a_z * (zt + zxw * ub + zyw * vb - wb), -1.0, 1.0)
        un = u - tau_u * (-_div(*pu) + ixw * qi + a_z * zxw * qz)
        vn = v - tau_v * (-_div(*pv) + iyw * qi + a_z * zyw * qz)
        wn = w - tau_w * (-_div(*pw) - a_z * qz)
        ub, vb, wb = 2 * un - u, 2 * vn - v, 2 * wn - w
        u, v, w = un, vn, wn
    return u, v, w


def ir_intensity(ir: np.ndarray, ir_max: float) -> np.ndarray:
    """IR counts to [0, 1] with the same square-root curve the DIS variant uses."""
    return np.sqrt(np.clip(ir.astype(np.float32) / ir_max, 0.0, 1.0))


def primal_dual(frames: xr.Dataset, config: PrimalDualConfig) -> xr.Dataset:
    """Stage `flow`, implementation `primal_dual`: PD-Flow on IR + depth, on a GPU when one is present."""
    dev = ("cuda" if torch.cuda.is_available() else "cpu") if config.device == "auto" else config.device

    def estimate(ir_ref, ir_prev, z_ref, z_prev, rays):
        u, v, w = pd_flow(ir_intensity(ir_ref, config.ir_max), ir_intensity(ir_prev, config.ir_max), z_ref, z_prev,
                          config, dev)
        return lift_points(np.stack([u, v], axis=-1), z_ref, z_prev, rays, config.max_depth_jump, z_corr=z_ref + w,
                           consistency=config.consistency)

    return flow_sequence(frames, estimate, color_scale_m=config.color_scale_m, max_depth_jump=config.max_depth_jump)
