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
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from uavmpc.avoidance.encounters import EncounterFinder, Encounters
from uavmpc.comms.inbox import InboxTable
from uavmpc.comms.message import PredictionMessage
from uavmpc.config import ConfigError, from_table, positive
from uavmpc.jit import kernel

#: Sanity bounds: beyond any multirotor scenario, small enough to catch unit mistakes.
MAX_DISTANCE_M = 1000.0
MAX_TIME_S = 600.0
MAX_SPEED_MPS = 100.0
MAX_ACCEL_MPS2 = 100.0
#: Two plans closer in height than this count as level for a climb's way check (rule 6): the
#: collision distance of the campaigns, so "above us" means above by more than a collision.
LEVEL_M = 1.0
#: The horizontal speed limit of a UAV holding short [m/s] (a limit must be positive).
HOLD_SPEED_MPS = 0.01
#: A plan whose points all lie within this of its first one, horizontally, stands still [m]
#: (:attr:`AvoidanceDecision.stuck`): a hold's creep at :data:`HOLD_SPEED_MPS` over the
#: horizon is a tenth of it.
STANDING_M = 1.0
#: Spacing of the delays a holding UAV probes its plan at [s] (``hold_delay_s``).
HOLD_PROBE_STEP_S = 1.0
#: Largest ``hold_delay_s`` [s]: each second is a probe, found with every avoidance round.
MAX_HOLD_DELAY_S = 10.0
#: Relative slack for "offset is a multiple of Δz that fits under the ceiling" (round-off).
_EPS = 1e-9


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

    # The fields' order is what HeightOffsetStrategy._decision builds a decision in.
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


def _standing_still(positions: np.ndarray | None) -> bool:
    """The plan ``positions`` (m, 3) stays within :data:`STANDING_M` of its first point,
    horizontally (False without a plan)."""
    if positions is None:
        return False
    d = positions[:, :2] - positions[0, :2]
    return bool(np.max(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) <= STANDING_M * STANDING_M)


def _named(ids: tuple[str, ...], which: np.ndarray) -> tuple[str, ...]:
    """The ids whose entry of ``which`` (k,) is set."""
    return tuple(i for i, h in zip(ids, which.tolist(), strict=True) if h)


def _half(enc: Encounters, half_height_m: float) -> np.ndarray:
    """(k, 1) each pair's half height: the cylinder's, widened for both UAVs' vertical
    position uncertainty (docs/safety.md, A3)."""
    return half_height_m + enc.widen_v_m[:, None]


@kernel
def _in_cylinder(near_xy: bool, dz_m: float, offset_m: float, half_m: float) -> bool:
    """The cylinder (SPEC §5.2) at one point: horizontally near, and our height raised by
    ``offset_m`` within ``half_m`` of theirs (``dz_m``: ours minus theirs)."""
    return near_xy and abs(dz_m + offset_m) <= half_m


@kernel
def conflict_points(near_xy: np.ndarray, dz_m: np.ndarray, widen_v_m: np.ndarray,
                    half_height_m: float, offsets_m: np.ndarray, out: np.ndarray) -> None:
    """Whether each of k encounters' m points (horizontally near: ``near_xy`` (k, m); our
    height minus theirs: ``dz_m`` (k, m)) is in the cylinder (:func:`_in_cylinder`) with our
    plan raised by each of ``offsets_m`` (c,), its half height ``half_height_m`` widened by
    the pair's ``widen_v_m`` (k,) (docs/safety.md, A3). Into ``out`` (c, k, m)."""
    for c in range(offsets_m.shape[0]):
        for j in range(near_xy.shape[0]):
            h = half_height_m + widen_v_m[j]
            for p in range(near_xy.shape[1]):
                out[c, j, p] = _in_cylinder(near_xy[j, p], dz_m[j, p], offsets_m[c], h)


@kernel
def conflict_rows(near_xy: np.ndarray, dz_m: np.ndarray, widen_v_m: np.ndarray,
                  half_height_m: float, offset_m: float, hit: np.ndarray) -> int:
    """:func:`conflict_points` at one offset, summed up: whether each encounter conflicts
    somewhere into ``hit`` (k,); returns the first point any of them conflicts at (−1: none
    does)."""
    m = near_xy.shape[1]
    first = m
    for j in range(near_xy.shape[0]):
        h = half_height_m + widen_v_m[j]
        hit[j] = False
        for p in range(m):
            if _in_cylinder(near_xy[j, p], dz_m[j, p], offset_m, h):
                hit[j] = True
                first = min(first, p)
                break
    return first if first < m else -1


@kernel
def conflict_below(near_xy: np.ndarray, dz_m: np.ndarray, widen_v_m: np.ndarray,
                   half_height_m: float, offset_m: float) -> bool:
    """Whether some point conflicts at SOME offset in [0, ``offset_m``]: the way down
    (arguments as :func:`conflict_points`). |dz + o| ≤ h for some o ∈ [0, z]  ⇔
    −h − z ≤ dz ≤ h (an exact interval test)."""
    for j in range(near_xy.shape[0]):
        h = half_height_m + widen_v_m[j]
        for p in range(near_xy.shape[1]):
            if near_xy[j, p] and dz_m[j, p] >= -h - offset_m and dz_m[j, p] <= h:
                return True
    return False


def _conflicts(enc: Encounters, offset_m: float | np.ndarray, half_height_m: float
               ) -> np.ndarray:
    """(k, m) for a scalar offset, (c, k, m) for (c,) candidate offsets
    (:func:`conflict_points`)."""
    offsets = np.asarray(offset_m, dtype=float)
    k, m = enc.near_xy.shape
    out = np.empty((offsets.size, k, m), dtype=bool)
    conflict_points(enc.near_xy, enc.dz_m, enc.widen_v_m, half_height_m,
                    offsets.reshape(-1), out)
    return out if offsets.ndim else out[0]


def _subset(enc: Encounters, keep: np.ndarray) -> Encounters:
    return Encounters(tuple(i for i, k in zip(enc.ids, keep, strict=True) if k),
                      enc.priority[keep], enc.avoiding[keep], enc.silent_row[keep],
                      enc.near_xy[keep], enc.dz_m[keep], enc.silent,
                      enc.announced_xy[keep], enc.hears_us[keep], enc.widen_v_m[keep],
                      enc.dxy_m[keep])


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
    """

    def __init__(self, params: AvoidanceParams | None = None, *,
                 pair_radius_m: Mapping[str, float] | None = None) -> None:
        self.params = params if params is not None else AvoidanceParams()
        #: Per-pair cylinder radii by the other UAV's id (e.g. members of this UAV's
        #: formation, :mod:`uavmpc.missions.formation`); everyone else: ``radius_m``.
        self.pair_radius_m: dict[str, float] = {}
        for other, r in (pair_radius_m or {}).items():
            self.pair_radius_m[str(other)] = positive(r, f"pair_radius_m[{other!r}]",
                                                      upper=MAX_DISTANCE_M)
        #: The highest offset the operational volume allows over the mission flown (its
        #: ceiling; :meth:`limit_offset`); ``max_offset_m`` applies too.
        self.offset_ceiling_m = math.inf
        self.reset()

    def limit_offset(self, ceiling_m: float) -> None:
        """(docs/safety.md, A6.) Offsets stay at or below ``ceiling_m`` [m] (≥ 0) as well as
        ``max_offset_m``: a
        geofence's maximum altitude over the mission (:meth:`uavmpc.geofence.Geofence.
        offset_ceiling_m`). A decision that wanted higher says so (``ceiling_hit``); an offset
        already above is not cut (it is released as usual)."""
        if not (ceiling_m >= 0.0):
            raise ValueError(f"ceiling_m: must be ≥ 0, got {ceiling_m}")
        self.offset_ceiling_m = float(ceiling_m)

    def reset(self) -> None:
        """Forget the offset and the conflict history (e.g. after landing)."""
        self.z_offset_m = 0.0
        #: Since when each UAV near us has not listed us (the acknowledgement).
        self._unlisted_since: dict[str, float] = {}
        #: When a UAV near us last listed us (None: never).
        self._listed_s: float | None = None
        self._last_conflict_s: float | None = None
        self._last_update_s: float | None = None
        #: While holding short: the plan from before the hold (times (m,), positions (m, 3)).
        self._hold_plan: tuple[np.ndarray, np.ndarray] | None = None
        #: :attr:`AvoidanceDecision.stuck`, kept until the conflict is resolved.
        self._stuck = False
        #: The last decision made and its field values (:meth:`_decision`).
        self._last_decision: tuple[tuple[object, ...], AvoidanceDecision] | None = None

    @property
    def holding(self) -> bool:
        """It holds short (``hold_delay_s``): its next round needs :meth:`hold_probes`."""
        return self._hold_plan is not None

    def hold_probes(self, now_s: float, grid_t_s: np.ndarray, here_m: np.ndarray
                    ) -> np.ndarray | None:
        """While holding (docs/safety.md, A6): (D, m, 3) its plan from before the hold, taken
        up again from ``here_m`` (3,) now and up to ``hold_delay_s`` later, at the times
        ``grid_t_s`` (m,) (:func:`hold_probes`); the driver finds their encounters and hands
        them to :meth:`decide`. None when not holding."""
        if self._hold_plan is None:
            return None
        hd = self.params.hold_delay_s
        delays = np.linspace(0.0, hd, math.ceil(hd / HOLD_PROBE_STEP_S - _EPS) + 1)
        grid = np.ascontiguousarray(grid_t_s, dtype=float)
        out = np.empty((delays.size, grid.size, 3))
        plan_t, plan_m = self._hold_plan
        hold_probes(plan_t, plan_m, float(now_s), np.asarray(here_m, dtype=float), delays,
                    grid, out)
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
        encounters of each of :meth:`hold_probes` (without them a hold goes on)."""
        prm = self.params
        half_h = 0.5 * prm.height_m
        times = own_prediction_times
        if not known.ids:
            return self._nobody_near(now_s, known, times, positions, probes, own_id,
                                     own_priority)
        # Silent UAVs count at their last plans (widened by how far they can have left them):
        # a pair that cannot hear each other still resolves its conflict.
        enc = known
        must_yield = known.must_yield(own_id, own_priority)
        deaf, unheard, deaf_ids = self._deaf(now_s, enc)
        if deaf_ids:
            must_yield = must_yield | deaf | unheard

        z_start = self.z_offset_m
        hit_start = np.empty(len(enc.ids), dtype=bool)
        first = conflict_rows(enc.near_xy, enc.dz_m, enc.widen_v_m, half_h, z_start, hit_start)
        any_start = first >= 0
        yield_hit = hit_start & must_yield
        ceiling_hit = False
        waiting_for: tuple[str, ...] = ()
        if any_start and yield_hit.any():
            # Found in the lossy 24 h campaign (trial 78): a UAV that had missed two messages of
            # another climbed into its layer. A new offset must be clear of the silent ones too.
            self.z_offset_m, ceiling_hit, waiting_for = self._climb(
                enc, must_yield, half_h, times - now_s,
                self.z_offset_m if climbed_m is None else min(climbed_m, self.z_offset_m))
        if self.z_offset_m == z_start:
            hit_end, any_end = hit_start, any_start
        else:
            hit_end = np.empty(len(enc.ids), dtype=bool)
            any_end = conflict_rows(enc.near_xy, enc.dz_m, enc.widen_v_m, half_h,
                                    self.z_offset_m, hit_end) >= 0
        unresolved = hit_end & must_yield
        any_unresolved = any_end and bool(unresolved.any())
        # "Conflict-free" for the hysteresis and the release means: no conflict at the offset
        # in force, and none anywhere on the way down to 0 either. Climbing over a UAV removes
        # the conflict but not the reason for the offset; without this, the offset would be
        # released on top of it and re-raised as soon as the conflict reappeared.
        if any_start or any_end or conflict_below(enc.near_xy, enc.dz_m, enc.widen_v_m, half_h,
                                                  self.z_offset_m):
            self._last_conflict_s = now_s
        else:
            # Found in the 24 h campaign with 30 % loss: a UAV that had not heard from another
            # for 5 s (ten lost messages in a row) released its offset onto it. Silent UAVs
            # are among the encounters, at their widened last plans: the way down is clear
            # of them too (until their plans end, with ``silent_hold_s``).
            self._release(now_s)
        self._last_update_s = now_s

        holding = self._hold_short(any_unresolved, times, positions,
                                   probes, own_id, own_priority, deaf_ids, unheard)
        # Stuck (docs/safety.md, A6): a hold is a stop within our plan, so that the one we
        # yield to passes ahead of us. When our plan stands still and one we yield to comes
        # to meet it later in the plan, it passes through us: found in the 24 h campaign
        # (trial 42), uav3 waiting at its waypoint under uav5 (no way up), uav1 flying to a
        # waypoint beside it, straight into uav3. Nothing we can do makes way; saying so (the
        # flag down, A7) makes the others yield. Only for a UAV we yield to by priority alone
        # (its flag up, it hears us, we are heard): a stuck UAV is never stuck for another
        # stuck one, so two never lower their flags for each other (found with every fault at
        # once: UAVs hovering at their starts, in each other's wide cylinders, all stuck).
        # Once stuck, until that conflict is resolved (a hold's rounds alternate between the
        # standing plan and the probes' one).
        if any_unresolved:
            by_rank = (unresolved & known.avoiding & ~deaf & (not unheard)
                       & known.outrank(own_id, own_priority))
            coming = by_rank & ~_conflicts(enc, self.z_offset_m, half_h)[:, 0]  # it comes to us
            self._stuck = bool(by_rank.any()) and (
                self._stuck or (bool(coming.any()) and _standing_still(positions)))
        else:
            self._stuck = False
        recent = (self._last_conflict_s is not None
                  and now_s - self._last_conflict_s < prm.release_hysteresis_s)
        limits_tight = bool(any_start or any_end or recent or holding)
        first_s = float(times[first] - now_s) if any_start else None
        return self._decision(
            self.z_offset_m,
            limits_tight or self.z_offset_m > 0.0,
            _named(enc.ids, hit_start) if any_start else (),  # conflicts
            _named(enc.ids, yield_hit) if any_start else (),  # yielding_to
            _named(enc.ids, unresolved) if any_unresolved else (),  # unresolved
            first_s,
            prm.horizontal_scale if limits_tight else 1.0,
            prm.climb_speed_mps if limits_tight else None,
            prm.climb_accel_mps2 if limits_tight else None,
            ceiling_hit,
            waiting_for,
            enc.silent,
            deaf_ids,  # deaf
            bool(unheard),
            holding,
            self._stuck,
        )

    def _nobody_near(self, now_s: float, known: Encounters, times: np.ndarray,
                     positions: np.ndarray | None, probes: list[Encounters] | None,
                     own_id: str, own_priority: int) -> AvoidanceDecision:
        """Nobody near: no conflict now, none on the way down; only the release runs (and a
        hold goes on until its probes clear)."""
        if not known.silent and self.rest(now_s):
            return CALM  # most UAVs, most rounds (a decision costs µs to build)
        prm = self.params
        self._unlisted_since = {}
        self._release(now_s)
        self._last_update_s = now_s
        holding = self._hold_short(False, times, positions, probes, own_id, own_priority, (),
                                   False)
        self._stuck = False  # nobody near: no conflict
        recent = holding or (self._last_conflict_s is not None
                             and now_s - self._last_conflict_s < prm.release_hysteresis_s)
        return self._decision(
            self.z_offset_m, recent or self.z_offset_m > 0.0, (), (), (), None,
            prm.horizontal_scale if recent else 1.0,
            prm.climb_speed_mps if recent else None,
            prm.climb_accel_mps2 if recent else None,
            False, (), known.silent, (), False, holding, False)

    def _decision(self, *values: Any) -> AvoidanceDecision:
        """The decision of these field values (in :class:`AvoidanceDecision`'s order): the
        last one made when they are the same. Most rounds decide what the last one did (two
        in three of those with someone near, in 4 s of the 300-UAV world); the stack already
        steers by it, and building one costs µs, applying it again more."""
        last = self._last_decision
        if last is not None and last[0] == values:
            return last[1]
        decision = AvoidanceDecision(*values)
        self._last_decision = (values, decision)
        return decision

    def rest(self, now_s: float) -> bool:
        """(The contract's :meth:`EncounterStrategy.rest`.) At rest: no offset, no hold,
        no conflict within ``release_hysteresis_s``. A round with nobody near then releases
        nothing and starts no hold: it forgets who had not listed us. (The time of the
        round is not noted: only a release reads it, and there is no offset to release; the
        next :meth:`decide` notes its own. Asked again, it does the same: idempotent.)"""
        if (self.z_offset_m != 0.0 or self._hold_plan is not None
                or (self._last_conflict_s is not None
                    and now_s - self._last_conflict_s < self.params.release_hysteresis_s)):
            return False
        self._unlisted_since = {}
        self._stuck = False
        return True

    def _hold_short(self, start: bool, times: np.ndarray, positions: np.ndarray | None,
                    probes: list[Encounters] | None, own_id: str, own_priority: int,
                    deaf_ids: tuple[str, ...], unheard: bool) -> bool:
        """(docs/safety.md, A6: time as well as height.) Whether we hold short after this
        round. A hold starts (``start``: a conflict with one we yield to is left unresolved)
        with the plan it interrupts; it ends once some layer, at or above the
        offset in force, is clear of them along every probe (:meth:`hold_probes`): going on
        now or up to ``hold_delay_s`` later meets none of them. The order is the priorities'
        (a total order): the highest never holds, and each holds only for higher ones."""
        if self._hold_plan is None:
            if start and self.params.hold_delay_s > 0.0 and positions is not None:
                self._hold_plan = (np.array(times, dtype=float),
                                   np.array(positions, dtype=float))
            return self._hold_plan is not None
        if probes is not None and self._way_clear(probes, own_id, own_priority, deaf_ids,
                                                  unheard):
            self._hold_plan = None
        return self._hold_plan is not None

    def _way_clear(self, probes: list[Encounters], own_id: str, own_priority: int,
                   deaf_ids: tuple[str, ...], unheard: bool) -> bool:
        """Some offset from the one in force up to the ceiling is clear, along every probe,
        of everyone we yield to (as :meth:`decide` counts them)."""
        prm = self.params
        z = self.z_offset_m
        top = min(prm.max_offset_m, self.offset_ceiling_m)
        candidates = z + prm.dz_m * np.arange(math.floor(max(top - z, 0.0) / prm.dz_m + _EPS)
                                              + 1)
        blocked = np.zeros(candidates.size, dtype=bool)
        for probe in probes:
            if not probe.ids:
                continue
            must = probe.must_yield(own_id, own_priority)
            must |= np.array([unheard or i in deaf_ids for i in probe.ids], dtype=bool)
            yielded = _subset(probe, must)
            c = _conflicts(yielded, candidates, 0.5 * prm.height_m)  # (c, k, m)
            # A conflict from the first point on that ends for good while we only go away from
            # them is one going on leaves behind (a UAV at the hold point itself, parked at
            # its goal there): not in the way. Found with 32 UAVs under a 30 m ceiling: a UAV
            # held beside the one whose goal its start was, each waiting for the other. But
            # one that comes closer first is passing through us: found in the lossy 16-UAV
            # antipodal swap (seed 0), a UAV held 4 m from a higher priority crossing its
            # way went on every other round and passed it at 1.24 m.
            d = yielded.dxy_m
            apart = np.ones(d.shape, dtype=bool)
            apart[:, 1:] = d[:, 1:] >= d[:, :-1]
            left = np.logical_and.accumulate(c & apart, axis=2) & ~c.all(axis=2, keepdims=True)
            blocked |= (c & ~left).any(axis=(1, 2))
        return not bool(blocked.all())

    def _deaf(self, now_s: float, enc: Encounters
              ) -> tuple[np.ndarray, bool, tuple[str, ...]]:
        """The acknowledgement (docs/safety.md, A2): (k,) the UAVs near that have not listed
        us for ``ack_grace_s``, whether nobody near has (then we yield to all of them), and
        the ids of the first.

        Only a UAV whose flag is up is judged (we yield to the others anyway), and only on a
        fresh message: a silent UAV's last list is old news, and a silent spell neither starts
        nor restarts the count (on a lossy link a UAV flickers between fresh and silent)."""
        grace = self.params.ack_grace_s
        k = len(enc.ids)
        deaf = np.zeros(k, dtype=bool)
        if grace <= 0.0:
            return deaf, False, ()
        since: dict[str, float] = {}
        named: list[str] = []
        for j, (other, up, silent, hears) in enumerate(zip(
                enc.ids, enc.avoiding.tolist(), enc.silent_row.tolist(), enc.hears_us.tolist(),
                strict=True)):
            if not up:
                continue
            if not silent and hears:
                self._listed_s = now_s
                continue
            start = self._unlisted_since.get(other)
            if start is None and silent:
                continue
            since[other] = now_s if start is None else start
            if now_s - since[other] >= grace:
                deaf[j] = True
                named.append(other)
        self._unlisted_since = since
        unheard = bool(named) and (self._listed_s is None or now_s - self._listed_s >= grace)
        return deaf, unheard, tuple(named)

    def _climb(self, enc: Encounters, must_yield: np.ndarray, half_h: float,
               ahead_s: np.ndarray, climbed: float) -> tuple[float, bool, tuple[str, ...]]:
        """(docs/safety.md: A6 the layers, A4 the way up, A1 the plans as announced.) The lowest
        offset z + jΔz (j ≥ 1) clear of everyone we yield to, reached without crossing anyone,
        and clear of everyone else near too when such an offset exists; returns (offset,
        ceiling hit, the UAVs in the way).

        The way up is checked against every known UAV, not only those we yield to: at each
        predicted point (``ahead_s`` (m,) seconds from now) the climb is somewhere between the
        fastest one (from rest at ``climb_accel_mps2`` up to ``climb_speed_mps``) and the same
        ``climb_lag_s`` later, and no altitude of that band may conflict. Found in the 24 h
        campaign: a UAV yielding to a conflict 8 s ahead climbed two layers at once, straight
        through the layer of a UAV passing over it 1.6 s later. When every offset clear at the
        end is blocked on the way, the offset is held (the conflict is reported unresolved and
        the limits stay tightened) and the climb starts once the way is clear.

        A climb raised again while the last one is under way starts where the UAV is now
        (``climbed`` of the offset in force ``z``), not at ``z``: the slow edge of the band
        starts there (it reaches every height later), the fast edge at ``z`` (it cannot be
        higher); the band holds every height the UAV can be at. Without this the slow edge was
        too high, and a UAV passing while the climb was still under way went unseen (the gap
        noted in docs/campaign.md).

        A point already in conflict at ``z`` does not block the climb when we are level with
        (within :data:`LEVEL_M`) or above the other there (climbing parts us), but it does
        when the other is higher (climbing closes in on it). Found in the 24 h campaign with
        burst loss (trial 12): uav5, at +3 m, heard uav3 again after 5 s of silence, 1.2 s
        before they met, uav3 still climbing to its +6 m layer in its plan; the climb to
        +9 m that uav5 took to escape went through uav3 (0.39 m). It now holds at +3 m while
        uav3 climbs away.

        The way is checked against the plans as announced (``announced_xy``), not against a
        silent UAV's widening (rule 7). Found in the same campaign (trial 18): uav3, yielding
        to uav1 from 8 s ahead, waited 7.6 s for the way up to clear of uav4, silent and so
        possibly anywhere within a radius growing with its silence, and climbed only 0.1 s
        before uav1 passed (1.22 m). The end layer is still chosen clear of the widened
        plans.
        """
        prm = self.params
        z = self.z_offset_m
        if climbed < z - LEVEL_M:
            # A climb under way goes on only while its way up to the offset in force is clear:
            # it was checked when the offset was raised, not against those heard of since.
            # Found with every fault at once (0.5 h, seed 11, trial 2): uav5, raised to the
            # ceiling for a non-cooperative UAV (nothing was clear), then yielding to uav3
            # hovering 20 m above it, climbed on at 5 m/s straight into uav3 (0.39 m). It now
            # stops where it is (the offset it has climbed) and holds there until the way is
            # clear, as a climb that was never started would.
            way = _blocked_way(enc, np.array([z]), z, climbed, ahead_s, half_h, prm,
                               at=climbed)[0]
            if way.any():
                return climbed, False, tuple(i for i, b in zip(enc.ids, way, strict=True) if b)
        steps = math.floor((min(prm.max_offset_m, self.offset_ceiling_m) - z) / prm.dz_m + _EPS)
        sub = _subset(enc, must_yield)
        if steps < 1:
            lower = self._layer_below(enc, sub, half_h)
            return (z if lower is None else lower), True, ()
        candidates = z + prm.dz_m * np.arange(1, steps + 1)
        blocked_end = _conflicts(sub, candidates, half_h).any(axis=(1, 2))  # (c,)
        blocked_way = _blocked_way(enc, candidates, z, climbed, ahead_s, half_h, prm)  # (c, k)
        clear_way = ~blocked_way.any(axis=1)

        def in_the_way(c: int) -> tuple[str, ...]:
            return tuple(i for i, b in zip(enc.ids, blocked_way[c], strict=True) if b)

        good = np.flatnonzero(~blocked_end & clear_way)
        if good.size:
            # Preferred: a layer clear of everyone, not only of those we yield to. Ending in
            # the layer of a UAV that yields to us counts on it hearing us; found in the 24 h
            # campaign with burst loss (trial 24): uav3 climbed into uav4's layer while uav4,
            # which had not heard it for 3 s, flew on into it.
            clear_all = ~_conflicts(enc, candidates, half_h).any(axis=(1, 2))
            best = np.flatnonzero(~blocked_end & clear_way & clear_all)
            return float(candidates[best[0] if best.size else good[0]]), False, ()
        clear_end = np.flatnonzero(~blocked_end)
        if clear_end.size:  # reachable later: hold until the way is clear
            return z, False, in_the_way(clear_end[0])
        # Nothing is clear up to the ceiling. A lower layer may be (a UAV above us at the
        # ceiling, one below gone): down to the nearest one clear of those we yield to, over
        # a way down clear of everyone known (docs/safety.md, A6). Found with 16 UAVs under a
        # 30 m ceiling: a UAV holding short at its start, in the top layer, and the UAV whose
        # goal that start is, arriving in the same layer: neither could move.
        lower = self._layer_below(enc, sub, half_h)
        if lower is not None:
            return lower, True, ()
        # Else as high as the way allows.
        reachable = np.flatnonzero(clear_way)
        if reachable.size:
            return float(candidates[reachable[-1]]), True, ()
        return z, True, in_the_way(candidates.size - 1)

    def _layer_below(self, enc: Encounters, sub: Encounters, half_h: float) -> float | None:
        """The highest offset z − jΔz ≥ 0 (j ≥ 1) clear of ``sub`` (those we yield to) along
        the whole plan, whose way down from the offset in force meets nobody in ``enc`` at
        any point of the plan (as the release checks its way) but those it escapes from;
        None if there is none."""
        prm = self.params
        z = self.z_offset_m
        for j in range(1, math.floor(z / prm.dz_m + _EPS) + 1):
            o = z - j * prm.dz_m
            if _conflicts(sub, o, half_h).any():
                continue
            way = np.arange(o, z, 0.5 * LEVEL_M)
            # A point already in conflict at z with the other level or above is what the
            # descent escapes from (as a climb escapes from one level or below).
            escaping = _conflicts(enc, z, half_h) & (enc.dz_m + z <= LEVEL_M)
            if (_conflicts(enc, way, half_h) & ~escaping).any():
                return None  # the way down is blocked: no lower layer is reachable either
            return max(o, 0.0)
        return None

    def _release(self, now_s: float) -> None:
        """(docs/safety.md, A1: the way down.) Lower the offset at the release rate once the
        hysteresis has passed. Only called
        when the whole way down is clear of every known UAV, so no step can land in a conflict
        however long the time between updates."""
        prm = self.params
        if self.z_offset_m <= 0.0 or self._last_conflict_s is None:
            return
        start = self._last_conflict_s + prm.release_hysteresis_s
        if now_s < start:
            return
        since = start if self._last_update_s is None else max(self._last_update_s, start)
        self.z_offset_m = max(0.0, self.z_offset_m - prm.release_rate_mps * (now_s - since))


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
    """Height gained after ``t_s`` by the fastest climb: from rest at the lifted acceleration
    up to the lifted speed (the virtual UAV cannot climb faster)."""
    a, v = prm.climb_accel_mps2, prm.climb_speed_mps
    t_a = v / a
    return np.where(t_s < t_a, 0.5 * a * t_s**2, 0.5 * v * t_a + v * (t_s - t_a))


def _blocked_way(enc: Encounters, candidates: np.ndarray, z: float, climbed: float,
                 ahead_s: np.ndarray, half_h: float, prm: AvoidanceParams,
                 at: float | None = None) -> np.ndarray:
    """(c, k): whether the climb from the offset in force ``z`` (``climbed`` of it reached so
    far) to each of the ``candidates`` (c,) offsets meets each of the k known UAVs on the way,
    at the predicted points ``ahead_s`` (m,) seconds from now (see ``_climb``). ``at``: the
    offset the UAV is at, from which a climb escapes (default ``z``)."""
    fast = z + _climbed(np.maximum(ahead_s, 0.0), prm)  # (m,)
    slow = climbed + _climbed(np.maximum(ahead_s - prm.climb_lag_s, 0.0), prm)
    hi = np.minimum(fast[None, :], candidates[:, None])[:, None, :]  # (c, 1, m)
    lo = np.minimum(slow[None, :], candidates[:, None])[:, None, :]
    # While still climbing (lo < o; once there, the check at the end applies):
    # |dz + o'| ≤ h for some o' in [lo, hi]  ⇔  dz + hi ≥ −h and dz + lo ≤ h
    # A point already in conflict at the offset in force, with us level or above, is not
    # made worse by climbing (it is what the climb escapes from). With them above us it
    # is: the climb would close in on them (rule 6). "Level" is within the collision
    # distance: two plans at one height differ by centimetres, and holding there is
    # worse than climbing (found in the same campaign, trial 33).
    climbing = lo < candidates[:, None, None]
    here = z if at is None else at
    escaping = _conflicts(enc, here, half_h) & (enc.dz_m + here >= -LEVEL_M)
    # Along the plans as announced: where a silent UAV could have gone since does not
    # hold a climb away from a conflict we know of (rule 7).
    h = _half(enc, half_h)
    in_way = (enc.announced_xy & climbing & ~escaping
              & (enc.dz_m + hi >= -h) & (enc.dz_m + lo <= h))
    return in_way.any(axis=2)
