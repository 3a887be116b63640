"""A ground vehicle driving a closed track at a set speed, carrying a landing deck (SPEC §6).

The default track is the competition's figure eight in a 90 m × 60 m arena: a lemniscate of
Gerono ``x = a sin s, y = b sin s cos s`` (``a`` = 45 m, ``b`` = 60 m, so the track spans
90 m × 60 m), driven at constant speed along its arc length (15 km/h by default). Its state at
any time is exact: position, heading, speed and yaw rate come from the track's geometry.

World frame ENU; the deck is a horizontal square centred above the vehicle's reference point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavmpc.plant import kernels as K

__all__ = ["DeckTouch", "FigureEightTrack", "GroundVehicle", "GroundVehicleState"]

KMH = 1.0 / 3.6


@dataclass(frozen=True)
class GroundVehicleState:
    """The vehicle at one time (ENU, SI).

    Attributes:
        t_s: time.
        position_m: (3,) the deck's centre.
        heading_rad: direction of travel (from east, counter-clockwise).
        speed_mps: along the heading.
        yaw_rate_radps: d(heading)/dt.
    """

    t_s: float
    position_m: np.ndarray
    heading_rad: float
    speed_mps: float
    yaw_rate_radps: float

    @property
    def velocity_mps(self) -> np.ndarray:
        return self.speed_mps * np.array([math.cos(self.heading_rad),
                                          math.sin(self.heading_rad), 0.0])


class FigureEightTrack:
    """A lemniscate of Gerono spanning ``length_m`` × ``width_m`` centred on ``centre_m``,
    tabulated by arc length (``samples`` points; linear between them)."""

    def __init__(self, length_m: float = 90.0, width_m: float = 60.0,
                 centre_m: tuple[float, float] = (0.0, 0.0), samples: int = 4000) -> None:
        if not (length_m > 0 and width_m > 0):
            raise ValueError(f"track: length and width must be > 0, got {length_m}, {width_m}")
        a, b = 0.5 * length_m, width_m  # sin s cos s spans ±1/2: y spans ±b/2
        s = np.linspace(0.0, 2.0 * math.pi, samples + 1)
        self._xy = np.stack([centre_m[0] + a * np.sin(s),
                             centre_m[1] + b * np.sin(s) * np.cos(s)], axis=1)
        seg = np.linalg.norm(np.diff(self._xy, axis=0), axis=1)
        self._arc = np.concatenate([[0.0], np.cumsum(seg)])
        self.length_of_lap_m = float(self._arc[-1])

    def point(self, arc_m: float) -> np.ndarray:
        """(x, y) at arc length ``arc_m`` (wrapped over a lap)."""
        d = arc_m % self.length_of_lap_m
        return np.array([np.interp(d, self._arc, self._xy[:, 0]),
                         np.interp(d, self._arc, self._xy[:, 1])])

    def heading(self, arc_m: float, ds_m: float = 0.25) -> float:
        p0, p1 = self.point(arc_m - ds_m), self.point(arc_m + ds_m)
        return math.atan2(p1[1] - p0[1], p1[0] - p0[0])

    def curvature(self, arc_m: float, ds_m: float = 0.5) -> float:
        """Signed curvature [1/m] (left turns positive)."""
        h0, h1 = self.heading(arc_m - ds_m), self.heading(arc_m + ds_m)
        return math.remainder(h1 - h0, 2.0 * math.pi) / (2.0 * ds_m)


class GroundVehicle:
    """A vehicle driving ``track`` at ``speed_mps`` from arc length ``start_arc_m``, its deck
    ``deck_size_m`` square at ``deck_height_m`` above the ground."""

    def __init__(self, track: FigureEightTrack | None = None, *, speed_mps: float = 15.0 * KMH,
                 start_arc_m: float = 0.0, deck_size_m: float = 1.5,
                 deck_height_m: float = 1.5) -> None:
        if not math.isfinite(speed_mps) or speed_mps < 0.0:
            raise ValueError(f"speed_mps: must be ≥ 0, got {speed_mps!r}")
        if not (deck_size_m > 0 and deck_height_m >= 0):
            raise ValueError("deck: size must be > 0 and height ≥ 0, got "
                             f"{deck_size_m!r}, {deck_height_m!r}")
        self.track = track if track is not None else FigureEightTrack()
        self.speed_mps = float(speed_mps)
        self.start_arc_m = float(start_arc_m)
        self.deck_size_m = float(deck_size_m)
        self.deck_height_m = float(deck_height_m)

    def state(self, t_s: float) -> GroundVehicleState:
        arc = self.start_arc_m + self.speed_mps * t_s
        xy = self.track.point(arc)
        return GroundVehicleState(
            t_s=float(t_s), position_m=np.array([xy[0], xy[1], self.deck_height_m]),
            heading_rad=self.track.heading(arc), speed_mps=self.speed_mps,
            yaw_rate_radps=self.speed_mps * self.track.curvature(arc))

    def deck_row(self, t_s: float) -> np.ndarray:
        """The deck at ``t_s`` as a plant's contact takes it (a ``deck`` row of
        :class:`~uavmpc.plant.rows.PlantRows`, columns ``DECK_*`` of
        :mod:`uavmpc.plant.kernels`)."""
        s = self.state(t_s)
        row = np.zeros(9)
        row[K.DECK_ACTIVE] = 1.0
        row[K.DECK_X:K.DECK_Z + 1] = s.position_m
        row[K.DECK_HEADING] = s.heading_rad
        row[K.DECK_VX:K.DECK_VY + 1] = s.velocity_mps[:2]
        row[K.DECK_YAW_RATE] = s.yaw_rate_radps
        row[K.DECK_HALF] = 0.5 * self.deck_size_m
        return row

    def on_deck(self, t_s: float, position_m: np.ndarray) -> bool:
        """True when ``position_m`` lies over the deck's square (its edges included)."""
        s = self.state(t_s)
        d = np.asarray(position_m, dtype=float)[:2] - s.position_m[:2]
        c, sn = math.cos(s.heading_rad), math.sin(s.heading_rad)
        along, across = c * d[0] + sn * d[1], -sn * d[0] + c * d[1]
        half = 0.5 * self.deck_size_m
        return abs(along) <= half and abs(across) <= half


@dataclass(frozen=True)
class DeckTouch:
    """What a plant did on the deck (read from its ``touch`` row).

    Attributes:
        touchdowns: times it came onto the deck's top from the air.
        t_s: the first touchdown's time [s] (None before one).
        relative_velocity_mps: (3,) its velocity minus the deck's at the contact point then.
        offset_m: (2,) its centre from the deck's centre then, along and across the deck [m].
        strikes: times its rotor disc hit the deck's edge or the vehicle's side.
        on_deck: on the deck's top now.
    """

    touchdowns: int
    t_s: float | None
    relative_velocity_mps: np.ndarray
    offset_m: np.ndarray
    strikes: int
    on_deck: bool

    @classmethod
    def from_row(cls, touch: np.ndarray) -> DeckTouch:
        n = int(touch[K.TOUCH_COUNT])
        return cls(touchdowns=n, t_s=float(touch[K.TOUCH_T]) if n else None,
                   relative_velocity_mps=touch[K.TOUCH_VX:K.TOUCH_VZ + 1].copy(),
                   offset_m=touch[K.TOUCH_ALONG:K.TOUCH_ACROSS + 1].copy(),
                   strikes=int(touch[K.TOUCH_STRIKES]),
                   on_deck=bool(touch[K.TOUCH_STATE] == K.ON_TOP))
