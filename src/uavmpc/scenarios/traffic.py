"""traffic: dense point-to-point traffic, e.g. parcel deliveries over a city district.

N UAVs each fly one trip from their own pad to another pad: a vertical take-off to a cruise
height, a straight cruise, a vertical descent onto the destination pad. The choices, and why:

Area from a density. The square's side is ``sqrt(n_uavs / density_per_km2)``, so that adding
UAVs grows the area and keeps the density (the quantity conflicts scale with) fixed. Default:
50 UAVs per km². Our own back-of-envelope for a dense urban delivery market: a district of
10 000 residents per km² (a dense European inner city) ordering one drone parcel each per
week is ~1 400 flights per km² per day; flown over ~12 busy hours with a peak hour twice the
mean, ~240 departures per km² per hour; at ~10 minutes per round trip, ~40 drones airborne per
km² at the peak. 50 rounds that up as a stress case; it is orders of magnitude above today's
drone traffic, which is the point of a capacity study. All N depart within a short window
(below) so that most of them are airborne together and the nominal density is the one flown.

Pads. ``2 · n_uavs`` pads: every UAV has its own origin pad and its own destination pad, so
that no two UAVs end at the same point (two goals at one point would be a collision by
construction, and ``reached_goal`` would mean nothing) and nobody lands on a pad another one is
still waiting on. Any two pads are at least ``min_pad_separation_m`` apart (default 15 m, three
times the avoidance's 5 m conflict radius, so UAVs resting on neighbouring pads are not in
conflict with each other). Origins are drawn uniformly in the area; each destination is drawn
at a uniform bearing and a uniform distance in ``[min_trip_m, max_trip_m]`` from its origin
(rejected if outside the area or too close to a pad), so trip lengths are controlled, not an
artefact of the area's size. Default 200–1000 m: long enough that cruise, not take-off and
landing, dominates and that trips cross each other; short enough to keep runs affordable.

Ground. Pads are on the ground (``pad_height_m = 0``): a UAV starts resting on its pad, rotors
idle, and ends resting on the destination pad (the plant's ground contact). This flies
cleanly: the take-off is a climb from rest, the touchdown is at the end of a decelerating
descent, and a landed UAV stays put, so ``reached_goal`` (within 1 m at the end) means "landed
on its destination pad". ``pad_height_m > 0`` (rooftop pads, or a hover start) is accepted.

Heights. Cruise at one of ``cruise_heights_m`` chosen by the direction of travel, like the
semicircular rule in aviation: the compass circle is cut into as many equal sectors as there
are heights, the first starting at north and turning clockwise (two heights: eastbound flies
the lower one, westbound the upper). Default: one height, 30 m (above a dense district's
roofline, far below the 120 m ceiling of the EU open category), so that every crossing and
head-on encounter is in one layer: the stress case for the avoidance. With two heights
(e.g. ``(30, 40)``: 10 m clears the conflict cylinder, |Δz| ≤ 3 m, with room for one 3 m
avoidance climb) head-on encounters are between layers; measured at 50 UAVs per km², the
semicircular rule alone then left no collision to avoid.

Timing. Each leg (climb, cruise, descent) is a trapezoidal speed profile, at rest at both ends,
at 90 % of the tracker's default speed limits and 80 % of its acceleration limits (8.3 m/s
horizontal, 2 m/s up, 1.5 m/s down; data/tracker.toml), sampled every 0.2 s: the reference is
flyable as given and the UAV is not left lagging behind it at the limits. Heading is the
bearing of the trip for the whole flight (no turns in the air). Departures are uniform in
``[DEPARTURE_START_S, DEPARTURE_START_S + departure_window_s]`` (default window 60 s): after
the first 2 s everybody has broadcast a few predictions, so no one leaves unheard.

Duration (default): the latest ``departure + 1.5 × nominal trip time``, plus 10 s. The slack
is for avoidance: a UAV that avoids flies at half its horizontal limits and climbs, so it
arrives late; with the slack a late UAV still lands, and a missed goal means something.

Priorities: a random permutation of 1..N (lower = higher priority), unrelated to anything
else, so that yielding is not biased by where or when a UAV flies.

Seeding: ``numpy.random.SeedSequence(seed).spawn(n_uavs + 2)``: child 0 draws the origins,
child 1 the priorities, child ``i + 2`` UAV ``i``'s departure and its destination. A UAV's
departure and its trip's length and bearing draws do not depend on N (the area and the other
pads, which the rejection sees, do).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from uavmpc.config import ConfigError, positive
from uavmpc.reference import Reference
from uavmpc.scenarios import LinkSettings, Scenario, UavSpec
from uavmpc.scenarios.stats import percentile
from uavmpc.tracker.params import DynamicLimits

if TYPE_CHECKING:
    from uavmpc.scenarios.run import Flight

DEFAULT_UAVS = 300
DEFAULT_DENSITY_PER_KM2 = 50.0
DEFAULT_CRUISE_HEIGHTS_M = (30.0,)
#: Share of the tracker's speed and acceleration limits the reference is timed at.
SPEED_SHARE = 0.9
ACCEL_SHARE = 0.8
SAMPLE_PERIOD_S = 0.2
#: Earliest departure: every UAV has broadcast its predictions a few times (2 Hz) by then.
DEPARTURE_START_S = 2.0
#: The default duration: the latest departure + DURATION_SLACK × its nominal trip + SETTLE_S.
DURATION_SLACK = 1.5
SETTLE_S = 10.0
#: Same as the world's goal tolerance: arriving means coming this close to the goal (3-D).
ARRIVAL_TOLERANCE_M = 1.0
#: A UAV counts as airborne when more than this above its origin and its destination pads.
AIRBORNE_HEIGHT_M = 1.0
MAX_UAVS = 1000
_ATTEMPTS_PER_PAD = 2000


@dataclass(frozen=True, eq=False)
class TrafficScenario(Scenario):
    """A :class:`~uavmpc.scenarios.Scenario` with the traffic's layout, for the outcome."""

    area_side_m: float = 0.0
    density_per_km2: float = 0.0
    #: Per UAV (in ``uavs`` order): the time it leaves its pad [s].
    departures_s: tuple[float, ...] = ()
    #: Per UAV: its cruise height [m] and its trip's horizontal length [m].
    cruise_m: tuple[float, ...] = ()
    trip_m: tuple[float, ...] = ()
    #: Per UAV: its nominal trip time: from departure until the reference comes within
    #: ARRIVAL_TOLERANCE_M of the goal [s].
    nominal_trip_s: tuple[float, ...] = ()

    @property
    def area_km2(self) -> float:
        return (self.area_side_m / 1000.0) ** 2


def _trapezoid(distance_m: float, speed_mps: float, accel_mps2: float,
               t_s: np.ndarray) -> np.ndarray:
    """Distance covered at ``t_s`` along a rest-to-rest trapezoidal profile."""
    t_acc = speed_mps / accel_mps2
    if distance_m < speed_mps * t_acc:  # never reaches cruise speed: a triangle
        t_acc = math.sqrt(distance_m / accel_mps2)
        speed_mps = accel_mps2 * t_acc
    total = 2.0 * t_acc + (distance_m - speed_mps * t_acc) / speed_mps
    t = np.clip(t_s, 0.0, total)
    s = np.where(t < t_acc, 0.5 * accel_mps2 * t**2,
                 0.5 * speed_mps * t_acc + speed_mps * (t - t_acc))
    tail = np.maximum(total - t, 0.0)
    s = np.where(t > total - t_acc, distance_m - 0.5 * accel_mps2 * tail**2, s)
    return np.asarray(np.minimum(s, distance_m))


def _leg_time(distance_m: float, speed_mps: float, accel_mps2: float) -> float:
    t_acc = speed_mps / accel_mps2
    if distance_m < speed_mps * t_acc:
        return 2.0 * math.sqrt(distance_m / accel_mps2)
    return 2.0 * t_acc + (distance_m - speed_mps * t_acc) / speed_mps


def take_off(up_m: float, tau_s: np.ndarray,
             limits: DynamicLimits | None = None) -> tuple[np.ndarray, float]:
    """The vertical take-off: the height gained ``tau_s`` [s] after lift-off (0 before, ``up_m``
    once there) along a rest-to-rest climb of ``up_m`` [m] at SPEED_SHARE of the ascent speed
    and ACCEL_SHARE of the ascent acceleration of ``limits`` (default: the tracker's), and the
    climb's duration [s]. A trip's climb, and the random walk's take-off from the ground
    (:mod:`uavmpc.scenarios.random_walk`)."""
    lim = limits if limits is not None else DynamicLimits()
    speed, accel = SPEED_SHARE * lim.ascend_speed_mps, ACCEL_SHARE * lim.ascend_accel_mps2
    return _trapezoid(up_m, speed, accel, tau_s), _leg_time(up_m, speed, accel)


def trip_reference(origin_xy: Sequence[float] | np.ndarray, dest_xy: Sequence[float] | np.ndarray,
                   pad_z_m: float, cruise_z_m: float, depart_s: float,
                   limits: DynamicLimits | None = None) -> tuple[Reference, float, float]:
    """One trip's reference (hold on the pad, climb, cruise, descend, hold), its departure
    (``depart_s`` rounded up to the sampling grid) and its nominal duration from departure to
    touchdown [s]."""
    lim = limits if limits is not None else DynamicLimits()
    o, d = np.asarray(origin_xy, float), np.asarray(dest_xy, float)
    length = float(np.linalg.norm(d - o))
    up = cruise_z_m - pad_z_m
    if length < 1e-6 or up <= 0.0:
        raise ConfigError(f"trip_reference: needs two distinct pads and a cruise above them, "
                          f"got a {length:g} m trip at {up:g} m above the pads")
    legs = (
        (up, lim.ascend_speed_mps, lim.ascend_accel_mps2),
        (length, lim.horizontal_speed_mps, lim.horizontal_accel_mps2),
        (up, lim.descend_speed_mps, lim.descend_accel_mps2),
    )
    durations = [_leg_time(dist, SPEED_SHARE * v, ACCEL_SHARE * a) for dist, v, a in legs]
    total = sum(durations)
    # A uniform grid from 0 (the reference samples in O(1)); the departure sits on it.
    k0 = math.ceil(depart_s / SAMPLE_PERIOD_S - 1e-9)
    t0 = k0 * SAMPLE_PERIOD_S
    n = k0 + math.ceil(total / SAMPLE_PERIOD_S) + 1
    times = SAMPLE_PERIOD_S * np.arange(n)
    tau = times - t0  # time since departure
    climb, _ = take_off(up, tau, lim)
    tau1 = tau - durations[0]
    along = _trapezoid(length, SPEED_SHARE * legs[1][1], ACCEL_SHARE * legs[1][2], tau1)
    tau2 = tau1 - durations[1]
    down = _trapezoid(up, SPEED_SHARE * legs[2][1], ACCEL_SHARE * legs[2][2], tau2)
    unit = (d - o) / length
    xy = o[None, :] + along[:, None] * unit[None, :]
    z = pad_z_m + climb - down
    heading = math.atan2(unit[1], unit[0])
    points = np.column_stack([xy, z, np.full(n, heading)])
    points[-1, :3] = (d[0], d[1], pad_z_m)  # exactly on the pad, not rounding away from it
    return Reference(times, points), t0, total


def cruise_height(bearing_rad: float, heights_m: Sequence[float]) -> float:
    """The layer of a trip by its compass bearing (clockwise from north, rad): equal sectors
    from north, clockwise, one per height, in the order given."""
    k = len(heights_m)
    sector = int((bearing_rad % (2.0 * math.pi)) / (2.0 * math.pi / k))
    return float(heights_m[min(sector, k - 1)])


def _check(n_uavs: int, density: float, duration_s: float | None, heights: Sequence[float],
           min_trip_m: float, max_trip_m: float, separation: float, window: float,
           pad_z: float) -> tuple[float, ...]:
    if isinstance(n_uavs, bool) or not isinstance(n_uavs, int) or not 1 <= n_uavs <= MAX_UAVS:
        raise ConfigError(f"n_uavs: must be an integer in [1, {MAX_UAVS}], got {n_uavs!r}")
    positive(density, "density_per_km2", upper=1e6)
    if duration_s is not None:
        positive(duration_s, "duration_s", upper=7 * 24 * 3600.0)
    positive(separation, "min_pad_separation_m", upper=1e4)
    positive(min_trip_m, "min_trip_m", upper=1e5)
    positive(max_trip_m, "max_trip_m", upper=1e5)
    if max_trip_m < min_trip_m:
        raise ConfigError(f"max_trip_m: must be ≥ min_trip_m ({min_trip_m}), got {max_trip_m}")
    if min_trip_m < separation:
        raise ConfigError(f"min_trip_m: must be ≥ min_pad_separation_m ({separation}), got "
                          f"{min_trip_m}")
    positive(window, "departure_window_s", upper=24 * 3600.0, allow_zero=True)
    positive(pad_z, "pad_height_m", upper=1e4, allow_zero=True)
    if isinstance(heights, str | bytes) or not isinstance(heights, Sequence) or not heights:
        raise ConfigError(f"cruise_heights_m: must be a non-empty list of heights, got "
                          f"{heights!r}")
    out = tuple(positive(h, f"cruise_heights_m[{i}]", upper=1e4) for i, h in enumerate(heights))
    for i, h in enumerate(out):
        if h < pad_z + 2.0 * AIRBORNE_HEIGHT_M:
            raise ConfigError(f"cruise_heights_m[{i}]: must be at least "
                              f"{2 * AIRBORNE_HEIGHT_M:g} m above pad_height_m ({pad_z}), got {h}")
        if h in out[:i]:
            raise ConfigError(f"cruise_heights_m[{i}]: duplicate of cruise_heights_m"
                              f"[{out.index(h)}]")
    return out


def _far_enough(p: np.ndarray, pads: np.ndarray, count: int, separation: float) -> bool:
    if count == 0:
        return True
    return bool(np.min(np.sum((pads[:count] - p) ** 2, axis=1)) >= separation**2)


def _origin_pads(rng: np.random.Generator, n_uavs: int, side: float,
                 separation: float) -> np.ndarray:
    """(2 n_uavs, 2): room for every pad, the first ``n_uavs`` (the origins) drawn uniformly
    in the square of side ``side`` [m], each ``separation`` [m] from those before it."""
    half = 0.5 * side
    pads = np.empty((2 * n_uavs, 2))
    count = 0
    for _ in range(_ATTEMPTS_PER_PAD * n_uavs):
        p = rng.uniform(-half, half, size=2)
        if _far_enough(p, pads, count, separation):
            pads[count] = p
            count += 1
            if count == n_uavs:
                return pads
    raise ConfigError(
        f"density_per_km2: cannot place {n_uavs} pads {separation:g} m apart "
        f"(min_pad_separation_m) in a {side:.0f} m square; lower the density")


def _destination(rng: np.random.Generator, pads: np.ndarray, count: int, i: int,
                 trip_m: tuple[float, float], side: float,
                 separation: float) -> tuple[np.ndarray, float, float]:
    """UAV ``i``'s destination pad, stored as ``pads[count]`` (at a uniform bearing and a
    distance uniform in ``trip_m`` from its origin, inside the square, ``separation`` from
    every pad so far): (pad, distance [m], compass bearing [rad])."""
    half = 0.5 * side
    for _ in range(_ATTEMPTS_PER_PAD):
        dist = float(rng.uniform(trip_m[0], trip_m[1]))
        bearing = float(rng.uniform(0.0, 2.0 * math.pi))  # compass: clockwise from north
        q = pads[i] + dist * np.array([math.sin(bearing), math.cos(bearing)])
        if np.all(np.abs(q) <= half) and _far_enough(q, pads, count, separation):
            pads[count] = q
            return q, dist, bearing
    raise ConfigError(
        f"min_trip_m: no destination pad {trip_m[0]:g}–{trip_m[1]:.0f} m from pad "
        f"{i + 1} fits in the {side:.0f} m square; lower density_per_km2 or the trip "
        "bounds")


def traffic(n_uavs: int = DEFAULT_UAVS, seed: int = 0, *,
            density_per_km2: float = DEFAULT_DENSITY_PER_KM2, duration_s: float | None = None,
            cruise_heights_m: Sequence[float] = DEFAULT_CRUISE_HEIGHTS_M,
            min_trip_m: float = 200.0, max_trip_m: float = 1000.0,
            min_pad_separation_m: float = 15.0, departure_window_s: float = 60.0,
            pad_height_m: float = 0.0, airframe: str = "f550",
            link: LinkSettings | None = None) -> TrafficScenario:
    """The traffic scenario (see the module docstring for the choices).

    ``duration_s``: None for the default (every trip has time to finish, with slack).
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigError(f"seed: must be a non-negative integer, got {seed!r}")
    heights = _check(n_uavs, density_per_km2, duration_s, cruise_heights_m, min_trip_m,
                     max_trip_m, min_pad_separation_m, departure_window_s, pad_height_m)
    side = 1000.0 * math.sqrt(n_uavs / float(density_per_km2))
    # The longest trip the square can hold (its diagonal), so the draws are not wasted.
    longest = min(float(max_trip_m), math.sqrt(2.0) * side)
    if longest < min_trip_m:
        raise ConfigError(
            f"min_trip_m: {min_trip_m} m does not fit in the {side:.0f} m square that "
            f"{n_uavs} UAVs at density_per_km2 = {density_per_km2:g} make")
    children = np.random.SeedSequence(int(seed)).spawn(n_uavs + 2)
    pads = _origin_pads(np.random.default_rng(children[0]), n_uavs, side,
                        min_pad_separation_m)
    count = n_uavs
    priorities = np.random.default_rng(children[1]).permutation(n_uavs) + 1
    limits = DynamicLimits()
    uavs = []
    departures, cruise, trips, nominal = [], [], [], []
    longest_s = 0.0
    for i in range(n_uavs):
        rng = np.random.default_rng(children[i + 2])
        depart = DEPARTURE_START_S + float(rng.uniform(0.0, departure_window_s))
        q, dist, bearing = _destination(rng, pads, count, i, (min_trip_m, longest), side,
                                        min_pad_separation_m)
        count += 1
        height = cruise_height(bearing, heights)
        mission, leave, total = trip_reference(pads[i], q, float(pad_height_m), height, depart,
                                               limits)
        start = (float(pads[i, 0]), float(pads[i, 1]), float(pad_height_m))
        goal = (float(q[0]), float(q[1]), float(pad_height_m))
        uavs.append(UavSpec(f"uav{i + 1}", int(priorities[i]), airframe, start,
                            float(mission.points[0, 3]), mission, goal))
        departures.append(leave)
        cruise.append(height)
        trips.append(dist)
        # Measured like a flown trip (first within the arrival tolerance), so that a flown
        # trip's delay over it is the cost of the flight, not of the definition.
        near = np.flatnonzero(np.sum((mission.points[:, :3] - np.asarray(goal)) ** 2, axis=1)
                              < ARRIVAL_TOLERANCE_M**2)
        nominal.append(float(mission.times_s[near[0]]) - leave)
        longest_s = max(longest_s, leave + DURATION_SLACK * total)
    if duration_s is None:
        duration_s = longest_s + SETTLE_S
    return TrafficScenario(
        "traffic", float(duration_s), tuple(uavs),
        link if link is not None else LinkSettings(),
        area_side_m=side, density_per_km2=float(density_per_km2),
        departures_s=tuple(departures), cruise_m=tuple(cruise), trip_m=tuple(trips),
        nominal_trip_s=tuple(nominal))


# ------------------------------------------------------------------------------ outcome
def arrival_times(result: Flight, scenario: TrafficScenario) -> dict[str, float | None]:
    """Per UAV: the first sample time it was within :data:`ARRIVAL_TOLERANCE_M` of its goal
    (3-D), or None if never."""
    index = {uid: k for k, uid in enumerate(result.uav_ids)}
    out: dict[str, float | None] = {}
    for u in scenario.uavs:
        track = result.positions_m[:, index[u.uav_id]]
        near = np.flatnonzero(np.sum((track - np.asarray(u.goal_m)) ** 2, axis=1)
                              < ARRIVAL_TOLERANCE_M**2)
        out[u.uav_id] = float(result.t_s[near[0]]) if near.size else None
    return out


def trip_times(result: Flight, scenario: TrafficScenario) -> dict[str, float | None]:
    """Per UAV: its trip time, from its scheduled departure to its first arrival within
    :data:`ARRIVAL_TOLERANCE_M` of its goal [s] (None if it never came that close)."""
    arrive = arrival_times(result, scenario)
    trips: dict[str, float | None] = {}
    for u, departure_s in zip(scenario.uavs, scenario.departures_s, strict=True):
        at_s = arrive[u.uav_id]
        trips[u.uav_id] = None if at_s is None else at_s - departure_s
    return trips


def airborne_counts(result: Flight, scenario: TrafficScenario) -> np.ndarray:
    """(K,) how many UAVs are airborne at each sample: more than :data:`AIRBORNE_HEIGHT_M`
    above both its pads (all pads of a scenario are at one height)."""
    pad_z = np.array([u.start_m[2] for u in scenario.uavs])
    index = [list(result.uav_ids).index(u.uav_id) for u in scenario.uavs]
    z = result.positions_m[:, index, 2]
    return np.asarray(np.count_nonzero(z > pad_z[None, :] + AIRBORNE_HEIGHT_M, axis=1))


def traffic_outcome(result: Flight, scenario: TrafficScenario) -> dict[str, Any]:
    """The traffic's figures from a :class:`~uavmpc.drivers.world.WorldResult` of
    ``scenario``: collisions, closest approach, goals reached, trip times, airborne density."""
    n = len(scenario.uavs)
    trips = trip_times(result, scenario)
    done = [t for t in trips.values() if t is not None]
    reached = sum(1 for o in result.per_uav.values() if o.reached_goal)
    airborne = airborne_counts(result, scenario)
    area = scenario.area_km2
    closest = float(np.min(result.min_distance_m)) if n > 1 and len(result.t_s) else None
    nominal = dict(zip((u.uav_id for u in scenario.uavs), scenario.nominal_trip_s,
                       strict=True))
    delay = [t - nominal[k] for k, t in trips.items() if t is not None]
    return {
        "uavs": n,
        "area_side_m": scenario.area_side_m,
        "area_km2": area,
        "density_per_km2": scenario.density_per_km2,
        "collisions": len(result.collisions),
        "colliding_uavs": len({c.a for c in result.collisions} | {c.b for c in result.collisions}),
        "closest_approach_m": closest,
        "goals_reached": reached,
        "goals_reached_share": reached / n,
        "arrived": len(done),
        "trip_s": {"p50": percentile(done, 50), "p95": percentile(done, 95),
                   "max": max(done) if done else None},
        "nominal_trip_s": {"p50": percentile(scenario.nominal_trip_s, 50),
                           "p95": percentile(scenario.nominal_trip_s, 95),
                           "max": max(scenario.nominal_trip_s)},
        "delay_s": {"mean": float(np.mean(delay)) if delay else None, "p50": percentile(delay, 50),
                    "p95": percentile(delay, 95)},
        "airborne": {"peak": int(airborne.max()) if airborne.size else 0,
                     "mean": float(airborne.mean()) if airborne.size else 0.0,
                     "peak_density_per_km2": (float(airborne.max()) / area
                                              if airborne.size else 0.0),
                     "mean_density_per_km2": (float(airborne.mean()) / area
                                              if airborne.size else 0.0)},
        "per_uav_trip_s": {k: (None if v is None else round(v, 3)) for k, v in trips.items()},
    }


def outcome_lines(o: dict[str, Any]) -> list[str]:
    """The outcome in a few human lines (``uavmpc run traffic``)."""
    def s(v: float | None) -> str:
        return "–" if v is None else f"{v:.1f} s"

    closest = o["closest_approach_m"]
    t, nom, a = o["trip_s"], o["nominal_trip_s"], o["airborne"]
    return [
        f"  traffic: {o['uavs']} UAVs over {o['area_km2']:.3g} km² "
        f"({o['area_side_m']:.0f} m square, {o['density_per_km2']:g}/km²); airborne peak "
        f"{a['peak']} ({a['peak_density_per_km2']:.1f}/km²), mean {a['mean']:.1f}",
        f"  {o['collisions']} collision(s) involving {o['colliding_uavs']} UAV(s); closest "
        f"approach {'–' if closest is None else f'{closest:.2f} m'}",
        f"  goals reached {o['goals_reached']}/{o['uavs']} "
        f"({100 * o['goals_reached_share']:.0f} %), arrived at some point {o['arrived']}",
        f"  trip time p50 {s(t['p50'])}, p95 {s(t['p95'])}, max {s(t['max'])} "
        f"(nominal p50 {s(nom['p50'])}, p95 {s(nom['p95'])}); delay over nominal p50 "
        f"{s(o['delay_s']['p50'])}, p95 {s(o['delay_s']['p95'])}",
    ]
