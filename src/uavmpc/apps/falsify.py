"""``uavmpc falsify``: a search of scenario space for the smallest separation the avoidance
allows, by the truth of the simulated world.

A *case* is a point θ of the unit cube [0, 1]^(8N) for N UAVs: per UAV its start and its goal
(x, y in the square of ``area_m``, z between ``min_height_m`` and ``max_height_m``), when it
sets off (0 to :data:`MAX_DELAY_S` after the common start) and a key that orders the
priorities. Each UAV flies a straight path from its start to its goal at ``speed_mps``, under
a geofence whose ceiling is ``ceiling_m``; the link and the faults are the run's (one flight
seed per case: the losses and the faults are drawn from it). A case whose starts or goals lie
closer than :data:`MIN_GAP_M` is drawn again.

That is the ``straight`` family, the default. The others (``--family``, :data:`FAMILIES`) map
θ to other scenarios the same search runs over: ``vertical`` (UAVs in a few columns climbing
and descending through each other's heights), ``grid`` (a grid's points shuffled among its
UAVs, under a 25 m ceiling unless one is given) and ``walk`` (waypoints in one height band).
Each says how many coordinates θ has (:meth:`Family.dims`), the case a θ is
(:meth:`Family.plan`: each UAV's waypoints, delay and priority) and what it asks of a case
besides the gaps (:meth:`Family.valid`); a space it cannot draw from is a ConfigError
(:meth:`Family.check`). The scenario file is written the same way for all.

The search is the cross-entropy method over θ, as falsification tools search the inputs of a
closed loop for the lowest robustness of a property (here: the closest approach of any pair,
and the highest altitude against the ceiling): a first generation drawn uniformly (random
search), then each generation drawn from a normal law per coordinate fitted to the best
:data:`ELITE` of all cases so far, its spread kept above :data:`MIN_SPREAD` so the search never
collapses onto one case. The budget counts flights.

What it writes (``out``): ``cases.json`` (every flight: its θ, seed, closest approach, when,
which pair, the highest altitude), and the worst cases as scenario files ``worst_<k>.toml``
each headed by the command that replays it (``uavmpc run FILE --seed S`` with the run's link
and fault flags). Judged, as every run is, by the simulated plants' truth.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from uavmpc.config import ConfigError, positive
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.faults import FaultSpec

#: Per UAV: start x, y, z, goal x, y, z, delay, priority key.
DIMS_PER_UAV = 8
#: Starts (and goals) closer than this are not searched [m]: the pair radius, so that no
#: pair starts near and what comes closer is the avoidance's doing (with 3 m, the first
#: search's worst cases were pairs 3 m apart at their starts).
MIN_GAP_M = 5.0
#: The latest a UAV sets off after the common start [s].
MAX_DELAY_S = 8.0
#: When every UAV may set off at the earliest [s]: each has broadcast by then.
START_S = 2.0
#: The share of all cases so far whose law the next generation is drawn from.
ELITE = 0.2
#: The smallest spread of a coordinate of θ (its range is 1).
MIN_SPREAD = 0.03
#: Draws of a case before a set-up error is given up on (a cube this crowded is refused).
MAX_DRAWS = 1000
#: The worst cases written as scenario files.
KEEP = 5
#: Two consecutive waypoints of a UAV closer than this are drawn again [m].
MIN_LEG_M = 1.0
#: family vertical: how far a UAV stands from its column's axis, at most, in x and in y [m].
COLUMN_RADIUS_M = 1.0
#: family grid: the grid's spacing [m] (``grid_shuffle``'s).
GRID_SPACING_M = 10.0
#: family walk: the waypoints each UAV flies to after its start.
WALK_LEGS = 4
#: family walk: the height band the walks fly in [m].
WALK_BAND_M = 2.0


@dataclass(frozen=True)
class Plan:
    """What a case flies: per UAV its waypoints (k ≥ 2, 3) [m], the first its start, when it
    sets off after :data:`START_S` [s] and its priority (1…N)."""

    paths: tuple[np.ndarray, ...]
    delays: np.ndarray
    priorities: np.ndarray


def _priorities(keys: np.ndarray) -> np.ndarray:
    """The priorities 1…N in the order of ``keys``."""
    priorities = np.empty(len(keys), dtype=np.int64)
    priorities[np.argsort(keys, kind="stable")] = np.arange(1, len(keys) + 1)
    return priorities


def _xy(u: np.ndarray, space: Space) -> np.ndarray:
    """Unit coordinates (…, 2) as x, y in the square of ``area_m`` [m]."""
    return (2.0 * u - 1.0) * (0.5 * space.area_m)


def _z(u: np.ndarray, space: Space) -> np.ndarray:
    """Unit coordinates as heights between ``min_height_m`` and ``max_height_m`` [m]."""
    return space.min_height_m + u * (space.max_height_m - space.min_height_m)


class Family(Protocol):
    """A family of scenarios: how a θ of the unit cube is a case to fly."""

    @property
    def name(self) -> str:
        """What ``--family`` calls it."""

    @property
    def ceiling_m(self) -> float:
        """The geofence's ceiling unless one is given [m]."""

    def dims(self, space: Space) -> int:
        """The coordinates of θ."""

    def check(self, space: Space) -> None:
        """A ConfigError if no case of ``space`` can be drawn."""

    def plan(self, space: Space, theta: np.ndarray) -> Plan:
        """θ as the case to fly."""

    def valid(self, space: Space, plan: Plan) -> bool:
        """What the family asks of a case beyond the gaps :meth:`Space.valid` checks."""


@dataclass(frozen=True)
class Straight:
    """Each UAV flies one straight path from its start to its goal, anywhere in the space.
    θ per UAV: start x, y, z, goal x, y, z, delay, priority key."""

    name: str = "straight"
    ceiling_m: float = 30.0

    def dims(self, space: Space) -> int:
        return DIMS_PER_UAV * space.uavs

    def check(self, space: Space) -> None:
        """Nothing a straight case cannot fit (the draws say when the area is too small)."""

    def plan(self, space: Space, theta: np.ndarray) -> Plan:
        t = theta.reshape(space.uavs, DIMS_PER_UAV)

        def place(u: np.ndarray) -> np.ndarray:
            return np.column_stack([_xy(u[:, :2], space), _z(u[:, 2], space)])

        starts, goals = place(t[:, 0:3]), place(t[:, 3:6])
        return Plan(tuple(np.array([s, g]) for s, g in zip(starts, goals, strict=True)),
                    t[:, 6] * MAX_DELAY_S, _priorities(t[:, 7]))

    def valid(self, space: Space, plan: Plan) -> bool:
        """Nothing besides the gaps (today's search, bit for bit)."""
        return True


@dataclass(frozen=True)
class Vertical:
    """Heavy vertical traffic: the UAVs stand in :meth:`columns` columns (each at x, y from
    θ), each UAV within :data:`COLUMN_RADIUS_M` of its column's axis, and each flies to a
    column (its own or another) at a height across the whole range, so that paths climb and
    descend through each other's heights (``vertical_swap``'s two stacks swapping places and
    inverting their heights is one case). In a column the UAVs are stacked at least
    :data:`MIN_GAP_M` apart in the order of their height keys. θ: per column x, y; then per
    UAV start column, goal column, start height key, goal height key, x and y offset from
    the axis, delay, priority key."""

    name: str = "vertical"
    ceiling_m: float = 30.0

    @staticmethod
    def columns(space: Space) -> int:
        """Two columns, or one per three UAVs."""
        return max(2, math.ceil(space.uavs / 3))

    @staticmethod
    def per_column(space: Space) -> int:
        """The most UAVs a column stacks :data:`MIN_GAP_M` apart in the height range."""
        return int((space.max_height_m - space.min_height_m) // MIN_GAP_M) + 1

    def dims(self, space: Space) -> int:
        return 2 * self.columns(space) + DIMS_PER_UAV * space.uavs

    def check(self, space: Space) -> None:
        c, m = self.columns(space), self.per_column(space)
        if c * m < space.uavs:
            raise ConfigError(
                f"family vertical: {space.uavs} UAVs do not fit {c} columns of at most {m} "
                f"each ({MIN_GAP_M:g} m apart between {space.min_height_m:g} and "
                f"{space.max_height_m:g} m): widen the heights or fly fewer")

    def plan(self, space: Space, theta: np.ndarray) -> Plan:
        c = self.columns(space)
        axes = _xy(theta[:2 * c].reshape(c, 2), space)
        t = theta[2 * c:].reshape(space.uavs, DIMS_PER_UAV)
        offset = (2.0 * t[:, 4:6] - 1.0) * COLUMN_RADIUS_M
        ends = []
        for col_key, height_key in ((0, 2), (1, 3)):
            column = np.minimum((t[:, col_key] * c).astype(np.int64), c - 1)
            z = self._stack(space, column, t[:, height_key])
            ends.append(np.column_stack([axes[column] + offset, z]))
        return Plan(tuple(np.array([s, g]) for s, g in zip(ends[0], ends[1], strict=True)),
                    t[:, 6] * MAX_DELAY_S, _priorities(t[:, 7]))

    @staticmethod
    def _stack(space: Space, column: np.ndarray, keys: np.ndarray) -> np.ndarray:
        """Heights [m]: in each column, its UAVs in the order of their keys, each at least
        :data:`MIN_GAP_M` above the one below (less only if the range is too short, which
        :meth:`check` refuses), the keys spreading them over the range."""
        span = space.max_height_m - space.min_height_m
        z = np.empty(len(keys))
        for col in np.unique(column):
            members = np.flatnonzero(column == col)
            members = members[np.argsort(keys[members], kind="stable")]
            gap = MIN_GAP_M if len(members) < 2 else min(MIN_GAP_M, span / (len(members) - 1))
            free = span - gap * (len(members) - 1)
            z[members] = (space.min_height_m + np.sort(keys[members]) * free
                          + gap * np.arange(len(members)))
        return z

    def valid(self, space: Space, plan: Plan) -> bool:
        """No UAV's goal within :data:`MIN_LEG_M` of its start."""
        return _legs_ok(plan)


@dataclass(frozen=True)
class Grid:
    """Starts on a grid of :data:`GRID_SPACING_M` around the origin (``grid_shuffle``'s),
    UAV i at point i in rows of ⌈√N⌉; each flies straight to another UAV's start point: the
    goals are the permutation of the goal keys' order, one without a fixed point (a case
    with a UAV flying to its own start is drawn again). Under a lower ceiling by default
    (25 m). θ per UAV: goal key, start height, goal height, delay, priority key."""

    name: str = "grid"
    ceiling_m: float = 25.0

    def dims(self, space: Space) -> int:
        return 5 * space.uavs

    def check(self, space: Space) -> None:
        """Any number of UAVs from 2 has a grid and a permutation without a fixed point."""

    @staticmethod
    def points(n: int) -> np.ndarray:
        """The grid's first ``n`` points (n, 2) [m], rows of ⌈√n⌉ centred on the origin."""
        cols = math.ceil(math.sqrt(n))
        rows = math.ceil(n / cols)
        k = np.arange(n)
        return np.column_stack([GRID_SPACING_M * (k % cols - 0.5 * (cols - 1)),
                                GRID_SPACING_M * (k // cols - 0.5 * (rows - 1))])

    def plan(self, space: Space, theta: np.ndarray) -> Plan:
        t = theta.reshape(space.uavs, 5)
        grid = self.points(space.uavs)
        goal_of = np.argsort(t[:, 0], kind="stable")
        starts = np.column_stack([grid, _z(t[:, 1], space)])
        goals = np.column_stack([grid[goal_of], _z(t[:, 2], space)])
        return Plan(tuple(np.array([s, g]) for s, g in zip(starts, goals, strict=True)),
                    t[:, 3] * MAX_DELAY_S, _priorities(t[:, 4]))

    def valid(self, space: Space, plan: Plan) -> bool:
        """Nobody's goal is its own start point."""
        return all(np.linalg.norm(p[-1, :2] - p[0, :2]) > 1e-9 for p in plan.paths)


@dataclass(frozen=True)
class Walk:
    """A random walk through the area in one height band (the reference protocol's, with
    its waypoints searched): each UAV flies from its start through :data:`WALK_LEGS`
    waypoints (x, y in the square of ``area_m``), all at its own height within
    :data:`WALK_BAND_M` around the middle of the height range. θ per UAV: start x, y, each
    waypoint's x, y, height, delay, priority key."""

    name: str = "walk"
    ceiling_m: float = 30.0
    legs: int = WALK_LEGS

    def dims(self, space: Space) -> int:
        return (2 * self.legs + 5) * space.uavs

    def check(self, space: Space) -> None:
        """Any space has room for a walk (the draws say when the area is too small)."""

    def plan(self, space: Space, theta: np.ndarray) -> Plan:
        k = self.legs + 1
        t = theta.reshape(space.uavs, 2 * k + 3)
        middle = 0.5 * (space.min_height_m + space.max_height_m)
        band = min(WALK_BAND_M, space.max_height_m - space.min_height_m)
        z = middle + (t[:, 2 * k] - 0.5) * band
        xy = _xy(t[:, :2 * k].reshape(space.uavs, k, 2), space)
        paths = tuple(np.column_stack([xy[i], np.full(k, z[i])]) for i in range(space.uavs))
        return Plan(paths, t[:, 2 * k + 1] * MAX_DELAY_S, _priorities(t[:, 2 * k + 2]))

    def valid(self, space: Space, plan: Plan) -> bool:
        """No two consecutive waypoints within :data:`MIN_LEG_M`."""
        return _legs_ok(plan)


def _ends(plan: Plan) -> tuple[np.ndarray, np.ndarray]:
    """Each UAV's first and last waypoint: (starts (N, 3), goals (N, 3)) [m]."""
    return np.array([w[0] for w in plan.paths]), np.array([w[-1] for w in plan.paths])


def _legs_ok(plan: Plan) -> bool:
    """No two consecutive waypoints of a UAV closer than :data:`MIN_LEG_M`."""
    return all(float(np.linalg.norm(np.diff(w, axis=0), axis=1).min()) >= MIN_LEG_M
               for w in plan.paths)


#: The families by name (``--family``).
FAMILIES: dict[str, Family] = {f.name: f for f in (Straight(), Vertical(), Grid(), Walk())}


@dataclass(frozen=True)
class Space:
    """The scenario space searched (SI units, ENU): the settings every family shares, and
    the family (:data:`FAMILIES`) that gives a θ as the case to fly."""

    uavs: int = 6
    area_m: float = 60.0
    min_height_m: float = 5.0
    max_height_m: float = 20.0
    ceiling_m: float = 30.0
    speed_mps: float = 5.0
    duration_s: float = 60.0
    link: LinkSettings = field(default_factory=LinkSettings)
    faults: FaultSpec = field(default_factory=FaultSpec)
    family: str = "straight"

    def __post_init__(self) -> None:
        n = self.uavs
        if isinstance(n, bool) or not isinstance(n, int) or not 2 <= n <= 64:
            raise ConfigError(f"uavs: must be an integer in [2, 64], got {n!r}")
        positive(self.area_m, "area_m", upper=1e4)
        positive(self.min_height_m, "min_height_m", upper=1e4)
        positive(self.max_height_m, "max_height_m", upper=1e4)
        positive(self.speed_mps, "speed_mps", upper=30.0)
        positive(self.duration_s, "duration_s", upper=3600.0)
        if not self.max_height_m >= self.min_height_m:
            raise ConfigError(f"max_height_m ({self.max_height_m}) must be ≥ min_height_m "
                              f"({self.min_height_m})")
        if not self.ceiling_m >= self.max_height_m + 2.0:
            raise ConfigError(f"ceiling_m: {self.ceiling_m} leaves no room above the highest "
                              f"start or goal ({self.max_height_m} m; need ≥ 2 m)")
        if self.family not in FAMILIES:
            raise ConfigError(f"family: {self.family!r} is not one of "
                              f"{', '.join(FAMILIES)}")
        self.shape.check(self)

    @property
    def shape(self) -> Family:
        """The family that gives a θ as its case."""
        return FAMILIES[self.family]

    @property
    def dims(self) -> int:
        return self.shape.dims(self)

    def plan(self, theta: np.ndarray) -> Plan:
        """θ as the case to fly."""
        t = np.asarray(theta, dtype=float)
        if t.shape != (self.dims,):
            raise ConfigError(f"theta: family {self.family} of {self.uavs} UAVs has "
                              f"{self.dims} coordinates, got shape {t.shape}")
        return self.shape.plan(self, t)

    def points(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """θ as (starts (N, 3), goals (N, 3), delays (N,) [s], priorities (N,) 1…N): each
        UAV's first and last waypoint."""
        p = self.plan(theta)
        starts, goals = _ends(p)
        return starts, goals, p.delays, p.priorities

    def valid(self, theta: np.ndarray) -> bool:
        """Starts and goals each at least :data:`MIN_GAP_M` apart, and what the family asks
        besides."""
        p = self.plan(theta)
        starts, goals = _ends(p)
        return (_closest(starts)[0] >= MIN_GAP_M and _closest(goals)[0] >= MIN_GAP_M
                and self.shape.valid(self, p))

    def toml(self, theta: np.ndarray, name: str, header: str = "") -> str:
        """Case θ as a scenario file (what is flown is what this file loads)."""
        p = self.plan(theta)
        reach = max(float(np.abs(w[:, :2]).max()) for w in p.paths)
        half = max(0.5 * self.area_m, reach) + 10.0
        lines = [f"# {line}" for line in header.splitlines()]
        lines += [f'name = "{name}"', f"duration_s = {self.duration_s!r}", "",
                  "[link]", f"latency_s = {self.link.latency_s!r}",
                  f"jitter_s = {self.link.jitter_s!r}", f"loss = {self.link.loss!r}",
                  f"burst_len = {self.link.burst_len!r}", "",
                  "[geofence]", f"box = [{-half!r}, {-half!r}, {half!r}, {half!r}]",
                  "min_altitude_m = 0.0", f"max_altitude_m = {self.ceiling_m!r}"]
        for i, path in enumerate(p.paths):
            points = [", ".join(repr(round(float(v), 3)) for v in w) for w in path]
            waypoints = ", ".join(f"[{w}]" for w in points)
            lines += ["", "[[uavs]]", f'id = "uav{i + 1}"',
                      f"priority = {int(p.priorities[i])}",
                      f"start = [{points[0]}]", "[uavs.path]", f"waypoints = [{waypoints}]",
                      f"speed_mps = {self.speed_mps!r}",
                      f"start_s = {round(START_S + float(p.delays[i]), 3)!r}"]
        return "\n".join(lines) + "\n"


def _closest(p: np.ndarray) -> tuple[float, int, int]:
    """The smallest distance between two of the points ``p`` (N, 3) [m], and which two
    (i < j)."""
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    d[np.diag_indices(len(p))] = np.inf
    a, b = np.unravel_index(int(np.argmin(d)), d.shape)
    return float(d[a, b]), int(min(a, b)), int(max(a, b))


@dataclass(frozen=True)
class Outcome:
    """One flight of a case: its closest approach by the truth and the highest altitude."""

    index: int
    seed: int
    theta: tuple[float, ...]
    min_distance_m: float
    at_s: float
    pair: tuple[str, str]
    collisions: int
    top_m: float


def fly_case(space: Space, theta: np.ndarray, seed: int, index: int = 0,
             avoidance: bool = True) -> Outcome:
    """Fly case ``theta`` once in the simulated world with flight seed ``seed``."""
    import tomllib

    from uavmpc import scenarios
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.run import RunSpec

    sc = scenarios.from_dict(tomllib.loads(space.toml(theta, f"falsify_{index}")),
                             f"case {index}")
    res = World(RunSpec(sc, seed=seed, avoidance=avoidance,
                                  faults=space.faults)).run()
    d = res.min_distance_m
    k = int(np.argmin(d))
    _, a, b = _closest(res.positions_m[k])
    return Outcome(index, seed, tuple(float(v) for v in theta), float(d[k]),
                   float(res.t_s[k]), (res.uav_ids[a], res.uav_ids[b]),
                   len(res.collisions), float(res.positions_m[:, :, 2].max()))


def _draw(space: Space, rng: np.random.Generator, mean: np.ndarray | None,
          spread: np.ndarray | None) -> np.ndarray:
    """A valid case: uniform (no law yet), else from the normal law, clipped to the cube."""
    for _ in range(MAX_DRAWS):
        if mean is None or spread is None:
            theta = rng.random(space.dims)
        else:
            theta = np.clip(rng.normal(mean, spread), 0.0, 1.0)
        if space.valid(theta):
            return theta
    raise ConfigError(f"{space.uavs} UAVs do not fit {MIN_GAP_M:g} m apart in a "
                      f"{space.area_m:g} m square: widen --area or fly fewer")


def _fly_one(job: tuple[Space, np.ndarray, int, int, bool]) -> Outcome:
    """:func:`fly_case` of one job (a worker process's entry point)."""
    return fly_case(*job)


def falsify(space: Space, budget: int, *, seed: int = 0, generation: int | None = None,
            avoidance: bool = True, workers: int = 1,
            on_flight: Callable[[Outcome], None] | None = None) -> list[Outcome]:
    """Search ``budget`` flights (cross-entropy over θ, see the module); every outcome in
    the order flown. ``generation``: cases per generation (default: a tenth of the budget,
    at least 4). ``workers``: processes the flights of a generation are shared among; the
    outcomes do not depend on it (a generation's cases are drawn before any is flown, each
    flight's seed is its index)."""
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise ConfigError(f"budget: must be an integer ≥ 1, got {budget!r}")
    size = max(4, budget // 10) if generation is None else generation
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ConfigError(f"generation: must be an integer ≥ 1, got {size!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers: must be an integer ≥ 1, got {workers!r}")
    rng = np.random.default_rng(seed)
    outcomes: list[Outcome] = []
    mean: np.ndarray | None = None
    spread: np.ndarray | None = None
    pool = ProcessPoolExecutor(workers) if workers > 1 else None
    try:
        while len(outcomes) < budget:
            jobs: list[tuple[Space, np.ndarray, int, int, bool]] = []
            for _ in range(min(size, budget - len(outcomes))):
                index = len(outcomes) + len(jobs)
                jobs.append((space, _draw(space, rng, mean, spread),
                             seed * 1_000_000 + index, index, avoidance))
            flown = map(_fly_one, jobs) if pool is None else pool.map(_fly_one, jobs)
            for out in flown:
                outcomes.append(out)
                if on_flight is not None:
                    on_flight(out)
            best = sorted(outcomes, key=_badness)[:max(2, math.ceil(ELITE * len(outcomes)))]
            elite = np.array([o.theta for o in best])
            mean = elite.mean(axis=0)
            spread = np.maximum(elite.std(axis=0), MIN_SPREAD)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    return outcomes


def _badness(o: Outcome) -> tuple[float, float]:
    """The order of the search: the closest approach first, then the highest altitude."""
    return o.min_distance_m, -o.top_m


def replay_flags(space: Space) -> str:
    """The ``uavmpc run`` flags that fly a case as the search did (the link is in the file
    as well)."""
    f = space.faults
    flags = []
    if space.link.loss:
        flags.append(f"--loss {space.link.loss:g}")
    if space.link.latency_s != LinkSettings().latency_s:
        flags.append(f"--latency {space.link.latency_s:g}")
    if f.clock_offset_s:
        flags.append(f"--clock-offset {f.clock_offset_s:g}")
    if f.time_reference is not None:
        flags.append(f"--time-reference {f.time_reference}")
    if f.gnss != "none":
        flags.append(f"--gnss {f.gnss}")
    if f.burst_len:
        flags.append(f"--burst-loss {f.burst_len:g}")
    if f.non_cooperative:
        flags.append(f"--non-cooperative {f.non_cooperative}")
    if f.silent:
        flags.append(f"--silent {f.silent}")
    return " ".join(flags)


def write_results(space: Space, outcomes: list[Outcome], out: Path, *,
                  avoidance: bool = True) -> list[Path]:
    """``cases.json`` and the :data:`KEEP` worst cases as scenario files; their paths."""
    out.mkdir(parents=True, exist_ok=True)
    worst = sorted(outcomes, key=_badness)[:KEEP]
    flags = replay_flags(space)
    paths = []
    for rank, o in enumerate(worst, 1):
        path = out / f"worst_{rank}.toml"
        command = (f"uavmpc run {path} --seed {o.seed}" + (f" {flags}" if flags else "")
                   + ("" if avoidance else " --no-avoidance"))
        family = "" if space.family == "straight" else f" (family {space.family})"
        header = (f"uavmpc falsify{family}: worst case {rank} of {len(outcomes)} flights: "
                  f"{o.min_distance_m:.2f} m ({o.pair[0]}–{o.pair[1]} at {o.at_s:.1f} s), "
                  f"highest {o.top_m:.1f} m under a {space.ceiling_m:g} m ceiling.\n"
                  f"Replay: {command}")
        path.write_text(space.toml(np.array(o.theta), f"falsify_worst_{rank}", header))
        paths.append(path)
    record = {"space": {k: v for k, v in space.__dict__.items() if k not in ("link", "faults")}
              | {"link": space.link.__dict__, "faults": space.faults.active()},
              "avoidance": avoidance, "flights": len(outcomes),
              "min_distance_m": min(o.min_distance_m for o in outcomes),
              "top_m": max(o.top_m for o in outcomes),
              "collisions": sum(o.collisions > 0 for o in outcomes),
              "worst": [str(p.name) for p in paths],
              "cases": [o.__dict__ for o in outcomes], "written_unix_s": round(time.time(), 3)}
    (out / "cases.json").write_text(json.dumps(record, indent=1, default=list))
    return paths


def summary_lines(space: Space, outcomes: list[Outcome], paths: list[Path]) -> list[str]:
    """What the command prints at the end."""
    worst = sorted(outcomes, key=_badness)[:len(paths)]
    hits = sum(o.collisions > 0 for o in outcomes)
    above = sum(o.top_m > space.ceiling_m for o in outcomes)
    lines = [f"{len(outcomes)} flights: closest {worst[0].min_distance_m:.2f} m; "
             f"{hits} with a collision; {above} above the {space.ceiling_m:g} m ceiling"]
    lines += [f"  {p}: {o.min_distance_m:.2f} m ({o.pair[0]}–{o.pair[1]} at {o.at_s:.1f} s), "
              f"seed {o.seed}, highest {o.top_m:.1f} m" for o, p in zip(worst, paths,
                                                                          strict=True)]
    return lines


def space_from_args(args: argparse.Namespace) -> Space:
    """The :class:`Space` of ``uavmpc falsify``'s flags."""
    from uavmpc.apps.campaign import fault_spec

    if args.launch_check is not None:
        raise ConfigError("--launch-check: the search flies every case with all UAVs "
                          "setting off at their times; it is not a dimension searched")
    family = FAMILIES.get(args.family)
    if family is None:
        raise ConfigError(f"--family: {args.family!r} is not one of {', '.join(FAMILIES)}")
    link = LinkSettings.from_dict({"loss": args.loss, "latency_s": args.latency}, "link")
    return Space(uavs=args.uavs, area_m=args.area, min_height_m=args.min_height,
                 max_height_m=args.max_height,
                 ceiling_m=family.ceiling_m if args.ceiling is None else args.ceiling,
                 speed_mps=args.speed, duration_s=args.duration, link=link,
                 faults=fault_spec(args), family=family.name)
