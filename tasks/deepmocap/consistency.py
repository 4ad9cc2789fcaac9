"""Plausibility of each view's labels where there is no ground truth: the take checked against itself.

A real recording has no truth to score the labelled 2D reflectors by, and a view that labels wrongly (the legs
exchanged in a side view, a label on the wrong limb) still yields markers. Beyond the paper, three checks score
each view's labels by the take's own evidence. Each works on the view's own lift of its labels
(``markers3d``'s ``view_position``: the region's centre back-projected at the median depth of its contour,
§3.4.1; a strap's pushed one nominal limb radius along the viewing ray, as its fusion assumes, Eq. A1):

- **agreement** (the views against each other): a view's lifted label agrees where it lies within
  ``agreement_m`` of the same label lifted by another view, the nearest of them. Patch views agree on one surface
  point (Eq. 10 averages them); strap views on the limb centre (Eq. A1), to the error of the nominal radius. The
  nearest other view, not the others' mean: one wrong view then marks itself, not the views that agree with
  each other. Counted where another view has that label in that frame.
- **left/right** (the view against the fitted body): a label with a mirrored name (``L``/``R`` tokens exchanged,
  tasks/shared/labels.py) is on its side where it lies nearer the body's reflector of its own label than the
  body's reflector of the mirrored label; a view that exchanges the legs fails it on every leg label.
- **on body** (the view against the fitted body): a label is where the body puts it when it lies within
  ``on_body_m`` of that reflector on the body (``body_poses``' ``reflector_position``, the place calibrated per
  take).

The body was fitted to the fused markers, so it follows the views' majority: one wrong view of three fails the
body checks, a mistake every view makes alike passes them (and the agreement too). Each check is a share of the
view's labels counted (passed / counted), kept as counts so that sequences add up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.labels import mirrored

CHECKS = ("agreement", "left_right", "on_body")


class ConsistencyError(ValueError):
    """Arrays or settings the plausibility checks of the views cannot use."""


@dataclass(frozen=True)
class ConsistencyConfig:
    # farthest a view's lifted label may lie from another view's lift of it: chosen on the mesh validation split
    # (training/validation_mesh.yaml, the shipped network), where two views' lifts both within 10 cm of the truth lie
    # 4.3 cm apart (median; p95 9.9 cm) and a wrong one 44 cm from the nearest other view (p10 12 cm): 10 cm passes
    # 95.3 % of the right lifts and 3.7 % of the wrong ones (5 cm: 56.7 % and 0.2 %)
    agreement_m: float = 0.10
    on_body_m: float = 0.10  # farthest a view's lifted label may lie from that reflector on the fitted body
    worst: int = 3  # labels named per view as the most often off the body

    def __post_init__(self):
        if not self.agreement_m > 0 or not self.on_body_m > 0:
            raise ConsistencyError(f"agreement_m and on_body_m must be > 0 metres (e.g. 0.05, 0.10), got "
                                   f"{self.agreement_m}, {self.on_body_m}")
        if self.worst < 0:
            raise ConsistencyError(f"worst must be >= 0 labels named per view (e.g. 3), got {self.worst}")


def nearest_other_view(view_position: np.ndarray) -> np.ndarray:
    """Distance of each view's lifted label to the nearest other view's lift of the same label in that frame; NaN
    where the view has no lift or no other view has one.  (frame, R, V, 3) -> (frame, R, V) m"""
    n_views = view_position.shape[2]
    gap = np.linalg.norm(view_position[:, :, :, None] - view_position[:, :, None], axis=-1)  # (frame, R, V, V)
    gap[..., np.arange(n_views), np.arange(n_views)] = np.nan  # not against itself
    out = np.full(gap.shape[:3], np.nan)
    some = np.isfinite(gap).any(-1)
    out[some] = np.nanmin(gap[some], axis=-1)
    return out


def side_margin(view_position: np.ndarray, body: np.ndarray, names: list[str]) -> np.ndarray:
    """How much nearer each view's lifted label lies to the body's reflector of its own label than to the body's
    reflector of the mirrored label (> 0: on its side); NaN for a label without a mirror among ``names``, or where
    the lift or either body reflector is missing.  (frame, R, V, 3), (frame, R, 3) -> (frame, R, V) m"""
    out = np.full(view_position.shape[:3], np.nan)
    for r, name in enumerate(names):
        m = mirrored(name)
        if m == name or m not in names:
            continue
        own = np.linalg.norm(view_position[:, r] - body[:, r, None], axis=-1)  # (frame, V)
        other = np.linalg.norm(view_position[:, r] - body[:, names.index(m), None], axis=-1)
        out[:, r] = other - own
    return out


def body_distance(view_position: np.ndarray, body: np.ndarray) -> np.ndarray:
    """Distance of each view's lifted label from that reflector on the body; NaN where either is missing.
    (frame, R, V, 3), (frame, R, 3) -> (frame, R, V) m"""
    return np.linalg.norm(view_position - body[:, :, None], axis=-1)


def view_counts(view_position: np.ndarray, body: np.ndarray, names: list[str],
                config: ConsistencyConfig) -> dict[str, np.ndarray]:
    """Per check, the labels that passed and those counted, per view and reflector: {check: (2, V, R) int64}
    ([0]: passed, [1]: counted); a body check counts only where the body has the reflector (NaN: a frame the fit
    left out).  view_position (frame, R, V, 3) NaN where the view has no lift; body (frame, R, 3)"""
    view_position = np.asarray(view_position, np.float64)
    body = np.asarray(body, np.float64)
    n_frames, n_refl, n_views, _ = view_position.shape
    if body.shape != (n_frames, n_refl, 3) or len(names) != n_refl:
        raise ConsistencyError(f"the body's reflectors {body.shape} and the names ({len(names)}) must match the views' "
                               f"lifted labels (frame, reflector, view, xyz) {view_position.shape}; read both for the "
                               "same frames and reflectors")
    with np.errstate(invalid="ignore"):
        measured = {"agreement": (nearest_other_view(view_position), lambda d: d <= config.agreement_m),
                    "left_right": (side_margin(view_position, body, names), lambda d: d > 0),
                    "on_body": (body_distance(view_position, body), lambda d: d <= config.on_body_m)}
        out = {}
        for check, (value, passes) in measured.items():
            counted = np.isfinite(value)
            passed = counted & passes(np.where(counted, value, 0.0))
            out[check] = np.stack([passed.sum(0).T, counted.sum(0).T]).astype(np.int64)  # (2, V, R)
    return out


def add_counts(a: dict[str, np.ndarray] | None, b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``view_counts`` of two takes, of the same views (or one view's: (2, R) each), added (``a`` None: ``b``)."""
    if a is None:
        return {k: v.copy() for k, v in b.items()}
    if any(a[k].shape != b[k].shape for k in CHECKS):
        raise ConsistencyError(f"counts of different views or reflectors cannot be added: {a['on_body'].shape} and "
                               f"{b['on_body'].shape}; add the counts of the same sensors and reflectors only")
    return {k: a[k] + b[k] for k in CHECKS}


def _share(passed, counted) -> float:
    return float(passed / counted) if counted else float("nan")


def summarize(counts: dict[str, np.ndarray], views: list[str], names: list[str], config: ConsistencyConfig) -> dict:
    """Per view and over all views, each check's share passed (NaN where nothing was counted) and the labels counted
    (``<check>_n``); per view also the ``worst`` labels most often off the body (name -> share off, those off at
    least once)."""

    def figures(index) -> dict:
        out = {}
        for check in CHECKS:
            passed, counted = counts[check][0][index].sum(), counts[check][1][index].sum()
            out[check], out[f"{check}_n"] = _share(passed, counted), int(counted)
        return out

    per_view = {}
    for v, view in enumerate(views):
        per_view[view] = figures(v)
        passed, counted = counts["on_body"][0][v], counts["on_body"][1][v]
        off = np.where(counted > 0, 1.0 - passed / np.maximum(counted, 1), 0.0)  # (R,)
        order = [r for r in np.argsort(-off, kind="stable") if off[r] > 0][:config.worst]
        per_view[view]["worst"] = {names[r]: float(off[r]) for r in order}
    return {"views": per_view, "all": figures(slice(None))}


def true_on_reflector(view_position: np.ndarray, truth: np.ndarray, config: ConsistencyConfig) -> np.ndarray:
    """Where there is truth, to validate the checks: per view the labels lifted within ``on_body_m`` of that
    reflector's true centre, and those lifted.  (frame, R, V, 3), (frame, R, 3) -> (2, V) int64"""
    distance = body_distance(np.asarray(view_position, np.float64), np.asarray(truth, np.float64))
    lifted = np.isfinite(view_position).all(-1)  # a label lifted where the truth has none (unseen) is wrong
    with np.errstate(invalid="ignore"):
        near = lifted & (distance <= config.on_body_m)
    return np.stack([near.sum((0, 1)), lifted.sum((0, 1))]).astype(np.int64)
