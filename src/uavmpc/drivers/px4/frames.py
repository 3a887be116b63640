"""uavmpc's conventions ↔ PX4's, written once (the edge of the MAVLink driver).

uavmpc: world ENU (x east, y north, z up), body FLU (x forward, y left, z up), quaternions
``(w, x, y, z)`` body → world, heading about world z counter-clockwise from east.
PX4 / MAVLink: world NED (x north, y east, z down), body FRD (x forward, y right, z down),
quaternions ``(w, x, y, z)`` body → world, yaw about world z (down) clockwise from north.

Every map here is its own inverse (ENU ↔ NED swaps x, y and negates z; FLU ↔ FRD negates y and
z; ψ ↔ π/2 − ψ), so one function serves both directions; the ``*_to_*`` names say which one a
caller means.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["enu_flu_quat_to_ned_frd", "enu_to_ned", "flu_to_frd", "frd_to_flu",
           "heading_enu_to_ned", "heading_ned_to_enu", "ned_frd_quat_to_enu_flu",
           "ned_to_enu"]

_S = math.sqrt(0.5)


def enu_to_ned(v: np.ndarray) -> np.ndarray:
    """World vectors (..., 3) from ENU to NED (positions, velocities, accelerations)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


ned_to_enu = enu_to_ned  # the same swap both ways


def flu_to_frd(v: np.ndarray) -> np.ndarray:
    """Body vectors (..., 3) from FLU to FRD (body rates, body velocities)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[..., 0], -v[..., 1], -v[..., 2]], axis=-1)


frd_to_flu = flu_to_frd


def enu_flu_quat_to_ned_frd(q: np.ndarray) -> np.ndarray:
    """Attitude quaternions (..., 4) ``(w, x, y, z)`` from body FLU → world ENU to body FRD →
    world NED.

    ``R_ned_frd = T · R_enu_flu · B`` with ``T`` (ENU → NED, a half turn about (1, 1, 0)/√2)
    and ``B`` (FRD → FLU, a half turn about x); as quaternions ``q_T ⊗ q ⊗ q_B``, which
    expands to ``√½ (w + z, x + y, x − y, w − z)``. A level vehicle facing east (identity in
    ENU) faces yaw +90° in NED: ``(√½, 0, 0, √½)``."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return _S * np.stack([w + z, x + y, x - y, w - z], axis=-1)


ned_frd_quat_to_enu_flu = enu_flu_quat_to_ned_frd


def heading_enu_to_ned(heading_rad: float) -> float:
    """Heading (ENU, from east, counter-clockwise) → yaw (NED, from north, clockwise), in
    [−π, π)."""
    return _wrap(0.5 * math.pi - float(heading_rad))


heading_ned_to_enu = heading_enu_to_ned


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi
