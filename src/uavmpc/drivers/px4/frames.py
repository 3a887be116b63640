"""uavmpc's conventions ↔ PX4's, written once (the edge of the MAVLink driver).

uavmpc: world ENU (x east, y north, z up), body FLU (x forward, y left, z up), quaternions
``(w, x, y, z)`` body → world, heading about world z counter-clockwise from east.
PX4 / MAVLink: world NED (x north, y east, z down), body FRD (x forward, y right, z down),
quaternions ``(w, x, y, z)`` body → world, yaw about world z (down) clockwise from north.

Every map here is its own inverse (ENU ↔ NED swaps x, y and negates z; FLU ↔ FRD negates y and
z; ψ ↔ π/2 − ψ), so one function serves both directions; the ``*_to_*`` names say which one a
caller means.

Geodetic ↔ local: PX4 places its local frame on the sphere of radius
``CONSTANTS_RADIUS_OF_EARTH`` (6 371 000 m) by an azimuthal equidistant projection about its
origin (``MapProjection`` in PX4's ``lib/geo``), altitude straight up from the origin's.
``geodetic_to_enu`` / ``enu_to_geodetic`` are that projection in ENU, so a vehicle's local
NED position and our ENU agree to float precision wherever PX4's own map is used.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["EARTH_RADIUS_M", "enu_flu_quat_to_ned_frd", "enu_to_geodetic", "enu_to_ned",
           "flu_to_frd", "frd_to_flu", "geodetic_to_enu", "heading_enu_to_ned",
           "heading_ned_to_enu", "ned_frd_quat_to_enu_flu", "ned_to_enu"]

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


EARTH_RADIUS_M = 6371000.0
"""PX4's ``CONSTANTS_RADIUS_OF_EARTH``: the sphere its local ↔ global map lives on (m)."""


def geodetic_to_enu(lat_deg: float | np.ndarray, lon_deg: float | np.ndarray,
                    alt_m: float | np.ndarray,
                    origin: tuple[float, float, float]) -> np.ndarray:
    """Geodetic point(s) → ENU position(s) (m) about ``origin = (lat_deg, lon_deg, alt_m)``.

    Latitude and longitude in degrees (WGS-84 numbers, taken on PX4's sphere), altitude in
    metres (AMSL, the same datum as the origin's). Scalars give shape (3,); arrays broadcast
    and give (..., 3). East/north are PX4's azimuthal equidistant projection, up is
    ``alt_m − origin alt``. Raises ``ValueError`` for a non-finite input, a latitude outside
    [−90, 90] or the origin's antipode (where the projection has no direction)."""
    lat0, lon0, alt0 = _origin(origin)
    lat = _finite(lat_deg, "latitude")
    lon = _finite(lon_deg, "longitude")
    alt = _finite(alt_m, "altitude")
    _latitude_range(lat, "latitude")
    phi, phi0 = np.radians(lat), math.radians(lat0)
    dlon = np.radians(lon) - math.radians(lon0)
    # Angular distance by the haversine: PX4 takes acos of a dot product, which is the same
    # angle but loses half its digits near the origin; only k = c / sin c depends on it.
    h = (np.sin(0.5 * (phi - phi0)) ** 2
         + math.cos(phi0) * np.cos(phi) * np.sin(0.5 * dlon) ** 2)
    c = 2.0 * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0)))
    if np.any(c > math.pi - 1e-9):
        raise ValueError("geodetic_to_enu: a point is the origin's antipode (no direction "
                         "to it in an azimuthal projection)")
    sin_c = np.sin(c)
    k = np.where(c > 0.0, c / np.where(c > 0.0, sin_c, 1.0), 1.0)
    north = k * (math.cos(phi0) * np.sin(phi) - math.sin(phi0) * np.cos(phi) * np.cos(dlon))
    east = k * np.cos(phi) * np.sin(dlon)
    up = alt - alt0
    north, east, up = np.broadcast_arrays(north * EARTH_RADIUS_M, east * EARTH_RADIUS_M, up)
    return np.stack([east, north, up], axis=-1).astype(float)


def enu_to_geodetic(p_enu: np.ndarray,
                    origin: tuple[float, float, float]) -> tuple[float | np.ndarray, ...]:
    """ENU position(s) (m, shape (3,) or (..., 3)) about ``origin = (lat_deg, lon_deg,
    alt_m)`` → ``(lat_deg, lon_deg, alt_m)``: the inverse of ``geodetic_to_enu`` (PX4's
    ``MapProjection::reproject``). Longitude wrapped to [−180, 180). Floats for one point,
    arrays of shape (...) for many. Raises ``ValueError`` for a non-finite input or a wrong
    shape."""
    lat0, lon0, alt0 = _origin(origin)
    p = _finite(p_enu, "ENU position")
    if p.ndim == 0 or p.shape[-1] != 3:
        raise ValueError(f"enu_to_geodetic: ENU position must have shape (..., 3), got "
                         f"{p.shape}")
    x_rad = p[..., 1] / EARTH_RADIUS_M  # north
    y_rad = p[..., 0] / EARTH_RADIUS_M  # east
    c = np.hypot(x_rad, y_rad)
    phi0 = math.radians(lat0)
    sin_c, cos_c = np.sin(c), np.cos(c)
    # sin(c)/c → 1 at the origin, where the direction (x, y) / c is undefined but unneeded
    sinc = np.where(c > 0.0, sin_c / np.where(c > 0.0, c, 1.0), 1.0)
    lat = np.degrees(np.arcsin(np.clip(cos_c * math.sin(phi0) + x_rad * sinc * math.cos(phi0),
                                       -1.0, 1.0)))
    dlon = np.arctan2(y_rad * sinc,
                      math.cos(phi0) * cos_c - x_rad * math.sin(phi0) * sinc)
    lon = (lon0 + np.degrees(dlon) + 180.0) % 360.0 - 180.0
    alt = alt0 + p[..., 2]
    if p.ndim == 1:
        return float(lat), float(lon), float(alt)
    return lat, lon, alt


def _finite(v: float | tuple[float, ...] | np.ndarray, what: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} must be a number or an array of numbers, got {v!r}") from e
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be finite, got {v!r}")
    return a


def _latitude_range(lat: np.ndarray, what: str) -> None:
    if np.any(np.abs(lat) > 90.0):
        raise ValueError(f"{what} must be in [-90, 90] degrees, got {lat.tolist()!r}")


def _origin(origin: tuple[float, float, float]) -> tuple[float, float, float]:
    o = _finite(origin, "origin")
    if o.shape != (3,):
        raise ValueError(f"origin must be (lat_deg, lon_deg, alt_m), got {origin!r}")
    _latitude_range(o[0], "origin latitude")
    return float(o[0]), float(o[1]), float(o[2])
