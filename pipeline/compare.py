"""`mocapflow compare`: every system that filmed a catalog's joint take (``joint_take:``), scored on the same truth.

A joint take is one studio performance (subject, motion, seed) filmed by several datasets, one per system, from
the same posed mesh (pipeline/catalog.py, JointTake). Each system's compare hook (registry.Comparer) reads its
capture of a sequence as a registry.Capture: its joints per frame, named by the skeleton the system declares, the
studio's truth of those frames, and the surface where the system gives one. This module knows no system and no
skeleton: it matches the captures' frames on the take's clock, checks that they give the same joints and hold the
same truth, and scores them alike.

Frames are matched by time: a frame ``f`` of a sequence filmed at ``fps`` is at ``f / fps`` s from the take's start
(every dataset films the same window: the joint take's ``start_s``); the frames compared are the instants every
system filmed (a 30 fps and a 10 fps capture meet at every third 30 fps frame). The studio samples a joint take's
clip once, on one clock whatever each system's rate (tasks/studio/take.py, ``time_base_fps``): one retargeting,
root centring, floor height, stance lift and subject body, so every system's truth of an instant (its joints) is
the same (measured: 0 mm on the CMU clips of benchmarks/compare.yaml, where sampling at each rate gave up to 9.6 mm).
The check: at every instant compared, every joint of each system's truth lies within TRUTH_TOLERANCE_M (2 mm) of the
first system's; else the takes are not one performance and nothing is scored (CompareError, naming the take, the
instant, the systems, the joint and the gap). Each system is scored against its own truth of those instants, and
the largest gap is reported.

Figures per system: MPJPE (mean over the joints it gives, per frame and over the take, mm), per body part (the
skeleton's parts), the surface error (per frame the median distance of the given surface from the true skin, mm),
completeness (the share of truth joint-frames given) and the cost: the CPU seconds the engine recorded for the
system's stages of the sequence (each region's worker CPU time, summed; the studio's filming, a source stage, left
out) per captured second. The comparison's table, JSON figures and page are presentation/compare.py's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.plan import Plan
from mocapflow.pipeline.storage import Store

TRUTH_TOLERANCE_M = 2e-3  # the systems' truths at a shared instant: one clip sampled once, so they agree (0 mm)


class CompareError(PlanError):
    """A joint take whose systems' captures hold different truths at the same instant: not one performance."""


@dataclass(frozen=True)
class Filmed:
    """One dataset of the joint take and the system that reads it."""

    dataset: str
    system: str
    comparer: registry.Comparer
    stage: str


def dataset_stages(catalog, dataset: str) -> list[str]:
    """The stages fed (through their ancestors) by ``dataset``'s source stage, in topological order."""
    return [name for name in catalog.stages
            if any(catalog.stages[a].dataset == dataset for a in catalog.ancestors(name))]


def filmed_by(catalog) -> list[Filmed]:
    """Each dataset of the joint take with the first system whose hook compares one of its stages."""
    if catalog.joint_take is None:
        raise PlanError(f"{catalog.path.name} declares no joint take; add 'joint_take: {{datasets: [...], sequences: "
                        "{...}}}' naming the datasets that film it (see benchmarks/compare.yaml)")
    out = []
    for dataset in catalog.joint_take.datasets:
        stages = dataset_stages(catalog, dataset)
        found = next(((c, s) for c in registry.comparers() if (s := c.stage(catalog, stages)) is not None), None)
        if found is None:
            raise PlanError(f"no system compares the stages of dataset {dataset!r} ({', '.join(stages) or 'none'}); "
                            f"systems with a compare hook: {[c.system for c in registry.comparers()]}; add the "
                            "system's final stage for that dataset")
        out.append(Filmed(dataset, found[0].system, found[0], found[1]))
    systems = [f.system for f in out]
    if len(set(systems)) != len(systems):
        raise PlanError(f"the joint take's datasets {[f.dataset for f in out]} are read by systems {systems}; "
                        "give each system one dataset")
    return out


def compare_plan(catalog, plan: Plan, store: Store) -> dict:
    """The comparison: per take the matched frames and per system its figures; overall per system."""
    filmed = filmed_by(catalog)
    takes = {}
    for take in catalog.joint_take.takes:
        ids = {f.system: catalog.joint_take.sequence(take, f.dataset) for f in filmed}
        if not all(any(s.id == i for s in plan.sequences) for i in ids.values()):
            continue  # left out by --sequences
        captures = {f.system: f.comparer.capture(catalog, plan, store, f.stage, ids[f.system]) for f in filmed}
        takes[take] = score_take(take, captures, {f.system: cost(catalog, plan, store, f.stage, ids[f.system],
                                                                  captures[f.system]) for f in filmed})
    if not takes:
        raise PlanError("no joint take is selected; check --sequences (a take's sequences are <take>.<dataset>)")
    systems, skeleton = [f.system for f in filmed], next(iter(takes.values()))["skeleton"]
    return {"systems": systems, "takes": takes, "skeleton": skeleton,
            "requirements": {f.system: f.comparer.requirements for f in filmed},
            "overall": {s: overall([t["systems"][s] for t in takes.values()], skeleton) for s in systems}}


def matched_frames(captures: dict[str, registry.Capture]) -> dict[str, np.ndarray]:
    """Per system the indices of its frames at the instants every system filmed (microsecond clock)."""
    clocks = {s: np.round(np.arange(len(c.joints)) / c.fps * 1e6).astype(np.int64) for s, c in captures.items()}
    shared = np.array(sorted(set.intersection(*(set(t.tolist()) for t in clocks.values()))), np.int64)
    if not shared.size:
        rates = {s: c.fps for s, c in captures.items()}
        raise PlanError(f"the systems' captures share no instant (frame rates {rates}); film the joint take at rates "
                        "that divide one another")
    return {s: np.searchsorted(t, shared) for s, t in clocks.items()}


def score_take(take: str, captures: dict[str, registry.Capture], costs: dict[str, float]) -> dict:
    """One take: the instants compared, the truth there, per system its figures on those instants."""
    skeleton = shared_skeleton(take, captures)
    frames = matched_frames(captures)
    first = next(iter(captures))
    truth = captures[first].truth[frames[first]].astype(np.float64)
    times = np.arange(len(captures[first].joints))[frames[first]] / captures[first].fps
    gaps = {}
    for system, capture in captures.items():
        theirs = capture.truth[frames[system]].astype(np.float64)
        distance = np.linalg.norm(theirs - truth, axis=-1)  # (instant, joint) m
        gaps[system] = float(distance.max()) if distance.size else 0.0
        if gaps[system] > TRUTH_TOLERANCE_M:
            i, j = np.unravel_index(int(np.argmax(distance)), distance.shape)
            raise CompareError(
                f"take {take!r}: at {times[i]:.3f} s (frame {frames[first][i]} of {first!r} at {captures[first].fps:g} "
                f"fps, frame {frames[system][i]} of {system!r} at {capture.fps:g} fps) the truth of {system!r} differs "
                f"from that of {first!r} by {gaps[system] * 1000:.1f} mm at the same instant: not one performance "
                f"(joint {skeleton.names[j]}; one take's truths agree within {TRUTH_TOLERANCE_M * 1000:g} mm); film every "
                "dataset of the joint take over the same window (start_s, frames / fps) on one clock (time_base_fps) "
                "and leave subject, motion and seed to the take")
    return {"times": times, "truth": truth, "truth_gap_mm": 1000 * max(gaps.values()), "skeleton": skeleton,
            "systems": {s: score_capture(c, frames[s], c.truth[frames[s]].astype(np.float64), costs[s])
                        for s, c in captures.items()}}


def shared_skeleton(take: str, captures: dict[str, registry.Capture]) -> registry.Skeleton:
    """The skeleton every system's capture of ``take`` gives (names, tree and parts alike), or a CompareError."""
    first, skeleton = next(iter(captures.items()))
    skeleton = skeleton.skeleton
    for system, capture in captures.items():
        if capture.skeleton != skeleton:
            raise CompareError(
                f"take {take!r}: {system!r} gives the joints {list(capture.skeleton.names)} and {first!r} gives "
                f"{list(skeleton.names)} (or their trees or parts differ); systems are compared on one skeleton: make "
                "their compare hooks give the same joints")
    return skeleton


def score_capture(capture: registry.Capture, frames: np.ndarray, truth: np.ndarray, cpu_s_per_s: float) -> dict:
    """One system's figures on the matched ``frames`` against its truth there, ``truth`` (frame, joint, 3) m."""
    joints = capture.joints[frames].astype(np.float64)
    error = np.linalg.norm(joints - truth, axis=-1) * 1000  # (frame, joint) mm, NaN where not given
    given = np.isfinite(error)
    per_frame = np.array([np.nan if not g.any() else float(e[g].mean()) for e, g in zip(error, given)])
    surface = None if capture.surface_error_mm is None else np.asarray(capture.surface_error_mm, float)[frames]
    return {"stage": capture.stage, "frames": int(len(frames)), "joints": joints, "error_mm": error,
            "mpjpe_per_frame_mm": per_frame, "mpjpe_mm": _mean(error[given]),
            "parts_mm": {p: _mean(error[:, i][given[:, i]]) for p, i in capture.skeleton.part_index().items()},
            "surface_per_frame_mm": surface, "surface_mm": None if surface is None else float(np.nanmedian(surface)),
            "surface": None if capture.surface is None else capture.surface[frames],
            "completeness": float(given.mean()), "cpu_s_per_s": cpu_s_per_s, "needs": dict(capture.needs)}


def cost(catalog, plan: Plan, store: Store, stage: str, sequence: str, capture: registry.Capture) -> float:
    """CPU seconds the engine recorded for ``stage`` and the stages it needs (not the source: the studio's filming)
    on ``sequence``, per captured second: each region's worker CPU time, or its wall seconds where a region was
    written before CPU time was recorded."""
    stages = {s for s in catalog.ancestors(stage) if not catalog.stages[s].spec.source}
    seconds = 0.0
    for item in plan.items.values():
        if item.partition.stage in stages and item.partition.sequence == sequence:
            cpu = store.region_cpu_seconds(item.partition.stage, item.key)
            seconds += store.region_seconds(item.partition.stage, item.key) if cpu is None else cpu
    return seconds / (len(capture.joints) / capture.fps)


def overall(rows: list[dict], skeleton: registry.Skeleton) -> dict:
    """A system over the takes: MPJPE over every joint-frame, its median and p90 over takes, per part, surface,
    completeness and cost (means over takes)."""
    error = np.concatenate([r["error_mm"].ravel() for r in rows])
    takes = np.array([r["mpjpe_mm"] for r in rows])
    surface = [r["surface_mm"] for r in rows if r["surface_mm"] is not None]
    return {"takes": len(rows), "frames": sum(r["frames"] for r in rows), "mpjpe_mm": _mean(error[np.isfinite(error)]),
            "take_median_mm": float(np.nanmedian(takes)), "take_p90_mm": float(np.nanpercentile(takes, 90)),
            "parts_mm": {p: _mean(np.concatenate([r["error_mm"][:, i].ravel() for r in rows])) for p, i in
                         skeleton.part_index().items()},
            "surface_mm": float(np.median(surface)) if surface else None,
            "completeness": float(np.mean([r["completeness"] for r in rows])),
            "cpu_s_per_s": float(np.mean([r["cpu_s_per_s"] for r in rows])), "needs": rows[0]["needs"]}


def _mean(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(values.mean()) if values.size else float("nan")
