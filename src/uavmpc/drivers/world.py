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
from uavmpc.avoidance.encounters import EncounterFinder
from uavmpc.avoidance.round import avoidance_round
from uavmpc.comms.inbox import InboxTable
from uavmpc.comms.link import SimulatedLink
from uavmpc.config import ConfigError
from uavmpc.drivers.delivery import WorldLink
from uavmpc.drivers.world_report import (
    COLLISION_DISTANCE_M,
    FORMATION_SETTLE_S,
    GOAL_TOLERANCE_M,
    Collision,
    Contacts,
    Traces,
    UavOutcome,
    WorldResult,
    Yields,
    world_result,
)
from uavmpc.drivers.world_tick import CompiledTick, world_post, world_pre, world_tick
from uavmpc.drivers.world_view import GROUND_VEHICLE_ID, SCENE_PERIOD_S, WorldScene
from uavmpc.estimation import ObserverParams
from uavmpc.estimation.fleet import FleetEstimator
from uavmpc.jit import HAS_CYCLE_COUNTER, CompileWatch, bound, cycle_count
from uavmpc.log import FlightRecorder
from uavmpc.missions.formation import FormationFollower
from uavmpc.missions.landing import LandingMission
from uavmpc.missions.mission import Mission
from uavmpc.onboard import (
    BROADCAST_PERIOD_S,
    OnboardBatch,
    OnboardStack,
    broadcast,
    broadcasts_due,
    next_broadcast_s,
)
from uavmpc.plant import Airframe, PlantRows, Wind
from uavmpc.plant.interface import heading_of
from uavmpc.plant.multirotor import Multirotor
from uavmpc.plant.sensors import TargetSensor
from uavmpc.reference import Reference
from uavmpc.scenarios import LinkSettings, Scenario, UavSpec
from uavmpc.scenarios.run import RunSpec
from uavmpc.supervisor import FenceGuard, Supervisor
from uavmpc.tracker import TrackerConfig
from uavmpc.view.scene import UavView

__all__ = ["COLLISION_DISTANCE_M", "FORMATION_SETTLE_S", "GOAL_TOLERANCE_M",
           "GROUND_VEHICLE_ID", "SCENE_PERIOD_S", "Collision", "UavOutcome", "World",
           "WorldResult", "WorldUav", "world_post", "world_pre", "world_tick"]

#: Log rate of poses and status (predictions are logged at each broadcast).
POSE_LOG_PERIOD_S = 0.05


@dataclass
class WorldUav:
    """One UAV of the world: its program, its plant, its supervisor, where it should end."""

    uav_id: str
    goal_m: np.ndarray
    stack: OnboardStack
    plant: Multirotor
    supervisor: Supervisor  # its mission, launch hold, geofence (uavmpc.supervisor)
    clock_offset_s: float = 0.0  # its clock minus the world's
    sensor: TargetSensor | None = None  # its fixes of the ground vehicle
    #: Whom it yielded to: other id → [first, last] time of a decision saying so [s].
    yielded_to: dict[str, list[float]] = field(default_factory=dict)


def broadcast_phase(i: int, n: int) -> float:
    """When UAV i of n first broadcasts: the phases are spread over the period."""
    return BROADCAST_PERIOD_S * (i + 0.5) / n


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


def _link_of(scenario: Scenario, link: LinkSettings | None, positions: dict[str, np.ndarray],
             seed: int) -> SimulatedLink:
    """The world's link (``link`` over the scenario's settings); its range check looks the
    UAVs up in ``positions``."""
    settings = link if link is not None else scenario.link
    return SimulatedLink(
        [u.uav_id for u in scenario.uavs], latency_s=settings.latency_s,
        jitter_s=settings.jitter_s, loss=settings.loss,
        range_m=settings.range_m or None, position_of=positions.__getitem__,
        seed=seed, burst_len=settings.burst_len,
    )


def _common_substeps(uavs: Sequence[WorldUav], period_s: float) -> int:
    """The plants' substeps per tick (a world steps them together: the same for all)."""
    n_sub = uavs[0].plant.substeps(period_s)
    if any(u.plant.substeps(period_s) != n_sub for u in uavs):
        raise ValueError("the plants' substeps differ; a world steps them together")
    return n_sub


def _mission_of(scenario: Scenario, spec: UavSpec, sensor_seed: int
                ) -> tuple[Mission | None, TargetSensor | None]:
    """The mission beside ``spec``'s program, if the scenario gives it one: the landing (and
    its sensor of the car, seeded ``sensor_seed``) or a formation follower's slot."""
    formation = scenario.formation
    if scenario.landing is not None and scenario.landing[0] == spec.uav_id:
        car = scenario.ground_vehicle
        assert car is not None  # the scenario's validation saw to it
        ts = scenario.target_sensor
        return LandingMission(scenario.landing[1]), TargetSensor(
            lambda t: car.state(t).position_m, rate_hz=ts.rate_hz,
            sigma_m=ts.sigma_m, dropout=ts.dropout, seed=sensor_seed)
    if formation is not None and spec.uav_id in formation.followers:
        return FormationFollower(formation, spec.uav_id), None
    return None, None


def _world_finder(stacks: Sequence[OnboardStack],
                  index: bool | None) -> EncounterFinder | None:
    """The one finder of the whole world's encounters: only when every UAV with a strategy
    decides from encounters (an :class:`~uavmpc.avoidance.EncounterStrategy`); else None
    (each plans alone)."""
    planners = [s for s in stacks if s.avoidance is not None]
    if not (planners and all(s.steering.own_finder is not None for s in planners)):
        return None
    # Every stack flies the world's parameters: the first one's finder is everyone's.
    return planners[0].steering.finder(use_index=index)


def _ticks_of(duration_s: float, realtime: float | None, period_s: float) -> int:
    """The ticks of a run of ``duration_s`` [s] (checked, as ``realtime``)."""
    duration = float(duration_s)
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration_s must be > 0, got {duration_s}")
    if realtime is not None and not (math.isfinite(realtime) and realtime > 0):
        raise ValueError(f"realtime must be > 0, got {realtime}")
    ticks = round(duration / period_s)
    if ticks < 1:
        raise ValueError(f"duration_s must be at least one tick ({period_s} s)")
    return ticks




def _world_uav(world: World, i: int, spec: UavSpec, af: Airframe, wind_mps: float, off: float,
               resolver: ResolutionStrategy | None) -> WorldUav:
    """Row ``i`` of ``world``: its plant and its stack on the world's rows, clock offset
    ``off`` [s], its supervisor flying its mission (held at its start when the launch check
    holds it) and the mission beside it, if any."""
    scenario, n, seed = world.scenario, len(world.scenario.uavs), world.seed
    wind = None
    if wind_mps > 0.0:
        wind = Wind(mean_mps=(wind_mps, 0.0, 0.0), gust_sigma_mps=0.3 * wind_mps,
                    seed=seed * 1000 + i)
    plant = Multirotor(af, position_m=spec.start_m, yaw_rad=spec.heading_rad, wind=wind,
                       rotors_at_hover=spec.start_m[2] > 0.0, rows=world.plants, row=i)
    # Each UAV broadcasts at its own phase, spread over the period.
    stack = OnboardStack(af, position_m=spec.start_m, heading_rad=spec.heading_rad,
                         t0_s=off, uav_id=spec.uav_id, priority=spec.priority,
                         avoidance=resolver, params=world.params,
                         broadcast_phase_s=broadcast_phase(i, n), batch=world.onboard,
                         row=i, inbox_table=world.inboxes)
    mission, sensor = _mission_of(scenario, spec, seed * 1000 + 500 + i)
    supervisor = Supervisor(stack, mission=mission, fence=(
        FenceGuard(world.geofence) if world.geofence is not None else None))
    reference = spec.mission
    if off:
        reference = Reference(reference.times_s + off, reference.points, reference.loop)
    formation = scenario.formation
    if (world.launch_check_s is not None and n > 1 and resolver is not None
            and scenario.landing is None
            and not (formation is not None and spec.uav_id in formation.followers)):
        # Hover where it starts; the mission waits for the link (:meth:`World._launch`).
        supervisor.hold(reference, Reference.goto(*spec.start_m, spec.heading_rad,
                                                  start_s=off))
        # While it waits, the ceiling over the mission it will fly, not over the hover.
        supervisor.limit_ceiling(spec.mission.points[:, 2])
    else:
        supervisor.fly(reference)
    return WorldUav(spec.uav_id, np.array(spec.goal_m), stack, plant, supervisor, off, sensor)


def _estimator_of(gnss: str | ObserverParams | None, onboard: OnboardBatch, n: int,
                  period_s: float, seed: int) -> FleetEstimator | None:
    """The observer every controller flies on, or None (the true state)."""
    if gnss is None:
        return None
    if not onboard.inline:
        raise ValueError("gnss: needs the compiled tracker solver (batchqp)")
    obs = ObserverParams.preset(gnss) if isinstance(gnss, str) else gnss
    onboard.position_sigma_m[:] = obs.position_sigma_m  # what each UAV's predictions state
    return FleetEstimator(obs, n, period_s, seed)


class World:
    """A flight (:class:`~uavmpc.scenarios.run.RunSpec`) flown by its UAVs in simulation.

    ``spec`` says what flies and how (scenario, avoidance, seed, link, wind, faults, launch
    check, the length of :meth:`run`). A UAV is cooperative iff the spec's avoidance is on,
    the scenario's spec of it says so and the faults do not make it non-cooperative. With a
    launch check, each UAV holds at its start until its inbox holds a prediction from every
    other UAV its avoidance counts, at most that long (``extra["launch"]`` says when, and
    who was not heard); a UAV flying without avoidance and a mission stepped beside the
    stack (a lander, a follower) set off at once.

    The keywords are the world's own wiring, not the flight's: ``recorder`` an optional MCAP
    recorder; ``strategy`` makes each UAV's strategy from the avoidance parameters (any
    :class:`~uavmpc.avoidance.ResolutionStrategy`); ``tracker_config`` every UAV's tracker
    set-up (default: packaged data/tracker.toml); ``batched`` False ticks each stack and
    plant on its own (:meth:`OnboardStack.tick`, :meth:`Multirotor.step`: the same kernels,
    bit for bit the same flight, slower); ``index`` finds encounters through the spatial
    index (True) or by every pair (False; :mod:`uavmpc.avoidance.encounters`), the same
    flight (default: the index from 32 UAVs on).
    """

    def __init__(
        self,
        spec: RunSpec,
        *,
        recorder: FlightRecorder | None = None,
        strategy: Callable[[AvoidanceParams], ResolutionStrategy] = HeightOffsetStrategy,
        tracker_config: TrackerConfig | None = None,
        batched: bool = True,
        index: bool | None = None,
    ) -> None:
        if not isinstance(spec, RunSpec):
            raise TypeError(f"World(spec): a RunSpec, got {type(spec).__name__} (a scenario "
                            "flies as World(RunSpec(scenario, ...)))")
        self.spec = spec
        flown = spec.flown
        scenario = self.scenario = flown.scenario
        faults = flown.faults
        self.flight_s = spec.flight_s  #: :meth:`run`'s default length [s]
        self.avoidance = spec.avoidance
        #: The ids of the UAVs flying without avoidance (all of them when ``avoidance`` is
        #: off), in the scenario's order.
        self.non_cooperative = tuple(
            u.uav_id for u in scenario.uavs
            if not (spec.avoidance and u.avoidance and u.uav_id not in faults.non_cooperative))
        self.seed = seed = spec.seed
        self.recorder = recorder
        self.batched = bool(batched)
        self.params = scenario.avoidance  # validated when the scenario was
        self._positions: dict[str, np.ndarray] = {}
        self.link = _link_of(scenario, flown.link, self._positions, seed)
        n = len(scenario.uavs)
        offsets = (np.zeros(n) if faults.clock_offsets_s is None
                   else np.array(faults.clock_offsets_s, dtype=float))
        #: The records of every UAV's numbers, one row each: their stacks' and their plants'.
        self.onboard = OnboardBatch(scenario.limits.over(tracker_config), n)
        self.ground_vehicle = scenario.ground_vehicle  #: carrying the landing deck, or None
        #: The scenario's operational volume: each UAV's failsafe, and its avoidance's
        #: ceiling over its mission (:mod:`uavmpc.geofence`, :class:`~uavmpc.supervisor.
        #: FenceGuard`).
        self.geofence = scenario.geofence
        airframes = {name: Airframe.named(name)
                     for name in dict.fromkeys(u.airframe for u in scenario.uavs)}
        self.plants = PlantRows.empty(n, max(a.n_rotors for a in airframes.values()))
        #: Every UAV's inbox, one row each (a broadcast is decoded once for all receivers).
        self.inboxes = InboxTable([u.uav_id for u in scenario.uavs],
                                  time_reference=self.params.time_reference,
                                  max_age_s=self.params.timeout_s,
                                  points=self.onboard.tracker.config.steps)
        self.launch_check_s = spec.launch_check_s
        #: Per id: when it set off [s, world time] and whom it had not heard then.
        self.launches: dict[str, dict[str, Any]] = {}
        self.period_s = self.onboard.tracker.config.first_step_s
        # Before the UAVs: the σ each states bounds its room under a geofence's ceiling.
        gnss = faults.spec.gnss
        self.estimator = _estimator_of(None if gnss == "none" else gnss, self.onboard, n,
                                       self.period_s, seed)
        self.uavs = self._add_uavs(airframes, strategy, spec.wind_mps, offsets)
        self._wire(offsets, index, recorder, faults.silent_from_s)

    def _wire(self, offsets: np.ndarray, index: bool | None, recorder: FlightRecorder | None,
              silent_from_s: Mapping[str, float]) -> None:
        """What connects the UAVs once they are made: the compiled tick, the link's delivery,
        the avoidance rounds' finder, the scene, the launch check's waiting rows."""
        #: The rows still held at their starts by the launch check.
        self._held = [i for i, u in enumerate(self.uavs) if not u.supervisor.launched]
        self.t_s = 0.0
        self.n_sub = _common_substeps(self.uavs, self.period_s)
        self._offsets = offsets.copy()
        #: The rows due to broadcast at a tick and their clocks (work arrays of _emit).
        self._due_rows = np.empty(len(self.uavs), dtype=np.int64)
        self._due_stamps = np.empty(len(self.uavs))
        #: The numerical tick of every UAV (one compiled call).
        self.ticker = CompiledTick(self.onboard, self.plants, self.n_sub, self.period_s,
                                   self.estimator,
                                   [u.plant for u in self.uavs if u.plant.wind is not None])
        #: UAV id → when its radio goes silent [s].
        self.silent_from_s = dict(silent_from_s)
        self._stacks = [u.stack for u in self.uavs]
        self.wire = WorldLink(self.link, self.inboxes, self._stacks, self._offsets,
                              self.silent_from_s, recorder)
        self.shown = WorldScene(self)
        self._missions = [u for u in self.uavs if u.supervisor.mission is not None]
        self._fenced = [u for u in self.uavs if u.supervisor.fence is not None]
        self._finder = _world_finder(self._stacks, index)
        self._steering = [s.steering for s in self._stacks]
        self._overrides = [s.overrides() for s in self._steering]
        self._next_round_s = -math.inf
        self._next_emit_s = -math.inf
        self._yields = Yields(self.uavs)
        self._started = False
        #: Wall time of the batched ticks' phases in the current run [s]: receiving and
        #: planning, the compiled tick, broadcasting (a kernel compiled mid-flight left out,
        #: as from the run's wall time).
        self.phase_wall_s = [0.0, 0.0, 0.0]
        #: The current run's compilations (:class:`~uavmpc.jit.CompileWatch`).
        self._compiling = CompileWatch()

    def _add_uavs(self, airframes: dict[str, Airframe],
                  strategy: Callable[[AvoidanceParams], ResolutionStrategy], wind_mps: float,
                  offsets: np.ndarray) -> list[WorldUav]:
        """Every UAV of the scenario on its row (:func:`_world_uav`), its strategy made by
        ``strategy`` unless it flies alone."""
        scenario, flying_alone = self.scenario, set(self.non_cooperative)
        uavs = []
        for i, spec in enumerate(scenario.uavs):
            resolver = (None if spec.uav_id in flying_alone
                        else _strategy_of(spec.uav_id, strategy, self.params,
                                          scenario.formation))
            uavs.append(_world_uav(self, i, spec, airframes[spec.airframe], wind_mps,
                                   float(offsets[i]), resolver))
            self._positions[spec.uav_id] = np.array(spec.start_m, dtype=float)
        return uavs

    @property
    def silenced(self) -> int:
        """Broadcasts swallowed by dead radios (``silent_from_s``)."""
        return self.wire.silenced

    def run(self, duration_s: float | None = None, *, realtime: float | None = None,
            on_log: Callable[[World], None] | None = None,
            on_scene: Callable[[float, dict[str, Any], dict[str, Any]], None] | None = None,
            ) -> WorldResult:
        """Fly for ``duration_s`` (default: :attr:`flight_s`) and return the result.

        ``realtime``: pace the simulated clock at this many times the wall clock (1.0: real
        time; default: as fast as it goes). ``on_log(world)`` is called at the log rate
        (every :data:`POSE_LOG_PERIOD_S`), e.g. to mirror the UAVs on ROS 2;
        ``on_scene(t_s, scene, metrics)`` every :data:`SCENE_PERIOD_S` with the 3-D scene
        (:meth:`scene`) and the metrics (:meth:`metrics`) the log also gets, e.g. to serve
        them live (:class:`uavmpc.view.live.LiveView`)."""
        ticks = _ticks_of(self.flight_s if duration_s is None else duration_s,
                          realtime, self.period_s)
        ids = [u.uav_id for u in self.uavs]
        tr = Traces.empty(ticks, len(ids), self.scenario.formation, ids)
        contacts = Contacts(ids)
        if self.batched and self.onboard.inline:
            # Compile (or load) the tick before the clock starts: wall_s and the real-time
            # factor measure flying, not a first run's compilation.
            self.ticker.start(tr.kernel_args(0))
        self.phase_wall_s = [0.0, 0.0, 0.0]
        # The compiled tick times its stages in CPU cycles, read against the wall clock.
        self.ticker.cycles[:] = 0
        cycles0 = cycle_count() if HAS_CYCLE_COUNTER else 0
        # Kernels first called mid-flight (the avoidance's, at its first round) compile then
        # on a cold cache: their compilation is not flying, and is left out of wall_s.
        with CompileWatch() as compiling:
            self._compiling = compiling
            wall0 = time.perf_counter()
            next_log = self.t_s
            for k in range(ticks):
                next_log = self._tick(k, tr, contacts, next_log, on_log, on_scene)
                if realtime is not None:
                    ahead = ((k + 1) * self.period_s / realtime
                             - (time.perf_counter() - wall0))
                    if ahead > 0.0:
                        time.sleep(ahead)
            elapsed = time.perf_counter() - wall0
        wall = elapsed - compiling.seconds
        cycles_per_s = ((cycle_count() - cycles0) / elapsed
                        if HAS_CYCLE_COUNTER and elapsed > 0 else 0.0)
        for i, u in enumerate(self.uavs):
            self._positions[u.uav_id] = tr.pos[-1, i].copy()
        return world_result(self, tr, contacts, wall, cycles_per_s)

    def rehearse(self, seconds: float = 1.0) -> None:
        """Run the parts of the batched tick around its compiled call (deliveries, missions,
        avoidance rounds, broadcasts) for ``seconds`` of world time on the state as it is,
        without the compiled tick: their kernels compile (or load) without the tick's. For a
        second process on a cold cache (:mod:`uavmpc.apps.prewarm`); the world is not
        to be flown afterwards."""
        now = self.t_s
        for _ in range(_ticks_of(seconds, None, self.period_s)):
            self._receive_and_plan_batched(now)
            self._emit(now)
            now += self.period_s

    def _tick(self, k: int, tr: Traces, contacts: Contacts, next_log: float,
              on_log: Callable[[World], None] | None,
              on_scene: Callable[[float, dict[str, Any], dict[str, Any]], None] | None
              ) -> float:
        """Tick ``k`` of a run and what follows it (the failsafe, the traces, the contacts,
        the log, the scene). Returns when the log is next due [s]."""
        now = self.t_s
        if self.batched:
            self._tick_batched(now, tr.kernel_args(k))
        else:
            self._tick_objects(now, tr.kernel_args(k))
        self.t_s = now + self.period_s
        tr.t_s[k] = self.t_s
        if self._fenced and self._fenced[0].supervisor.fence_due(k):
            self._watch_fence()
        if tr.members.size:
            tr.members_avoiding[k] = self.onboard.stats.avoiding[tr.members].any()
        if self.link.range_m is not None:  # the link's range check sees where the UAVs are
            for i, u in enumerate(self.uavs):
                self._positions[u.uav_id] = tr.pos[k, i]
        n = len(self.uavs)
        if n > 1:
            contacts.update(self.t_s, float(tr.dmin[k]), tr.pos[k])
        if (self.recorder is not None or on_log is not None) and self.t_s >= next_log - 1e-9:
            next_log = self.t_s + POSE_LOG_PERIOD_S
            if self.recorder is not None:
                self.shown.log()
            if on_log is not None:
                on_log(self)
        if (self.recorder is not None or on_scene is not None) \
                and self.t_s >= self.shown.next_scene_s - 1e-9:
            self.shown.show(float(tr.dmin[k]) if n > 1 else None, on_scene)
        return next_log

    # ------------------------------------------------------------------------------ one tick
    def _receive_and_plan(self, now: float) -> None:
        """Every UAV, UAV by UAV (the per-object path): its datagrams into its inbox, its
        mission, its avoidance."""
        if self.ground_vehicle is not None:  # every plant's contact knows where the deck is
            self.plants.deck[:] = self.ground_vehicle.deck_row(now)
        for i, u in enumerate(self.uavs):
            self.wire.receive_one(i, now)
            if u.supervisor.mission_due(now):
                self._step_mission(u, now)
            if self._held:
                self._launch(now, (i,))
            u.stack.plan(now + u.clock_offset_s)
        self._yields.note(now, range(len(self.uavs)))

    def _receive_and_plan_batched(self, now: float) -> None:
        """The same for every UAV at once: the tick's deliveries into the inbox rows in one
        compiled call, then the missions, then the avoidance of the UAVs due, their
        encounters found in one compiled call (:mod:`uavmpc.avoidance.encounters`)."""
        if self.ground_vehicle is not None:
            self.plants.deck[:] = self.ground_vehicle.deck_row(now)
        if now >= self.link.next_due_s:
            self.wire.deliver(now)
        for u in self._missions:
            if u.supervisor.mission_due(now):
                self._step_mission(u, now)
                self._next_round_s = -math.inf  # the mission may have changed who plans
        if self._held:
            self._launch(now, list(self._held))
        if self._finder is None:
            for u in self.uavs:
                u.stack.plan(now + u.clock_offset_s)
            self._yields.note(now, range(len(self.uavs)))
        else:
            if now >= self._next_round_s:
                self._plan_round(now)
            self._yields.note(now, ())

    def _plan_round(self, now: float) -> None:
        """The avoidance round of every UAV due at this tick (:func:`~uavmpc.avoidance.round.
        avoidance_round`, one finder for all), and when the next one can be due."""
        assert self._finder is not None
        decided = avoidance_round(self.onboard, self._steering, self._finder,
                                  overrides=self._overrides)
        self._yields.add(decided.tolist())  # the others are calm: they yield to nobody
        sched = self.onboard.schedule
        planning = sched.planning
        if planning.any():
            # The next tick any UAV can be due at (a tick early is harmless: nobody is due).
            t = self.onboard.tracker.rows.t_s
            lead = np.min(sched.next_avoidance_s[planning] - t[planning])
            self._next_round_s = now + lead - self.period_s
        else:
            self._next_round_s = math.inf

    def _launch(self, now: float, which: Iterable[int]) -> None:
        """The launch check: a UAV held at its start sets off on its mission once its
        avoidance knows every other UAV (:meth:`~uavmpc.supervisor.Supervisor.heard_from`),
        or once ``launch_check_s`` has passed. Found in the 24 h campaign with burst loss
        (trial 118): two UAVs 8 m apart set off towards each other; one heard the other only
        1.3 s later and met it at 2.0 s, before its climb was under way."""
        for i in [i for i in which if i in self._held]:
            u = self.uavs[i]
            own = now + u.clock_offset_s
            # The world's receivers are its UAVs: row i, and UAV j in column j.
            others = np.array([c for c in range(len(self.uavs)) if c != i], dtype=np.int64)
            ready = u.supervisor.heard_from(own, others)
            assert self.launch_check_s is not None
            if not ready and now < self.launch_check_s:
                continue
            unheard = [] if ready else [self.uavs[j].uav_id
                                        for j in u.supervisor.unheard(own, others)]
            u.supervisor.launch()
            self._held.remove(i)
            self.launches[u.uav_id] = {"launched_s": round(now, 3), "not_heard": unheard}
            self._next_round_s = -math.inf  # its plan changed

    def _step_mission(self, u: WorldUav, now: float) -> None:
        """``u``'s mission, from what the UAV knows on its own clock (its fixes too)."""
        estimate = u.plant.state()
        fixes = u.sensor.fixes_until(now) if u.sensor is not None else ()
        if u.clock_offset_s and fixes:
            fixes = [f._replace(t_s=f.t_s + u.clock_offset_s) for f in fixes]
        # The land detector: resting, or the landing gear's contact switch on the deck's top
        # (cutting the motors at first contact keeps a UAV from sliding across the deck).
        touching = u.plant.landed or u.plant.deck_touch().on_deck
        if u.supervisor.step_mission(now, now + u.clock_offset_s, estimate, touching, fixes):
            u.plant.cut_motors()

    def _watch_fence(self) -> None:
        """Every UAV's failsafe (:meth:`~uavmpc.supervisor.Supervisor.watch_fence`), on the
        margins of all UAVs computed at once."""
        assert self.geofence is not None
        pos = self.plants.x[:, 0:3]
        margins = self.geofence.margin(pos)
        look = [i for i, u in enumerate(self.uavs)
                if u.supervisor.fence is not None and u.supervisor.fence.needs_look(margins[i])]
        for i in look:
            u = self.uavs[i]
            u.supervisor.watch_fence(self.t_s + u.clock_offset_s, pos[i],
                                     float(heading_of(self.plants.x[i, 6:10])), margins[i])

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
        rows, stamps = self._due_rows, self._due_stamps
        n = bound(broadcasts_due)(sched, self._offsets, now, rows, stamps)
        if n:
            stacks = [self._stacks[i] for i in rows[:n].tolist()]
            self.wire.publish(stacks, broadcast(self.onboard, stacks, stamps[:n]), now)
        # The next tick anyone can be due at (a tick early is harmless).
        self._next_emit_s = bound(next_broadcast_s)(sched, self._offsets) - self.period_s

    def _tick_batched(self, now: float, traces: tuple[Any, ...]) -> None:
        clock = time.perf_counter
        watch = self._compiling
        t0, c0 = clock(), watch.seconds
        self._receive_and_plan_batched(now)
        t1, c1 = clock(), watch.seconds
        bad = self.ticker(traces)
        if bad >= 0:
            raise ValueError(f"invalid attitude target for {self.uavs[bad].uav_id} "
                             "(not finite): the controller got a degenerate state")
        t2, c2 = clock(), watch.seconds
        self._emit(now)
        phase = self.phase_wall_s
        phase[0] += (t1 - t0) - (c1 - c0)
        phase[1] += (t2 - t1) - (c2 - c1)
        phase[2] += (clock() - t2) - (watch.seconds - c2)

    def _tick_objects(self, now: float, traces: tuple[Any, ...]) -> None:
        # Receive and plan for everyone first, as the batched tick does: a UAV must not see a
        # message another UAV sent in this same tick.
        self._receive_and_plan(now)
        self._started = True
        self._next_round_s = self._next_emit_s = -math.inf  # if the batched path takes over
        est = self.ticker.estimates()
        for i, u in enumerate(self.uavs):
            # received and planned above: those phases are no-ops here
            state = u.plant.state()
            if est.shape[0]:
                state = dataclasses.replace(state, position_m=est[i, 0:3].copy(),
                                            velocity_mps=est[i, 3:6].copy())
            out = u.stack.tick(now + u.clock_offset_s, state)
            u.plant.step(out.target, self.period_s)
            if out.outgoing is not None:
                self.wire.publish((u.stack,), (out.outgoing,), now)
        self.ticker.trace(traces)

    # ------------------------------------------------------------------------------ views
    def views(self) -> list[UavView]:
        """Every flying UAV as the 3-D scene shows it now (:mod:`uavmpc.view.scene`)."""
        return self.shown.views()

    def scene(self, views: Sequence[UavView] | None = None) -> dict[str, Any]:
        """The ``foxglove.SceneUpdate`` of now (:meth:`WorldScene.scene`)."""
        return self.shown.scene(views)

    def metrics(self, min_distance_m: float | None,
                views: Sequence[UavView] | None = None) -> dict[str, Any]:
        """The plot-ready numbers of now (:meth:`WorldScene.metrics`)."""
        return self.shown.metrics(min_distance_m, views)
