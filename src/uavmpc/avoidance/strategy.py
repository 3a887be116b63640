"""Conflict resolution strategies (SPEC §5.3) behind one small contract.

A :class:`ResolutionStrategy` turns the newest messages of the others plus our own nominal
prediction into an :class:`AvoidanceDecision`: a z offset for the reference, and the limits to
fly with. :class:`HeightOffsetStrategy` is the reference design's "reshape": the UAV that must
yield climbs in steps of Δz until its prediction is clear, the other keeps its altitude and only
slows down.

Two contracts, one law. :class:`ResolutionStrategy` is what every strategy honours: its
parameters and :meth:`~ResolutionStrategy.update`, which takes the newest messages (nodes, tests,
any strategy). :class:`EncounterStrategy` is the whole contract of the built-in strategies
(:class:`HeightOffsetStrategy` and its subclasses): besides ``update`` it finds its encounters
(``finder``, ``overrides``) and decides from them (``decide``), flies per-pair radii
(``pair_radius_m``) and an offset ceiling (``limit_offset``). The onboard stack and the simulated
world check it with ``isinstance`` and hand such a strategy its encounters
(:mod:`uavmpc.avoidance.encounters`), batched over every UAV in the world; ``update`` itself finds
them and calls ``decide``: a subclass changes the decision by overriding ``decide``. A strategy
that is only a :class:`ResolutionStrategy` gets the messages through ``update``, flies no
per-pair radii (a formation refuses it) and no geofence ceiling.

The safety argument behind every rule here is docs/safety.md; each rule names the assumption
(A1 … A7) it answers.

Note on flags: :attr:`AvoidanceDecision.avoiding` says "currently avoiding" (diagnostics, logs).
The flag a UAV *broadcasts* (:attr:`~uavmpc.comms.PredictionMessage.avoiding`) means "I run
collision avoidance and will yield" and must stay up whenever a strategy runs, conflict or not:
a UAV that broadcast its down flag while quiet would look non-cooperative to everyone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from uavmpc.avoidance.decide import (
    CALM_KIND,
    F_AVOIDING,
    F_CEILING,
    F_HOLDING,
    F_STUCK,
    F_TIGHT,
    F_UNHEARD,
    M_CONFLICT,
    M_DEAF,
    M_UNRESOLVED,
    M_WAITING,
    M_YIELD,
    N_FLAGS,
    N_MASKS,
    SAME_KIND,
    EncounterRows,
    StrategyRows,
    climb_height,
    decide_rows,
    reset_row,
    rest_row,
)
from uavmpc.avoidance.decide import EPS as _EPS
from uavmpc.avoidance.decide import conflict_below as conflict_below
from uavmpc.avoidance.decide import conflict_points as conflict_points
from uavmpc.avoidance.decide import conflict_rows as conflict_rows
from uavmpc.avoidance.encounters import EncounterFinder, Encounters
from uavmpc.comms.inbox import InboxTable
from uavmpc.comms.message import PredictionMessage
from uavmpc.config import ConfigError, from_table, positive
from uavmpc.jit import bound, kernel

#: Sanity bounds: beyond any multirotor scenario, small enough to catch unit mistakes.
MAX_DISTANCE_M = 1000.0
MAX_TIME_S = 600.0
MAX_SPEED_MPS = 100.0
MAX_ACCEL_MPS2 = 100.0
#: The horizontal speed limit of a UAV holding short [m/s] (a limit must be positive).
HOLD_SPEED_MPS = 0.01
#: Spacing of the delays a holding UAV probes its plan at [s] (``hold_delay_s``).
HOLD_PROBE_STEP_S = 1.0
#: Largest ``hold_delay_s`` [s]: each second is a probe, found with every avoidance round.
MAX_HOLD_DELAY_S = 10.0


@dataclass(frozen=True)
class AvoidanceParams:
    """Parameters of the height-offset strategy (SPEC §5.2–5.3). SI units.

    Attributes:
        radius_m: R_p, horizontal radius of the conflict cylinder.
        height_m: H_p, full height of the conflict cylinder (conflict if |Δz| ≤ H_p / 2).
        dz_m: Δz, one height correction; must exceed H_p / 2 so one step resolves one conflict.
        timeout_s: messages older than this are ignored; also how long a received prediction is
            extrapolated past its end (its age shifts its end before ours).
        max_offset_m: ceiling of the accumulated z offset; reaching it is reported.
        release_rate_mps: speed at which the offset is released once conflict-free.
        release_hysteresis_s: conflict-free time before the release starts and limits are
            restored (so that a conflict flickering with packet loss does not make it oscillate).
        horizontal_scale: factor on the horizontal speed/acceleration limits while avoiding,
            in (0, 1].
        climb_speed_mps, climb_accel_mps2: ascend limits while avoiding (the reference
            implementation lifted them to 5 m/s and 3 m/s² so that a climbing UAV can get out of
            the way of another climbing one).
        time_reference: "stamp" (synchronised clocks) or "receive" (the message's
            ``received_s`` replaces its stamp: fallback for unsynchronised clocks, off by the
            link latency).
        silent_hold_s: a UAV heard from within this time whose latest prediction is older
            than ``timeout_s`` is silent, not absent (silence on a lossy link is not absence;
            0 turns the rule off): its last plan still counts, for conflicts, climbs and the
            way down, widened as below.
        silent_radius_m, silent_speed_mps, silent_accel_mps2: a silent UAV also comes near
            when it could have come within ``silent_radius_m`` of us: that radius widened by
            how far it can have left its last plan since the plan went stale
            (:func:`~uavmpc.avoidance.encounters.silent_reach_m` of its age minus
            ``timeout_s``: from rest at the horizontal limits ``silent_speed_mps`` and
            ``silent_accel_mps2``; a limit 0 turns this off). Smaller than ``radius_m``: the
            cylinder's margin is for plans we know, this one for where a UAV nobody hears
            could be; a hovering neighbour 6.4 m away is in the way after 2.6 s of silence,
            not after 1.9 s. Found in the 24 h campaign with burst loss: two UAVs that had
            not heard each other for 5 s, one of them off to a new waypoint, met head-on.
        ack_grace_s: the acknowledgement (docs/safety.md, A2): a UAV near our plan whose
            current message does not list us (:attr:`~uavmpc.comms.PredictionMessage.heard`)
            for this long has not heard us and will not make way for us: we yield to it
            whatever its priority. While no one near lists us, nobody hears us (our radio is
            silent): we yield to everyone near. 0 turns it off; else at least ``timeout_s``,
            so that the fresh message judged was sent after the nearness began (2 s, the
            default, leaves a broadcast period and the latency on top; docs/safety.md).
        uncertainty_k: the pair's cylinder widens by this many σ of both UAVs' position
            uncertainty, each as its message states it (docs/safety.md, A3): the radius by
            k √(σ_h,own² + σ_h,other²), the half height by k √(σ_v,own² + σ_v,other²). 0 for a
            true state or a centimetre-class fix changes nothing; a single-band receiver's
            metres widen the cylinder so that its conflicts take several layers.
        hold_delay_s: time as well as height (docs/safety.md, A6): when a conflict with a
            UAV we yield to is left unresolved (no layer under the ceiling is clear of it, or
            the way to the one that is is blocked), we hold short — stop within our plan, at
            full braking — and go on once our plan, started now or up to this much later
            (probed every :data:`HOLD_PROBE_STEP_S`), meets none of those we yield to in some
            layer at or above ours. The delay covers the restart from rest (the plan at speed
            reaches each point sooner). 0 turns holding off (the UAV then flies on, climbing
            as high as the way allows, as before).
        climb_lag_s: how far the real climb may lag the fastest one (start at rest, then
            ``climb_accel_mps2`` up to ``climb_speed_mps``). A climb must not cross anyone on
            the way up: every altitude between the lagging and the fastest climb is checked
            (see :meth:`HeightOffsetStrategy._climb`).
    """

    radius_m: float = 5.0
    height_m: float = 5.99
    dz_m: float = 3.0
    timeout_s: float = 1.0
    max_offset_m: float = 30.0
    release_rate_mps: float = 2.0
    release_hysteresis_s: float = 2.0
    horizontal_scale: float = 0.5
    climb_speed_mps: float = 5.0
    climb_accel_mps2: float = 3.0
    time_reference: Literal["stamp", "receive"] = "stamp"
    climb_lag_s: float = 1.0
    silent_hold_s: float = 10.0
    silent_radius_m: float = 3.0
    silent_speed_mps: float = 8.3
    silent_accel_mps2: float = 2.5
    ack_grace_s: float = 2.0
    uncertainty_k: float = 2.0
    hold_delay_s: float = 3.0

    def __post_init__(self) -> None:
        p = "avoidance"
        for name in ("radius_m", "height_m", "dz_m", "max_offset_m"):
            positive(getattr(self, name), f"{p}.{name}", upper=MAX_DISTANCE_M)
        positive(self.timeout_s, f"{p}.timeout_s", upper=MAX_TIME_S)
        positive(self.release_hysteresis_s, f"{p}.release_hysteresis_s", upper=MAX_TIME_S,
                 allow_zero=True)
        positive(self.release_rate_mps, f"{p}.release_rate_mps", upper=MAX_SPEED_MPS)
        positive(self.climb_speed_mps, f"{p}.climb_speed_mps", upper=MAX_SPEED_MPS)
        positive(self.climb_accel_mps2, f"{p}.climb_accel_mps2", upper=MAX_ACCEL_MPS2)
        positive(self.horizontal_scale, f"{p}.horizontal_scale", upper=1.0)
        positive(self.climb_lag_s, f"{p}.climb_lag_s", upper=MAX_TIME_S, allow_zero=True)
        positive(self.silent_hold_s, f"{p}.silent_hold_s", upper=MAX_TIME_S, allow_zero=True)
        positive(self.silent_radius_m, f"{p}.silent_radius_m", upper=MAX_DISTANCE_M,
                 allow_zero=True)
        positive(self.silent_speed_mps, f"{p}.silent_speed_mps", upper=MAX_SPEED_MPS,
                 allow_zero=True)
        positive(self.silent_accel_mps2, f"{p}.silent_accel_mps2", upper=MAX_ACCEL_MPS2,
                 allow_zero=True)
        positive(self.ack_grace_s, f"{p}.ack_grace_s", upper=MAX_TIME_S, allow_zero=True)
        positive(self.uncertainty_k, f"{p}.uncertainty_k", upper=10.0, allow_zero=True)
        positive(self.hold_delay_s, f"{p}.hold_delay_s", upper=MAX_HOLD_DELAY_S,
                 allow_zero=True)
        for f in fields(self):
            if f.name != "time_reference":
                object.__setattr__(self, f.name, float(getattr(self, f.name)))
        if self.dz_m <= 0.5 * self.height_m:
            raise ConfigError(
                f"{p}.dz_m: must be > height_m / 2 = {0.5 * self.height_m} so that one "
                f"correction resolves one conflict, got {self.dz_m}")
        if self.max_offset_m < self.dz_m:
            raise ConfigError(
                f"{p}.max_offset_m: must be ≥ dz_m = {self.dz_m} (else no correction fits), "
                f"got {self.max_offset_m}")
        if 0.0 < self.ack_grace_s < self.timeout_s:
            raise ConfigError(
                f"{p}.ack_grace_s: must be 0 (off) or ≥ timeout_s = {self.timeout_s} (a fresh "
                f"message must have been sent after the nearness began), got {self.ack_grace_s}")
        if self.time_reference not in ("stamp", "receive"):
            raise ConfigError(
                f"{p}.time_reference: must be 'stamp' or 'receive', got {self.time_reference!r}")

    @classmethod
    def from_dict(cls, table: dict[str, Any], prefix: str = "avoidance") -> AvoidanceParams:
        """From a TOML table; missing fields take their defaults, unknown ones are errors."""
        return from_table(cls, table, prefix)


@dataclass(frozen=True)
class AvoidanceDecision:
    """What the avoidance asks of the tracker for the next period.

    Attributes:
        z_offset_m: add to the desired trajectory's z (m, ≥ 0).
        avoiding: currently avoiding (a conflict, within the hysteresis after one, or an offset
            not yet released). For diagnostics and logs; see the module note on the broadcast
            flag.
        conflicts: ids of the UAVs in conflict with our prediction at the offset in force when
            the update began (what triggered this decision).
        yielding_to: those of ``conflicts`` we must yield to (higher priority or flag down).
        unresolved: UAVs we must yield to still in conflict at ``z_offset_m`` (the ceiling).
        first_conflict_s: time from now to the earliest conflict in ``conflicts`` (s), or None.
        horizontal_scale: factor on the nominal horizontal limits (1.0 = nominal).
        climb_speed_mps, climb_accel_mps2: lifted ascend limits, or None for nominal.
        ceiling_hit: the offset could not be raised as needed because of ``max_offset_m``.
        waiting_for: UAVs in the way of the climb this decision needs (the offset is held
            until they have passed).
        silent: UAVs heard from recently whose latest prediction is stale (see
            ``AvoidanceParams.silent_hold_s``); those near are among the conflicts.
        deaf: UAVs near that have not listed us for ``ack_grace_s``: we yield to them.
        unheard: nobody near has listed us for ``ack_grace_s`` while some were near (our
            radio is silent or unheard): we yield to everyone near.
        holding: we hold short (``hold_delay_s``): the horizontal speed limit drops to
            :data:`HOLD_SPEED_MPS` at the nominal acceleration, so the UAV brakes to a stop
            within its plan and stays there until the way is clear.
        stuck: our plan stands still (we hold short, or wait at a waypoint) and one we
            yield to by priority alone (its flag up, hearing us) comes to meet it later in the
            plan: it would fly through us. We cannot make way, so our broadcast flag goes down,
            until that conflict is resolved, and everyone near yields to us (docs/safety.md,
            A6 and A7).
    """

    # The fields' order is what HeightOffsetStrategy.decision_of builds a decision in.
    z_offset_m: float = 0.0
    avoiding: bool = False
    conflicts: tuple[str, ...] = ()
    yielding_to: tuple[str, ...] = ()
    unresolved: tuple[str, ...] = ()
    first_conflict_s: float | None = None
    horizontal_scale: float = 1.0
    climb_speed_mps: float | None = None
    climb_accel_mps2: float | None = None
    ceiling_hit: bool = False
    waiting_for: tuple[str, ...] = ()
    silent: tuple[str, ...] = ()
    deaf: tuple[str, ...] = ()
    unheard: bool = False
    holding: bool = False
    stuck: bool = False


#: The decision with nothing to do: no offset, no conflict, nominal limits.
CALM = AvoidanceDecision()


@runtime_checkable
class ResolutionStrategy(Protocol):
    """What every conflict-resolution strategy honours (one instance per UAV, may keep state).

    The onboard stack reads :attr:`params` (the inbox's time reference and message timeout,
    the cylinder's radius) unless it is given its own, and calls :meth:`update` every
    avoidance period. The richer contract of the built-in strategies is
    :class:`EncounterStrategy`.
    """

    #: The parameters it flies (SI units, see :class:`AvoidanceParams`).
    params: AvoidanceParams

    def update(self, now_s: float, own_id: str, own_priority: int,
               own_prediction_times: np.ndarray, own_prediction_positions: np.ndarray,
               others: Mapping[str, PredictionMessage]) -> AvoidanceDecision:
        """Decide for the next period.

        Args:
            now_s: current time (s), non-decreasing between calls.
            own_id, own_priority: this UAV (lower priority number = higher priority).
            own_prediction_times: (m,) absolute times (s).
            own_prediction_positions: (m, 3) where the UAV would be WITHOUT any z offset (m):
                e.g. the desired trajectory at those times, or the tracker's prediction minus
                the offset in force.
            others: newest message per sender (may contain stale ones and our own).

        Returns:
            The z offset (m, ≥ 0) and the limits for the next period.
        """
        ...


@runtime_checkable
class EncounterStrategy(ResolutionStrategy, Protocol):
    """The whole contract of the built-in strategies (:class:`HeightOffsetStrategy`): a
    :class:`ResolutionStrategy` that decides from encounters found for it, flies per-pair
    radii and an offset ceiling.

    The onboard stack and the simulated world check it with ``isinstance``: such a strategy
    gets its encounters from a finder it makes (:meth:`finder`, one per world when every UAV's
    strategy is one: every UAV is found in one compiled call) instead of the messages, and
    :meth:`decide` must give what :meth:`update` gives on the same messages (bit for bit).
    """

    #: Per-pair cylinder radii [m] by the other UAV's id (e.g. the members of this UAV's
    #: formation); everyone else: ``params.radius_m``. Drivers may add to it before the flight.
    pair_radius_m: dict[str, float]

    def limit_offset(self, ceiling_m: float) -> None:
        """Offsets stay at or below ``ceiling_m`` [m] (≥ 0; a geofence's ceiling over the
        mission flown) as well as ``params.max_offset_m``."""
        ...

    def finder(self, table: InboxTable, *, use_index: bool | None = True) -> EncounterFinder:
        """A finder of this strategy's encounters among the messages ``table`` holds (with its
        parameters; ``use_index`` as :class:`~uavmpc.avoidance.encounters.EncounterFinder`
        takes it)."""
        ...

    def overrides(self, table: InboxTable) -> dict[int, float]:
        """:attr:`pair_radius_m` by ``table``'s columns: column → radius [m], what
        :meth:`~uavmpc.avoidance.encounters.EncounterFinder.find` takes per receiver."""
        ...

    def hold_probes(self, now_s: float, grid_t_s: np.ndarray, here_m: np.ndarray
                    ) -> np.ndarray | None:
        """While holding short: (D, m, 3) the plans whose encounters the next :meth:`decide`
        needs as ``probes`` (at the times ``grid_t_s`` (m,), from ``here_m`` (3,) [m]);
        else None."""
        ...

    def rest(self, now_s: float) -> bool:
        """A round at ``now_s`` with nobody near and nobody silent, when the strategy has
        nothing left to do: left as :meth:`decide` would leave it, and True (the decision
        is :data:`CALM`); else False and nothing changes (:meth:`decide` must run).

        Idempotent: once it has given True, asked again later with no :meth:`decide` in
        between it gives True and changes nothing (a driver need not ask again,
        :attr:`~uavmpc.onboard.OnboardBatch.resting`)."""
        ...

    def decide(self, now_s: float, own_id: str, own_priority: int,
               own_prediction_times: np.ndarray, known: Encounters,
               climbed_m: float | None = None, *, positions: np.ndarray | None = None,
               probes: list[Encounters] | None = None) -> AvoidanceDecision:
        """Decide for the next period from the encounters.

        Args:
            now_s, own_id, own_priority: as :meth:`update`.
            own_prediction_times: (m,) absolute times (s) of our prediction.
            known: the senders near our prediction (k of them, m points each; fresh, or
                silent at their last known plans), found by :meth:`finder`.
            climbed_m: how much of the offset in force the UAV has climbed now [m] (None:
                all of it).
            positions: (m, 3) our prediction's positions without the offset [m] (what a
                hold keeps to go on with later).
            probes: while holding, the encounters of each plan of :meth:`hold_probes`, in
                its order.

        Returns:
            The z offset (m, ≥ 0) and the limits for the next period.
        """
        ...


class StrategyTable:
    """The rows of height-offset strategies (:class:`~uavmpc.avoidance.decide.StrategyRows`)
    and what their columns are: an inbox table's (every strategy of one
    :class:`~uavmpc.onboard.OnboardBatch`, found in one call), or ids of its own (a strategy
    by itself).

    Args:
        n: how many rows.
        table: the inbox table whose columns the rows' columns are (None: its own).
    """

    def __init__(self, n: int, table: InboxTable | None = None) -> None:
        self.rows = StrategyRows.empty(n)
        self.table = table
        #: (N,) bool a strategy's state is the row (:meth:`HeightOffsetStrategy.bind`).
        self.bound = np.zeros(n, dtype=np.bool_)
        self._ids: list[str] = []
        self._cols: dict[str, int] = {}

    @property
    def ids(self) -> list[str]:
        """Each column's UAV id."""
        return self.table.ids if self.table is not None else self._ids

    def col_of(self, uav_id: str) -> int:
        """The column of ``uav_id`` (a new one the first time)."""
        if self.table is not None:
            return self.table.col_of(uav_id)
        col = self._cols.get(uav_id)
        if col is None:
            col = self._cols[uav_id] = len(self._ids)
            self._ids.append(uav_id)
        return col

    def ensure(self, points: int) -> StrategyRows:
        """The rows, grown to hold plans of ``points`` points and every column."""
        self.rows = self.rows.grown(points, len(self.ids))
        return self.rows


def _packed(plans: Sequence[Encounters], own_id: str, col_of: Callable[[str], int]
            ) -> tuple[EncounterRows, np.ndarray]:
    """The encounters of ``plans`` as one call's rows (:func:`~uavmpc.avoidance.decide.
    decide_rows`' ``e`` and ``e_start``)."""
    e_start = np.zeros(len(plans) + 1, dtype=np.int64)
    e_start[1:] = np.cumsum([len(p.ids) for p in plans])
    m = plans[0].near_xy.shape[1]
    ids = [i for p in plans for i in p.ids]

    def cat(name: str, dtype: Any, shape: tuple[int, ...] = ()) -> np.ndarray:
        parts = [np.asarray(getattr(p, name), dtype=dtype).reshape(len(p.ids), *shape)
                 for p in plans]
        return np.ascontiguousarray(np.concatenate(parts))  # plans: ours, then any probes

    enc = EncounterRows(
        np.array([col_of(i) for i in ids], dtype=np.int64), cat("silent_row", np.bool_),
        cat("near_xy", np.bool_, (m,)), cat("announced_xy", np.bool_, (m,)),
        cat("dz_m", float, (m,)), cat("dxy_m", float, (m,)), cat("hears_us", np.bool_),
        cat("widen_v_m", float), cat("priority", np.int64), cat("avoiding", np.bool_),
        np.array([i < own_id for i in ids], dtype=np.bool_))
    return enc, e_start


class HeightOffsetStrategy:
    """The reference design's reshape (SPEC §5.3), one instance per UAV: an
    :class:`EncounterStrategy` (the whole contract).

    Each :meth:`update`:

    1. ignores our own messages and those stamped more than ``timeout_s`` away from now (stale
       or from a faulty clock), aligns the others'
       predictions with ours in time and checks the cylinder along the whole horizon with our
       prediction raised by the current offset;
    2. while a conflict remains with a UAV we must yield to (lower priority number, or flag
       down; equal numbers, which a valid set-up never has, are broken by id), raises the offset
       by Δz — up to ``max_offset_m``, else reports ``ceiling_hit``. Conflicts with UAVs that
       must yield to us never change our offset: they climb;
    3. after ``release_hysteresis_s`` without any conflict — at the current offset nor at any
       offset down to 0, so that it never descends into a conflict, nor back onto the UAV it
       climbed over — lowers the offset at ``release_rate_mps`` (using the time between
       updates). A UAV found on the way down holds the offset and restarts the hysteresis.

    The horizontal limits stay tightened (and the ascend limits lifted) until the release
    starts; :attr:`AvoidanceDecision.avoiding` stays up until the offset is back to 0.

    The law is compiled (:mod:`uavmpc.avoidance.decide`, where each rule below is written
    once) and the strategy is a view of its row of a :class:`StrategyTable`: its own, or,
    once an onboard stack binds it (:meth:`bind`), its batch's, whose rows a world's avoidance round
    decides all at once. Each rule, and the campaign that found it, is documented where it
    is written (docs/safety.md lists them).
    """

    def __init__(self, params: AvoidanceParams | None = None, *,
                 pair_radius_m: Mapping[str, float] | None = None) -> None:
        #: Per-pair cylinder radii by the other UAV's id (e.g. members of this UAV's
        #: formation, :mod:`uavmpc.missions.formation`); everyone else: ``radius_m``.
        self.pair_radius_m: dict[str, float] = {}
        for other, r in (pair_radius_m or {}).items():
            self.pair_radius_m[str(other)] = positive(r, f"pair_radius_m[{other!r}]",
                                                      upper=MAX_DISTANCE_M)
        self._home = StrategyTable(1)
        self._row = 0
        self._home.bound[0] = True
        #: The last decision made (:func:`~uavmpc.avoidance.decide.decide_rows` says when the
        #: next one is the same, field for field: the stack already steers by it).
        self._last_decision: AvoidanceDecision | None = None
        self.params = params if params is not None else AvoidanceParams()
        self.reset()

    @property
    def params(self) -> AvoidanceParams:
        """The parameters it flies (written into its row)."""
        return self._params

    @params.setter
    def params(self, params: AvoidanceParams) -> None:
        self._params = params
        self._home.rows.params[self._row] = (
            params.height_m, params.dz_m, params.max_offset_m, params.release_rate_mps,
            params.release_hysteresis_s, params.climb_speed_mps, params.climb_accel_mps2,
            params.climb_lag_s, params.ack_grace_s, params.hold_delay_s)

    @property
    def home(self) -> StrategyTable:
        """The rows its state lives in (:meth:`bind`)."""
        return self._home

    @property
    def row(self) -> int:
        """Its row of :attr:`home`."""
        return self._row

    def bind(self, home: StrategyTable, row: int) -> None:
        """Its state into row ``row`` of ``home`` from now on (an onboard stack's batch, whose
        rows a world decides at once), as it is now."""
        old, r0, old_ids = self._home.rows, self._row, self._home.ids
        points = int(old.hold_n[r0])
        unlisted = [(old_ids[c], float(old.unlisted_s[r0, c]))
                    for c in np.flatnonzero(~np.isnan(old.unlisted_s[r0])).tolist()]
        cols = [home.col_of(i) for i, _ in unlisted]
        new = home.ensure(old.hold_t_s.shape[1])
        for name in ("params", "ceiling_m", "z_offset_m", "listed_s", "last_conflict_s",
                     "last_update_s", "climb_from_m", "climb_since_s", "stuck", "holding",
                     "hold_n"):
            getattr(new, name)[row] = getattr(old, name)[r0]
        new.hold_t_s[row, :points] = old.hold_t_s[r0, :points]
        new.hold_m[row, :points] = old.hold_m[r0, :points]
        new.unlisted_s[row] = np.nan
        for c, (_, since) in zip(cols, unlisted, strict=True):
            new.unlisted_s[row, c] = since
        new.key_n[row] = -1
        self._last_decision = None
        self._home.bound[r0] = False
        self._home, self._row = home, int(row)
        home.bound[row] = True

    @property
    def z_offset_m(self) -> float:
        """The offset in force [m]."""
        return float(self._home.rows.z_offset_m[self._row])

    @z_offset_m.setter
    def z_offset_m(self, value: float) -> None:
        self._home.rows.z_offset_m[self._row] = float(value)

    @property
    def offset_ceiling_m(self) -> float:
        """The highest offset the operational volume allows over the mission flown (its
        ceiling; :meth:`limit_offset`); ``max_offset_m`` applies too."""
        return float(self._home.rows.ceiling_m[self._row])

    def limit_offset(self, ceiling_m: float) -> None:
        """(docs/safety.md, A6.) Offsets stay at or below ``ceiling_m`` [m] (≥ 0) as well as
        ``max_offset_m``: a
        geofence's maximum altitude over the mission (:meth:`uavmpc.geofence.Geofence.
        offset_ceiling_m`). A decision that wanted higher says so (``ceiling_hit``); an offset
        already above is not cut (it is released as usual)."""
        if not (ceiling_m >= 0.0):
            raise ValueError(f"ceiling_m: must be ≥ 0, got {ceiling_m}")
        self._home.rows.ceiling_m[self._row] = float(ceiling_m)

    def reset(self) -> None:
        """Forget the offset and the conflict history (e.g. after landing)."""
        reset_row(self._home.rows, self._row)
        self._last_decision = None

    @property
    def holding(self) -> bool:
        """It holds short (``hold_delay_s``): its next round needs :meth:`hold_probes`."""
        return bool(self._home.rows.holding[self._row])

    def hold_probes(self, now_s: float, grid_t_s: np.ndarray, here_m: np.ndarray
                    ) -> np.ndarray | None:
        """While holding (docs/safety.md, A6): (D, m, 3) its plan from before the hold, taken
        up again from ``here_m`` (3,) now and up to ``hold_delay_s`` later, at the times
        ``grid_t_s`` (m,) (:func:`hold_probes`); the driver finds their encounters and hands
        them to :meth:`decide`. None when not holding."""
        rows, i = self._home.rows, self._row
        if not rows.holding[i]:
            return None
        hd = self.params.hold_delay_s
        delays = np.linspace(0.0, hd, math.ceil(hd / HOLD_PROBE_STEP_S - _EPS) + 1)
        grid = np.ascontiguousarray(grid_t_s, dtype=float)
        out = np.empty((delays.size, grid.size, 3))
        n = int(rows.hold_n[i])
        hold_probes(rows.hold_t_s[i, :n], rows.hold_m[i, :n], float(now_s),
                    np.asarray(here_m, dtype=float), delays, grid, out)
        return out

    def update(self, now_s: float, own_id: str, own_priority: int,
               own_prediction_times: np.ndarray, own_prediction_positions: np.ndarray,
               others: Mapping[str, PredictionMessage]) -> AvoidanceDecision:
        times = np.asarray(own_prediction_times, dtype=float)
        own = np.asarray(own_prediction_positions, dtype=float)
        if times.ndim != 1 or own.shape != (times.shape[0], 3):
            raise ValueError(
                f"own prediction: times (m,) and positions (m, 3) expected, got {times.shape} "
                f"and {own.shape}")
        # The messages as a one-receiver inbox table: the same comparison as a world's.
        table = InboxTable([own_id], time_reference=self.params.time_reference)
        for sender, msg in others.items():
            if sender == own_id or msg.uav_id == own_id:
                continue
            slot = table.put(msg)
            col = table.col_of(msg.uav_id)
            rows = table.rows
            rows.held_slot[0, col] = slot
            rows.held_stamp_s[0, col] = msg.stamp_s
            rows.held_received_s[0, col] = (np.nan if msg.received_s is None
                                            else msg.received_s)
            table.store.holders[slot] += 1
        table.unpin()
        probes = self.hold_probes(now_s, times, own[0])
        plans = own[None] if probes is None else np.concatenate([own[None], probes])
        n = plans.shape[0]
        found = self.finder(table).find(np.zeros(n, dtype=np.int64),
                                        np.repeat(times[None], n, axis=0), plans,
                                        np.full(n, float(now_s)),
                                        np.full(n, self.params.radius_m),
                                        [self.overrides(table)] * n)
        return self.decide(now_s, own_id, own_priority, times, found[0], positions=own,
                           probes=found[1:] if probes is not None else None)

    def finder(self, table: InboxTable, *, use_index: bool | None = True) -> EncounterFinder:
        """How this strategy finds its encounters in ``table`` (with its parameters;
        ``use_index`` as :class:`~uavmpc.avoidance.encounters.EncounterFinder` takes it)."""
        prm = self.params
        return EncounterFinder(table, timeout_s=prm.timeout_s, silent_hold_s=prm.silent_hold_s,
                               use_received=prm.time_reference == "receive",
                               silent_radius_m=prm.silent_radius_m,
                               silent_speed_mps=prm.silent_speed_mps,
                               silent_accel_mps2=prm.silent_accel_mps2, use_index=use_index,
                               sigma_k=prm.uncertainty_k)

    def overrides(self, table: InboxTable) -> dict[int, float]:
        """The per-pair radii by the table's columns."""
        return {table.col_of(other): r for other, r in self.pair_radius_m.items()}

    def decide(self, now_s: float, own_id: str, own_priority: int,
               own_prediction_times: np.ndarray, known: Encounters,
               climbed_m: float | None = None, *, positions: np.ndarray | None = None,
               probes: list[Encounters] | None = None) -> AvoidanceDecision:
        """The decision from the encounters (:mod:`uavmpc.avoidance.encounters`): everyone
        near, fresh or silent at its last known plan (``update`` finds them itself).
        ``climbed_m``: how much of the offset in force the UAV has climbed now (default: all
        of it); a climb raised again starts from there. ``positions`` (m, 3): the plan
        itself (without it the UAV never holds short); ``probes``: while holding, the
        encounters of each of :meth:`hold_probes` (without them a hold goes on). One row of
        :func:`~uavmpc.avoidance.decide.decide_rows`."""
        home = self._home
        times = np.ascontiguousarray(own_prediction_times, dtype=float)
        m = times.shape[0]
        plans = [known, *(probes or ())]
        enc, e_start = _packed(plans, own_id, home.col_of)
        s_col = np.array([home.col_of(i) for i in known.silent], dtype=np.int64)
        rows = home.ensure(m)
        pos = (np.zeros((1, m, 3)) if positions is None
               else np.ascontiguousarray(positions, dtype=float).reshape(1, m, 3))
        kind = np.empty(1, dtype=np.int8)
        z, first = np.empty(1), np.empty(1)
        flags = np.empty((1, N_FLAGS), dtype=np.bool_)
        masks = np.empty((enc.col.shape[0], N_MASKS), dtype=np.bool_)
        bound(decide_rows)(
                    rows, np.array([self._row], dtype=np.int64), np.array([float(now_s)]),
                    times.reshape(1, m), pos, np.array([positions is not None]),
                    np.array([np.nan if climbed_m is None else float(climbed_m)]),
                    np.array([own_priority], dtype=np.int64), enc, e_start,
                    np.zeros(1, dtype=np.int64), np.ones(1, dtype=np.int64),
                    np.array([len(plans)], dtype=np.int64), np.array([probes is not None]),
                    np.array([0, s_col.shape[0]], dtype=np.int64), s_col, kind, z, first,
                    flags, masks)
        k = len(known.ids)
        return self.decision_of(int(kind[0]), float(z[0]), float(first[0]), flags[0],
                                masks[:k], known.ids, known.silent)

    def decision_of(self, kind: int, z_offset_m: float, first_s: float,
                    flags: np.ndarray | None, masks: np.ndarray | None, ids: Sequence[str],
                    silent: tuple[str, ...]) -> AvoidanceDecision:
        """The decision :func:`~uavmpc.avoidance.decide.decide_rows` made for this strategy's
        row (its ``kind``, offset, first conflict (NaN: none), ``flags`` (6,), ``masks``
        (k, 5) over the encounters of ``ids`` (k,), the ``silent`` ids): :data:`CALM`, the
        last one made when it is the same, else a new one."""
        if kind == CALM_KIND:
            return CALM
        if kind == SAME_KIND:
            # The kernel says so only after a decision this made (a reset or a bind forgets
            # the last one's fields with it).
            assert self._last_decision is not None
            return self._last_decision
        assert flags is not None and masks is not None
        prm = self.params
        f = flags.tolist()
        tight = f[F_TIGHT]
        rows = masks.tolist()

        def named(which: int) -> tuple[str, ...]:
            return tuple(i for i, r in zip(ids, rows, strict=True) if r[which])

        decision = AvoidanceDecision(
            z_offset_m, f[F_AVOIDING], named(M_CONFLICT), named(M_YIELD),
            named(M_UNRESOLVED), None if math.isnan(first_s) else first_s,
            prm.horizontal_scale if tight else 1.0,
            prm.climb_speed_mps if tight else None,
            prm.climb_accel_mps2 if tight else None,
            f[F_CEILING], named(M_WAITING), silent, named(M_DEAF), f[F_UNHEARD],
            f[F_HOLDING], f[F_STUCK])
        self._last_decision = decision
        return decision

    def rest(self, now_s: float) -> bool:
        """(The contract's :meth:`EncounterStrategy.rest`.) At rest: no offset, no hold,
        no conflict within ``release_hysteresis_s``. A round with nobody near then releases
        nothing and starts no hold: it forgets who had not listed us. (The time of the
        round is not noted: only a release reads it, and there is no offset to release; the
        next :meth:`decide` notes its own. Asked again, it does the same: idempotent.)"""
        return bool(rest_row(self._home.rows, self._row, float(now_s)))


@kernel
def hold_probes(plan_t_s: np.ndarray, plan_m: np.ndarray, now_s: float, here_m: np.ndarray,
                delays_s: np.ndarray, grid_t_s: np.ndarray, out_m: np.ndarray) -> None:
    """(docs/safety.md, A6: time as well as height.) Where a UAV holding short would be if it
    went on now, ``delays_s`` (D,) late: its plan from before the hold (times ``plan_t_s``
    (m,), positions ``plan_m`` (m, 3)) taken up again from its point nearest ``here_m`` (3,)
    horizontally, at the times ``grid_t_s`` (m,); before the delay has passed, at that point;
    past the plan's end, at its end. Into ``out_m`` (D, m, 3)."""
    m = plan_t_s.shape[0]
    best, k0 = np.inf, 0
    for k in range(m):
        d2 = (plan_m[k, 0] - here_m[0]) ** 2 + (plan_m[k, 1] - here_m[1]) ** 2
        if d2 < best:
            best, k0 = d2, k
    for d in range(delays_s.shape[0]):
        j = k0
        for g in range(grid_t_s.shape[0]):
            t = plan_t_s[k0] + max(grid_t_s[g] - now_s - delays_s[d], 0.0)
            while j < m - 1 and plan_t_s[j + 1] <= t:
                j += 1
            if j == m - 1:
                for ax in range(3):
                    out_m[d, g, ax] = plan_m[m - 1, ax]
                continue
            w = (t - plan_t_s[j]) / (plan_t_s[j + 1] - plan_t_s[j])
            for ax in range(3):
                out_m[d, g, ax] = plan_m[j, ax] + w * (plan_m[j + 1, ax] - plan_m[j, ax])



def _climbed(t_s: np.ndarray, prm: AvoidanceParams) -> np.ndarray:
    """Height gained after each of ``t_s`` by the fastest climb
    (:func:`~uavmpc.avoidance.decide.climb_height`)."""
    return np.array([climb_height(float(t), prm.climb_accel_mps2, prm.climb_speed_mps)
                     for t in np.ravel(t_s)]).reshape(np.shape(t_s))
