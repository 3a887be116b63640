"""The proximity condition (SPEC §5.2), compared at the receiver's own prediction times
(docs/safety.md, A1 and A5: a plan up to a timeout old, on another clock, compared in time).

The reference implementation compared its prediction with a received one index to index,
although the received one is up to ~1 s old: point i of a 0.7 s old message describes where the
other UAV will be 0.7 s *earlier* than our point i. Here the other prediction is first
re-sampled at our prediction times by linear interpolation in time, then the cylinder test is
applied point by point.

Outside the other prediction's time span:

- before its first time: its first point is held (only happens with clock disagreement; the
  first point is the other UAV's state when it sent the message);
- after its last time: its last segment is extrapolated at constant velocity for at most
  ``extrapolate_s`` (the message age makes our horizon end up to the timeout later than
  theirs; holding the last point would make a UAV that is still moving look as if it stopped,
  and miss the conflicts that it would cause). Beyond that the points are "unknown" and never
  count as a conflict.

Everything is vectorised over points and over senders (arrays ``(k, m)``).
:func:`align_into` is the alignment law (compiled, one prediction); :func:`near_and_dz` the
form the avoidance calls at 10 Hz per UAV (alignment, then the horizontal test), and
:func:`align_batch` the array form for k senders.
"""

from __future__ import annotations

import math

import numpy as np

from uavmpc.jit import kernel


@kernel
def align_into(other_times_s: np.ndarray, other_positions_m: np.ndarray,
               at_times_s: np.ndarray, extrapolate_s: float, out: np.ndarray,
               known: np.ndarray) -> None:
    """The alignment law: one prediction (times (n,) strictly increasing, n ≥ 2, positions
    (n, 3)) re-sampled at ``at_times_s`` (m,) into ``out`` (m, 3); ``known`` (m,) is False
    where a sample lies more than ``extrapolate_s`` after its end (see the module doc)."""
    n = other_times_s.shape[0]
    t_end = other_times_s[n - 1] + extrapolate_s
    count = 0
    for i in range(at_times_s.shape[0]):
        at = at_times_s[i]
        if i > 0 and at < at_times_s[i - 1]:
            count = 0  # the times went back: walk again from the start
        while count < n and other_times_s[count] <= at:
            count += 1
        # The segment [j, j+1] holding the sample, clipped to the first/last segment. w < 0
        # only before the first time: clamped, the first point is held. w > 1 only after the
        # last time: left as is, the constant-velocity extrapolation of the last segment.
        j = min(max(count - 1, 0), n - 2)
        t0 = other_times_s[j]
        w = max((at - t0) / (other_times_s[j + 1] - t0), 0.0)
        for ax in range(3):
            p0 = other_positions_m[j, ax]
            out[i, ax] = p0 + w * (other_positions_m[j + 1, ax] - p0)
        known[i] = at <= t_end


@kernel
def near_and_dz(other_times_s: np.ndarray, other_positions_m: np.ndarray, at_times_s: np.ndarray,
                extrapolate_s: float, own_positions_m: np.ndarray, radius_m: float,
                near_out: np.ndarray, dz_out: np.ndarray, dxy_out: np.ndarray,
                aligned: np.ndarray) -> None:
    """One other prediction against ours: :func:`align_into` (into ``aligned`` (m, 3), work
    space), then per point whether it is known and horizontally within ``radius_m``
    (``near_out`` (m,) bool), our height minus theirs (``dz_out`` (m,)) and the horizontal
    distance between the two (``dxy_out`` (m,) [m]; where the point is unknown, that of the
    extrapolation).

    Args:
        other_times_s: (n,) strictly increasing, n ≥ 2; other_positions_m: (n, 3).
        at_times_s: (m,) our prediction times; own_positions_m: (m, 3).
    """
    m = at_times_s.shape[0]
    align_into(other_times_s, other_positions_m, at_times_s, extrapolate_s, aligned, near_out)
    r2 = radius_m**2
    for i in range(m):
        dx = aligned[i, 0] - own_positions_m[i, 0]
        dy = aligned[i, 1] - own_positions_m[i, 1]
        d2 = dx**2 + dy**2
        near_out[i] = near_out[i] and d2 <= r2
        dz_out[i] = own_positions_m[i, 2] - aligned[i, 2]
        dxy_out[i] = math.sqrt(d2)


def align_batch(other_times_s: np.ndarray, other_positions_m: np.ndarray, at_times_s: np.ndarray,
                extrapolate_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Re-sample k predictions of n points each at m times (:func:`align_into` for each).

    Args:
        other_times_s: (k, n) strictly increasing times of each prediction (s), n ≥ 2.
        other_positions_m: (k, n, 3) positions (m).
        at_times_s: (m,) times to sample at (s), on the same clock.
        extrapolate_s: how long after a prediction's last time it is extrapolated (s, ≥ 0).

    Returns:
        positions: (k, m, 3) sampled positions (m).
        known: (k, m) False where the sample lies more than ``extrapolate_s`` after the end.
    """
    times = np.ascontiguousarray(other_times_s, dtype=float)
    pos = np.ascontiguousarray(other_positions_m, dtype=float)
    at = np.ascontiguousarray(at_times_s, dtype=float)
    k, m = times.shape[0], at.shape[0]
    out = np.empty((k, m, 3))
    known = np.empty((k, m), dtype=bool)
    for i in range(k):
        align_into(times[i], pos[i], at, float(extrapolate_s), out[i], known[i])
    return out, known


def align(other_times_s: np.ndarray, other_positions_m: np.ndarray, at_times_s: np.ndarray,
          extrapolate_s: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`align_batch` for one prediction: (n,), (n, 3) → positions (m, 3), known (m,)."""
    out, known = align_batch(np.asarray(other_times_s)[None], np.asarray(other_positions_m)[None],
                             at_times_s, extrapolate_s)
    return out[0], known[0]


def cylinder_conflicts(own_positions_m: np.ndarray, other_positions_m: np.ndarray,
                       radius_m: float, height_m: float) -> np.ndarray:
    """The proximity condition at corresponding points (SPEC §5.2).

    Args:
        own_positions_m: (m, 3).
        other_positions_m: (m, 3) or (k, m, 3), already aligned in time with ours.
        radius_m: R_p, horizontal radius of the cylinder (m).
        height_m: H_p, full height of the cylinder (m); the vertical test is |Δz| ≤ H_p / 2.

    Returns:
        (m,) or (k, m) bool: ‖Δxy‖ ≤ R_p and |Δz| ≤ H_p / 2.
    """
    d = np.asarray(other_positions_m, dtype=float) - np.asarray(own_positions_m, dtype=float)
    horizontal = d[..., 0] ** 2 + d[..., 1] ** 2 <= radius_m**2
    return horizontal & (np.abs(d[..., 2]) <= 0.5 * height_m)


def conflict_points(own_times_s: np.ndarray, own_positions_m: np.ndarray,
                    other_times_s: np.ndarray, other_positions_m: np.ndarray, *,
                    radius_m: float = 5.0, height_m: float = 5.99,
                    extrapolate_s: float = 1.0) -> np.ndarray:
    """Which of our prediction points conflict with another UAV's prediction.

    Args:
        own_times_s: (m,) our prediction times (s).
        own_positions_m: (m, 3) our positions (m), already offset by the z offset in force.
        other_times_s: (n,) the other prediction's times (s), on our clock.
        other_positions_m: (n, 3) the other prediction's positions (m).
        radius_m, height_m: the cylinder (SPEC §5.2).
        extrapolate_s: see the module docstring.

    Returns:
        (m,) bool, True where the points conflict.
    """
    aligned, known = align(other_times_s, other_positions_m, own_times_s, extrapolate_s)
    return known & cylinder_conflicts(own_positions_m, aligned, radius_m, height_m)


def first_conflict_time(own_times_s: np.ndarray, conflicts: np.ndarray) -> float | None:
    """The earliest of ``own_times_s`` (m,) where ``conflicts`` (m,) or (k, m) holds, or None."""
    c = np.asarray(conflicts, dtype=bool)
    if c.ndim == 2:
        c = np.asarray(c.any(axis=0))
    idx = np.flatnonzero(c)
    return float(np.asarray(own_times_s)[idx[0]]) if idx.size else None
