"""Dense and adversarial scenarios: the antipodal circle for any N, vertical stack swaps, a
grid shuffled, and when goals are reached.

``antipodal(n)``: N UAVs evenly on a circle, all at one height, each flying a straight path to
the point diametrically opposite its start, all at the same speed from the same time, so that
every path crosses every other above the centre at once: the densest meeting N UAVs can be
asked for. The built-ins ``antipodal_8`` and ``antipodal_12`` (``scenarios.load``) are
``antipodal(8)`` and ``antipodal(12, duration_s=150)`` written out by :func:`antipodal_toml`;
any other N: ``antipodal(n)``, e.g. ``World(RunSpec(antipodal(10))).run()``.

Above one point, N UAVs need N layers: the reference parameters (``dz_m`` = 3 m under the
ceiling ``max_offset_m`` = 30 m) give 11, a geofence's ceiling (``ceiling_m``) fewer. Beyond
them, the lower priorities hold short until the way is clear (docs/safety.md, A6); measured
with benchmarks/sweep_dense.py.

Reaching a goal. The world's :class:`~uavmpc.drivers.world.UavOutcome` says whether a UAV
*ended* within :data:`~uavmpc.drivers.world.GOAL_TOLERANCE_M` (3-D) of its goal.
:func:`time_to_goals` says *when*, from the position traces: by default the time from which it
stayed within the tolerance until the end (a UAV crossing its goal on the way, or hovering at
it before being pushed off, has not reached it yet), else the first time it came within.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from uavmpc.config import ConfigError, positive
from uavmpc.geofence import Geofence
from uavmpc.reference import Reference
from uavmpc.scenarios import LinkSettings, Scenario, UavSpec

if TYPE_CHECKING:
    from uavmpc.scenarios.run import Flight

#: Same tolerance as the world's ``reached_goal`` (uavmpc.drivers.world.GOAL_TOLERANCE_M; not
#: imported from there: the drivers import the scenarios; a test checks they agree).
GOAL_TOLERANCE_M = 1.0
#: Decimals the built-in TOML files carry (far below any physical scale of a flight).
_DECIMALS = 12
#: The antipodal circles' cruise: one speed for all, so that all meet above the centre at
#: once (a goto would not do: the limits are per axis, so a UAV flying diagonally would be
#: √2 faster and pass first). 6 m/s leaves the tracker 2.3 m/s below its 8.3 m/s limit to
#: catch up with the path after the avoidance slowed it.
SPEED_MPS = 6.0
#: Everyone departs at once, after 2 s: each has broadcast a few predictions by then, so no one
#: leaves unheard (as uavmpc.scenarios.traffic's departures).
START_S = 2.0
DURATION_S = 90.0


def _fence(box: list[float], ceiling_m: float | None, highest_m: float,
           what: str) -> Geofence | None:
    """The operational volume of a generated scenario: ``box`` [x0, y0, x1, y1] [m] from the
    ground up to ``ceiling_m`` [m] (None: no geofence), which must leave 2 m above
    ``highest_m``, the highest start (``what``, for the error)."""
    if ceiling_m is None:
        return None
    top = positive(ceiling_m, "ceiling_m", upper=1e4)
    if top < highest_m + 2.0:
        raise ConfigError(f"ceiling_m: {top:g} m leaves no room above {what} "
                          f"{highest_m:g} m (need ≥ {highest_m + 2.0:g} m)")
    return Geofence.from_dict({"box": box, "min_altitude_m": 0.0, "max_altitude_m": top},
                              "geofence")


def antipodal(n_uavs: int, radius_m: float = 30.0, height_m: float = 10.0,
              speed_mps: float = SPEED_MPS, start_s: float = START_S,
              duration_s: float = DURATION_S, *, link: LinkSettings | None = None,
              ceiling_m: float | None = None, reversed_priorities: bool = False) -> Scenario:
    """N UAVs on a circle of ``radius_m`` [m] around the origin at ``height_m`` [m], UAV i
    (``uav{i+1}``, priority i + 1, or N − i with ``reversed_priorities``) at the angle 2πi/N,
    heading the way it will fly; each flies a straight path to the opposite point at
    ``speed_mps`` [m/s] from ``start_s`` [s]. ``duration_s`` [s] is the run's length.
    ``ceiling_m`` [m]: an operational volume (a geofence) over the circle, from the ground up
    to that altitude: the layers above the circle's height run out sooner."""
    if isinstance(n_uavs, bool) or not isinstance(n_uavs, int) or not 2 <= n_uavs <= 1000:
        raise ConfigError(f"uavs: must be an integer in [2, 1000], got {n_uavs!r}")
    radius = positive(radius_m, "radius_m", upper=1e4)
    height = positive(height_m, "height_m", upper=1e4)
    speed = positive(speed_mps, "speed_mps", upper=100.0)
    start = positive(start_s, "start_s", upper=3600.0, allow_zero=True)
    duration = positive(duration_s, "duration_s", upper=7 * 24 * 3600.0)
    # Neighbours closer than a collision at the start are a set-up error, not a conflict.
    gap = 2.0 * radius * math.sin(math.pi / n_uavs)
    if gap < 2.0:
        raise ConfigError(f"radius_m: {n_uavs} UAVs on a {radius:g} m circle start "
                          f"{gap:.2f} m apart, need ≥ 2 m")
    uavs = []
    for i in range(n_uavs):
        a = 2.0 * math.pi * i / n_uavs
        x = round(radius * math.cos(a), _DECIMALS) + 0.0  # + 0.0: no −0.0 in the files
        y = round(radius * math.sin(a), _DECIMALS) + 0.0
        heading = round(math.atan2(-y, -x), _DECIMALS) + 0.0
        here, there = (x, y, height), (-x + 0.0, -y + 0.0, height)
        # As the scenario loader builds a [uavs.path]: the built-in files fly the same.
        mission = Reference.along_path(np.array([here, there]), speed, start)
        goal = tuple(float(v) for v in mission.points[-1, :3])
        priority = n_uavs - i if reversed_priorities else i + 1
        uavs.append(UavSpec(f"uav{i + 1}", priority, "f550", here, heading, mission,
                            (goal[0], goal[1], goal[2])))
    side = radius + 10.0
    fence = _fence([-side, -side, side, side], ceiling_m, height, "the circle's")
    name = f"antipodal_{n_uavs}" + ("_reversed" if reversed_priorities else "")
    return Scenario(name, duration, tuple(uavs),
                    link if link is not None else LinkSettings(), geofence=fence)


def vertical_swap(per_stack: int, gap_m: float = 40.0, bottom_m: float = 6.0,
                  spacing_m: float = 6.0, speed_mps: float = SPEED_MPS,
                  start_s: float = START_S, duration_s: float = DURATION_S, *,
                  link: LinkSettings | None = None, ceiling_m: float | None = None
                  ) -> Scenario:
    """Two stacks of ``per_stack`` UAVs, one above the other every ``spacing_m`` [m] from
    ``bottom_m`` [m], ``gap_m`` [m] apart on the x axis, swap places and invert their heights:
    the lowest of one stack flies to the top of the other's place. Every path climbs or
    descends through the others' heights while they cross: vertical traffic, which a layer of
    offsets alone does not separate. Priorities: the west stack first (bottom up), then the
    east. ``ceiling_m``: a geofence from the ground up to it (default: 12 m above the top)."""
    if isinstance(per_stack, bool) or not isinstance(per_stack, int) or not 1 <= per_stack <= 50:
        raise ConfigError(f"per_stack: must be an integer in [1, 50], got {per_stack!r}")
    gap = positive(gap_m, "gap_m", upper=1e4)
    bottom = positive(bottom_m, "bottom_m", upper=1e4)
    spacing = positive(spacing_m, "spacing_m", upper=1e3)
    if spacing < 2.0:
        raise ConfigError(f"spacing_m: UAVs of a stack {spacing:g} m apart, need ≥ 2 m")
    speed = positive(speed_mps, "speed_mps", upper=100.0)
    start = positive(start_s, "start_s", upper=3600.0, allow_zero=True)
    duration = positive(duration_s, "duration_s", upper=7 * 24 * 3600.0)
    heights = [bottom + spacing * k for k in range(per_stack)]
    side_m = 0.5 * gap + 10.0
    fence = _fence([-side_m, -10.0, side_m, 10.0],
                   heights[-1] + 12.0 if ceiling_m is None else ceiling_m, heights[-1],
                   "the stack's top")
    uavs = []
    for side, x in enumerate((-0.5 * gap, 0.5 * gap)):
        heading = 0.0 if x < 0.0 else math.pi
        for k, z in enumerate(heights):
            here, there = (x, 0.0, z), (-x, 0.0, heights[per_stack - 1 - k])
            mission = Reference.along_path(np.array([here, there]), speed, start)
            n = side * per_stack + k + 1
            uavs.append(UavSpec(f"uav{n}", n, "f550", here, heading, mission, there))
    return Scenario(f"vertical_swap_{per_stack}", duration, tuple(uavs),
                    link if link is not None else LinkSettings(), geofence=fence)


def grid_shuffle(n_uavs: int, spacing_m: float = 10.0, height_m: float = 10.0,
                 speed_mps: float = SPEED_MPS, start_s: float = START_S,
                 duration_s: float = 120.0, seed: int = 0, *,
                 link: LinkSettings | None = None, ceiling_m: float | None = 25.0
                 ) -> Scenario:
    """``n_uavs`` (a square number) UAVs on a square grid of ``spacing_m`` [m] around the
    origin at ``height_m`` [m], each flying straight to another grid point (a random
    permutation without a fixed point, from ``seed``) at ``speed_mps`` [m/s] from ``start_s``
    [s]: paths crossing in every direction and at every distance, where an antipodal circle's
    all cross at one point. Priorities in grid order. ``ceiling_m``: a geofence from the
    ground up to it, 10 m around the grid (None: none)."""
    if isinstance(n_uavs, bool) or not isinstance(n_uavs, int) or not 4 <= n_uavs <= 400:
        raise ConfigError(f"uavs: must be an integer in [4, 400], got {n_uavs!r}")
    side = math.isqrt(n_uavs)
    if side * side != n_uavs:
        raise ConfigError(f"uavs: a square grid needs a square number, got {n_uavs}")
    spacing = positive(spacing_m, "spacing_m", upper=1e3)
    if spacing < 2.0:
        raise ConfigError(f"spacing_m: grid points {spacing:g} m apart, need ≥ 2 m")
    height = positive(height_m, "height_m", upper=1e4)
    speed = positive(speed_mps, "speed_mps", upper=100.0)
    start = positive(start_s, "start_s", upper=3600.0, allow_zero=True)
    duration = positive(duration_s, "duration_s", upper=7 * 24 * 3600.0)
    half = 0.5 * spacing * (side - 1)
    points = [(round(-half + spacing * (k % side), _DECIMALS) + 0.0,
               round(-half + spacing * (k // side), _DECIMALS) + 0.0) for k in range(n_uavs)]
    rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
    while True:  # a derangement: nobody's goal is its start
        goal_of = rng.permutation(n_uavs)
        if not np.any(goal_of == np.arange(n_uavs)):
            break
    uavs = []
    for i in range(n_uavs):
        (x, y), (gx, gy) = points[i], points[int(goal_of[i])]
        here, there = (x, y, height), (gx, gy, height)
        heading = round(math.atan2(gy - y, gx - x), _DECIMALS) + 0.0
        mission = Reference.along_path(np.array([here, there]), speed, start)
        uavs.append(UavSpec(f"uav{i + 1}", i + 1, "f550", here, heading, mission, there))
    box = half + 10.0
    fence = _fence([-box, -box, box, box], ceiling_m, height, "the grid's")
    return Scenario(f"grid_{n_uavs}", duration, tuple(uavs),
                    link if link is not None else LinkSettings(), geofence=fence)


def antipodal_toml(n_uavs: int, radius_m: float = 30.0, height_m: float = 10.0,
                   speed_mps: float = SPEED_MPS, start_s: float = START_S,
                   duration_s: float = DURATION_S) -> str:
    """:func:`antipodal`'s scenario as a scenario file's text (how the built-ins were
    written: ``antipodal_toml(8)``)."""
    sc = antipodal(n_uavs, radius_m, height_m, speed_mps, start_s, duration_s)

    def num(v: float) -> str:
        return repr(float(v))

    gap = 2.0 * radius_m * math.sin(math.pi / n_uavs)
    lines = [f"# {n_uavs} UAVs evenly on a circle of radius {radius_m:g} m at {height_m:g} m "
             f"(neighbours {gap:.1f} m apart), each",
             f"# flying straight to the diametrically opposite point at {speed_mps:g} m/s, all "
             f"from t = {start_s:g} s: every",
             "# path crosses every other above the origin at the same time, in one layer.",
             f"# Written by uavmpc.scenarios.dense.antipodal_toml({n_uavs}).",
             f'name = "{sc.name}"', f"duration_s = {num(sc.duration_s)}", "",
             "[link]", f"latency_s = {num(sc.link.latency_s)}",
             f"jitter_s = {num(sc.link.jitter_s)}", f"loss = {num(sc.link.loss)}"]
    for u in sc.uavs:
        here = ", ".join(num(v) for v in u.start_m)
        x, y, z = u.start_m
        there = ", ".join(num(v) for v in (-x + 0.0, -y + 0.0, z))
        lines += ["", "[[uavs]]", f'id = "{u.uav_id}"', f"priority = {u.priority}",
                  f'airframe = "{u.airframe}"', f"start = [{here}]",
                  f"heading_rad = {num(u.heading_rad)}", "[uavs.path]",
                  f"waypoints = [[{here}], [{there}]]",
                  f"speed_mps = {num(speed_mps)}", f"start_s = {num(start_s)}"]
    return "\n".join(lines) + "\n"


def time_to_goals(result: Flight, scenario: Scenario, *, settled: bool = True,
                  tolerance_m: float = GOAL_TOLERANCE_M) -> dict[str, float | None]:
    """Per UAV id, when it reached its goal [s, the world's clock], from
    ``result.positions_m`` (K, N, 3) and ``result.t_s`` (K,) of a
    :class:`~uavmpc.drivers.world.WorldResult` (any object with those two arrays).

    ``settled`` (default): the first sample from which it stayed within ``tolerance_m`` [m]
    (3-D) of its goal to the end; None if it ended outside. Else: the first sample within; None
    if never. None too for a UAV whose mission sets its way (a lander, a formation's
    follower: its ``reached_goal`` is None)."""
    tol = positive(tolerance_m, "tolerance_m", upper=1e4)
    t, pos, ids, per_uav = result.t_s, result.positions_m, result.uav_ids, result.per_uav
    goals = {u.uav_id: np.asarray(u.goal_m) for u in scenario.uavs}
    if set(ids) != set(goals):
        raise ValueError(f"the result's UAVs {sorted(ids)} are not the scenario's "
                         f"{sorted(goals)}")
    out: dict[str, float | None] = {}
    for i, uid in enumerate(ids):
        if per_uav[uid].reached_goal is None:
            out[uid] = None
            continue
        within = np.linalg.norm(pos[:, i] - goals[uid], axis=1) < tol
        if settled:
            if not within[-1]:
                out[uid] = None
                continue
            outside = np.flatnonzero(~within)
            k = int(outside[-1]) + 1 if outside.size else 0
        else:
            hits = np.flatnonzero(within)
            if not hits.size:
                out[uid] = None
                continue
            k = int(hits[0])
        out[uid] = float(t[k])
    return out
