"""Label continuity of the 3D optical data before its temporal filter (DeepMoCap §3.4.2): the mirrored
limb reflectors first, then any two labels the body keeps apart that sit on one point.

The FCN names a reflector from its look and from the body around it, and the look of a left and a
right limb is the same: in a side view, or when the legs cross, a limb's reflectors can take the
other side's labels. When two views agree on the exchange, fusion (markers3d) keeps it, and the 3D
data then has the left ankle where the right one is and back again a few frames later, which no
per-reflector filter can undo.

Tracking mocap systems keep labels by continuity; this is that rule for each mirrored pair of limb
reflectors (L_ANKLE and R_ANKLE, ...), solved over the whole take rather than frame by frame (a
greedy tracker that takes one wrong decision follows the wrong side for the rest of the take). Pairs
are resolved one by one: after fusion, a limb's reflectors are seldom exchanged together (each is
fused from its own views). Each frame of a pair is either as labelled or exchanged. Between
consecutive frames, the cost of an assignment is how far each measurement lies from the same label's
position in the frame before (held for at most ``reach`` frames over a gap), each
distance capped at ``JUMP_CAP_M`` so that one wild point cannot decide; an exchanged frame
additionally costs ``penalty_m`` per measurement, so the labels as given win unless the data jumps
across the body and back. The cheapest sequence of states is found by the Viterbi recursion over the
two states. A take whose labels are exchanged from its first frame to its last stays so: continuity
cannot tell which side is which, only when they trade places.

Before that, a pair's other failure is removed: one limb under both labels (one view names it left,
another right, and the other limb is unlabelled), so fusion puts both labels on it. Where the two
measurements lie within a few centimetres while the two sides were apart a frame before, the label
whose track the point does not continue is dropped for that frame (``drop_impostors``, judged from
the frames before and from the frames after).

After the exchanges, the same test runs on every other pair of labels that the body keeps apart (more
than ``REST_NEIGHBOURS_M`` on the rest-pose template): in a deep squat the thigh hides the calf strap
and the views name the ankle strap "calf", so the calf label sits on the ankle's track beside the ankle
label; a shoulder label lands on the hand held before it (``drop_shared``). Reflectors closer than that
at rest (the forehead, chest and back patches, a shoulder's two patches, a wrist and its hand, an ankle
and its foot) can share one image region and so one point, both labels a few centimetres from the
truth, and keep both.
"""

from __future__ import annotations

import numpy as np

from mocapflow.tasks.deepmocap.skeleton import neighbours
from mocapflow.tasks.shared.labels import mirrored_pairs

JUMP_CAP_M = 0.5  # a larger jump between frames is an outlier: it counts as no more than this
REST_NEIGHBOURS_M = 0.15  # reflectors this close on the rest-pose template may share a point (see the docstring)


def held(z: np.ndarray, reach: int) -> np.ndarray:
    """Each point's last observed position, held for at most ``reach`` frames.  (frame, ..., 3) -> same"""
    out = z.copy()
    age = np.where(np.isfinite(z[..., 0]), 0, reach + 1)
    for f in range(1, len(z)):
        carry = ~np.isfinite(z[f, ..., 0]) & (age[f - 1] < reach)
        out[f][carry] = out[f - 1][carry]
        age[f][carry] = age[f - 1][carry] + 1
    return out


def continuity_costs(z: np.ndarray, reach: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: distance of its measurements to the frame before as labelled and as exchanged, and count.

    z (frame, side=2, 3) NaN where missing -> same (frame,), exchanged (frame,), measurements (frame,)
    A measurement counts where both sides are known in the frame before (held over short gaps).
    """
    before = held(z, reach)[:-1]  # (frame - 1, side, 3)
    now = z[1:]
    known = np.isfinite(before[..., 0]).all(axis=1)  # (frame - 1,): both sides known before
    same, exchanged = np.zeros(len(z)), np.zeros(len(z))
    for side in (0, 1):
        ok = known & np.isfinite(now[:, side, 0])
        to_same = np.minimum(np.linalg.norm(now[:, side] - before[:, side], axis=-1), JUMP_CAP_M)
        to_other = np.minimum(np.linalg.norm(now[:, side] - before[:, 1 - side], axis=-1), JUMP_CAP_M)
        same[1:] += np.where(ok, to_same, 0.0)
        exchanged[1:] += np.where(ok, to_other, 0.0)
    measured = np.isfinite(z[..., 0]).sum(axis=1)
    return same, exchanged, measured


def viterbi(same: np.ndarray, exchanged: np.ndarray, unary: np.ndarray) -> np.ndarray:
    """Cheapest state sequence of a two-state chain: staying costs ``same[f]``, switching ``exchanged[f]`` at
    frame f, state 1 costs ``unary[f]``.  (frame,) x3 -> (frame,) bool"""
    n = len(unary)
    cost = np.array([0.0, unary[0]])
    back = np.zeros((n, 2), np.int8)
    for f in range(1, n):
        stay, switch = cost + same[f], cost[::-1] + exchanged[f]  # arriving in state 0 / 1 from either
        back[f] = np.where(stay <= switch, [0, 1], [1, 0])
        cost = np.minimum(stay, switch) + [0.0, unary[f]]
    states = np.zeros(n, bool)
    states[-1] = bool(np.argmin(cost))
    for f in range(n - 1, 0, -1):
        states[f - 1] = back[f, int(states[f])]
    return states


def resolve_pair(z: np.ndarray, *, penalty_m: float, reach: int) -> np.ndarray:
    """Frames whose two labels are exchanged.  z (frame, side=2, 3) NaN where missing -> (frame,) bool"""
    same, exchanged, measured = continuity_costs(z, reach)
    return viterbi(same, exchanged, penalty_m * measured)


def impostors(z: np.ndarray, *, near_m: float, reach: int) -> np.ndarray:
    """Which measurement of a pair is the other limb seen twice, judged from the frames before.

    z (frame, side=2, 3) NaN where missing -> (frame, side) bool.
    A frame whose two measurements lie within ``near_m`` of each other, where the two sides' last kept
    positions (at most ``reach`` frames old) were more than 2 ``near_m`` apart, has one limb under both
    labels: the side whose own track the point does not continue (it lies ``near_m`` nearer the other
    side's last position) is the impostor. Limbs that come together keep both labels: their last
    positions were already close.
    """
    out = np.zeros(z.shape[:2], bool)
    last = np.full((2, 3), np.nan)
    age = np.full(2, reach + 1)
    for f in range(len(z)):
        both = np.isfinite(z[f, :, 0]).all()
        known = (age <= reach).all() and np.linalg.norm(last[0] - last[1]) > 2 * near_m
        if both and known and np.linalg.norm(z[f, 0] - z[f, 1]) < near_m:
            point = z[f].mean(axis=0)
            own = np.linalg.norm(point - last, axis=1)  # (side,): from each side's last position
            for side in (0, 1):
                out[f, side] = own[side] > own[1 - side] + near_m
        seen = np.isfinite(z[f, :, 0]) & ~out[f]
        last[seen], age[seen], age[~seen] = z[f, seen], 0, age[~seen] + 1
    return out


def drop_impostors(z: np.ndarray, *, near_m: float, reach: int) -> np.ndarray:
    """``impostors`` judged from the frames before and from the frames after (a take can open with one limb
    under both labels); where the two disagree, both measurements stay.  (frame, side, 3) -> (frame, side) bool"""
    forward, backward = impostors(z, near_m=near_m, reach=reach), impostors(z[::-1], near_m=near_m, reach=reach)[::-1]
    conflict = (forward | backward).all(axis=1)
    return (forward | backward) & ~conflict[:, None]


def coinciding(position: np.ndarray, near_m: float, apart: np.ndarray) -> list[tuple[int, int]]:
    """Pairs of reflectors, among those ``apart`` allows, measured within ``near_m`` of each other in some frame.

    position (frame, reflector, 3) NaN where missing, apart (reflector, reflector) bool -> [(i, j)], i < j
    """
    gap = np.linalg.norm(position[:, :, None] - position[:, None, :], axis=-1)  # (frame, reflector, reflector)
    close = np.triu((gap < near_m).any(axis=0) & apart, 1)  # NaN compares False: a missing one is never close
    return [(int(i), int(j)) for i, j in zip(*np.nonzero(close))]


def drop_pair_impostors(position: np.ndarray, confidence: np.ndarray, pair: tuple[int, int], *, near_m: float,
                        reach: int) -> int:
    """``drop_impostors`` on the two reflectors of ``pair``, removing each impostor measurement in place.
    position (frame, reflector, 3), confidence (frame, reflector) -> number of dropped measurements"""
    drop = drop_impostors(position[:, list(pair)], near_m=near_m, reach=reach)  # (frame, side)
    for side, r in enumerate(pair):
        position[drop[:, side], r], confidence[drop[:, side], r] = np.nan, 0.0
    return int(drop.sum())


def drop_shared(position: np.ndarray, confidence: np.ndarray, names: list[str], *, near_m: float, reach: int) -> int:
    """One reflector under the labels of two reflectors the body keeps apart: ``drop_pair_impostors`` on each
    such pair that comes within ``near_m``.  -> number of dropped measurements"""
    return sum(drop_pair_impostors(position, confidence, pair, near_m=near_m, reach=reach)
               for pair in coinciding(position, near_m, ~neighbours(names, REST_NEIGHBOURS_M)))


def resolve_swaps(position: np.ndarray, confidence: np.ndarray, names: list[str], *, penalty_m: float, reach: int,
                  duplicate_m: float, duplicate_reach: int, shared_m: float) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Drop a limb seen under both labels (``drop_impostors``; ``duplicate_m`` 0: off), exchange the labels
    of mirrored limb reflectors where continuity says so, then drop a label on another reflector's point
    (``drop_shared``; ``shared_m`` 0: off).

    position (frame, reflector, 3) NaN where missing, confidence (frame, reflector)
    -> position, confidence (same shapes, relabelled), number of (frame, pair) exchanges, of dropped measurements
    """
    position, confidence = position.copy(), confidence.copy()
    count = dropped = 0
    for left, right in mirrored_pairs(names):
        if duplicate_m > 0:
            dropped += drop_pair_impostors(position, confidence, (left, right), near_m=duplicate_m, reach=duplicate_reach)
        sides = position[:, [left, right]]  # (frame, side, 3)
        frames = np.flatnonzero(resolve_pair(sides, penalty_m=penalty_m, reach=reach))
        for values in (position, confidence):
            values[np.ix_(frames, [left, right])] = values[np.ix_(frames, [right, left])]
        count += len(frames)
    if shared_m > 0:
        dropped += drop_shared(position, confidence, names, near_m=shared_m, reach=duplicate_reach)
    return position, confidence, count, dropped
