"""One UAV's onboard stack as its own process, in real time, over a real network (issue 6).

A :class:`Node` flies the same :class:`~uavmpc.onboard.OnboardStack` as the simulated world, on
the wall clock, against a vehicle: its own simulated plant (:class:`SimulatedVehicle`, software
in the loop) or a PX4 autopilot over MAVLink (:class:`~uavmpc.drivers.px4.vehicle.Px4Vehicle`,
which takes off from the ground, flies the mission, lands and disarms):

- every 10 ms: hand the stack what the transport delivered (at most a bounded number of
  messages per tick, so a flood cannot starve the loop), step the plant with its target, and
  publish what the stack wants broadcast (its prediction every 0.5 s at its own phase, signed
  when a key is configured);
- at ``state_rate_hz``: publish its state (JSON) on ``uavmpc/<swarm>/<id>/state``;
- any time: accept a new mission (JSON, validated) on ``uavmpc/<swarm>/<id>/mission`` or from
  Python (:meth:`Node.set_mission`);
- or fly a :class:`~uavmpc.missions.mission.Mission` beside the stack (e.g. a formation
  follower's slot along its leader's received plans), stepped at its period once the vehicle
  is ours to fly; such a node takes its trajectory from the mission only.

Clocks: stamps are Unix time (``time.time()``), as GNSS-synchronised UAVs would have; on one host
they are synchronised by construction.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from uavmpc.assumptions import DEAD_AFTER_S, AssumptionWatch, failsafe_prediction
from uavmpc.avoidance import AvoidanceParams, HeightOffsetStrategy
from uavmpc.comms.auth import CommandGate, Identity, Roster, SharedKey
from uavmpc.comms.link import NetworkTransport
from uavmpc.comms.message import PredictionMessage
from uavmpc.comms.state import NodeState
from uavmpc.drivers.ros2 import publish_plan, publish_status, ros2_mission
from uavmpc.drivers.summary import RunStatus, run_status
from uavmpc.geofence import Geofence, GeofenceError
from uavmpc.missions.format import mission_from_json
from uavmpc.missions.mission import CommandedMission, Mission
from uavmpc.onboard import OnboardStack
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.plant.interface import heading_of
from uavmpc.plant.multirotor import Multirotor
from uavmpc.reference import InvalidReferenceError, Reference
from uavmpc.supervisor import FenceGuard, Supervisor
from uavmpc.tracker import TrackerConfig

PERIOD_S = 0.01
#: Most messages taken from the transport per tick: a flood is dropped, not queued forever.
MAX_MESSAGES_PER_TICK = 32
#: A loop this many periods late skips ahead instead of trying to catch up.
RESYNC_PERIODS = 5
#: A vehicle this far below its start position takes off to it before its mission [m].
TAKEOFF_BELOW_M = 0.5
#: Landing: down at the tracker's pace to this height above the ground, then at the flare
#: speed [m, m/s] through the ground until the vehicle's driver says landed. The descent goes
#: on after touchdown because an autopilot's land detector looks for exactly that: a commanded
#: descent with no vertical movement (PX4: more than 1.1 × LNDMC_Z_VEL_MAX = 0.275 m/s, and, in
#: attitude control, thrust falling to idle as the position error grows).
FLARE_HEIGHT_M = 1.0
FLARE_SPEED_MPS = 0.5
#: Longest landing before the node gives up waiting (the vehicle is left to its autopilot).
LANDING_TIMEOUT_S = 60.0
#: A sealed command sent longer ago than this (by its signer's clock) is refused as stale: it
#: bounds the replay of a recorded command to a node that restarted since [s].
COMMAND_MAX_SKEW_S = 30.0
#: The channel formation commands are sealed for (every member hears the same command).
FORMATION_CHANNEL = "formation"


@dataclass
class NodeStats:
    """What a node reports when it stops (printed as one JSON line by ``uavmpc node``)."""

    uav_id: str
    ticks: int = 0
    overruns: int = 0
    period_p50_ms: float = 0.0
    period_p99_ms: float = 0.0
    period_max_ms: float = 0.0
    predictions_sent: int = 0
    accepted: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    missions_rejected: int = 0
    #: With a key or a roster: commands refused by the gate, by kind (``unsigned``,
    #: ``forged``, ``unknown signer``, ``not allowed``, ``replayed``, ``stale``).
    commands_rejected: dict[str, int] = field(default_factory=dict)
    #: With a geofence: missions refused for leaving it, breaches, the farthest outside [m].
    geofence: dict[str, Any] = field(default_factory=dict)
    #: Over the flight until the landing began: the landing descends through the ground on
    #: purpose (an autopilot's land detector wants a commanded descent), not a tracking error.
    tracking_rmse_m: float = 0.0
    max_z_offset_m: float = 0.0
    avoidance_active_s: float = 0.0
    final_position_m: list[float] = field(default_factory=list)
    #: Where the vehicle was (its estimate) when the mission ended and the landing began.
    mission_end_position_m: list[float] = field(default_factory=list)
    #: Where the virtual UAV (the tracker's command) was at that moment: what the node asked
    #: for, to set against the vehicle's estimate above.
    mission_end_command_m: list[float] = field(default_factory=list)
    cpu_s: float = 0.0
    wall_s: float = 0.0
    #: The vehicle driver's report (the MAVLink link's phases, commands, rates), if any.
    vehicle: dict[str, Any] = field(default_factory=dict)
    #: What it measured of the safety argument's assumptions while flying: the worst of each
    #: measure, how often each broke, the link per peer (:mod:`uavmpc.assumptions`).
    assumptions: dict[str, Any] = field(default_factory=dict)
    #: How the run ended as far as the node knows, a :class:`~uavmpc.drivers.summary.RunStatus`
    #: value: ``complete`` (its time ran out), ``interrupted`` (stopped before it, SIGINT or
    #: SIGTERM), ``vehicle_stopped`` (the vehicle stopped being ours to fly before the
    #: landing: its autopilot failed safe, refused, or a pilot took it). Its goal it does not
    #: judge: the swarm does, from where it ended.
    status: str = RunStatus.COMPLETE.value

    @property
    def run_status(self) -> RunStatus:
        """:attr:`status` as a :class:`~uavmpc.drivers.summary.RunStatus`."""
        return RunStatus(self.status)


@runtime_checkable
class VehicleDriver(Protocol):
    """What a node flies: it gives the state, takes each tick's target, and has a life cycle
    (:class:`SimulatedVehicle` is always flying; a PX4 vehicle walks offboard → arm → fly →
    land)."""

    @property
    def commanding(self) -> bool:
        """Our targets steer the vehicle (False: it is its autopilot's or a pilot's)."""
        ...

    @property
    def flying(self) -> bool:
        """Ours to fly a mission now."""
        ...

    @property
    def done(self) -> bool:
        """Nothing left to do (landed)."""
        ...

    @property
    def ground_z_m(self) -> float:
        """Height of the ground it started from [m]."""
        ...

    @property
    def position_sigma_m(self) -> tuple[float, float]:
        """The estimate's (horizontal, vertical) 1σ as the autopilot states it [m]; NaN:
        not stated."""
        ...

    def start(self, timeout_s: float = 20.0) -> VehicleState: ...

    def update(self, now_s: float) -> VehicleState | None: ...

    def actuate(self, now_s: float, target: AttitudeTarget, command: Any) -> None: ...

    def land(self, now_s: float) -> None: ...

    def abort(self, now_s: float, reason: str) -> None: ...

    def report(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


class SimulatedVehicle:
    """The node's own simulated plant, stepped one period per tick (software in the loop)."""

    commanding = True
    flying = True
    ground_z_m = 0.0
    position_sigma_m = (0.0, 0.0)  # its state is its plant's

    def __init__(self, airframe: Airframe, start_m: Sequence[float], heading_rad: float) -> None:
        self.plant = Multirotor(airframe, position_m=start_m, yaw_rad=heading_rad,
                                rotors_at_hover=start_m[2] > 0.0)
        self.done = False
        self._state = self.plant.state()

    def start(self, timeout_s: float = 20.0) -> VehicleState:
        return self._state

    def update(self, now_s: float) -> VehicleState | None:
        return self._state

    def actuate(self, now_s: float, target: AttitudeTarget, command: Any) -> None:
        self._state = self.plant.step(target, PERIOD_S)

    def land(self, now_s: float) -> None:
        self.done = True  # a simulated flight simply ends where it is

    def abort(self, now_s: float, reason: str) -> None:
        self.done = True

    def report(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


def warm_up(airframe: Airframe) -> None:
    """Compile (or load from the cache) the kernels one UAV's tick needs, before a real-time
    clock starts: the first tick of a flight must not take the seconds a compilation does.

    Two stacks head-on, each hearing the other, so that the encounter and strategy kernels
    compile too: cold, the first received prediction would otherwise stall a flying node's
    tick for tens of seconds on a small machine."""
    starts = ((0.0, 0.0, 5.0), (20.0, 0.0, 5.0))
    plants = [Multirotor(airframe, position_m=p) for p in starts]
    stacks = [OnboardStack(airframe, position_m=p, uav_id=f"warm{i}", priority=i,
                           avoidance=HeightOffsetStrategy()) for i, p in enumerate(starts)]
    for stack, goal in zip(stacks, reversed(starts), strict=True):
        stack.set_mission(Reference.goto(*goal))
    inboxes: list[list[bytes]] = [[], []]
    for k in range(50):  # half a second: both have sent, heard and decided
        outs = [s.tick(k * s.period_s, pl.state(), box)
                for s, pl, box in zip(stacks, plants, inboxes, strict=True)]
        inboxes = [[o.outgoing] if o.outgoing else [] for o in reversed(outs)]
        for s, pl, o in zip(stacks, plants, outs, strict=True):
            pl.step(o.target, s.period_s)


def _command_gate(key: bytes | None, roster: Roster | None) -> CommandGate | None:
    """Who may command a node: a holder of the shared ``key``, an operator of the
    ``roster``, or anyone (neither)."""
    if key is not None and roster is not None:
        raise ValueError("a node takes a shared key or identities, not both")
    if key is not None:
        return CommandGate(SharedKey(key), max_skew_s=COMMAND_MAX_SKEW_S)
    if roster is not None:
        return CommandGate(roster, max_skew_s=COMMAND_MAX_SKEW_S)
    return None


class Node:
    """One UAV in real time: a driver (the wall clock, a transport, a vehicle) around one
    :class:`~uavmpc.onboard.OnboardStack`. ``transport`` is a
    :class:`~uavmpc.comms.link.NetworkTransport` (the Zenoh one). ``vehicle`` is what it
    flies (default: a :class:`SimulatedVehicle` at ``start_m``); a vehicle on the ground below
    ``start_m`` takes off to it once it is ours to fly, before the mission."""

    def __init__(
        self,
        uav_id: str,
        priority: int,
        airframe: Airframe,
        transport: NetworkTransport,
        *,
        start_m: Sequence[float] = (0.0, 0.0, 5.0),
        heading_rad: float = 0.0,
        avoidance: bool = True,
        params: AvoidanceParams | None = None,
        key: bytes | None = None,
        identity: Identity | None = None,
        roster: Roster | None = None,
        geofence: Geofence | None = None,
        tracker_config: TrackerConfig | None = None,
        state_rate_hz: float = 50.0,
        phase_s: float = 0.0,
        vehicle: VehicleDriver | None = None,
        ros2: Any = None,
        mission: Mission | None = None,
        pair_radius_m: Mapping[str, float] | None = None,
    ) -> None:
        self.uav_id = uav_id
        self.priority = priority
        self.airframe = airframe
        self.transport = transport
        self.key = key
        self.identity = identity
        self.roster = roster
        #: With a key or a roster, commands (missions, formation changes) must be sealed by
        #: a holder of the key or by an operator of the roster, and newer than the last one
        #: of their signer (:class:`~uavmpc.comms.auth.CommandGate`); else anyone may command.
        self.commands = _command_gate(key, roster)
        #: The operational volume: missions outside it are refused, and a vehicle found
        #: outside flies back in and holds (:class:`~uavmpc.geofence.FenceWatch`).
        self.geofence = geofence
        self._fence = FenceGuard(geofence) if geofence is not None else None
        self.start_m = tuple(float(v) for v in start_m)
        self.heading_rad = float(heading_rad)
        self.avoidance = avoidance
        self.params = params if params is not None else AvoidanceParams()
        #: The tracker's set-up (its limits: a scenario's over the packaged ones).
        self.tracker_config = tracker_config
        self.vehicle: VehicleDriver | None = vehicle
        #: The UAV's ROS 2 topics (:class:`uavmpc.comms.ros2.UavTopics`), or None.
        self.ros2 = ros2
        #: A mission stepped beside the stack (then the only source of its trajectory), and
        #: per-pair avoidance radii (e.g. the formation's members).
        self.mission = mission
        self.pair_radius_m = dict(pair_radius_m or {})
        # A mission that takes commands (a formation follower's shape changes) hears them on
        # uavmpc/<swarm>/<sender>/formation.
        self._commanded = mission if isinstance(mission, CommandedMission) else None
        self._mission_commands = (transport.subscribe("*/formation", maxlen=16)
                                  if self._commanded is not None else None)
        self._ros2_ticks = 0
        self._missions = transport.subscribe(f"{uav_id}/mission", maxlen=16)
        self._pending_mission: Reference | None = None
        self._lock = threading.Lock()
        self.state_period_s = 1.0 / state_rate_hz
        self.phase_s = phase_s
        self.stats = NodeStats(uav_id)
        self._stop = threading.Event()
        self._stop_requests = 0
        self._flew = False  # the vehicle has been ours to fly
        self._vehicle_stopped = False  # ... and stopped being so before the landing
        self._interrupted = False  # stopped before its time
        #: Its measures of the safety argument's assumptions (:mod:`uavmpc.assumptions`),
        #: and the ones broken now (said in its state; it holds while any is).
        self.watch = AssumptionWatch(self.params.uncertainty_k)
        self.broken: tuple[str, ...] = ()
        #: Peers taken for dead (A7): id → (their last prediction, the stamp of the failsafe
        #: prediction we hold for them last, or None before the first).
        self._dead: dict[str, tuple[PredictionMessage, float | None]] = {}
        self.stack: OnboardStack | None = None
        #: The stack's supervisor (its mission, launch hold, geofence), built with it.
        self.supervisor: Supervisor | None = None

    def _build(self) -> tuple[OnboardStack, VehicleState]:
        # Built when the flight starts, so the virtual UAV's clock starts on the wall clock
        # (stamps are absolute), after the kernels are loaded, at the vehicle's own state.
        warm_up(self.airframe)
        if self.geofence is not None:  # its kernels too: none may load inside the 100 Hz loop
            self.geofence.recovery_point(np.array(self.start_m))
            self.geofence.check_reference(Reference.goto(*self.geofence.recovery_point(
                np.array(self.start_m))))
        if self.vehicle is None:
            self.vehicle = SimulatedVehicle(self.airframe, self.start_m, self.heading_rad)
        first = self.vehicle.start()
        now = time.time()
        heading = float(heading_of(first.attitude_wxyz))
        self.stack = OnboardStack(
            self.airframe, self.tracker_config, position_m=first.position_m,
            heading_rad=heading, t0_s=now,
            uav_id=self.uav_id, priority=self.priority,
            avoidance=(HeightOffsetStrategy(self.params, pair_radius_m=self.pair_radius_m)
                       if self.avoidance else None),
            params=self.params, key=self.key, identity=self.identity, roster=self.roster,
            broadcast_phase_s=self.phase_s)
        # Hold where it is until it may fly (a mission starting later keeps this before).
        self.stack.set_mission(Reference.goto(first.position_m[0], first.position_m[1],
                                                  first.position_m[2], heading, start_s=now))
        self.supervisor = Supervisor(self.stack, mission=self.mission, fence=self._fence,
                                     launched=False)
        return self.stack, first

    def set_mission(self, reference: Reference) -> None:
        """Fly ``reference`` (thread-safe; taken at the next tick once the vehicle flies).

        Raises:
            GeofenceError: with a geofence, ``reference`` leaves it (the message says where).
        """
        if not isinstance(reference, Reference):
            raise TypeError(f"reference must be a uavmpc.Reference, got {type(reference).__name__}")
        if self._fence is not None:
            self._fence.check_mission(reference)
        with self._lock:
            self._pending_mission = reference

    def stop(self) -> None:
        """End the flight (thread- and signal-safe): a vehicle in the air lands first; a second
        stop ends the loop at once."""
        self._stop_requests += 1
        self._stop.set()

    def run(self, duration_s: float | None = None) -> NodeStats:
        """Fly until :meth:`stop` (or SIGINT/SIGTERM via :func:`run_node`) or ``duration_s``,
        then land (a vehicle that can) and return the statistics."""
        stack, state = self._build()
        vehicle = self.vehicle
        assert vehicle is not None
        tracker = stack.tracker
        t_end = None if duration_s is None else tracker.time_s + duration_s
        next_state = tracker.time_s
        intervals: list[float] = []
        cpu0 = time.process_time()
        wall0 = time.perf_counter()
        deadline = time.perf_counter()
        last = None
        landing_until: float | None = None
        mission_rmse: float | None = None
        ticks = 0
        commanded = False
        try:
            while True:
                now = tracker.time_s
                if landing_until is None and (self._stop.is_set()
                                              or (t_end is not None and now >= t_end)):
                    landing_until = now + LANDING_TIMEOUT_S
                    self._interrupted = t_end is None or now < t_end
                    self.stats.mission_end_position_m = state.position_m.tolist()
                    self.stats.mission_end_command_m = stack.command().position_m.tolist()
                    mission_rmse = stack.report().tracking_rmse_m
                    self._land(now, state)
                    vehicle.land(time.time())
                if landing_until is not None and (vehicle.done or now >= landing_until
                                                  or self._stop_requests >= 2):
                    break
                fresh = vehicle.update(time.time())
                if fresh is not None:
                    state = fresh
                self._note_vehicle(landing=landing_until is not None)
                self._supervise(now, state, ticks, landing=landing_until is not None)
                if ticks % 10 == 0:  # the avoidance's rate
                    self._watch_assumptions(now, state, landing=landing_until is not None,
                                            fresh=fresh is not None)
                if commanded and not vehicle.commanding and fresh is not None \
                        and ticks % 10 == 0:
                    stack.follow(now, fresh)  # no longer ours: say what it really does
                commanded = self._tick(now, state) or commanded
                ticks += 1
                if now >= next_state:
                    next_state += self.state_period_s
                    self._publish_state(now, state)
                    if self.ros2 is not None:
                        self._publish_ros2(now, state)
                # Real time: sleep to the next deadline; if far behind, skip ahead (never burst).
                deadline += PERIOD_S
                slack = deadline - time.perf_counter()
                if slack > 0:
                    time.sleep(slack)
                elif -slack > RESYNC_PERIODS * PERIOD_S:
                    self.stats.overruns += 1
                    deadline = time.perf_counter()
                tick_end = time.perf_counter()
                if last is not None:
                    intervals.append(tick_end - last)
                last = tick_end
        finally:
            vehicle.close()
        return self._final_stats(state, intervals, time.perf_counter() - wall0,
                                 time.process_time() - cpu0, mission_rmse)

    def _note_vehicle(self, landing: bool) -> None:
        """Note a vehicle that stops being ours to fly before the landing (for the status)."""
        assert self.vehicle is not None
        if self.vehicle.flying:
            self._flew = True
        elif self._flew and not landing:
            self._vehicle_stopped = True

    def _supervise(self, now: float, state: VehicleState, ticks: int, landing: bool) -> None:
        """The supervisor's part of a tick: the launch once the vehicle is ours to fly, the
        missions received, the mission beside the stack, the geofence failsafe (10 Hz)."""
        sup = self.supervisor
        assert sup is not None and self.vehicle is not None
        flying = self.vehicle.flying
        if flying and not sup.launched:
            self._launch(now, state)
        self._take_missions(now)
        if not (sup.launched and flying and not landing):
            return
        if sup.mission_due(now):
            self._step_mission(now, state)
        if sup.fence_due(ticks):
            self._watch_fence(state)

    def _watch_assumptions(self, now: float, state: VehicleState, landing: bool,
                           fresh: bool = True) -> None:
        """The measures of the assumptions (:mod:`uavmpc.assumptions`): the uncertainty the
        UAV states from its autopilot's and its tracking error, and a hold where its plan is
        while one is beyond its bound (the mission resumes when all are back)."""
        stack, sup, vehicle = self.stack, self.supervisor, self.vehicle
        assert stack is not None and sup is not None and vehicle is not None
        w = self.watch
        w.estimate(*vehicle.position_sigma_m)
        self._assume_dead_peers(now)
        # A message's age is its arrival less its stamp with the receive-time reference only:
        # with stamps, ``received_s`` is set for a sender whose clock the inbox measured off,
        # and is then its stamp on our clock, not its arrival.
        if stack.inbox.time_reference == "receive":
            for msg in stack.inbox.latest.values():
                if msg.received_s is not None and msg.uav_id not in self._dead:
                    w.heard(msg.uav_id, msg.stamp_s, msg.received_s)
        if not (sup.launched and vehicle.flying and vehicle.commanding and not landing):
            return  # on the ground, landing, or no longer ours: nothing to hold
        if fresh:  # an old estimate would read as a tracking error (PX4 flies on a fresh one)
            w.tracking(now, state.position_m, stack.command().position_m,
                       airborne=bool(state.position_m[2] - vehicle.ground_z_m > TAKEOFF_BELOW_M))
        sup.state_sigma(w.stated_sigma_m(), w.sigma_m[1])
        self.broken = w.broken(now)
        if self.broken and sup.paused is None:
            # Hold where the virtual UAV comes to rest braking at its limits from now (a
            # hold at where it is now would overshoot and fly back).
            cmd = stack.command()
            lim = stack.tracker.limits
            v = cmd.velocity_mps
            here = cmd.position_m.copy()
            here[:2] += v[:2] * float(np.hypot(v[0], v[1])) / (2.0 * lim.horizontal_accel_mps2)
            brake_z = lim.ascend_accel_mps2 if v[2] < 0.0 else lim.descend_accel_mps2
            here[2] += v[2] * abs(float(v[2])) / (2.0 * brake_z)
            here[2] -= stack.tracker.z_offset_m  # the mission's frame: the offset stays
            sup.pause(Reference.goto(here[0], here[1], here[2],
                                     float(heading_of(state.attitude_wxyz)), start_s=now))
        elif not self.broken and sup.paused is not None:
            sup.resume()

    def _assume_dead_peers(self, now: float) -> None:
        """A peer unheard for :data:`~uavmpc.assumptions.DEAD_AFTER_S` is a node that died,
        its vehicle flying on under its autopilot's failsafe: we hold, in its place, where
        that failsafe can take it (:func:`~uavmpc.assumptions.failsafe_prediction`, flag
        down: every UAV gives way to it), renewed every round, until it can only have landed
        or it speaks again."""
        stack = self.stack
        assert stack is not None
        latest = stack.inbox.latest
        for peer in list(latest):
            msg = latest[peer]
            dead = self._dead.get(peer)
            if dead is not None and msg.stamp_s != dead[1]:
                if dead[1] is not None or msg.stamp_s != dead[0].stamp_s:
                    self._dead.pop(peer)  # it spoke again
                    dead = None
            if dead is None:
                if now - msg.stamp_s <= DEAD_AFTER_S:
                    continue
                dead = (msg, None)
                self.watch.dead_peers.setdefault(peer, now)
            assumed = failsafe_prediction(dead[0], now, self.params.uncertainty_k)
            if assumed is None:  # it can only be on the ground by now
                self._dead[peer] = dead
                continue
            stack.inbox.assume(assumed, now)
            self._dead[peer] = (dead[0], assumed.stamp_s)

    def _tick(self, now: float, state: VehicleState) -> bool:
        """The stack's tick on what the transport delivered, the vehicle actuated, the
        broadcast published. Returns whether the vehicle is ours to command."""
        assert self.stack is not None and self.vehicle is not None
        received = self.transport.receive(self.uav_id, now)[:MAX_MESSAGES_PER_TICK]
        out = self.stack.tick(now, state, received)
        self.vehicle.actuate(time.time(), out.target, self.stack.command())
        if out.outgoing is not None:
            self.transport.publish(out.outgoing, self.uav_id, now)
            if self.ros2 is not None:
                publish_plan(self.ros2, now, self.stack)
        return self.vehicle.commanding

    def _final_stats(self, state: VehicleState, intervals: list[float], wall_s: float,
                     cpu_s: float, mission_rmse: float | None) -> NodeStats:
        """The statistics of the flight that ended at ``state``."""
        assert self.stack is not None and self.vehicle is not None
        s = self.stats
        s.wall_s = wall_s
        s.cpu_s = cpu_s
        if intervals:
            ms = np.array(intervals) * 1e3
            s.period_p50_ms = float(np.median(ms))
            s.period_p99_ms = float(np.percentile(ms, 99))
            s.period_max_ms = float(ms.max())
        rep = self.stack.report()
        s.ticks = rep.ticks
        s.predictions_sent = rep.predictions_sent
        s.accepted = rep.messages_accepted
        s.rejected = dict(rep.messages_rejected)
        if self.commands is not None:
            s.commands_rejected = dict(self.commands.rejected)
        s.tracking_rmse_m = rep.tracking_rmse_m if mission_rmse is None else mission_rmse
        s.max_z_offset_m = rep.max_z_offset_m
        s.avoidance_active_s = rep.avoidance_active_s
        s.final_position_m = state.position_m.tolist()
        s.vehicle = self.vehicle.report()
        s.assumptions = self.watch.report()
        s.status = run_status(collisions=0, reached_goal=(),
                              stopped=[self.uav_id] if self._vehicle_stopped else (),
                              interrupted=self._interrupted).value
        return s

    def _launch(self, now: float, state: VehicleState) -> None:
        """The vehicle is ours to fly: take off to the start position if on the ground below
        it, then fly the missions that waited."""
        assert self.supervisor is not None
        takeoff = None
        if self.start_m[2] - state.position_m[2] > TAKEOFF_BELOW_M:
            takeoff = Reference.goto(self.start_m[0], self.start_m[1], self.start_m[2],
                                     self.heading_rad, start_s=now)
        self.supervisor.launch(takeoff)

    def _land(self, now: float, state: VehicleState) -> None:
        """Fly down where it is: at the tracker's pace to the flare height, then at the flare
        speed into the ground until the vehicle's driver says landed (and disarms)."""
        assert self.stack is not None and self.vehicle is not None
        if not self.vehicle.flying:
            return
        x, y, z = (float(v) for v in state.position_m)
        heading = float(heading_of(state.attitude_wxyz))
        ground = self.vehicle.ground_z_m
        flare = ground + FLARE_HEIGHT_M
        descend = self.stack.tracker.limits.descend_speed_mps
        t1 = now + max(z - flare, 0.0) / descend + 0.01  # knots strictly increase
        t2 = t1 + LANDING_TIMEOUT_S
        self.stack.set_mission(Reference(
            np.array([now, t1, t2]),
            np.array([[x, y, z, heading], [x, y, min(z, flare), heading],
                      [x, y, min(z, flare) - FLARE_SPEED_MPS * LANDING_TIMEOUT_S, heading]])))

    def _step_mission(self, now: float, state: VehicleState) -> None:
        """The mission's commands, then its step (:meth:`~uavmpc.supervisor.Supervisor.
        step_mission`); a node whose mission cuts the motors lands instead: its vehicle's
        landing is the safe cut."""
        assert self.supervisor is not None
        if self._mission_commands is not None and self._commanded is not None:
            for _key, payload in self._mission_commands.drain(4):
                try:
                    self._commanded.command(self._open_command(payload, FORMATION_CHANNEL), now)
                except ValueError:
                    self.stats.missions_rejected += 1
        if self.supervisor.step_mission(now, now, state):
            self.stop()

    def _take_missions(self, now: float) -> None:
        """Missions from the network and ROS 2 (checked), flown once the vehicle is ours."""
        sup = self.supervisor
        assert sup is not None
        for _key, payload in self._missions.drain(4):
            try:
                if sup.mission is not None:
                    raise ValueError("this UAV flies its mission (e.g. a formation slot)")
                ref = mission_from_json(self._open_command(payload, f"{self.uav_id}/mission"), now)
                self._set_checked(ref)
            except (InvalidReferenceError, ValueError, TypeError):
                self.stats.missions_rejected += 1
                continue
        if self.ros2 is not None:
            refs, rejected = self.ros2.missions(now, lambda times, pts: ros2_mission(
                times, pts, now))
            self.stats.missions_rejected += len(rejected)
            for ref in refs:
                try:
                    self._set_checked(ref)
                except GeofenceError:
                    self.stats.missions_rejected += 1
        if not sup.launched:
            return  # missions wait until the vehicle is ours to fly
        with self._lock:
            pending, self._pending_mission = self._pending_mission, None
        if pending is not None:
            sup.fly(pending)

    def _set_checked(self, ref: Reference) -> None:
        """:meth:`set_mission`, counting a refusal by the geofence as such."""
        try:
            self.set_mission(ref)
        except GeofenceError:
            if self._fence is not None:
                self._fence.refused += 1
                self.stats.geofence = self._fence.report()
            raise

    def _watch_fence(self, state: VehicleState) -> None:
        """The failsafe at 10 Hz: a vehicle found outside the volume flies back in and holds."""
        fence, sup = self._fence, self.supervisor
        assert fence is not None and sup is not None
        if sup.watch_fence(sup.stack.tracker.time_s, state.position_m,
                           float(heading_of(state.attitude_wxyz))):
            with self._lock:
                self._pending_mission = None  # a mission that waited led out as well
        self.stats.geofence = fence.report()

    def _open_command(self, payload: bytes, channel: str) -> bytes:
        """The command inside ``payload`` (checked by the gate, if any)."""
        if self.commands is None:
            return payload
        return self.commands.open(payload, channel, time.time()).data

    def _publish_ros2(self, now: float, state: VehicleState) -> None:
        assert self.ros2 is not None and self.stack is not None
        self.ros2.publish_state(now, state.position_m, state.velocity_mps, state.attitude_wxyz,
                                state.body_rates_radps)
        self._ros2_ticks += 1
        if self._ros2_ticks % 5 == 0:  # the avoidance's own rate, 10 Hz
            publish_status(self.ros2, now, self.stack, self.broken)

    def _publish_state(self, now: float, state: VehicleState) -> None:
        stack = self.stack
        assert stack is not None
        decision = stack.steering.decision
        cmd = stack.command()
        p, v, c = state.position_m, state.velocity_mps, cmd.position_m
        self.transport.put("state", NodeState(
            t_s=now, position_m=(float(p[0]), float(p[1]), float(p[2])),
            velocity_mps=(float(v[0]), float(v[1]), float(v[2])),
            heading_rad=float(heading_of(state.attitude_wxyz)),
            command_m=(float(c[0]), float(c[1]), float(c[2])),
            z_offset_m=float(stack.tracker.z_offset_m),
            avoiding=bool(decision is not None and decision.avoiding),
            conflicts=tuple(decision.conflicts) if decision is not None else (),
            yielding_to=tuple(decision.yielding_to) if decision is not None else (),
            waiting_for=tuple(decision.waiting_for) if decision is not None else (),
            broken=self.broken,
        ).encode())


def run_node(node: Node, duration_s: float | None = None) -> NodeStats:
    """Run ``node`` until SIGINT/SIGTERM (clean shutdown) or ``duration_s``."""
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in previous:
        signal.signal(sig, lambda *_: node.stop())
    try:
        return node.run(duration_s)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

