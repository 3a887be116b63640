"""What a :class:`~uavmpc.drivers.world.World` run reports besides its traces: the contacts
between UAVs, each UAV's outcome, whom each yielded to, and the extras only some runs have
(the geofence, the launch check, the landing and the formation)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from uavmpc.drivers.summary import (
    Contact,
    Formation,
    Landing,
    LinkCounts,
    RunSummary,
    UavSummary,
    run_status,
)
from uavmpc.drivers.world_tick import STAGES, WAIT, pair_distances
from uavmpc.jit import thread_count
from uavmpc.missions.formation import formation_error
from uavmpc.missions.landing import LandingMission, landing_outcome

if TYPE_CHECKING:
    from uavmpc.drivers.world import World, WorldUav
    from uavmpc.missions.formation import FormationSpec
    from uavmpc.plant.ground_vehicle import GroundVehicle

COLLISION_DISTANCE_M = 1.0
#: A UAV has reached its goal when it ends within this 3-D distance of it.
GOAL_TOLERANCE_M = 1.0
#: The formation error is measured from this time on (the followers' first plans arrive and
#: settle).
FORMATION_SETTLE_S = 10.0


@dataclasses.dataclass
class Collision:
    """One contact: from when two UAVs came closer than the threshold, its closest distance."""

    t: float
    a: str
    b: str
    distance_m: float


class Contacts:
    """The contacts of a run: each pair of UAVs closer than :data:`COLLISION_DISTANCE_M`,
    one :class:`Collision` per contact (from when it began, its closest distance)."""

    def __init__(self, ids: Sequence[str]) -> None:
        self.ids = list(ids)
        self._pairs = np.triu_indices(len(ids), 1)
        self._pair_d = np.empty(self._pairs[0].shape[0])
        self._open: dict[tuple[int, int], Collision] = {}
        self.collisions: list[Collision] = []

    def update(self, t_s: float, closest_m: float, positions_m: np.ndarray) -> None:
        """The UAVs at ``positions_m`` (N, 3) at ``t_s``, ``closest_m`` the smallest distance
        between two of them [m]: the distance of every pair is only computed while a contact
        begins, goes on or ends."""
        if not closest_m < COLLISION_DISTANCE_M and not self._open:
            return
        pair_distances(positions_m, self._pair_d)
        self.update_pairs(t_s, self._pair_d)

    def update_pairs(self, t_s: float, pair_d: np.ndarray) -> None:
        """Every pair's distance at ``t_s``, ``pair_d`` (N (N − 1) / 2,) [m] in
        ``np.triu_indices(N, 1)``'s order (:func:`~uavmpc.drivers.world_tick.pair_distances`);
        NaN for a pair not seen now, whose contact neither begins nor ends."""
        close = pair_d < COLLISION_DISTANCE_M
        if not close.any() and not self._open:
            return
        iu = self._pairs
        for j in range(pair_d.shape[0]):
            key = (int(iu[0][j]), int(iu[1][j]))
            if close[j]:
                c = self._open.get(key)
                if c is None:
                    c = Collision(t_s, self.ids[key[0]], self.ids[key[1]], float(pair_d[j]))
                    self._open[key] = c
                    self.collisions.append(c)
                c.distance_m = min(c.distance_m, float(pair_d[j]))
            elif not math.isnan(pair_d[j]):
                self._open.pop(key, None)


class Yields:
    """Whom each UAV yielded to: other id → [first, last] time of a decision saying so [s]
    (into each :class:`~uavmpc.drivers.world.WorldUav`'s ``yielded_to``)."""

    def __init__(self, uavs: Sequence[WorldUav]) -> None:
        self.uavs = uavs
        self._yielding: set[int] = set()

    def add(self, decided: Iterable[int]) -> None:
        """``decided``: UAVs that may have decided since (those yielding are followed)."""
        for i in decided:
            d = self.uavs[i].stack.steering.decision
            if d is not None and d.yielding_to:
                self._yielding.add(i)

    def note(self, now: float, decided: Iterable[int]) -> None:
        """At ``now``, whom each UAV followed (and those of ``decided``) yields to."""
        self.add(decided)
        for i in sorted(self._yielding):
            u = self.uavs[i]
            d = u.stack.steering.decision
            if d is None or not d.yielding_to:
                self._yielding.discard(i)
                continue
            for other in d.yielding_to:
                span = u.yielded_to.setdefault(other, [now, now])
                span[1] = now


def arrival_s(t_s: np.ndarray, track_m: np.ndarray, goal_m: np.ndarray,
              tolerance_m: float = GOAL_TOLERANCE_M) -> float | None:
    """When a UAV arrived for good: the first time ``t_s`` (K,) from which its positions
    ``track_m`` (K, 3) stay within ``tolerance_m`` of ``goal_m`` to the end; None if it ends
    outside."""
    inside = np.linalg.norm(track_m - goal_m, axis=1) < tolerance_m
    if not inside.size or not inside[-1]:
        return None
    outside = np.flatnonzero(~inside)
    return float(t_s[0 if not outside.size else outside[-1] + 1])


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
        goal_reached_s: when it arrived for good (within the tolerance from then to the end)
            [s]; None if it did not, or its mission sets its way.
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
    goal_reached_s: float | None = None


@dataclass(frozen=True)
class Timing:
    """Where a batched run's wall time went (its summary's ``timing`` section).

    Attributes:
        threads: the threads its tick ran on.
        wall_s_by_phase: wall time of receiving and planning, the compiled tick and the
            broadcasts [s] (a kernel compiled mid-flight left out).
        compiled_us_per_uav_tick: CPU µs per UAV and tick of each stage inside the compiled
            tick, summed over the threads (None without the x86 cycle counter).
        threads_wait_us_per_uav_tick: µs per UAV and tick the threads waited for the slowest
            block (None without the cycle counter).
    """

    threads: int
    wall_s_by_phase: dict[str, float]
    compiled_us_per_uav_tick: dict[str, float] | None = None
    threads_wait_us_per_uav_tick: float | None = None


@dataclass
class WorldResult:
    """What a run produced (:meth:`summary` gives its :class:`~uavmpc.drivers.summary.RunSummary`).

    Attributes:
        t_s: (K,) sample times of the traces (every tick).
        positions_m: (K, N, 3) true positions; z_offset_m: (K, N); min_distance_m: (K,).
        sections: the reports of the parts this run had (``geofence``, ``launch``,
            ``non_cooperative``, ``timing``), each as JSON.
        landing: a landing's outcome (a scenario with a lander), else None.
        formation: a formation's error (a scenario with a formation), else None.
        ground_vehicle_m: (K, 3) the ground vehicle's position, with one.
        members_avoiding: (K,) whether any formation member avoided, with a formation.
        formation_t_s: (M,) the times the formation error is measured at, from
            :data:`~uavmpc.drivers.world_report.FORMATION_SETTLE_S`; formation_error_m:
            (M, followers) each follower's distance from its slot [m].
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
    sections: dict[str, Any] = field(default_factory=dict)
    timing: Timing | None = None
    landing: Landing | None = None
    formation: Formation | None = None
    ground_vehicle_m: np.ndarray | None = None
    members_avoiding: np.ndarray | None = None
    formation_t_s: np.ndarray | None = None
    formation_error_m: np.ndarray | None = None

    def summary(self) -> RunSummary:
        """The run's summary (driver ``world``)."""
        uavs = {k: UavSummary(
            max_z_offset_m=v.max_z_offset_m, avoidance_active_s=v.avoidance_active_s,
            tracking_rmse_m=v.tracking_rmse_m, reached_goal=v.reached_goal,
            final_position_m=_point(v.final_position_m),
            details={"limit_violations": v.limit_violations,
                     "max_limit_excess": v.max_limit_excess,
                     "tracker_fallbacks": v.tracker_fallbacks,
                     "messages_rejected": v.messages_rejected, "yielded_to": v.yielded_to,
                     "goal_reached_s": v.goal_reached_s})
            for k, v in self.per_uav.items()}
        contacts = tuple(Contact(c.t, c.a, c.b, c.distance_m) for c in self.collisions)
        return RunSummary(
            driver="world",
            status=run_status(collisions=len(contacts),
                              reached_goal=[u.reached_goal for u in uavs.values()],
                              landed=None if self.landing is None else self.landing.landed),
            scenario=self.scenario, seed=self.seed, avoidance=self.avoidance,
            duration_s=self.duration_s, collisions=contacts,
            # None with a single UAV (no pair): JSON has no infinity.
            min_distance_m=(float(self.min_distance_m.min()) if len(self.uav_ids) > 1
                            else None),
            uavs=uavs,
            messages=LinkCounts(self.messages["sent"], self.messages["delivered"],
                                self.messages["dropped"]),
            wall_s=self.wall_s,
            realtime_factor=self.duration_s / self.wall_s if self.wall_s > 0 else None,
            landing=self.landing, formation=self.formation,
            sections=(self.sections if self.timing is None
                      else {**self.sections, "timing": dataclasses.asdict(self.timing)}))


def _point(p: Any) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in p)
    return x, y, z



def uav_outcomes(uavs: Sequence[WorldUav], t_s: np.ndarray,
                 positions_m: np.ndarray) -> dict[str, UavOutcome]:
    """Per UAV, how its flight ended, from its program's report and its true positions
    ``positions_m`` (K, N, 3) [m] at ``t_s`` (K,)."""
    per_uav = {}
    for i, u in enumerate(uavs):
        rep = u.stack.report()
        arrived = (None if u.supervisor.mission is not None
                   else arrival_s(t_s, positions_m[:, i], u.goal_m))
        per_uav[u.uav_id] = UavOutcome(
            max_z_offset_m=rep.max_z_offset_m, avoidance_active_s=rep.avoidance_active_s,
            tracking_rmse_m=rep.tracking_rmse_m,
            reached_goal=None if u.supervisor.mission is not None else arrived is not None,
            goal_reached_s=arrived,
            final_position_m=positions_m[-1, i].tolist(), limit_violations=rep.limit_violations,
            max_limit_excess=rep.max_limit_excess, tracker_fallbacks=rep.tracker_fallbacks,
            messages_rejected=rep.messages_rejected_total,
            yielded_to={k: [round(a, 3), round(b, 3)] for k, (a, b) in u.yielded_to.items()})
    return per_uav


def fleet_extras(result: WorldResult, uavs: Sequence[WorldUav], *,
                 launch_check_s: float | None, launches: dict[str, dict[str, Any]],
                 non_cooperative: Sequence[str], avoidance: bool) -> None:
    """The geofence, the launch check and who flew without avoidance, into ``result``."""
    fenced = [(u.uav_id, u.supervisor.fence) for u in uavs]
    if any(f is not None for _, f in fenced):
        result.sections["geofence"] = {uid: f.report() for uid, f in fenced if f is not None}
    if launch_check_s is not None:
        result.sections["launch"] = {
            "max_wait_s": launch_check_s, **launches,
            **{u.uav_id: {"launched_s": None, "not_heard": None}
               for u in uavs if not u.supervisor.launched}}
    if avoidance and non_cooperative:
        # Who flew without avoidance while the others avoided (with ``avoidance`` off,
        # the summary's "avoidance": false already says everyone did).
        result.sections["non_cooperative"] = list(non_cooperative)


def applications(result: WorldResult, uavs: Sequence[WorldUav], car: GroundVehicle | None,
                 spec: FormationSpec | None) -> None:
    """The field applications' outcomes (landing, formation) into ``result``."""
    if car is not None:
        result.ground_vehicle_m = np.array(
            [car.state(t).position_m for t in result.t_s])
    for i, u in enumerate(uavs):
        mission = u.supervisor.mission
        if isinstance(mission, LandingMission):
            assert car is not None
            end = float(result.t_s[-1])
            final = result.positions_m[-1, i]
            rests = bool(u.plant.landed and abs(final[2] - car.deck_height_m) < 1e-6
                         and car.on_deck(end, final))
            out = landing_outcome(mission, u.plant.deck_touch(),
                                  u.stack.airframe.max_touchdown_speed_mps, rests, end)
            result.landing = Landing.of(u.uav_id, out)
    if spec is not None:
        _formation(result, spec)


def _formation(result: WorldResult, spec: FormationSpec) -> None:
    keep = result.t_s >= FORMATION_SETTLE_S
    index = {uid: k for k, uid in enumerate(result.uav_ids)}
    err = formation_error(spec, result.t_s[keep],
                          {m: result.positions_m[keep, index[m]] for m in spec.members})
    series = err.pop("series_m")
    assert result.members_avoiding is not None
    calm = ~result.members_avoiding[keep]
    if calm.any():
        err["while_no_member_avoids"] = {
            "rms": float(np.sqrt(np.mean(series[calm] ** 2))),
            "max": float(series[calm].max()), "share_of_time": float(calm.mean())}
    result.formation_error_m = series
    result.formation_t_s = result.t_s[keep]
    result.formation = Formation.of(
        spec, FORMATION_SETTLE_S, err,
        outsiders=[uid for uid in result.uav_ids if uid not in spec.members])


@dataclasses.dataclass
class Traces:
    """A run's traces, written tick by tick: times (K,), true positions (K, N, 3), z offsets
    (K, N), closest distance (K,), and whether any formation member (rows ``members``)
    avoids (K,)."""

    t_s: np.ndarray
    pos: np.ndarray
    zoff: np.ndarray
    dmin: np.ndarray
    members: np.ndarray
    members_avoiding: np.ndarray

    @classmethod
    def empty(cls, ticks: int, n: int, formation: FormationSpec | None,
              ids: list[str]) -> Traces:
        members = (np.array([ids.index(m) for m in formation.members])
                   if formation is not None else np.zeros(0, dtype=np.int64))
        return cls(np.empty(ticks), np.empty((ticks, n, 3)), np.empty((ticks, n)),
                   np.full(ticks, np.inf), members, np.zeros(ticks, dtype=bool))

    def kernel_args(self, k: int) -> tuple[Any, ...]:
        """Row ``k``'s traces as :func:`~uavmpc.drivers.world_tick.world_tick` writes them."""
        return (k, self.pos, self.zoff, self.dmin)


def world_result(world: World, tr: Traces, contacts: Contacts, wall_s: float,
                 cycles_per_s: float) -> WorldResult:
    """The result of ``world``'s run: its traces ``tr``, its contacts, each UAV's outcome,
    the messages, the extras; ``wall_s`` it took [s], the CPU's cycles per second."""
    st = world.link.stats
    messages = {"sent": st.sent, "delivered": st.delivered,
                "dropped": st.dropped + st.dropped_range, "published": st.published}
    result = WorldResult(world.scenario.name, world.seed, world.avoidance,
                         tr.t_s.shape[0] * world.period_s, [u.uav_id for u in world.uavs],
                         tr.t_s, tr.pos, tr.zoff, tr.dmin, contacts.collisions,
                         uav_outcomes(world.uavs, tr.t_s, tr.pos), messages, wall_s)
    if tr.members.size:
        result.members_avoiding = tr.members_avoiding
    if world.batched:
        result.timing = _timing(world.phase_wall_s, world.ticker.cycles, cycles_per_s)
    fleet_extras(result, world.uavs, launch_check_s=world.launch_check_s,
                 launches=world.launches, non_cooperative=world.non_cooperative,
                 avoidance=world.avoidance)
    applications(result, world.uavs, world.ground_vehicle, world.scenario.formation)
    return result


def _timing(phase_wall_s: Sequence[float], cycles: np.ndarray, cycles_per_s: float
            ) -> Timing:
    """Where a batched run's wall time went: the numbers of a scale benchmark."""
    by_phase = dict(zip(("receive_and_plan", "compiled_tick", "broadcast"),
                        (round(v, 6) for v in phase_wall_s), strict=True))
    c = cycles
    if not (c.size and c[-1] > 0 and cycles_per_s > 0):
        return Timing(thread_count(), by_phase)
    # Per UAV and tick, inside the compiled call: the floor of a UAV-second (CPU time, summed
    # over the threads); and the threads idle at the end of the call, waiting for the slowest
    # block (summed over the threads; not part of any UAV's work).
    return Timing(thread_count(), by_phase,
                  {name: round(float(c[j] / c[-1] / cycles_per_s * 1e6), 3)
                   for j, name in enumerate(STAGES)},
                  round(float(c[WAIT] / c[-1] / cycles_per_s * 1e6), 3))
