"""Many UAVs, one sky: N onboard stacks, N plants, one lossy link, one simulated clock.

Each UAV runs its own :class:`~uavmpc.onboard.OnboardStack` and sees only what the link
delivered to its own :class:`~uavmpc.comms.link.Inbox`; nothing is shared between UAVs but the
bytes on the link. The world itself only advances the clock, moves the bytes, and watches for
collisions (a 3-D distance between centres below :data:`COLLISION_DISTANCE_M`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from uavmpc.avoidance import AvoidanceParams, HeightOffsetStrategy, ResolutionStrategy
from uavmpc.comms.link import Inbox, SimulatedLink
from uavmpc.comms.message import encode, from_prediction
from uavmpc.config import ConfigError
from uavmpc.log import FlightRecorder
from uavmpc.onboard import OnboardStack
from uavmpc.plant import Airframe, Wind
from uavmpc.plant.interface import heading_of
from uavmpc.plant.multirotor import Multirotor
from uavmpc.scenarios import LinkSettings, Scenario
from uavmpc.tracker.tracker import step_trackers
from uavmpc.world_kernel import CompiledStep, compiled_supported

COLLISION_DISTANCE_M = 1.0
#: A UAV has reached its goal when it ends within this 3-D distance of it.
GOAL_TOLERANCE_M = 1.0
#: Predictions are broadcast at 2 Hz (SPEC §5.1).
BROADCAST_PERIOD_S = 0.5
#: Log rate of poses and status (predictions are logged at each broadcast).
POSE_LOG_PERIOD_S = 0.05
#: A virtual-UAV state outside its limits by more than this (when not braking) is a violation.
LIMIT_TOL = 1e-6


@dataclass
class Collision:
    """One contact: from when two UAVs came closer than the threshold, its closest distance."""

    t: float
    a: str
    b: str
    distance_m: float


@dataclass
class _Uav:
    uav_id: str
    goal_m: np.ndarray
    stack: OnboardStack
    plant: Multirotor
    inbox: Inbox
    next_broadcast_s: float
    err_sq_sum: float = 0.0
    max_z_offset_m: float = 0.0
    avoiding_ticks: int = 0
    limit_violations: int = 0
    max_limit_excess: float = 0.0
    fallbacks: int = 0


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
    per_uav: dict[str, dict[str, Any]]
    messages: dict[str, int]
    wall_s: float
    extra: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "seed": self.seed,
            "avoidance": self.avoidance,
            "duration_s": self.duration_s,
            "collisions": [c.__dict__ for c in self.collisions],
            "min_distance_m": float(self.min_distance_m.min()),
            "uavs": self.per_uav,
            "messages": self.messages,
            "wall_s": self.wall_s,
            "realtime_factor": self.duration_s / self.wall_s if self.wall_s > 0 else None,
            **self.extra,
        }


class World:
    """A scenario flown by its UAVs.

    Args:
        scenario: who flies where (see :mod:`uavmpc.scenarios`).
        avoidance: run collision avoidance on every UAV (else: none, flags down).
        seed: fixes the link's randomness and the wind.
        link: overrides the scenario's link settings.
        wind_mps: mean wind along x (each UAV its own seeded gusts, σ = 0.3 × mean).
        recorder: optional MCAP recorder.
        strategy: makes each UAV's conflict-resolution strategy from the scenario's avoidance
            parameters (any :class:`~uavmpc.avoidance.ResolutionStrategy`).
        backend: ``"compiled"`` (default) ticks every UAV's tracker, controller and plant in one
            numba call (:mod:`uavmpc.world_kernel`), with messages, avoidance and broadcasts
            still per UAV in Python; ``"plain"`` ticks the per-UAV objects one by one (the
            readable reference). A world the kernel does not cover (a recorder attached, mixed
            airframes, …) runs plain; :attr:`backend_used` says which ran.
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
        backend: Literal["compiled", "plain"] = "compiled",
    ) -> None:
        if backend not in ("compiled", "plain"):
            raise ValueError(f"backend must be 'compiled' or 'plain', got {backend!r}")
        self.backend = backend
        #: The backend of the last run (``"plain"`` when the kernel does not cover the world).
        self.backend_used: str | None = None
        self._compiled: CompiledStep | None = None
        self.scenario = scenario
        self.avoidance = avoidance
        self.seed = seed
        self.recorder = recorder
        settings = link if link is not None else scenario.link
        try:
            params = AvoidanceParams.from_dict(scenario.avoidance)
        except TypeError as exc:
            raise ConfigError(f"avoidance: {exc}") from None
        self._positions: dict[str, np.ndarray] = {}
        self.link = SimulatedLink(
            [u.uav_id for u in scenario.uavs], latency_s=settings.latency_s,
            jitter_s=settings.jitter_s, loss=settings.loss,
            range_m=settings.range_m or None, position_of=self._positions.__getitem__,
            seed=seed,
        )
        airframes: dict[str, Airframe] = {}
        self.uavs: list[_Uav] = []
        n = len(scenario.uavs)
        for i, spec in enumerate(scenario.uavs):
            if spec.airframe not in airframes:
                airframes[spec.airframe] = (Airframe.from_toml(spec.airframe)
                                            if spec.airframe.endswith(".toml")
                                            else Airframe.packaged(spec.airframe))
            af = airframes[spec.airframe]
            wind = None
            if wind_mps > 0.0:
                wind = Wind(mean_mps=(wind_mps, 0.0, 0.0), gust_sigma_mps=0.3 * wind_mps,
                            seed=seed * 1000 + i)
            plant = Multirotor(af, position_m=spec.start_m, yaw_rad=spec.heading_rad, wind=wind,
                               rotors_at_hover=spec.start_m[2] > 0.0)
            stack = OnboardStack(af, position_m=spec.start_m, heading_rad=spec.heading_rad,
                                 uav_id=spec.uav_id, priority=spec.priority,
                                 avoidance=strategy(params) if avoidance else None)
            stack.set_mission(spec.mission)
            inbox = Inbox(spec.uav_id, max_age_s=params.timeout_s)
            # Each UAV broadcasts at its own phase, spread over the period.
            phase = BROADCAST_PERIOD_S * (i + 0.5) / n
            self.uavs.append(_Uav(spec.uav_id, np.array(spec.goal_m), stack, plant, inbox, phase))
            self._positions[spec.uav_id] = np.array(spec.start_m, dtype=float)
        self.t_s = 0.0
        self.period_s = self.uavs[0].stack.period_s

    def run(self, duration_s: float | None = None) -> WorldResult:
        """Fly for ``duration_s`` (default: the scenario's) and return the result."""
        duration = self.scenario.duration_s if duration_s is None else float(duration_s)
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(f"duration_s must be > 0, got {duration_s}")
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
        contact: dict[tuple[int, int], Collision] = {}
        collisions: list[Collision] = []
        wall0 = time.perf_counter()
        why_not = compiled_supported(self) if self.backend == "compiled" else "not asked"
        self.backend_used = "compiled" if why_not is None else "plain"
        if why_not is None:
            self._run_compiled(ticks, pos, zoff, dmin, t_log, ids, iu, contact, collisions)
        else:
            self._run_plain(ticks, pos, zoff, dmin, t_log, ids, iu, contact, collisions)
        wall = time.perf_counter() - wall0
        per_uav = {}
        for i, u in enumerate(self.uavs):
            final = pos[-1, i]
            per_uav[u.uav_id] = {
                "max_z_offset_m": u.max_z_offset_m,
                "avoidance_active_s": u.avoiding_ticks * self.period_s,
                "tracking_rmse_m": math.sqrt(u.err_sq_sum / ticks),
                "reached_goal": bool(np.linalg.norm(final - u.goal_m) < GOAL_TOLERANCE_M),
                "final_position_m": final.tolist(),
                "limit_violations": u.limit_violations,
                "max_limit_excess": u.max_limit_excess,
                "tracker_fallbacks": u.stack.tracker.fallback_count,
                "messages_rejected": u.inbox.rejected_total,
            }
        st = self.link.stats
        messages = {"sent": st.sent, "delivered": st.delivered,
                    "dropped": st.dropped + st.dropped_range, "published": st.published}
        return WorldResult(self.scenario.name, self.seed, self.avoidance, ticks * self.period_s,
                           ids, t_log, pos, zoff, dmin, collisions, per_uav, messages, wall)

    def _run_plain(self, ticks: int, pos: np.ndarray, zoff: np.ndarray, dmin: np.ndarray,
                   t_log: np.ndarray, ids: list[str], iu: tuple[np.ndarray, np.ndarray],
                   contact: dict[tuple[int, int], Collision],
                   collisions: list[Collision]) -> None:
        """The per-UAV objects, one by one: the readable reference of every tick."""
        n = len(self.uavs)
        next_log = 0.0
        states = [u.plant.state() for u in self.uavs]
        trackers = [u.stack.tracker for u in self.uavs]
        for k in range(ticks):
            now = self.t_s
            for u in self.uavs:
                others = self._receive(u, now)
                u.stack.reshape(others if u.stack.avoidance is not None else None)
            # All trackers in one batch (same results as one by one, fewer array calls).
            tracked = step_trackers(trackers)
            for i, u in enumerate(self.uavs):
                out = u.stack.control(tracked[i], states[i])
                states[i] = u.plant.step(out.target, self.period_s)
                self._bookkeeping(u, out, states[i])
                if now >= u.next_broadcast_s - 1e-9:
                    u.next_broadcast_s += BROADCAST_PERIOD_S
                    self._broadcast(u, out, now)
            self.t_s = now + self.period_s
            for i, u in enumerate(self.uavs):
                p = states[i].position_m
                pos[k, i] = p
                self._positions[u.uav_id] = p
                zoff[k, i] = u.stack.tracker.z_offset_m
            t_log[k] = self.t_s
            if n > 1:
                d = np.linalg.norm(pos[k, iu[0]] - pos[k, iu[1]], axis=1)
                dmin[k] = d.min()
                self._collisions(d, iu, ids, contact, collisions)
            if self.recorder is not None and self.t_s >= next_log - 1e-9:
                next_log = self.t_s + POSE_LOG_PERIOD_S
                self._log(states)

    def _run_compiled(self, ticks: int, pos: np.ndarray, zoff: np.ndarray, dmin: np.ndarray,
                      t_log: np.ndarray, ids: list[str], iu: tuple[np.ndarray, np.ndarray],
                      contact: dict[tuple[int, int], Collision],
                      collisions: list[Collision]) -> None:
        """:meth:`_run_plain` with the numerical work in :func:`uavmpc.world_kernel.world_tick`;
        messages, avoidance and broadcasts stay per UAV, in the same order."""
        if self._compiled is None:
            self._compiled = CompiledStep(self, LIMIT_TOL)
        step = self._compiled
        step.pack()
        n = len(self.uavs)
        pair_d = np.empty(max(1, n * (n - 1) // 2))
        stacks = [u.stack for u in self.uavs]
        winds = [(i, u.plant.wind) for i, u in enumerate(self.uavs) if u.plant.wind is not None]
        ranged = self.link.range_m is not None
        try:
            for k in range(ticks):
                now = self.t_s
                for i, u in enumerate(self.uavs):
                    others = u.inbox.poll(self.link, now)
                    stack = stacks[i]
                    if (stack.avoidance is not None and step.has_plan[i]
                            and stack.avoidance_due(step.time_s(i))):
                        stack.reshape(others, step.prediction(i))
                        step.refresh_limits(i)
                        step.refresh_avoiding(i)
                for i, wind in winds:
                    step.wind[i] = wind.update(self.period_s)
                step.tick(k, pos, zoff, dmin, pair_d)
                for i, u in enumerate(self.uavs):
                    if now >= u.next_broadcast_s - 1e-9:
                        u.next_broadcast_s += BROADCAST_PERIOD_S
                        self._publish(u, step.prediction(i), now)
                if ranged:  # the link's range check sees where the UAVs are (as in plain)
                    for i, u in enumerate(self.uavs):
                        self._positions[u.uav_id] = pos[k, i]
                self.t_s = now + self.period_s
                t_log[k] = self.t_s
                if n > 1 and (dmin[k] < COLLISION_DISTANCE_M or contact):
                    self._collisions(pair_d, iu, ids, contact, collisions)
        finally:
            step.unpack()
        for i, u in enumerate(self.uavs):
            self._positions[u.uav_id] = pos[ticks - 1, i].copy()

    # ------------------------------------------------------------------------------ internals
    def _bookkeeping(self, u: _Uav, out: Any, state: Any) -> None:
        tracker = u.stack.tracker
        cmd = out.tracker.command
        err = state.position_m - cmd.position_m
        u.err_sq_sum += float(err @ err)
        u.max_z_offset_m = max(u.max_z_offset_m, tracker.z_offset_m)
        decision = u.stack.decision
        if decision is not None and decision.avoiding:
            u.avoiding_ticks += 1
        if not out.tracker.braking:
            excess = tracker.limit_excess()
            u.max_limit_excess = max(u.max_limit_excess, excess)
            if excess > LIMIT_TOL:
                u.limit_violations += 1

    def _receive(self, u: _Uav, now: float) -> Any:
        if self.recorder is None:
            return u.inbox.poll(self.link, now)
        for data in self.link.receive(u.uav_id, now):
            rejected_before = u.inbox.rejected_total
            msg = u.inbox.accept(data, now)
            if msg is not None:
                self.recorder.link(now, "delivered", msg.uav_id, u.uav_id, msg.stamp_s)
            elif u.inbox.rejected_total > rejected_before:
                self.recorder.link(now, "rejected", "?", u.uav_id, detail=f"{len(data)} bytes")
        return u.inbox.latest

    def _broadcast(self, u: _Uav, out: Any, now: float) -> None:
        self._publish(u, out.tracker.prediction, now)

    def _publish(self, u: _Uav, pred: Any, now: float) -> None:
        msg = from_prediction(pred, uav_id=u.uav_id, priority=u.stack.priority,
                              stamp_s=now, avoiding=u.stack.avoidance is not None)
        self.link.publish(encode(msg), u.uav_id, now)
        if self.recorder is not None:
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

    def _log(self, states: list[Any]) -> None:
        rec = self.recorder
        assert rec is not None
        for u, s in zip(self.uavs, states, strict=True):
            last = u.stack.last_output
            if last is None:
                continue
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
                       limit_excess=u.stack.tracker.limit_excess(),
                       braking=bool(last.braking))
