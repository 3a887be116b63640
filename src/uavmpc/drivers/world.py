"""Many UAVs, one sky: N onboard stacks, N plants, one lossy link, one simulated clock.

Each UAV runs its own :class:`~uavmpc.onboard.OnboardStack` and sees only the bytes the link
delivered to it; nothing is shared between UAVs but the bytes on the link. The world itself only
advances the clock, moves the bytes, and watches for collisions (a 3-D distance between centres
below :data:`COLLISION_DISTANCE_M`).

Every tick is one compiled call for all UAVs (:func:`world_tick`): each UAV's numerical part of
its stack (:func:`~uavmpc.onboard.onboard_row`) and its plant
(:func:`~uavmpc.plant.kernels.plant_step`) on its own row of the records the world owns — the
same functions a stack and a plant run when ticked alone (``World(..., batched=False)`` does
that, UAV by UAV, and flies bit for bit the same). Around it, for all UAVs at once
(docs/scale.md): the link's due copies go through each receiver's rule into its row of one
:class:`~uavmpc.comms.inbox.InboxTable` (each broadcast decoded once), and every 0.1 s the UAVs
due find their encounters in one compiled call (a box test and a spatial index over the plans
they hold); each then decides alone (its strategy's ``decide``) and broadcasts at 2 Hz.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uavmpc.avoidance import (
    AvoidanceParams,
    EncounterStrategy,
    HeightOffsetStrategy,
    ResolutionStrategy,
)
from uavmpc.avoidance.encounters import EncounterFinder, heard_from_all
from uavmpc.comms.inbox import InboxTable, accept_copies
from uavmpc.comms.link import SimulatedLink
from uavmpc.comms.message import InvalidMessageError
from uavmpc.config import ConfigError
from uavmpc.estimation import ObserverParams
from uavmpc.estimation.fleet import FleetEstimator
from uavmpc.geofence import FenceWatch
from uavmpc.jit import HAS_CYCLE_COUNTER, bind, cycle_count, kernel
from uavmpc.log import FlightRecorder
from uavmpc.missions.formation import FormationFollower, formation_error
from uavmpc.missions.landing import LandingMission, landing_outcome
from uavmpc.missions.mission import Mission, MissionInput
from uavmpc.onboard import (
    AVOIDANCE_PERIOD_S,
    BROADCAST_PERIOD_S,
    OnboardBatch,
    OnboardStack,
    avoidance_plans,
    onboard_post,
    onboard_pre,
    onboard_row,
)
from uavmpc.plant import Airframe, PlantRows, Wind
from uavmpc.plant.interface import heading_of
from uavmpc.plant.kernels import fly_target
from uavmpc.plant.multirotor import Multirotor
from uavmpc.plant.sensors import TargetSensor
from uavmpc.reference import Reference
from uavmpc.scenarios import LinkSettings, Scenario, UavSpec
from uavmpc.scenarios.faults import Faults
from uavmpc.tracker import TrackerConfig
from uavmpc.tracker.kernels import make_scratch
from uavmpc.view.scene import (
    ObjectView,
    UavView,
    detail_of,
    ground_around,
    scene_update,
    state_of,
)

COLLISION_DISTANCE_M = 1.0
#: A UAV has reached its goal when it ends within this 3-D distance of it.
GOAL_TOLERANCE_M = 1.0
#: The geofence failsafe looks every this many ticks (10 Hz, the avoidance's rate).
FENCE_CHECK_TICKS = 10
#: Log rate of poses and status (predictions are logged at each broadcast).
POSE_LOG_PERIOD_S = 0.05
#: Period of the 3-D scene and the metrics in logs and live views [s].
SCENE_PERIOD_S = 0.1
#: The ground vehicle's name in logs (``/ground_vehicle/state``: its deck's centre).
GROUND_VEHICLE_ID = "ground_vehicle"
#: The formation error is measured from this time on (the followers' first plans arrive and
#: settle).
FORMATION_SETTLE_S = 10.0


@dataclass
class Collision:
    """One contact: from when two UAVs came closer than the threshold, its closest distance."""

    t: float
    a: str
    b: str
    distance_m: float


@dataclass
class WorldUav:
    """One UAV of the world: its program, its plant, where it should end."""

    uav_id: str
    goal_m: np.ndarray
    stack: OnboardStack
    plant: Multirotor
    clock_offset_s: float = 0.0  # its clock minus the world's
    mission: Mission | None = None  # stepped beside the stack (uavmpc.missions)
    sensor: TargetSensor | None = None  # its fixes of the ground vehicle
    next_mission_s: float = 0.0
    motors_cut: bool = False
    #: Whom it yielded to: other id → [first, last] time of a decision saying so [s].
    yielded_to: dict[str, list[float]] = field(default_factory=dict)


@dataclass(frozen=True)
class UavOutcome:
    """How one UAV's flight went (``summary.json``'s per-UAV entry).

    Attributes:
        max_z_offset_m, avoidance_active_s, tracking_rmse_m, limit_violations,
        max_limit_excess, tracker_fallbacks: from its stack (:class:`~uavmpc.onboard.StackReport`).
        reached_goal: it ended within :data:`GOAL_TOLERANCE_M` of its goal (None for a UAV
            whose mission sets its way, e.g. a lander or a formation's follower).
        final_position_m: where it ended (ENU, m).
        messages_rejected: messages its inbox rejected.
        yielded_to: whom its avoidance yielded to, other id → [first, last] time [s].
    """

    max_z_offset_m: float
    avoidance_active_s: float
    tracking_rmse_m: float
    reached_goal: bool | None
    final_position_m: list[float]
    limit_violations: int
    max_limit_excess: float
    tracker_fallbacks: int
    messages_rejected: int
    yielded_to: dict[str, list[float]] = field(default_factory=dict)


@dataclass
class WorldResult:
    """What a run produced (``summary()`` gives the summary.json dictionary).

    Attributes:
        t_s: (K,) sample times of the traces (every tick).
        positions_m: (K, N, 3) true positions; z_offset_m: (K, N); min_distance_m: (K,).
    """

    scenario: str
    seed: int
    avoidance: bool
    duration_s: float
    uav_ids: list[str]
    t_s: np.ndarray
    positions_m: np.ndarray
    z_offset_m: np.ndarray
    min_distance_m: np.ndarray
    collisions: list[Collision]
    per_uav: dict[str, UavOutcome]
    messages: dict[str, int]
    wall_s: float
    extra: dict[str, Any] = field(default_factory=dict)
    #: Time series for figures (not in the summary): e.g. ``"ground_vehicle_m"`` (K, 3).
    traces: dict[str, np.ndarray] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "seed": self.seed,
            "avoidance": self.avoidance,
            "duration_s": self.duration_s,
            "collisions": [c.__dict__ for c in self.collisions],
            # None with a single UAV (no pair): JSON has no infinity.
            "min_distance_m": (float(self.min_distance_m.min()) if len(self.uav_ids) > 1
                               else None),
            "uavs": {k: dataclasses.asdict(v) for k, v in self.per_uav.items()},
            "messages": self.messages,
            "wall_s": self.wall_s,
            "realtime_factor": self.duration_s / self.wall_s if self.wall_s > 0 else None,
            **self.extra,
        }


def broadcast_phase(i: int, n: int) -> float:
    """When UAV i of n first broadcasts: the phases are spread over the period."""
    return BROADCAST_PERIOD_S * (i + 0.5) / n


@kernel
def world_tick(trk, refs, consts, ctl, stats, plant, n_sub, dt, k, pos_out, zoff_out, dmin_out,
               pair_d, cycles, est):
    """One 10 ms tick of every UAV, the compiled solver inline: each UAV's stack
    (:func:`~uavmpc.onboard.onboard_row`) controls its plant row from its true state, then the
    plant flies the target (:func:`~uavmpc.plant.kernels.fly_target`); row ``k`` of the traces
    (positions (K, N, 3), z offsets (K, N), closest distance (K,)) and the pair distances
    ``pair_d`` (N (N − 1) / 2,) are written. Returns −1, or the index of a UAV whose attitude
    target could not be flown (the tick stops there).

    ``cycles``: (4,) int64 to profile the tick, or (0,) not to: adds the cycle counts of the
    stacks, the plants and the traces, and the number of UAV-ticks (:func:`cycle_count`).
    ``est``: (N, 6) the estimated [p, v] the stacks fly on (attitude and rates stay the
    plants' own), or (0, 6) for the true state."""
    n = plant.x.shape[0]
    sc = make_scratch(consts.horizon_s.shape[0])
    qd = np.empty(4)
    ff = np.empty(3)
    timed = cycles.shape[0] > 0
    estimated = est.shape[0] > 0
    c0 = c1 = 0
    for i in range(n):
        x = plant.x[i]
        if timed:
            c0 = cycle_count()
        if estimated:
            thrust = onboard_row(i, trk, refs, consts, ctl, stats, est[i, 0:3], est[i, 3:6],
                                 x[6:10], dt, sc, qd, ff)
        else:
            thrust = onboard_row(i, trk, refs, consts, ctl, stats, x[0:3], x[3:6], x[6:10], dt,
                                 sc, qd, ff)
        if timed:
            c1 = cycle_count()
            cycles[0] += c1 - c0
        if not fly_target(i, plant, n_sub, qd, thrust, ff):
            return i
        if timed:
            cycles[1] += cycle_count() - c1
            cycles[3] += 1
    if timed:
        c0 = cycle_count()
    _trace(trk, plant, k, pos_out, zoff_out, dmin_out, pair_d)
    if timed:
        cycles[2] += cycle_count() - c0
    return -1


@kernel
def world_pre(trk, stats, plant):
    """:func:`world_tick`'s bookkeeping before the trackers tick (Python solvers)."""
    for i in range(plant.x.shape[0]):
        onboard_pre(i, trk, stats, plant.x[i, 0:3])


@kernel
def world_post(trk, consts, ctl, stats, plant, n_sub, dt, k, pos_out, zoff_out, dmin_out,
               pair_d):
    """:func:`world_tick` after the trackers ticked (Python solvers): control and plants."""
    qd = np.empty(4)
    ff = np.empty(3)
    for i in range(plant.x.shape[0]):
        x = plant.x[i]
        thrust = onboard_post(i, trk, consts, ctl, stats, x[0:3], x[3:6], x[6:10], dt, qd, ff)
        if not fly_target(i, plant, n_sub, qd, thrust, ff):
            return i
    _trace(trk, plant, k, pos_out, zoff_out, dmin_out, pair_d)
    return -1


@kernel
def _trace(trk, plant, k, pos_out, zoff_out, dmin_out, pair_d):
    n = plant.x.shape[0]
    for i in range(n):
        for j in range(3):
            pos_out[k, i, j] = plant.x[i, j]
        zoff_out[k, i] = trk.z_offset_m[i]
    best = math.inf
    p = 0
    for a in range(n):
        for b in range(a + 1, n):
            d0 = pos_out[k, a, 0] - pos_out[k, b, 0]
            d1 = pos_out[k, a, 1] - pos_out[k, b, 1]
            d2 = pos_out[k, a, 2] - pos_out[k, b, 2]
            d = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            pair_d[p] = d
            best = min(best, d)
            p += 1
    dmin_out[k] = best


def world_faults(faults: Faults) -> dict[str, Any]:
    """The :class:`World` arguments of a drawn set of faults (:mod:`uavmpc.scenarios.faults`;
    the link's burst length and the time reference go into the link and the scenario)."""
    return {"clock_offsets_s": faults.clock_offsets_s,
            "non_cooperative": faults.non_cooperative,
            "silent_from_s": faults.silent_from_s,
            "gnss": None if faults.spec.gnss == "none" else faults.spec.gnss}


def _flying_alone(scenario: Scenario, avoidance: bool,
                  non_cooperative: Iterable[str]) -> tuple[str, ...]:
    """The ids of the UAVs that fly without avoidance, in the scenario's order: every one
    when ``avoidance`` is off, else those the scenario or ``non_cooperative`` names."""
    if isinstance(non_cooperative, str):  # its characters would be taken for ids
        raise ValueError(f"non_cooperative: an iterable of UAV ids, not the string "
                         f"{non_cooperative!r}")
    listed = set(non_cooperative)
    unknown = sorted(str(x) for x in listed - {u.uav_id for u in scenario.uavs})
    if unknown:
        raise ValueError(f"non_cooperative: {', '.join(map(repr, unknown))} not UAVs of "
                         f"the scenario {scenario.name!r}")
    return tuple(u.uav_id for u in scenario.uavs
                 if not (avoidance and u.avoidance and u.uav_id not in listed))


def _with_scenario_limits(config: TrackerConfig | None,
                          scenario: Scenario) -> TrackerConfig | None:
    """``config`` (default: the packaged one) with the scenario's limits over its own; as
    given when the scenario sets none."""
    if not scenario.limits:
        return config
    base = config if config is not None else TrackerConfig.from_toml()
    return dataclasses.replace(base, limits=scenario.limits.apply(base.limits))


def _strategy_of(uav_id: str, strategy: Callable[[AvoidanceParams], ResolutionStrategy],
                 params: AvoidanceParams, formation: Any) -> ResolutionStrategy:
    """A new strategy for ``uav_id``; a formation member's flies the members' pair radii."""
    resolver = strategy(params)
    if formation is not None and uav_id in formation.members:
        if not isinstance(resolver, EncounterStrategy):
            raise ConfigError(f"formation: the strategy {type(resolver).__name__} "
                              "has no per-pair radii for the members")
        resolver.pair_radius_m.update(formation.pair_radii(uav_id))
    return resolver


def _silent_times(scenario: Scenario, silent_from_s: Mapping[str, float] | None
                  ) -> dict[str, float]:
    """UAV id → when its radio goes silent [s], checked against the scenario."""
    silent = dict(silent_from_s or {})
    unknown = sorted(set(silent) - {u.uav_id for u in scenario.uavs})
    if unknown:
        raise ValueError(f"silent_from_s: {', '.join(map(repr, unknown))} not UAVs of "
                         f"the scenario {scenario.name!r}")
    if not all(math.isfinite(float(t)) for t in silent.values()):
        raise ValueError(f"silent_from_s: times must be finite, got {silent!r}")
    return {k: float(v) for k, v in silent.items()}


class World:
    """A scenario flown by its UAVs.

    Args:
        scenario: who flies where (see :mod:`uavmpc.scenarios`).
        avoidance: run collision avoidance on every UAV (else: none, flags down).
        non_cooperative: ids of UAVs that fly without avoidance, their flags down (the
            others yield to them), besides those the scenario says so of
            (``avoidance = false``). A UAV is cooperative iff ``avoidance`` is on, its spec
            says so and it is not listed here.
        seed: fixes the link's randomness and the wind.
        link: overrides the scenario's link settings.
        wind_mps: mean wind along x (each UAV its own seeded gusts, σ = 0.3 × mean).
        recorder: optional MCAP recorder.
        strategy: makes each UAV's conflict-resolution strategy from the scenario's avoidance
            parameters (any :class:`~uavmpc.avoidance.ResolutionStrategy`).
        tracker_config: the tracker set-up of every UAV (default: packaged data/tracker.toml).
        clock_offsets_s: per UAV, how far its clock is ahead of the world's [s] (default: all
            synchronised). A UAV stamps its messages, judges their age and schedules itself
            on its own clock; its mission's times are read on it too.
        batched: tick every UAV in one compiled call (default); False ticks each stack and
            plant on its own (:meth:`OnboardStack.tick`, :meth:`Multirotor.step`): the same
            kernels, bit for bit the same flight, slower.
        index: find each UAV's encounters through the spatial index (True) or compare it
            with every other UAV (False; :mod:`uavmpc.avoidance.encounters`): the same
            flight. Default: the index from 32 UAVs on.
        gnss: fly every controller on a state observer fed with GNSS-like fixes (a preset,
            ``"single"`` or ``"rtk"``, or :class:`~uavmpc.estimation.ObserverParams`) instead
            of the true position and velocity (:class:`~uavmpc.estimation.fleet.
            FleetEstimator`, seeded from ``seed``).
        silent_from_s: UAV id → world time [s] from which its radio sends nothing; the UAV
            flies on (its stack still plans and thinks it broadcasts).
        launch_check_s: hold each UAV at its start until its inbox holds a prediction from
            every other UAV of the scenario that its avoidance counts (fresh, or silent at
            most ``silent_hold_s`` old), at most this long [s]; then it flies its mission
            (``extra["launch"]`` says when, and who was not heard). A UAV flying without
            avoidance ignores the others, and a mission stepped beside the stack (a lander, a
            follower) starts its own way: both set off at once. Default None: every UAV sets
            off at once.
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        avoidance: bool = True,
        seed: int = 0,
        link: LinkSettings | None = None,
        wind_mps: float = 0.0,
        recorder: FlightRecorder | None = None,
        strategy: Callable[[AvoidanceParams], ResolutionStrategy] = HeightOffsetStrategy,
        tracker_config: TrackerConfig | None = None,
        clock_offsets_s: Sequence[float] | None = None,
        batched: bool = True,
        index: bool | None = None,
        non_cooperative: Iterable[str] = (),
        gnss: str | ObserverParams | None = None,
        silent_from_s: Mapping[str, float] | None = None,
        launch_check_s: float | None = None,
    ) -> None:
        self.scenario = scenario
        self.avoidance = avoidance
        #: The ids of the UAVs flying without avoidance (all of them when ``avoidance`` is
        #: off), in the scenario's order.
        self.non_cooperative = _flying_alone(scenario, avoidance, non_cooperative)
        flying_alone = set(self.non_cooperative)
        self.seed = seed
        self.recorder = recorder
        self.batched = bool(batched)
        settings = link if link is not None else scenario.link
        params = scenario.avoidance  # validated when the scenario was
        self.params = params
        self._positions: dict[str, np.ndarray] = {}
        self.link = SimulatedLink(
            [u.uav_id for u in scenario.uavs], latency_s=settings.latency_s,
            jitter_s=settings.jitter_s, loss=settings.loss,
            range_m=settings.range_m or None, position_of=self._positions.__getitem__,
            seed=seed, burst_len=settings.burst_len,
        )
        airframes: dict[str, Airframe] = {}
        for spec in scenario.uavs:
            if spec.airframe not in airframes:
                airframes[spec.airframe] = Airframe.named(spec.airframe)
        n = len(scenario.uavs)
        offsets = np.zeros(n) if clock_offsets_s is None else np.asarray(clock_offsets_s, float)
        if offsets.shape != (n,) or not np.all(np.isfinite(offsets)):
            raise ValueError(f"clock_offsets_s: need {n} finite offsets [s], got "
                             f"{clock_offsets_s!r}")
        tracker_config = _with_scenario_limits(tracker_config, scenario)
        #: The records of every UAV's numbers, one row each: their stacks' and their plants'.
        self.onboard = OnboardBatch(tracker_config, n)
        #: The ground vehicle carrying the landing deck, when the scenario has one.
        self.ground_vehicle = scenario.ground_vehicle
        formation = scenario.formation
        self.plants = PlantRows.empty(n, max(a.n_rotors for a in airframes.values()))
        #: Every UAV's inbox, one row each (a broadcast is decoded once for all receivers).
        self.inboxes = InboxTable([u.uav_id for u in scenario.uavs],
                                  time_reference=params.time_reference,
                                  max_age_s=params.timeout_s,
                                  points=self.onboard.tracker.config.steps)
        self.uavs: list[WorldUav] = []
        if launch_check_s is not None and not (math.isfinite(launch_check_s)
                                               and launch_check_s >= 0.0):
            raise ValueError(f"launch_check_s: must be a time ≥ 0 [s], got {launch_check_s!r}")
        self.launch_check_s = launch_check_s
        #: Row → its mission, for the UAVs still held at their starts by the launch check;
        #: and per id: when it set off [s, world time] and whom it had not heard then.
        self._unlaunched: dict[int, Reference] = {}
        self.launches: dict[str, dict[str, Any]] = {}
        period = self.onboard.tracker.config.first_step_s
        for i, spec in enumerate(scenario.uavs):
            wind = None
            if wind_mps > 0.0:
                wind = Wind(mean_mps=(wind_mps, 0.0, 0.0), gust_sigma_mps=0.3 * wind_mps,
                            seed=seed * 1000 + i)
            resolver = (None if spec.uav_id in flying_alone
                        else _strategy_of(spec.uav_id, strategy, params, formation))
            u = self._add_uav(i, spec, airframes[spec.airframe], wind, float(offsets[i]),
                              resolver)
            self._attach_mission(u, i, spec)
            self.uavs.append(u)
            self._positions[spec.uav_id] = np.array(spec.start_m, dtype=float)
        self.t_s = 0.0
        self.period_s = period
        self.n_sub = self.uavs[0].plant.substeps(period)
        if any(u.plant.substeps(period) != self.n_sub for u in self.uavs):
            raise ValueError("the plants' substeps differ; a world steps them together")
        self._kernels: tuple[Any, Any] | None = None
        self._offsets = offsets.copy()
        self.estimator: FleetEstimator | None = None
        if gnss is not None:
            if not self.onboard.inline:
                raise ValueError("gnss: needs the compiled tracker solver (batchqp)")
            obs = ObserverParams.preset(gnss) if isinstance(gnss, str) else gnss
            self.estimator = FleetEstimator(obs, n, period, seed)
        self._no_estimate = np.zeros((0, 6))
        #: UAV id → when its radio goes silent [s]; and how many broadcasts it swallowed.
        self.silent_from_s = _silent_times(scenario, silent_from_s)
        self._ground: dict[str, Any] | None = None  # the scene's ground, made once
        self._next_scene_s = -math.inf
        self.silenced = 0
        self._windy = [u.plant for u in self.uavs if u.plant.wind is not None]
        self._missions = [u for u in self.uavs if u.mission is not None]
        #: The scenario's operational volume: each UAV's failsafe, and its avoidance's
        #: ceiling over its mission (:mod:`uavmpc.geofence`).
        self.geofence = scenario.geofence
        self.fence_watches: list[FenceWatch] = []
        if self.geofence is not None:
            self.fence_watches = [FenceWatch(self.geofence) for _ in self.uavs]
            for u, spec in zip(self.uavs, scenario.uavs, strict=True):
                if isinstance(u.stack.avoidance, EncounterStrategy):
                    u.stack.avoidance.limit_offset(
                        self.geofence.offset_ceiling_m(spec.mission.points[:, 2]))
        self._deciders, self._finder = self._world_finder(index)
        self._overrides = [d.overrides(self.inboxes) if d is not None else {}
                           for d in self._deciders]
        self._radius = np.full(n, params.radius_m)
        self._next_round_s = -math.inf
        self._next_emit_s = -math.inf
        self._yielding: set[int] = set()
        self._started = False
        #: Wall time of the batched ticks' phases in the current run [s]: receiving and
        #: planning, the compiled tick, broadcasting.
        self._phase_wall_s = [0.0, 0.0, 0.0]
        #: The compiled tick's cycle counts in the current run (see :func:`world_tick`).
        self._cycles = np.zeros(4 if HAS_CYCLE_COUNTER else 0, dtype=np.int64)

    def _add_uav(self, i: int, spec: UavSpec, af: Airframe, wind: Wind | None, off: float,
                 resolver: ResolutionStrategy | None) -> WorldUav:
        """Row ``i``: its plant and its stack on the world's rows, clock offset ``off`` [s],
        flying its mission (held at its start when the launch check holds it)."""
        scenario, n = self.scenario, len(self.scenario.uavs)
        plant = Multirotor(af, position_m=spec.start_m, yaw_rad=spec.heading_rad, wind=wind,
                           rotors_at_hover=spec.start_m[2] > 0.0, rows=self.plants, row=i)
        # Each UAV broadcasts at its own phase, spread over the period.
        stack = OnboardStack(af, position_m=spec.start_m, heading_rad=spec.heading_rad,
                             t0_s=off, uav_id=spec.uav_id, priority=spec.priority,
                             avoidance=resolver, params=self.params,
                             broadcast_phase_s=broadcast_phase(i, n), batch=self.onboard,
                             row=i, inbox_table=self.inboxes)
        reference = spec.mission
        if off:
            reference = Reference(reference.times_s + off, reference.points, reference.loop)
        formation = scenario.formation
        held = (self.launch_check_s is not None and n > 1 and resolver is not None
                and scenario.landing is None
                and not (formation is not None and spec.uav_id in formation.followers))
        if held:
            # Hover where it starts; the mission waits for the link (:meth:`_launch`).
            self._unlaunched[i] = reference
            reference = Reference.goto(*spec.start_m, spec.heading_rad, start_s=off)
        stack.set_mission(reference)
        return WorldUav(spec.uav_id, np.array(spec.goal_m), stack, plant, off)

    def _attach_mission(self, u: WorldUav, i: int, spec: UavSpec) -> None:
        """The mission beside ``u``'s program, if the scenario gives it one: the landing (and
        its sensor of the car) or a formation follower's slot."""
        scenario, formation, seed = self.scenario, self.scenario.formation, self.seed
        if scenario.landing is not None and scenario.landing[0] == spec.uav_id:
            u.mission = LandingMission(scenario.landing[1])
            car = scenario.ground_vehicle
            assert car is not None  # the scenario's validation saw to it
            ts = scenario.target_sensor
            u.sensor = TargetSensor(lambda t, car=car: car.state(t).position_m,
                                    rate_hz=ts.rate_hz, sigma_m=ts.sigma_m,
                                    dropout=ts.dropout, seed=seed * 1000 + 500 + i)
        elif formation is not None and spec.uav_id in formation.followers:
            u.mission = FormationFollower(formation, spec.uav_id)

    def _world_finder(self, index: bool | None
                      ) -> tuple[list[EncounterStrategy | None], EncounterFinder | None]:
        """Per UAV, its strategy when the world finds its encounters (else None), and the one
        finder for the whole world: only when every UAV with a strategy decides from
        encounters (an :class:`~uavmpc.avoidance.EncounterStrategy`); else each plans alone."""
        strategies = [u.stack.avoidance for u in self.uavs if u.stack.avoidance is not None]
        if not (strategies and all(isinstance(d, EncounterStrategy) for d in strategies)):
            return [None] * len(self.uavs), None
        deciders = [u.stack.avoidance if isinstance(u.stack.avoidance, EncounterStrategy)
                    else None for u in self.uavs]
        # Every stack flies the world's parameters: the first one's finder is everyone's.
        first = next(d for d in deciders if d is not None)
        return deciders, first.finder(self.inboxes, use_index=index)

    def run(self, duration_s: float | None = None, *, realtime: float | None = None,
            on_log: Callable[[World], None] | None = None,
            on_scene: Callable[[float, dict[str, Any], dict[str, Any]], None] | None = None,
            ) -> WorldResult:
        """Fly for ``duration_s`` (default: the scenario's) and return the result.

        ``realtime``: pace the simulated clock at this many times the wall clock (1.0: real
        time; default: as fast as it goes). ``on_log(world)`` is called at the log rate
        (every :data:`POSE_LOG_PERIOD_S`), e.g. to mirror the UAVs on ROS 2;
        ``on_scene(t_s, scene, metrics)`` every :data:`SCENE_PERIOD_S` with the 3-D scene
        (:meth:`scene`) and the metrics (:meth:`metrics`) the log also gets, e.g. to serve
        them live (:class:`uavmpc.view.live.LiveView`)."""
        duration = self.scenario.duration_s if duration_s is None else float(duration_s)
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(f"duration_s must be > 0, got {duration_s}")
        if realtime is not None and not (math.isfinite(realtime) and realtime > 0):
            raise ValueError(f"realtime must be > 0, got {realtime}")
        ticks = round(duration / self.period_s)
        if ticks < 1:
            raise ValueError(f"duration_s must be at least one tick ({self.period_s} s)")
        n = len(self.uavs)
        ids = [u.uav_id for u in self.uavs]
        pos = np.empty((ticks, n, 3))
        zoff = np.empty((ticks, n))
        dmin = np.full(ticks, np.inf)
        t_log = np.empty(ticks)
        iu = np.triu_indices(n, 1)
        pair_d = np.empty(max(1, n * (n - 1) // 2))
        contact: dict[tuple[int, int], Collision] = {}
        collisions: list[Collision] = []
        ranged = self.link.range_m is not None
        next_log = self.t_s
        spec = self.scenario.formation
        members = (np.array([ids.index(m) for m in spec.members]) if spec is not None
                   else np.zeros(0, dtype=np.int64))
        members_avoiding = np.zeros(ticks, dtype=bool)
        if self.batched and self.onboard.inline:
            # Compile (or load) the tick before the clock starts: wall_s and the real-time
            # factor measure flying, not a first run's compilation.
            self._bound_tick(self.onboard.tracker.table(), (0, pos, zoff, dmin, pair_d))
        self._phase_wall_s = [0.0, 0.0, 0.0]
        # The compiled tick times its stages in CPU cycles, read against the wall clock.
        self._cycles[:] = 0
        cycles0 = cycle_count() if HAS_CYCLE_COUNTER else 0
        wall0 = time.perf_counter()
        for k in range(ticks):
            now = self.t_s
            if self.batched:
                self._tick_batched(now, k, pos, zoff, dmin, pair_d)
            else:
                self._tick_objects(now, k, pos, zoff, dmin, pair_d)
            self.t_s = now + self.period_s
            t_log[k] = self.t_s
            if self.fence_watches and k % FENCE_CHECK_TICKS == 0:
                self._watch_fence()
            if members.size:
                members_avoiding[k] = self.onboard.stats.avoiding[members].any()
            if ranged:  # the link's range check sees where the UAVs are
                for i, u in enumerate(self.uavs):
                    self._positions[u.uav_id] = pos[k, i]
            if n > 1 and (dmin[k] < COLLISION_DISTANCE_M or contact):
                self._collisions(pair_d, iu, ids, contact, collisions)
            if (self.recorder is not None or on_log is not None) \
                    and self.t_s >= next_log - 1e-9:
                next_log = self.t_s + POSE_LOG_PERIOD_S
                if self.recorder is not None:
                    self._log()
                if on_log is not None:
                    on_log(self)
            if (self.recorder is not None or on_scene is not None) \
                    and self.t_s >= self._next_scene_s - 1e-9:
                self._show(float(dmin[k]) if n > 1 else None, on_scene)
            if realtime is not None:
                ahead = (k + 1) * self.period_s / realtime - (time.perf_counter() - wall0)
                if ahead > 0.0:
                    time.sleep(ahead)
        wall = time.perf_counter() - wall0
        cycles_per_s = (cycle_count() - cycles0) / wall if HAS_CYCLE_COUNTER and wall > 0 else 0.0
        for i, u in enumerate(self.uavs):
            self._positions[u.uav_id] = pos[ticks - 1, i].copy()
        st = self.link.stats
        messages = {"sent": st.sent, "delivered": st.delivered,
                    "dropped": st.dropped + st.dropped_range, "published": st.published}
        result = WorldResult(self.scenario.name, self.seed, self.avoidance,
                             ticks * self.period_s, ids, t_log, pos, zoff, dmin, collisions,
                             self._outcomes(pos[-1]), messages, wall)
        if members.size:
            result.traces["members_avoiding"] = members_avoiding
        self._add_extras(result, cycles_per_s)
        self._applications(result)
        return result

    def _show(self, min_distance_m: float | None,
              on_scene: Callable[[float, dict[str, Any], dict[str, Any]], None] | None) -> None:
        """The 3-D scene and the metrics now, to the log and to ``on_scene``."""
        self._next_scene_s = self.t_s + SCENE_PERIOD_S
        views = self.views()
        scene = self.scene(views)
        metrics = self.metrics(min_distance_m, views)
        if self.recorder is not None:
            self.recorder.scene(self.t_s, scene)
            self.recorder.metrics(self.t_s, metrics)
        if on_scene is not None:
            on_scene(self.t_s, scene, metrics)

    def _outcomes(self, final_m: np.ndarray) -> dict[str, UavOutcome]:
        """Per UAV, how its flight ended, from its program's report and its last position
        ``final_m`` (N, 3) [m]."""
        per_uav = {}
        for u, final in zip(self.uavs, final_m, strict=True):
            rep = u.stack.report()
            per_uav[u.uav_id] = UavOutcome(
                max_z_offset_m=rep.max_z_offset_m, avoidance_active_s=rep.avoidance_active_s,
                tracking_rmse_m=rep.tracking_rmse_m,
                reached_goal=(None if u.mission is not None
                              else bool(np.linalg.norm(final - u.goal_m) < GOAL_TOLERANCE_M)),
                final_position_m=final.tolist(), limit_violations=rep.limit_violations,
                max_limit_excess=rep.max_limit_excess, tracker_fallbacks=rep.tracker_fallbacks,
                messages_rejected=rep.messages_rejected_total,
                yielded_to={k: [round(a, 3), round(b, 3)] for k, (a, b) in u.yielded_to.items()})
        return per_uav

    def _add_extras(self, result: WorldResult, cycles_per_s: float) -> None:
        """What only some runs have: where a batched run's time went, the geofence, the
        launch check, who flew without avoidance."""
        if self.batched:
            # Where a batched run's wall time went: the numbers of a scale benchmark.
            result.extra["wall_s_by_phase"] = dict(zip(
                ("receive_and_plan", "compiled_tick", "broadcast"),
                (round(v, 6) for v in self._phase_wall_s), strict=True))
            c = self._cycles
            if c.size and c[3] > 0 and cycles_per_s > 0:
                # Per UAV and tick, inside the compiled call: the floor of a UAV-second.
                result.extra["compiled_us_per_uav_tick"] = {
                    name: round(float(c[j] / c[3] / cycles_per_s * 1e6), 3)
                    for j, name in enumerate(("stack", "plant", "trace"))}
        if self.fence_watches:
            result.extra["geofence"] = {u.uav_id: w.report() for u, w in
                                        zip(self.uavs, self.fence_watches, strict=True)}
        if self.launch_check_s is not None:
            result.extra["launch"] = {
                "max_wait_s": self.launch_check_s, **self.launches,
                **{self.uavs[i].uav_id: {"launched_s": None, "not_heard": None}
                   for i in self._unlaunched}}
        if self.avoidance and self.non_cooperative:
            # Who flew without avoidance while the others avoided (with ``avoidance`` off,
            # the summary's "avoidance": false already says everyone did).
            result.extra["non_cooperative"] = list(self.non_cooperative)

    def _applications(self, result: WorldResult) -> None:
        """The field applications' outcomes (landing, formation) into the result."""
        car = self.ground_vehicle
        if car is not None:
            result.traces["ground_vehicle_m"] = np.array(
                [car.state(t).position_m for t in result.t_s])
        for i, u in enumerate(self.uavs):
            if isinstance(u.mission, LandingMission):
                assert car is not None
                end = float(result.t_s[-1])
                final = result.positions_m[-1, i]
                rests = bool(u.plant.landed and abs(final[2] - car.deck_height_m) < 1e-6
                             and car.on_deck(end, final))
                out = landing_outcome(u.mission, u.plant.deck_touch(),
                                      u.stack.airframe.max_touchdown_speed_mps, rests, end)
                result.extra.update({"landing_uav": u.uav_id, **out})
                result.traces["lander_index"] = np.array(i)
        spec = self.scenario.formation
        if spec is not None:
            keep = result.t_s >= FORMATION_SETTLE_S
            index = {uid: k for k, uid in enumerate(result.uav_ids)}
            err = formation_error(spec, result.t_s[keep],
                                  {m: result.positions_m[keep, index[m]] for m in spec.members})
            series = err.pop("series_m")
            calm = ~result.traces["members_avoiding"][keep]
            if calm.any():
                err["while_no_member_avoids"] = {
                    "rms": float(np.sqrt(np.mean(series[calm] ** 2))),
                    "max": float(series[calm].max()), "share_of_time": float(calm.mean())}
            result.traces["formation_error_m"] = series
            result.traces["formation_t_s"] = result.t_s[keep]
            result.extra["formation_error_m"] = err
            result.extra["formation"] = {
                "leader": spec.leader, "followers": list(spec.followers),
                "measured_from_s": FORMATION_SETTLE_S,
                "outsiders": [uid for uid in result.uav_ids if uid not in spec.members]}

    # ------------------------------------------------------------------------------ one tick
    def _receive_and_plan(self, now: float) -> None:
        """Every UAV, UAV by UAV (the per-object path): its datagrams into its inbox, its
        mission, its avoidance."""
        rec = self.recorder
        if self.ground_vehicle is not None:  # every plant's contact knows where the deck is
            self.plants.deck[:] = self.ground_vehicle.deck_row(now)
        for i, u in enumerate(self.uavs):
            data = self.link.receive(u.uav_id, now)
            rejected = u.stack.inbox.rejected_total
            kept = u.stack.receive(now + u.clock_offset_s, data)
            if rec is not None:
                for msg in kept:
                    if msg is not None:
                        rec.link(now, "delivered", msg.uav_id, u.uav_id, msg.stamp_s)
                for _ in range(u.stack.inbox.rejected_total - rejected):
                    rec.link(now, "rejected", "?", u.uav_id)
            if u.mission is not None and now >= u.next_mission_s - 1e-9:
                u.next_mission_s = now + u.mission.period_s
                self._step_mission(u, now)
            if self._unlaunched:
                self._launch(now, (i,))
            u.stack.plan(now + u.clock_offset_s)
        self._note_yields(now, range(len(self.uavs)))

    def _receive_and_plan_batched(self, now: float) -> None:
        """The same for every UAV at once: the tick's deliveries into the inbox rows in one
        compiled call, then the missions, then the avoidance of the UAVs due, their
        encounters found in one compiled call (:mod:`uavmpc.avoidance.encounters`)."""
        if self.ground_vehicle is not None:
            self.plants.deck[:] = self.ground_vehicle.deck_row(now)
        if now >= self.link.next_due_s:
            self._deliver(now)
        for u in self._missions:
            if now >= u.next_mission_s - 1e-9 and u.mission is not None:
                u.next_mission_s = now + u.mission.period_s
                self._step_mission(u, now)
                self._next_round_s = -math.inf  # the mission may have changed who plans
        if self._unlaunched:
            self._launch(now, list(self._unlaunched))
        if self._finder is None:
            for u in self.uavs:
                u.stack.plan(now + u.clock_offset_s)
            self._note_yields(now, range(len(self.uavs)))
        else:
            if now >= self._next_round_s:
                self._plan_round(now)
            self._note_yields(now, ())

    def _deliver(self, now: float) -> None:
        due = self.link.take_due(now)
        if due is None:
            return
        receivers, payloads = due
        table = self.inboxes
        n = len(self.uavs)
        # A tick's copies come from a few broadcasts: each is decoded (or found) once.
        pids = np.unique(payloads)
        slots = np.empty(pids.shape[0], dtype=np.int64)
        errors: dict[int, str] = {}
        for j, pid in enumerate(pids.tolist()):
            try:
                slots[j] = table.slot_for(self.link.payload(pid))
            except InvalidMessageError as exc:
                slots[j] = -1
                errors[pid] = str(exc)
        self.link.release(payloads)
        copy_slots = (np.full(payloads.shape[0], slots[0]) if pids.shape[0] == 1
                      else slots[np.searchsorted(pids, payloads)])
        good = (receivers < n) & (copy_slots >= 0)  # < n: not copies injected for strangers
        if errors:
            for k in np.flatnonzero((receivers < n) & (copy_slots < 0)).tolist():
                self.uavs[receivers[k]].stack.inbox.count_rejected(errors[int(payloads[k])])
        rec = self.recorder
        if rec is not None:
            before = table.rows.accepted.copy()
        try:
            if good.all():
                accept_copies(table.rows, table.store, receivers, copy_slots,
                              now + self._offsets)
            else:
                accept_copies(table.rows, table.store, receivers[good], copy_slots[good],
                              now + self._offsets)
        finally:
            table.unpin()
        if rec is not None:
            self._log_deliveries(now, receivers, copy_slots, good, before)

    def _log_deliveries(self, now: float, receivers: np.ndarray, slots: np.ndarray,
                        good: np.ndarray, before: np.ndarray) -> None:
        """Delivered (kept) and rejected copies into the flight log: a receiver's kept copies
        are the newest of each sender it now holds that it did not hold before."""
        rec = self.recorder
        assert rec is not None
        table = self.inboxes
        st = table.store
        for k in range(receivers.shape[0]):
            r = int(receivers[k])
            if r >= len(self.uavs):
                continue
            if not good[k]:
                rec.link(now, "rejected", "?", self.uavs[r].uav_id)
                continue
            slot = int(slots[k])
            col = int(st.col[slot])
            if table.rows.held_slot[r, col] == slot and table.rows.accepted[r] > before[r]:
                rec.link(now, "delivered", table.ids[col], self.uavs[r].uav_id,
                         float(st.stamp_s[slot]))

    def _plan_round(self, now: float) -> None:
        """The avoidance of every UAV due at this tick, on its tracker's clock."""
        sched = self.onboard.schedule
        trk = self.onboard.tracker
        t = trk.rows.t_s
        due = np.flatnonzero(sched.planning & (t >= sched.next_avoidance_s - 1e-9))
        if due.size:
            plan_s = t[due]
            sched.next_avoidance_s[due] = plan_s + AVOIDANCE_PERIOD_S
            m = trk.config.steps
            times = np.empty((due.size, m))
            own = np.empty((due.size, m, 3))
            climbed = np.empty(due.size)
            avoidance_plans(due, trk.rows, trk.table(), trk.consts, times, own, climbed)
            assert self._finder is not None
            found = self._finder.find(due, times, own, plan_s, self._radius[due],
                                      [self._overrides[i] for i in due.tolist()])
            for j, i in enumerate(due.tolist()):
                stack = self.uavs[i].stack
                decider = self._deciders[i]
                assert decider is not None  # planning: a strategy, and the world finds for it
                stack.apply(decider.decide(
                    float(plan_s[j]), stack.uav_id, stack.priority, times[j], found[j],
                    climbed_m=float(climbed[j])))
                if stack.decision is not None and stack.decision.yielding_to:
                    self._yielding.add(i)
        planning = sched.planning
        if planning.any():
            # The next tick any UAV can be due at (a tick early is harmless: nobody is due).
            lead = np.min(sched.next_avoidance_s[planning] - t[planning])
            self._next_round_s = now + lead - self.period_s
        else:
            self._next_round_s = math.inf

    def _note_yields(self, now: float, decided: Iterable[int]) -> None:
        """Whom each UAV yields to, at every tick its decision says so (``decided``: the UAVs
        that may have decided since; those yielding already are followed)."""
        for i in decided:
            d = self.uavs[i].stack.decision
            if d is not None and d.yielding_to:
                self._yielding.add(i)
        for i in sorted(self._yielding):
            u = self.uavs[i]
            d = u.stack.decision
            if d is None or not d.yielding_to:
                self._yielding.discard(i)
                continue
            for other in d.yielding_to:
                span = u.yielded_to.setdefault(other, [now, now])
                span[1] = now

    def _launch(self, now: float, which: Iterable[int]) -> None:
        """The launch check: a UAV held at its start sets off on its mission once its
        avoidance knows every other UAV (holds a prediction from each, fresh or silent, that
        its encounters count), or once ``launch_check_s`` has passed. Found in the 24 h
        campaign with burst loss (trial 118): two UAVs 8 m apart set off towards each other;
        one heard the other only 1.3 s later and met it at 2.0 s, before its climb was under
        way."""
        rows = self.inboxes.rows
        prm = self.params
        use_received = prm.time_reference == "receive"
        for i in [i for i in which if i in self._unlaunched]:
            u = self.uavs[i]
            own = now + u.clock_offset_s
            others = np.array([c for c in range(len(self.uavs)) if c != i], dtype=np.int64)
            # The world's receivers are its UAVs: row i, and UAV j in column j.
            ready = heard_from_all(rows, i, others, own, use_received, prm.timeout_s,
                                   prm.silent_hold_s)
            assert self.launch_check_s is not None
            if not ready and now < self.launch_check_s:
                continue
            unheard = [] if ready else [
                self.uavs[j].uav_id for j in others.tolist()
                if not heard_from_all(rows, i, np.array([j]), own, use_received,
                                      prm.timeout_s, prm.silent_hold_s)]
            u.stack.set_mission(self._unlaunched.pop(i))
            self.launches[u.uav_id] = {"launched_s": round(now, 3), "not_heard": unheard}
            self._next_round_s = -math.inf  # its plan changed

    def _step_mission(self, u: WorldUav, now: float) -> None:
        assert u.mission is not None
        own = now + u.clock_offset_s
        estimate = u.plant.state()
        fixes = u.sensor.fixes_until(now) if u.sensor is not None else ()
        if u.clock_offset_s and fixes:
            fixes = [f._replace(t_s=f.t_s + u.clock_offset_s) for f in fixes]
        # The land detector: resting, or the landing gear's contact switch on the deck's top
        # (cutting the motors at first contact keeps a UAV from sliding across the deck).
        touching = u.plant.landed or u.plant.deck_touch().on_deck
        out = u.mission.step(MissionInput(own, estimate, touching, u.stack.inbox.latest, fixes))
        if out.cut_motors:
            if not u.motors_cut:
                u.motors_cut = True
                u.plant.cut_motors()
            # Where it rests is what it will do: broadcast that, flag down (others avoid it).
            u.stack.follow(own, estimate)
        elif out.reference is not None:
            u.stack.set_mission(out.reference)

    def _emit(self, now: float) -> None:
        """The broadcasts due at this tick (each UAV on its own clock)."""
        if not self._started:
            self._started = True
            for u in self.uavs:
                u.stack.mark_ticked()
            self._next_round_s = -math.inf
        if now < self._next_emit_s:
            return
        sched = self.onboard.schedule
        for i in np.flatnonzero(now + self._offsets
                                >= sched.next_broadcast_s - 1e-9).tolist():
            u = self.uavs[i]
            data = u.stack.emit(now + u.clock_offset_s)
            if data is not None:
                self._publish(u, data, now)
        # The next tick anyone can be due at (a tick early is harmless).
        self._next_emit_s = float(np.min(sched.next_broadcast_s - self._offsets)) \
            - self.period_s

    def _tick_batched(self, now: float, k: int, pos: np.ndarray, zoff: np.ndarray,
                      dmin: np.ndarray, pair_d: np.ndarray) -> None:
        clock = time.perf_counter
        t0 = clock()
        self._receive_and_plan_batched(now)
        t1 = clock()
        for plant in self._windy:
            plant.hold_wind(self.period_s)
        ob = self.onboard
        trk = ob.tracker
        table = trk.table()
        traces = (k, pos, zoff, dmin, pair_d)
        if ob.inline:
            bad = self._bound_tick(table, traces)(trk.rows, table, trk.consts, ob.control,
                                                  ob.stats, self.plants, self.n_sub,
                                                  self.period_s, *traces, self._cycles,
                                                  self._estimates())
        else:
            world_pre(trk.rows, ob.stats, self.plants)
            trk.step()
            bad = world_post(trk.rows, trk.consts, ob.control, ob.stats, self.plants,
                             self.n_sub, self.period_s, *traces)
        if bad >= 0:
            raise ValueError(f"invalid attitude target for {self.uavs[bad].uav_id} "
                             "(not finite): the controller got a degenerate state")
        t2 = clock()
        self._emit(now)
        phase = self._phase_wall_s
        phase[0] += t1 - t0
        phase[1] += t2 - t1
        phase[2] += clock() - t2

    def _bound_tick(self, table: Any, traces: tuple[Any, ...]) -> Any:
        """:func:`world_tick` bound to this world's records (compiled on first use)."""
        if self._kernels is None or self._kernels[0] is not table:
            ob = self.onboard
            trk = ob.tracker
            self._kernels = (table, bind(world_tick, trk.rows, table, trk.consts, ob.control,
                                         ob.stats, self.plants, self.n_sub, self.period_s,
                                         *traces, self._cycles, self._estimates(peek=True)))
        return self._kernels[1]

    def _tick_objects(self, now: float, k: int, pos: np.ndarray, zoff: np.ndarray,
                      dmin: np.ndarray, pair_d: np.ndarray) -> None:
        # Receive and plan for everyone first, as the batched tick does: a UAV must not see a
        # message another UAV sent in this same tick.
        self._receive_and_plan(now)
        self._started = True
        self._next_round_s = self._next_emit_s = -math.inf  # if the batched path takes over
        est = self._estimates()
        for i, u in enumerate(self.uavs):
            # received and planned above: those phases are no-ops here
            state = u.plant.state()
            if est.shape[0]:
                state = dataclasses.replace(state, position_m=est[i, 0:3].copy(),
                                            velocity_mps=est[i, 3:6].copy())
            out = u.stack.tick(now + u.clock_offset_s, state)
            u.plant.step(out.target, self.period_s)
            if out.outgoing is not None:
                self._publish(u, out.outgoing, now)
        _trace(self.onboard.tracker.rows, self.plants, k, pos, zoff, dmin, pair_d)

    # ------------------------------------------------------------------------------ internals
    def _watch_fence(self) -> None:
        """The failsafe of every UAV (:class:`~uavmpc.geofence.FenceWatch`): one found outside
        the volume flies back in and holds; its mission, if one steps beside it, stops."""
        assert self.geofence is not None
        pos = self.plants.x[:, 0:3]
        margins = self.geofence.margin(pos)
        for i in np.flatnonzero(~(margins >= 0.0) | ~np.array(
                [w.entered for w in self.fence_watches])).tolist():
            back = self.fence_watches[i].check(pos[i], margins[i])
            if back is None:
                continue
            u = self.uavs[i]
            if u.mission is not None:
                self._missions = [m for m in self._missions if m is not u]
                u.mission = None
            ref = Reference.goto(*back, float(heading_of(self.plants.x[i, 6:10])),
                                 start_s=self.t_s + u.clock_offset_s)
            if isinstance(u.stack.avoidance, EncounterStrategy):
                u.stack.avoidance.limit_offset(self.geofence.offset_ceiling_m(back[2:3]))
            u.stack.set_mission(ref)

    def _estimates(self, peek: bool = False) -> np.ndarray:
        """What the controllers fly on this tick: (N, 6) estimated [p, v], or (0, 6) (the
        truth). ``peek``: the array only, the sensors not advanced (to compile the tick)."""
        if self.estimator is None:
            return self._no_estimate
        if peek:
            return self.estimator.estimate
        x = self.plants.x
        return self.estimator.step(x[:, 0:3], x[:, 3:6])

    def _publish(self, u: WorldUav, data: bytes, now: float) -> None:
        if now >= self.silent_from_s.get(u.uav_id, math.inf):
            self.silenced += 1  # a dead radio: the UAV does not know it
            return
        self.link.publish(data, u.uav_id, now)
        pred = u.stack.last_broadcast
        if self.recorder is not None and pred is not None:
            self.recorder.prediction(u.uav_id, now, pred.position_m, pred.heading_rad)
            self.recorder.link(now, "sent", u.uav_id, stamp_s=now)

    def _collisions(self, d: np.ndarray, iu: tuple[np.ndarray, np.ndarray], ids: list[str],
                    contact: dict[tuple[int, int], Collision],
                    collisions: list[Collision]) -> None:
        close = d < COLLISION_DISTANCE_M
        if not close.any() and not contact:
            return
        for j in range(d.shape[0]):
            key = (int(iu[0][j]), int(iu[1][j]))
            if close[j]:
                c = contact.get(key)
                if c is None:
                    c = Collision(self.t_s, ids[key[0]], ids[key[1]], float(d[j]))
                    contact[key] = c
                    collisions.append(c)
                c.distance_m = min(c.distance_m, float(d[j]))
            else:
                contact.pop(key, None)

    def views(self) -> list[UavView]:
        """Every flying UAV as the 3-D scene shows it now (:mod:`uavmpc.view.scene`)."""
        out = []
        for u in self.uavs:
            stack = u.stack
            if stack.last_output is None:
                continue
            s = u.plant.state()
            d = stack.decision
            plan = stack.last_broadcast
            desired = np.zeros((0, 3))
            ref = stack.tracker.reference
            if plan is not None and ref is not None:
                desired = ref.sample(plan.times_s)[:, :3]
            silent = self.t_s >= self.silent_from_s.get(u.uav_id, math.inf)
            state = state_of(silent=silent, waiting_for=d.waiting_for if d else (),
                             yielding_to=d.yielding_to if d else (),
                             z_offset_m=stack.tracker.z_offset_m,
                             avoiding=bool(d is not None and d.avoiding))
            detail = detail_of(yielding_to=d.yielding_to if d else (),
                               waiting_for=d.waiting_for if d else ())
            out.append(UavView(
                u.uav_id, s.position_m, float(heading_of(s.attitude_wxyz)),
                plan.position_m if plan is not None else np.zeros((0, 3)), desired,
                stack.tracker.z_offset_m, state, stack.params.radius_m, stack.params.height_m,
                detail))
        return out

    def scene(self, views: Sequence[UavView] | None = None) -> dict[str, Any]:
        """The ``foxglove.SceneUpdate`` of now: the UAVs (``views``, default :meth:`views`),
        the ground, the geofence, the car and its deck."""
        if self._ground is None:
            self._ground = ground_around(self.scenario.points_m())
        objects = []
        if self.ground_vehicle is not None:
            car = self.ground_vehicle.state(self.t_s)
            deck = self.ground_vehicle.deck_size_m
            x, y, deck_z = (float(v) for v in car.position_m)
            objects = [  # the car's body under its deck
                ObjectView("car", np.array([x, y, 0.5 * deck_z]), car.heading_rad,
                           (2.0 * deck, deck, deck_z), (0.2, 0.2, 0.25, 1.0)),
                ObjectView("deck", car.position_m, car.heading_rad, (deck, deck, 0.05),
                           (0.95, 0.85, 0.2, 1.0))]
        fence = None
        if self.geofence is not None:
            g = self.geofence
            fence = (g.polygon_xy_m, g.min_altitude_m, g.max_altitude_m)
        return scene_update(self.t_s, self.views() if views is None else views, fence=fence,
                            objects=objects,
                            ground=self._ground)

    def metrics(self, min_distance_m: float | None,
                views: Sequence[UavView] | None = None) -> dict[str, Any]:
        """The plot-ready numbers of now: the closest pair's distance and, per UAV, its
        cylinder state and whom it yields to or waits for (``views``, default
        :meth:`views`), its z offset, how far its virtual UAV is outside the limits, its
        tracker fallbacks."""
        shown = {v.uav_id: v for v in (self.views() if views is None else views)}
        out: dict[str, Any] = {}
        for u in self.uavs:
            row: dict[str, Any] = {"z_offset_m": u.stack.tracker.z_offset_m,
                                   "limit_excess": u.stack.tracker.limit_excess(),
                                   "tracker_fallbacks": u.stack.tracker.fallback_count,
                                   "avoiding": bool(u.stack.decision is not None
                                                    and u.stack.decision.avoiding)}
            if u.uav_id in shown:
                row.update(state=shown[u.uav_id].state, detail=shown[u.uav_id].detail)
            out[u.uav_id] = row
        return {"t_s": self.t_s, "min_distance_m": min_distance_m, "uavs": out}

    def _log(self) -> None:
        rec = self.recorder
        assert rec is not None
        if self.ground_vehicle is not None:
            car = self.ground_vehicle.state(self.t_s)
            rec.pose(GROUND_VEHICLE_ID, "state", self.t_s, car.position_m, car.heading_rad)
        for u in self.uavs:
            last = u.stack.last_output
            if last is None:
                continue
            s = u.plant.state()
            rec.pose(u.uav_id, "state", self.t_s, s.position_m, float(heading_of(s.attitude_wxyz)))
            c = last.command
            rec.pose(u.uav_id, "command", self.t_s, c.position_m, c.heading_rad)
            ref = u.stack.tracker.reference
            if ref is not None:
                r = ref.sample(np.array([self.t_s]))[0]
                rec.pose(u.uav_id, "reference", self.t_s, r[:3], float(r[3]))
            decision = u.stack.decision
            rec.status(u.uav_id, self.t_s,
                       velocity_mps=s.velocity_mps.tolist(),
                       command_velocity_mps=c.velocity_mps.tolist(),
                       z_offset_m=u.stack.tracker.z_offset_m,
                       avoiding=bool(decision is not None and decision.avoiding),
                       conflicts=list(decision.conflicts) if decision is not None else [],
                       yielding_to=list(decision.yielding_to) if decision is not None else [],
                       limit_excess=u.stack.tracker.limit_excess(),
                       braking=bool(last.braking))
