"""One UAV's onboard stack as its own process, in real time, over a real network (issue 6).

A :class:`Node` flies the same :class:`~uavmpc.onboard.OnboardStack` as the simulated world,
against its own simulated plant (software in the loop), on the wall clock:

- every 10 ms: hand the stack what the transport delivered (at most a bounded number of
  messages per tick, so a flood cannot starve the loop), step the plant with its target, and
  publish what the stack wants broadcast (its prediction every 0.5 s at its own phase, signed
  when a key is configured);
- at ``state_rate_hz``: publish its state (JSON) on ``uavmpc/<swarm>/<id>/state``;
- any time: accept a new mission (JSON, validated) on ``uavmpc/<swarm>/<id>/mission`` or from
  Python (:meth:`Node.set_mission`).

Clocks: stamps are Unix time (``time.time()``), as GNSS-synchronised UAVs would have; on one host
they are synchronised by construction.
"""

from __future__ import annotations

import json
import signal
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uavmpc.avoidance import AvoidanceParams, HeightOffsetStrategy
from uavmpc.comms.link import Transport
from uavmpc.onboard import OnboardStack
from uavmpc.plant import Airframe, VehicleState
from uavmpc.plant.interface import heading_of
from uavmpc.plant.multirotor import Multirotor
from uavmpc.reference import InvalidReferenceError, Reference

PERIOD_S = 0.01
#: Most messages taken from the transport per tick: a flood is dropped, not queued forever.
MAX_MESSAGES_PER_TICK = 32
#: A loop this many periods late skips ahead instead of trying to catch up.
RESYNC_PERIODS = 5


def parse_mission(payload: bytes, now_s: float) -> Reference:
    """A mission message: JSON ``{"goto": [x, y, z, heading]}`` or ``{"points": [[x, y, z, h],
    ...], "sample_period_s": 0.2, "start_s": t}`` (``start_s`` absolute; default now)."""
    try:
        data = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidReferenceError(f"mission is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise InvalidReferenceError("mission must be a JSON object")
    start = data.get("start_s", now_s)
    if "goto" in data:
        goal = data["goto"]
        if not isinstance(goal, list) or len(goal) != 4:
            raise InvalidReferenceError("mission.goto must be [x, y, z, heading]")
        return Reference(np.array([start], dtype=float), np.array([goal], dtype=float))
    if "points" in data:
        return Reference.sampled(np.asarray(data["points"], dtype=float),
                                 data.get("sample_period_s", 0.2), start,
                                 loop=bool(data.get("loop", False)))
    raise InvalidReferenceError("mission needs 'goto' or 'points'")


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
    tracking_rmse_m: float = 0.0
    max_z_offset_m: float = 0.0
    avoidance_active_s: float = 0.0
    final_position_m: list[float] = field(default_factory=list)
    cpu_s: float = 0.0
    wall_s: float = 0.0


def warm_up(airframe: Airframe) -> None:
    """Compile (or load from the cache) the kernels one UAV's tick needs, before a real-time
    clock starts: the first tick of a flight must not take the seconds a compilation does."""
    plant = Multirotor(airframe, position_m=(0.0, 0.0, 5.0))
    stack = OnboardStack(airframe, position_m=(0.0, 0.0, 5.0),
                         avoidance=HeightOffsetStrategy())
    out = stack.tick(0.0, plant.state(), ())
    plant.step(out.target, stack.period_s)


class Node:
    """One UAV in real time: a driver (the wall clock, a transport, a simulated plant) around
    one :class:`~uavmpc.onboard.OnboardStack`. ``transport`` is any
    :class:`~uavmpc.comms.link.Transport` that also offers ``put(topic, bytes)`` and
    ``subscribe(suffix) -> .drain()`` (the Zenoh one)."""

    def __init__(
        self,
        uav_id: str,
        priority: int,
        airframe: Airframe,
        transport: Any,
        *,
        start_m: Sequence[float] = (0.0, 0.0, 5.0),
        heading_rad: float = 0.0,
        avoidance: bool = True,
        params: AvoidanceParams | None = None,
        key: bytes | None = None,
        state_rate_hz: float = 50.0,
        phase_s: float = 0.0,
    ) -> None:
        self.uav_id = uav_id
        self.priority = priority
        self.airframe = airframe
        self.transport: Transport = transport
        self.key = key
        self.start_m = tuple(float(v) for v in start_m)
        self.heading_rad = float(heading_rad)
        self.avoidance = avoidance
        self.params = params if params is not None else AvoidanceParams()
        self._missions = transport.subscribe(f"{uav_id}/mission", maxlen=16)
        self._pending_mission: Reference | None = None
        self._lock = threading.Lock()
        self.state_period_s = 1.0 / state_rate_hz
        self.phase_s = phase_s
        self.stats = NodeStats(uav_id)
        self._stop = threading.Event()
        self.stack: OnboardStack | None = None

    def _build(self) -> OnboardStack:
        # Built when the flight starts, so the virtual UAV's clock starts on the wall clock
        # (stamps are absolute), after the kernels are loaded.
        warm_up(self.airframe)
        self.plant = Multirotor(self.airframe, position_m=self.start_m, yaw_rad=self.heading_rad,
                                rotors_at_hover=self.start_m[2] > 0.0)
        now = time.time()
        self.stack = OnboardStack(
            self.airframe, position_m=self.start_m, heading_rad=self.heading_rad, t0_s=now,
            uav_id=self.uav_id, priority=self.priority,
            avoidance=HeightOffsetStrategy(self.params) if self.avoidance else None,
            params=self.params, key=self.key, broadcast_phase_s=self.phase_s)
        # Hold the start until a mission arrives (a mission starting later keeps this before).
        self.stack.set_mission(Reference.goto(*self.start_m, self.heading_rad, start_s=now))
        return self.stack

    def set_mission(self, reference: Reference) -> None:
        """Fly ``reference`` (thread-safe; taken at the next tick)."""
        if not isinstance(reference, Reference):
            raise TypeError(f"reference must be a uavmpc.Reference, got {type(reference).__name__}")
        with self._lock:
            self._pending_mission = reference

    def stop(self) -> None:
        """Ask the loop to end after the current tick (thread- and signal-safe)."""
        self._stop.set()

    def run(self, duration_s: float | None = None) -> NodeStats:
        """Fly until :meth:`stop` (or SIGINT/SIGTERM via :func:`run_node`) or ``duration_s``."""
        stack = self._build()
        tracker = stack.tracker
        t_end = None if duration_s is None else tracker.time_s + duration_s
        next_state = tracker.time_s
        intervals: list[float] = []
        cpu0 = time.process_time()
        wall0 = time.perf_counter()
        deadline = time.perf_counter()
        last = None
        state = self.plant.state()
        while not self._stop.is_set() and (t_end is None or tracker.time_s < t_end):
            now = tracker.time_s
            self._take_missions(now)
            received = self.transport.receive(self.uav_id, now)[:MAX_MESSAGES_PER_TICK]
            out = stack.tick(now, state, received)
            state = self.plant.step(out.target, PERIOD_S)
            if out.outgoing is not None:
                self.transport.publish(out.outgoing, self.uav_id, now)
            if now >= next_state:
                next_state += self.state_period_s
                self._publish_state(now, state)
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
        s = self.stats
        s.wall_s = time.perf_counter() - wall0
        s.cpu_s = time.process_time() - cpu0
        if intervals:
            ms = np.array(intervals) * 1e3
            s.period_p50_ms = float(np.median(ms))
            s.period_p99_ms = float(np.percentile(ms, 99))
            s.period_max_ms = float(ms.max())
        rep = stack.report()
        s.ticks = rep.ticks
        s.predictions_sent = rep.predictions_sent
        s.accepted = rep.messages_accepted
        s.rejected = dict(rep.messages_rejected)
        s.tracking_rmse_m = rep.tracking_rmse_m
        s.max_z_offset_m = rep.max_z_offset_m
        s.avoidance_active_s = rep.avoidance_active_s
        s.final_position_m = state.position_m.tolist()
        return s

    def _take_missions(self, now: float) -> None:
        for _key, payload in self._missions.drain(4):
            try:
                ref = parse_mission(payload, now)
            except (InvalidReferenceError, ValueError, TypeError):
                self.stats.missions_rejected += 1
                continue
            self.set_mission(ref)
        with self._lock:
            ref, self._pending_mission = self._pending_mission, None
        if ref is not None:
            assert self.stack is not None
            self.stack.set_mission(ref)

    def _publish_state(self, now: float, state: VehicleState) -> None:
        stack = self.stack
        assert stack is not None
        decision = stack.decision
        cmd = stack.command()
        self.transport.put("state", json.dumps({
            "t": now,
            "p": state.position_m.tolist(),
            "v": state.velocity_mps.tolist(),
            "heading": float(heading_of(state.attitude_wxyz)),
            "cmd": cmd.position_m.tolist(),
            "z_offset": stack.tracker.z_offset_m,
            "avoiding": bool(decision is not None and decision.avoiding),
            "conflicts": list(decision.conflicts) if decision is not None else [],
        }, separators=(",", ":")).encode())


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

