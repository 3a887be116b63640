"""The height-offset strategy's law (:class:`~uavmpc.avoidance.strategy.HeightOffsetStrategy`)
as compiled kernels over rows: each UAV's state one row of a :class:`StrategyRows`, a round's
decisions one call of :func:`decide_rows` for every UAV that decides (docs/scale.md).

A strategy object is a view of its row: it packs what it is handed (its
:class:`~uavmpc.avoidance.encounters.Encounters`) into the arrays below and calls the same
kernel for its one row; a world's avoidance round hands the kernel the encounters it found
for all its UAVs at once (:func:`uavmpc.avoidance.round.avoidance_round`). Every rule and the safety
argument behind it is documented on the strategy (docs/safety.md: A1 … A7); the comments here
only say where the arrays differ from the objects.

Encounters as rows: a call's encounter rows E (one per sender near a plan, for every plan:
each deciding UAV's own, then its probes while it holds short) are grouped by plan, plan f's
rows ``e_start[f]`` … ``e_start[f + 1]`` − 1 (see
:class:`~uavmpc.avoidance.encounters.EncounterOutputs`), and each one carries its sender's
column of the state (``e_col``: whom the acknowledgement's clock and the decision's names
belong to), priority, flag, and whether its id sorts before the deciding UAV's own (a tie of
priorities, which a valid set-up never has, is broken by id).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from uavmpc.jit import kernel

#: Two plans closer in height than this count as level for a climb's way check (rule 6): the
#: collision distance of the campaigns, so "above us" means above by more than a collision.
LEVEL_M = 1.0
#: A plan whose points all lie within this of its first one, horizontally, stands still [m]
#: (:attr:`~uavmpc.avoidance.strategy.AvoidanceDecision.stuck`): a hold's creep at
#: :data:`~uavmpc.avoidance.strategy.HOLD_SPEED_MPS` over the horizon is a tenth of it.
STANDING_M = 1.0
#: A plan that leaves a conflict behind may first bring the pair this much nearer in 3-D [m]
#: (:func:`_in_the_way`): the other's creep while it holds, our start from rest.
LEAVE_TOL_M = 0.1
#: Relative slack for "offset is a multiple of Δz that fits under the ceiling" (round-off).
EPS = 1e-9

#: The columns of :attr:`StrategyRows.params` (:class:`~uavmpc.avoidance.strategy.
#: AvoidanceParams`' fields of the same names).
P_HEIGHT, P_DZ, P_MAX_OFFSET, P_RELEASE_RATE, P_HYSTERESIS, P_CLIMB_SPEED, P_CLIMB_ACCEL, \
    P_CLIMB_LAG, P_ACK_GRACE, P_HOLD_DELAY = range(10)
N_PARAMS = 10

#: The masks a decision returns per encounter row (:func:`decide_rows`' ``masks``): the
#: decision's ``conflicts``, ``yielding_to``, ``unresolved``, ``waiting_for`` and ``deaf``.
M_CONFLICT, M_YIELD, M_UNRESOLVED, M_WAITING, M_DEAF = range(5)
N_MASKS = 5
#: The flags a decision returns per deciding UAV (:func:`decide_rows`' ``flags``): its
#: ``avoiding``, whether its limits are tightened (its ``horizontal_scale`` and climb limits),
#: ``ceiling_hit``, ``unheard``, ``holding`` and ``stuck``.
F_AVOIDING, F_TIGHT, F_CEILING, F_UNHEARD, F_HOLDING, F_STUCK = range(6)
N_FLAGS = 6
#: What became of a deciding UAV (:func:`decide_rows`' ``kind``): at rest (steered by the calm
#: decision), the decision its last one was (field for field), or a new one.
CALM_KIND, SAME_KIND, NEW_KIND = 0, 1, 2
#: How many numbers a decision's key holds at most (:attr:`StrategyRows.key`); a longer one
#: is never taken for the last one (only a new decision object is made).
KEY_LEN = 64


class StrategyRows(NamedTuple):
    """The state of N height-offset strategies, one row each (SI units; NaN: never).

    Attributes:
        params: (N, :data:`N_PARAMS`) its parameters (columns ``P_*``).
        ceiling_m: (N,) the offset ceiling over its mission (``limit_offset``; inf: none).
        z_offset_m: (N,) the offset in force.
        listed_s: (N,) when a UAV near it last listed it.
        last_conflict_s, last_update_s: (N,) its last conflict, its last update.
        climb_from_m, climb_since_s: (N,) where and when the climb under way started (the
            offset reached then, and the time; NaN: none), from rest at the lifted limits:
            it can be no higher than that climb.
        stuck: (N,) bool :attr:`~uavmpc.avoidance.strategy.AvoidanceDecision.stuck` kept.
        holding: (N,) bool it holds short, with the plan from before the hold: its first
            ``hold_n`` (N,) times ``hold_t_s`` (N, m) and positions ``hold_m`` (N, m, 3).
        unlisted_s: (N, C) since when each column's UAV near it has not listed it.
        key: (N, :data:`KEY_LEN`) its last decision's field values (:func:`_key`), the first
            ``key_n`` (N,) (−1: none).
    """

    params: np.ndarray
    ceiling_m: np.ndarray
    z_offset_m: np.ndarray
    listed_s: np.ndarray
    last_conflict_s: np.ndarray
    last_update_s: np.ndarray
    climb_from_m: np.ndarray
    climb_since_s: np.ndarray
    stuck: np.ndarray
    holding: np.ndarray
    hold_n: np.ndarray
    hold_t_s: np.ndarray
    hold_m: np.ndarray
    unlisted_s: np.ndarray
    key: np.ndarray
    key_n: np.ndarray

    @classmethod
    def empty(cls, n: int, points: int = 0, cols: int = 0) -> StrategyRows:
        rows = cls(np.zeros((n, N_PARAMS)), np.full(n, math.inf), np.zeros(n), np.zeros(n),
                   np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.bool_),
                   np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.int64),
                   np.zeros((n, points)), np.zeros((n, points, 3)), np.zeros((n, cols)),
                   np.zeros((n, KEY_LEN)), np.zeros(n, dtype=np.int64))
        for i in range(n):
            reset_row(rows, i)
        return rows

    def grown(self, points: int, cols: int) -> StrategyRows:
        """These rows with room for plans of ``points`` points and ``cols`` columns (the
        same object when there is room already)."""
        n, p0 = self.hold_t_s.shape
        c0 = self.unlisted_s.shape[1]
        if points <= p0 and cols <= c0:
            return self
        p, c = max(points, p0), max(cols, c0)
        hold_t, hold_m = np.zeros((n, p)), np.zeros((n, p, 3))
        hold_t[:, :p0], hold_m[:, :p0] = self.hold_t_s, self.hold_m
        unlisted = np.full((n, c), np.nan)
        unlisted[:, :c0] = self.unlisted_s
        return self._replace(hold_t_s=hold_t, hold_m=hold_m, unlisted_s=unlisted)


def reset_row(rows: StrategyRows, i: int) -> None:
    """Row ``i`` forgets its offset and its conflict history (its parameters and ceiling
    stay)."""
    rows.z_offset_m[i] = 0.0
    rows.listed_s[i] = rows.last_conflict_s[i] = rows.last_update_s[i] = np.nan
    rows.climb_from_m[i] = rows.climb_since_s[i] = np.nan
    rows.stuck[i] = rows.holding[i] = False
    rows.hold_n[i] = 0
    rows.unlisted_s[i] = np.nan
    rows.key_n[i] = -1


@kernel
def in_cylinder(near_xy: bool, dz_m: float, offset_m: float, half_m: float) -> bool:
    """The cylinder (SPEC §5.2) at one point: horizontally near, and our height raised by
    ``offset_m`` within ``half_m`` of theirs (``dz_m``: ours minus theirs)."""
    return near_xy and abs(dz_m + offset_m) <= half_m


@kernel
def conflict_points(near_xy: np.ndarray, dz_m: np.ndarray, widen_v_m: np.ndarray,
                    half_height_m: float, offsets_m: np.ndarray, out: np.ndarray) -> None:
    """Whether each of k encounters' m points (horizontally near: ``near_xy`` (k, m); our
    height minus theirs: ``dz_m`` (k, m)) is in the cylinder (:func:`in_cylinder`) with our
    plan raised by each of ``offsets_m`` (c,), its half height ``half_height_m`` widened by
    the pair's ``widen_v_m`` (k,) (docs/safety.md, A3). Into ``out`` (c, k, m)."""
    for c in range(offsets_m.shape[0]):
        for j in range(near_xy.shape[0]):
            h = half_height_m + widen_v_m[j]
            for p in range(near_xy.shape[1]):
                out[c, j, p] = in_cylinder(near_xy[j, p], dz_m[j, p], offsets_m[c], h)


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
            if in_cylinder(near_xy[j, p], dz_m[j, p], offset_m, h):
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


@kernel
def outranks(priority: int, own_priority: int, before_us: bool) -> bool:
    """A sender of ``priority`` outranks us: a lower number; equal numbers, which a valid
    set-up never has, broken by id (``before_us``: its id sorts before ours)."""
    return priority < own_priority or (priority == own_priority and before_us)


@kernel
def climb_height(t_s: float, accel_mps2: float, speed_mps: float) -> float:
    """Height gained after ``t_s`` by the fastest climb: from rest at the lifted acceleration
    up to the lifted speed (the virtual UAV cannot climb faster)."""
    t_a = speed_mps / accel_mps2
    if t_s < t_a:
        return 0.5 * accel_mps2 * (t_s * t_s)
    return 0.5 * speed_mps * t_a + speed_mps * (t_s - t_a)


@kernel
def _lower(a: float, b: float) -> float:
    """Python's ``min(a, b)`` (``a`` unless ``b`` is smaller)."""
    return b if b < a else a


@kernel
def _higher(a: float, b: float) -> float:
    """Python's ``max(a, b)`` (``a`` unless ``b`` is larger)."""
    return b if b > a else a


class EncounterRows(NamedTuple):
    """Encounter rows (E of them, m points; see the module's note): each one's column
    ``col``, whether it is a silent UAV's last plan ``silent``, its points near (``near``)
    and near as announced (``announced``) (E, m) bool, our height minus theirs ``dz`` and
    the horizontal distance ``dxy`` (E, m) [m], whether its message lists us ``hears``, its
    half height's widening ``widen_v`` [m], its sender's ``priority`` and flag
    (``avoiding``), and whether its id sorts before ours ``before_us``
    (:class:`~uavmpc.avoidance.encounters.Encounters` field by field)."""

    col: np.ndarray
    silent: np.ndarray
    near: np.ndarray
    announced: np.ndarray
    dz: np.ndarray
    dxy: np.ndarray
    hears: np.ndarray
    widen_v: np.ndarray
    priority: np.ndarray
    avoiding: np.ndarray
    before_us: np.ndarray


@kernel(allocates=True)
def _plan_rows(e: EncounterRows, lo: int, hi: int) -> EncounterRows:
    """Plan rows ``lo`` … ``hi`` − 1 of ``e`` (views)."""
    return EncounterRows(e.col[lo:hi], e.silent[lo:hi], e.near[lo:hi], e.announced[lo:hi],
                         e.dz[lo:hi], e.dxy[lo:hi], e.hears[lo:hi], e.widen_v[lo:hi],
                         e.priority[lo:hi], e.avoiding[lo:hi], e.before_us[lo:hi])


@kernel
def _conflicts_any(enc: EncounterRows, keep: np.ndarray, offset_m: float, half_h: float) -> bool:
    """Some point of an encounter in ``keep`` (k,) is in the cylinder at ``offset_m``."""
    for j in range(enc.near.shape[0]):
        if not keep[j]:
            continue
        h = half_h + enc.widen_v[j]
        for p in range(enc.near.shape[1]):
            if in_cylinder(enc.near[j, p], enc.dz[j, p], offset_m, h):
                return True
    return False


@kernel(allocates=True)
def _blocked_way(enc: EncounterRows, candidates: np.ndarray, z: float, climbed: float,
                 ahead_s: np.ndarray, half_h: float, prm: np.ndarray, here: float,
                 from_m: float, since_s: float, out: np.ndarray) -> None:
    """(docs/safety.md, A4: the way up.) Into ``out`` (c, k): whether the climb from the
    offset in force ``z`` (``climbed`` of it reached so far) to each of ``candidates`` (c,)
    meets each encounter on the way, at the points ``ahead_s`` (m,) seconds from now;
    ``here``: the offset the UAV is at, from which a climb escapes; ``from_m``: where the
    climb under way started, ``since_s`` seconds ago (NaN: none under way)."""
    m = ahead_s.shape[0]
    a, v, lag = prm[P_CLIMB_ACCEL], prm[P_CLIMB_SPEED], prm[P_CLIMB_LAG]
    fast = np.empty(m)
    slow = np.empty(m)
    for p in range(m):
        t = ahead_s[p]
        fast[p] = z + climb_height(t if t > 0.0 else 0.0, a, v)
        # A climb under way is no higher than the fastest one from where and when it
        # started: the same band in every round as in the one that chose it. Bounded by
        # ``z`` alone, a climb re-checked a round after it was chosen counted itself at its
        # end already, found its way blocked and stopped, to be chosen again in the next
        # round (a grid of 16, seed 1: raised and cancelled every other round).
        if not math.isnan(from_m):
            fast[p] = _lower(fast[p], from_m + climb_height(_higher(t + since_s, 0.0), a, v))
        t = ahead_s[p] - lag
        slow[p] = climbed + climb_height(t if t > 0.0 else 0.0, a, v)
    k = enc.near.shape[0]
    for c in range(candidates.shape[0]):
        cand = candidates[c]
        for j in range(k):
            h = half_h + enc.widen_v[j]
            hit = False
            for p in range(m):
                hi = cand if cand < fast[p] else fast[p]
                lo = cand if cand < slow[p] else slow[p]
                # While still climbing (lo < o; once there, the check at the end applies):
                # |dz + o'| ≤ h for some o' in [lo, hi]  ⇔  dz + hi ≥ −h and dz + lo ≤ h.
                # A point already in conflict at the offset the UAV is at, with us level or
                # above, is not made worse by climbing (it is what the climb escapes from);
                # with them above us it is (rule 6). "Level" is within the collision
                # distance: two plans at one height differ by centimetres, and holding there
                # is worse than climbing (found in the same campaign, trial 33). Along the
                # plans as announced: where a silent UAV could have gone since does not hold
                # a climb away from a conflict we know of (rule 7).
                if not (lo < cand) or not enc.announced[j, p]:
                    continue
                d = enc.dz[j, p]
                if in_cylinder(enc.near[j, p], d, here, h) and d + here >= -LEVEL_M:
                    continue
                if d + hi >= -h and d + lo <= h:
                    hit = True
                    break
            out[c, j] = hit


@kernel(allocates=True)
def _layer_below(enc: EncounterRows, must: np.ndarray, z: float, half_h: float,
                 prm: np.ndarray) -> float:
    """The highest offset z − jΔz ≥ 0 (j ≥ 1) clear of those in ``must`` (k,) (those we
    yield to) along the whole plan, whose way down from the offset in force ``z`` meets
    nobody in ``enc`` at any point of the plan (as the release checks its way) but those it
    escapes from; NaN if there is none."""
    dz = prm[P_DZ]
    k, m = enc.near.shape
    for j in range(1, math.floor(z / dz + EPS) + 1):
        o = z - j * dz
        if _conflicts_any(enc, must, o, half_h):
            continue
        # The way down: numpy's ``arange(o, z, 0.5 * LEVEL_M)``, value for value.
        step = 0.5 * LEVEL_M
        n_way = math.ceil((z - o) / step)
        way = np.empty(max(n_way, 0))
        if n_way > 0:
            way[0] = o
        if n_way > 1:
            second = o + step
            delta = second - o
            way[1] = second
            for w in range(2, n_way):
                way[w] = o + w * delta
        for e in range(k):
            h = half_h + enc.widen_v[e]
            for p in range(m):
                d = enc.dz[e, p]
                # Escaping: a descent escapes from one level or above, surely so: found by
                # the falsifier (single-band GNSS), a UAV held 9 m up took one 1.3 m above
                # it, within the pair's vertical uncertainty (7.2 m), as above, and
                # descended onto it (1.64 m).
                if in_cylinder(enc.near[e, p], d, z, h) and d + z <= LEVEL_M - enc.widen_v[e]:
                    continue
                for w in range(way.shape[0]):
                    if in_cylinder(enc.near[e, p], d, way[w], h):
                        return np.nan  # the way down is blocked: no lower layer either
        return 0.0 if o < 0.0 else o
    return np.nan


@kernel(allocates=True)
def _climb_blocked(enc: EncounterRows, half_h: float, ahead_s: np.ndarray, climbed: float,
                   z: float, prm: np.ndarray, from_m: float, since_s: float,
                   waiting: np.ndarray) -> bool:
    """(docs/safety.md, A4.) Whether a climb under way (``climbed`` of the offset in force
    ``z``, started at ``from_m`` ``since_s`` ago) meets someone on its way up
    (:func:`_blocked_way`); the UAVs in the way into
    ``waiting`` (k,), every other entry False. Then it stops at what it has climbed."""
    k = enc.near.shape[0]
    for j in range(k):
        waiting[j] = False
    if not climbed < z - LEVEL_M:
        return False
    way = np.empty((1, k), dtype=np.bool_)
    _blocked_way(enc, np.array([z]), z, climbed, ahead_s, half_h, prm, climbed, from_m,
                 since_s, way)
    for j in range(k):
        waiting[j] = way[0, j]
    return way[0].any()


@kernel(allocates=True)
def _climb(enc: EncounterRows, must: np.ndarray, half_h: float, ahead_s: np.ndarray,
           climbed: float, z: float, ceiling: float, prm: np.ndarray, from_m: float,
           since_s: float, waiting: np.ndarray) -> tuple[float, bool]:
    """(docs/safety.md: A6 the layers, A4 the way up, A1 the plans as announced.) The lowest
    offset z + jΔz (j ≥ 1) clear of everyone we yield to, reached without crossing anyone,
    and clear of everyone else near too when such an offset exists (those we yield to:
    ``must`` (k,)); returns (offset, ceiling hit), the UAVs in the way into ``waiting`` (k,).

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
    k = enc.near.shape[0]
    dz = prm[P_DZ]
    if _climb_blocked(enc, half_h, ahead_s, climbed, z, prm, from_m, since_s, waiting):
        return climbed, False
    steps = math.floor((_lower(prm[P_MAX_OFFSET], ceiling) - z) / dz + EPS)
    if steps < 1:
        lower = _layer_below(enc, must, z, half_h, prm)
        return (z if math.isnan(lower) else lower), True
    candidates = np.empty(steps)
    for c in range(steps):
        candidates[c] = z + dz * float(c + 1)
    blocked_end = np.empty(steps, dtype=np.bool_)
    for c in range(steps):
        blocked_end[c] = _conflicts_any(enc, must, candidates[c], half_h)
    blocked_way = np.empty((steps, k), dtype=np.bool_)
    _blocked_way(enc, candidates, z, climbed, ahead_s, half_h, prm, z, from_m, since_s,
                 blocked_way)
    clear_way = np.empty(steps, dtype=np.bool_)
    for c in range(steps):
        clear_way[c] = not blocked_way[c].any()
    everyone = np.ones(k, dtype=np.bool_)
    first_good = -1
    for c in range(steps):
        if not blocked_end[c] and clear_way[c]:
            if first_good < 0:
                first_good = c
            # Preferred: a layer clear of everyone, not only of those we yield to.
            if not _conflicts_any(enc, everyone, candidates[c], half_h):
                return candidates[c], False
    if first_good >= 0:
        return candidates[first_good], False
    for c in range(steps):
        if not blocked_end[c]:  # reachable later: hold until the way is clear
            for j in range(k):
                waiting[j] = blocked_way[c, j]
            return z, False
    lower = _layer_below(enc, must, z, half_h, prm)
    if not math.isnan(lower):
        return lower, True
    for c in range(steps - 1, -1, -1):
        if clear_way[c]:
            return candidates[c], True
    for j in range(k):
        waiting[j] = blocked_way[steps - 1, j]
    return z, True


@kernel
def _standing_still(pos: np.ndarray, until: int) -> bool:
    """The plan ``pos`` (m, 3) stays within :data:`STANDING_M` of its first point up to
    point ``until`` (included)."""
    best = -math.inf
    for p in range(min(until + 1, pos.shape[0])):
        d0 = pos[p, 0] - pos[0, 0]
        d1 = pos[p, 1] - pos[0, 1]
        best = max(best, d0 * d0 + d1 * d1)
    return best <= STANDING_M * STANDING_M


@kernel
def _climb_from(st: StrategyRows, i: int, climbed: float, z: float) -> float:
    """Where the climb under way to the offset ``z`` started (``climbed`` of it reached so
    far), NaN when none is under way."""
    return st.climb_from_m[i] if climbed < z - LEVEL_M else np.nan


@kernel
def _climb_started(st: StrategyRows, i: int, z_before: float, climbed: float,
                   now_s: float) -> None:
    """Row ``i``'s offset was just set over ``z_before``: a climb starts now from
    ``climbed`` unless one was under way already (then it keeps its start)."""
    if st.z_offset_m[i] > z_before and not climbed < z_before - LEVEL_M:
        st.climb_from_m[i] = climbed
        st.climb_since_s[i] = now_s


@kernel
def _must_respect(enc: EncounterRows, j: int, own_priority: int, unheard: bool,
                  deaf_col: np.ndarray) -> bool:
    """Encounter ``j`` is one we yield to: its flag is down, it outranks us, it has not
    heard us (``deaf_col``: this round's deaf columns), or nobody hears us (``unheard``)."""
    return (not enc.avoiding[j] or outranks(enc.priority[j], own_priority, enc.before_us[j])
            or unheard or deaf_col[enc.col[j]])


@kernel
def _in_the_way(probe: EncounterRows, j: int, offset_m: float, half_h: float) -> bool:
    """Encounter ``j`` of a plan we would fly (a probe) is in its way at ``offset_m``: in
    conflict somewhere, but for a conflict from the first point on that ends for good while
    we only go away from it in 3-D (never closer vertically, and horizontally closer only
    to one whose flag is down, which does not make way, while the pair stays at least as far
    apart as now, less :data:`LEAVE_TOL_M`), which flying that plan leaves behind.

    Left behind: a UAV at the hold point itself, parked at its goal there, does not hold us.
    Found with 32 UAVs under a 30 m ceiling: a UAV held beside the one whose goal its start
    was, each waiting for the other. But one that comes closer first is passing through us:
    found in the lossy 16-UAV antipodal swap (seed 0), a UAV held 4 m from a higher priority
    crossing its way went on every other round and passed it at 1.24 m. Away in 3-D: found in
    the vertical stack swap (2 × 5), uav2, held under uav3 in one column, went on every other
    round (horizontally it only drew away), and each time its mission's climb carried it on
    up into uav3 (0.29 m). Horizontally closer while going away vertically: found in the
    clean antipodal swap of 16 (seed 0), uav12, held 1.85 m under uav16 by their plans
    (stuck at the top layer), would have descended away from it to its own layer, but its
    way there first drew 0.28 m nearer horizontally (4.35 → 4.07 m, 4.7 m apart in 3-D);
    it held to the end of the run, and so did uav16, which waited for it."""
    h = half_h + probe.widen_v[j]
    m = probe.near.shape[1]
    all_hit = True
    for p in range(m):
        if not in_cylinder(probe.near[j, p], probe.dz[j, p], offset_m, h):
            all_hit = False
            break
    run = True  # logical_and.accumulate(conflict & apart)
    d0 = math.hypot(probe.dxy[j, 0], probe.dz[j, 0] + offset_m)
    for p in range(m):
        hit = in_cylinder(probe.near[j, p], probe.dz[j, p], offset_m, h)
        dz_p = abs(probe.dz[j, p] + offset_m)
        apart = p == 0 or (
            dz_p >= abs(probe.dz[j, p - 1] + offset_m) - EPS
            and (probe.dxy[j, p] >= probe.dxy[j, p - 1]
                 or (not probe.avoiding[j]
                     and math.hypot(probe.dxy[j, p], dz_p) >= d0 - LEAVE_TOL_M)))
        run = run and hit and apart
        if hit and not (run and not all_hit):
            return True
    return False


@kernel(allocates=True)
def _way_clear(e: EncounterRows, e_start: np.ndarray, q_lo: int, q_hi: int, own_priority: int,
               deaf_col: np.ndarray, unheard: bool, z: float, ceiling: float, prm: np.ndarray,
               way_up: bool, ahead_s: np.ndarray, climbed: float, from_m: float,
               since_s: float) -> float:
    """(docs/safety.md, A6.) The lowest offset from ``z`` up to the ceiling (only ``z``
    without ``way_up``: the climb to any other is blocked) clear, along every probe (plans
    ``q_lo`` … ``q_hi`` − 1), of everyone we yield to (``deaf_col``: this round's deaf
    columns), and, above ``z``, whose way up from ``climbed`` (the climb under way from
    ``from_m`` ``since_s`` ago, :func:`_blocked_way`) meets nobody along the probes; NaN
    when there is none."""
    dz = prm[P_DZ]
    half_h = 0.5 * prm[P_HEIGHT]
    top = _lower(prm[P_MAX_OFFSET], ceiling)
    n_c = math.floor(_higher(top - z, 0.0) / dz + EPS) + 1 if way_up else 1
    blocked = np.zeros(n_c, dtype=np.bool_)
    cands = np.empty(n_c)
    for c in range(n_c):
        cands[c] = z + dz * float(c)
    for q in range(q_lo, q_hi):
        probe = _plan_rows(e, e_start[q], e_start[q + 1])
        k = probe.near.shape[0]
        # A layer above ends the hold only if the climb to it, which going on takes, meets
        # nobody on its way: the climb checked as in any other round. Found in a grid of 16
        # (seed 1): a hold ended for a layer clear at its end whose way up was blocked; the
        # UAV went on at its offset, met the one it held for in the next round and held
        # again, every other round, creeping closer between the holds.
        if n_c > 1:
            way = np.empty((n_c - 1, k), dtype=np.bool_)
            _blocked_way(probe, cands[1:], z, climbed, ahead_s, half_h, prm, z, from_m,
                         since_s, way)
            for c in range(1, n_c):
                if way[c - 1].any():
                    blocked[c] = True
        for j in range(k):
            if not _must_respect(probe, j, own_priority, unheard, deaf_col):
                continue
            for c in range(n_c):
                if not blocked[c] and _in_the_way(probe, j, cands[c], half_h):
                    blocked[c] = True
    for c in range(n_c):
        if not blocked[c]:
            return cands[c]
    return np.nan


@kernel(allocates=True)
def _hold_short(st: StrategyRows, i: int, start: bool, times: np.ndarray, pos: np.ndarray,
                has_pos: bool, e: EncounterRows, e_start: np.ndarray, q_lo: int, q_hi: int,
                has_probes: bool, own_priority: int, deaf_col: np.ndarray, unheard: bool,
                way_up: bool, now_s: float, ahead_s: np.ndarray, climbed: float) -> bool:
    """(docs/safety.md, A6: time as well as height.) Whether we hold short after this
    round. A hold starts (``start``: a conflict with one we yield to is left unresolved)
    with the plan it interrupts; it ends once some layer, at or above the
    offset in force, is clear of them along every probe (:meth:`~uavmpc.avoidance.
    HeightOffsetStrategy.hold_probes`, plans ``q_lo`` … ``q_hi`` − 1): going on
    now or up to ``hold_delay_s`` later meets none of them (a layer above only with
    ``way_up``: the climb to it is not waiting for anyone; found in the vertical stack swap,
    a hold that ended for a layer its climb could not reach began again in the next round,
    and the mission's climb went on between the holds). Going on for a layer above takes it:
    the offset is raised to it, whose way up :func:`_way_clear` found clear. The order is the
    priorities' (a total order): the highest never holds, and each holds only for higher
    ones."""
    if not st.holding[i]:
        if start and st.params[i, P_HOLD_DELAY] > 0.0 and has_pos:
            m = times.shape[0]
            st.holding[i] = True
            st.hold_n[i] = m
            for p in range(m):
                st.hold_t_s[i, p] = times[p]
                for ax in range(3):
                    st.hold_m[i, p, ax] = pos[p, ax]
        return st.holding[i]
    if not has_probes:
        return True
    z = st.z_offset_m[i]
    layer = _way_clear(e, e_start, q_lo, q_hi, own_priority, deaf_col, unheard, z,
                       st.ceiling_m[i], st.params[i], way_up, ahead_s, climbed,
                       _climb_from(st, i, climbed, z), now_s - st.climb_since_s[i])
    if not math.isnan(layer):
        st.holding[i] = False
        st.hold_n[i] = 0
        if layer > z:
            st.z_offset_m[i] = layer
            _climb_started(st, i, z, climbed, now_s)
    return st.holding[i]


@kernel
def _release(st: StrategyRows, i: int, now_s: float) -> None:
    """(docs/safety.md, A1: the way down.) Lower the offset at the release rate once the
    hysteresis has passed. Only called
    when the whole way down is clear of every known UAV, so no step can land in a conflict
    however long the time between updates."""
    z = st.z_offset_m[i]
    last = st.last_conflict_s[i]
    if z <= 0.0 or math.isnan(last):
        return
    start = last + st.params[i, P_HYSTERESIS]
    if now_s < start:
        return
    upd = st.last_update_s[i]
    since = start if math.isnan(upd) else _higher(upd, start)
    st.z_offset_m[i] = _higher(0.0, z - st.params[i, P_RELEASE_RATE] * (now_s - since))


@kernel
def rest_row(st: StrategyRows, i: int, now_s: float) -> bool:
    """(:meth:`~uavmpc.avoidance.EncounterStrategy.rest`.) At rest: no offset, no hold, no
    conflict within the hysteresis; it then forgets who had not listed it."""
    last = st.last_conflict_s[i]
    if (st.z_offset_m[i] != 0.0 or st.holding[i]
            or (not math.isnan(last) and now_s - last < st.params[i, P_HYSTERESIS])):
        return False
    st.unlisted_s[i, :] = np.nan
    st.stuck[i] = False
    return True


@kernel(allocates=True)
def _deaf(st: StrategyRows, i: int, now_s: float, enc: EncounterRows, deaf: np.ndarray
          ) -> bool:
    """The acknowledgement (docs/safety.md, A2): into ``deaf`` (k,) the UAVs near that have
    not listed row ``i`` for ``ack_grace_s``; returns whether nobody near has (then it
    yields to all of them). Its clock of each UAV not judged now is forgotten.

    Only a UAV whose flag is up is judged (we yield to the others anyway), and only on a
    fresh message: a silent UAV's last list is old news, and a silent spell neither starts
    nor restarts the count (on a lossy link a UAV flickers between fresh and silent)."""
    grace = st.params[i, P_ACK_GRACE]
    k = enc.near.shape[0]
    for j in range(k):
        deaf[j] = False
    if grace <= 0.0:
        return False
    since = np.full(k, np.nan)
    named = False
    for j in range(k):
        if not enc.avoiding[j]:
            continue
        if not enc.silent[j] and enc.hears[j]:
            st.listed_s[i] = now_s
            continue
        start = st.unlisted_s[i, enc.col[j]]
        if math.isnan(start) and enc.silent[j]:
            continue
        since[j] = now_s if math.isnan(start) else start
        if now_s - since[j] >= grace:
            deaf[j] = True
            named = True
    st.unlisted_s[i, :] = np.nan
    for j in range(k):
        if not math.isnan(since[j]):
            st.unlisted_s[i, enc.col[j]] = since[j]
    listed = st.listed_s[i]
    return named and (math.isnan(listed) or now_s - listed >= grace)


@kernel
def _key(z: float, first_s: float, flags: np.ndarray, enc: EncounterRows, masks: np.ndarray,
         s_col: np.ndarray, out: np.ndarray) -> int:
    """A decision's field values as numbers into ``out``: its offset, first conflict (NaN
    none: a flag and a value), flags, then each name list (``masks`` (k, 5) over the
    encounters' columns, and the silent columns ``s_col``) as its length and columns.
    Returns how many, or −1 when they do not fit."""
    n = 0
    out[0] = z
    out[1] = 0.0 if math.isnan(first_s) else 1.0
    out[2] = 0.0 if math.isnan(first_s) else first_s
    n = 3
    for f in range(flags.shape[0]):
        out[n] = 1.0 if flags[f] else 0.0
        n += 1
    for mk in range(masks.shape[1]):
        count = 0
        for j in range(masks.shape[0]):
            if masks[j, mk]:
                count += 1
        if n + 1 + count > out.shape[0]:
            return -1
        out[n] = count
        n += 1
        for j in range(masks.shape[0]):
            if masks[j, mk]:
                out[n] = enc.col[j]
                n += 1
    if n + 1 + s_col.shape[0] > out.shape[0]:
        return -1
    out[n] = s_col.shape[0]
    n += 1
    for j in range(s_col.shape[0]):
        out[n] = s_col[j]
        n += 1
    return n


@kernel(allocates=True)
def _decide_one(st: StrategyRows, i: int, now_s: float, times: np.ndarray, pos: np.ndarray,
                has_pos: bool, climbed_m: float, own_priority: int, e: EncounterRows,
                e_start: np.ndarray, f: int, q_lo: int, q_hi: int, has_probes: bool,
                n_silent: int, deaf_col: np.ndarray, flags: np.ndarray, masks: np.ndarray
                ) -> tuple[int, float, float]:
    """Row ``i``'s decision from plan ``f``'s encounters (:meth:`~uavmpc.avoidance.
    HeightOffsetStrategy.decide`; nobody near: only the release runs). Returns
    (:data:`CALM_KIND` or not, the offset, the first conflict's time from now (NaN: none));
    its flags into ``flags`` (7,), its masks into ``masks`` (k, 5)."""
    prm = st.params[i]
    half_h = 0.5 * prm[P_HEIGHT]
    hyst = prm[P_HYSTERESIS]
    for fl in range(flags.shape[0]):
        flags[fl] = False
    masks[:, :] = False
    lo, hi = e_start[f], e_start[f + 1]
    k = hi - lo
    ahead = np.empty(times.shape[0])
    for p in range(times.shape[0]):
        ahead[p] = times[p] - now_s
    z_start = st.z_offset_m[i]
    climbed = z_start if math.isnan(climbed_m) else _lower(climbed_m, z_start)
    if k == 0:  # nobody near: only the release runs (and a hold goes on until it clears)
        if n_silent == 0 and rest_row(st, i, now_s):
            return CALM_KIND, 0.0, np.nan
        st.unlisted_s[i, :] = np.nan
        if not st.holding[i]:
            _release(st, i, now_s)
        st.last_update_s[i] = now_s
        holding = _hold_short(st, i, False, times, pos, has_pos, e, e_start, q_lo, q_hi,
                              has_probes, own_priority, deaf_col, False, True, now_s, ahead,
                              climbed)
        st.stuck[i] = False
        last = st.last_conflict_s[i]
        recent = holding or (not math.isnan(last) and now_s - last < hyst)
        z = st.z_offset_m[i]
        flags[F_AVOIDING] = recent or z > 0.0
        flags[F_TIGHT] = recent
        flags[F_HOLDING] = holding
        return NEW_KIND, z, np.nan
    # Silent UAVs count at their last plans (widened by how far they can have left them):
    # a pair that cannot hear each other still resolves its conflict.
    enc = _plan_rows(e, lo, hi)
    must = np.empty(k, dtype=np.bool_)
    rank = np.empty(k, dtype=np.bool_)
    for j in range(k):
        rank[j] = outranks(enc.priority[j], own_priority, enc.before_us[j])
        must[j] = not enc.avoiding[j] or rank[j]
    deaf = masks[:, M_DEAF]
    unheard = _deaf(st, i, now_s, enc, deaf)
    any_deaf = deaf.any()
    if any_deaf:
        for j in range(k):
            must[j] = must[j] or deaf[j] or unheard
            if deaf[j]:
                deaf_col[enc.col[j]] = True
    hit_start = masks[:, M_CONFLICT]
    first = conflict_rows(enc.near, enc.dz, enc.widen_v, half_h, z_start, hit_start)
    any_start = first >= 0
    yield_hit = masks[:, M_YIELD]
    any_yield = False
    for j in range(k):
        yield_hit[j] = hit_start[j] and must[j]
        any_yield = any_yield or yield_hit[j]
    ceiling_hit = False
    from_m = _climb_from(st, i, climbed, z_start)
    since_s = now_s - st.climb_since_s[i]
    # A hold stops in 3-D: a held UAV takes no new layer but the one its hold ends for
    # (:func:`_hold_short`, whose way up is checked as a climb's).
    if any_start and any_yield and not st.holding[i]:
        # Found in the lossy 24 h campaign (trial 78): a UAV that had missed two messages of
        # another climbed into its layer. A new offset must be clear of the silent ones too.
        z_new, ceiling_hit = _climb(enc, must, half_h, ahead, climbed, z_start,
                                    st.ceiling_m[i], prm, from_m, since_s,
                                    masks[:, M_WAITING])
        st.z_offset_m[i] = z_new
        _climb_started(st, i, z_start, climbed, now_s)
    elif _climb_blocked(enc, half_h, ahead, climbed, z_start, prm, from_m, since_s,
                        masks[:, M_WAITING]):
        # A climb under way is checked in every round, not only in those that yield: its
        # conflict may be resolved while someone moves into its way. Found in the vertical
        # stack swap (2 × 5): uav9, climbing 15 m for those above it, went on through uav10
        # hovering 6 m over it, which had no layer left under the ceiling (0.06 m).
        st.z_offset_m[i] = climbed
    z = st.z_offset_m[i]
    if z == z_start:
        hit_end = hit_start
        any_end = any_start
    else:
        hit_end = np.empty(k, dtype=np.bool_)
        any_end = conflict_rows(enc.near, enc.dz, enc.widen_v, half_h, z, hit_end) >= 0
    unresolved = masks[:, M_UNRESOLVED]
    any_unresolved = False
    for j in range(k):
        unresolved[j] = hit_end[j] and must[j]
        any_unresolved = any_unresolved or unresolved[j]
    any_unresolved = any_end and any_unresolved
    # "Conflict-free" for the hysteresis and the release means: no conflict at the offset in
    # force, and none anywhere on the way down to 0 either. Climbing over a UAV removes the
    # conflict but not the reason for the offset; without this, the offset would be released
    # on top of it and re-raised as soon as the conflict reappeared.
    if any_start or any_end or conflict_below(enc.near, enc.dz, enc.widen_v, half_h, z):
        st.last_conflict_s[i] = now_s
    else:
        # Found in the 24 h campaign with 30 % loss: a UAV that had not heard from another
        # for 5 s (ten lost messages in a row) released its offset onto it. Silent UAVs are
        # among the encounters, at their widened last plans: the way down is clear of them
        # too (until their plans end, with ``silent_hold_s``).
        #
        # Not while holding: a hold stops in 3-D, the offset included. Found by the falsifier
        # (bursty loss, single-band GNSS): a UAV held 9 m up released its offset while
        # holding, heard again the one it had yielded to, now level with its way down, and
        # held, still descending into it (0.81 m).
        if not st.holding[i]:
            _release(st, i, now_s)
    st.last_update_s[i] = now_s
    holding = _hold_short(st, i, any_unresolved, times, pos, has_pos, e, e_start, q_lo, q_hi,
                          has_probes, own_priority, deaf_col, unheard,
                          not masks[:, M_WAITING].any(), now_s, ahead, climbed)
    z = st.z_offset_m[i]
    if any_unresolved:
        # Stuck (docs/safety.md, A6): a hold is a stop within our plan, so that the one we
        # yield to passes ahead of us. When our plan stands still and one we yield to comes
        # to meet it later in the plan, it passes through us: found in the 24 h campaign
        # (trial 42), uav3 waiting at its waypoint under uav5 (no way up), uav1 flying to a
        # waypoint beside it, straight into uav3. Nothing we can do makes way; saying so (the
        # flag down, A7) makes the others yield. Only for a UAV we yield to by priority
        # alone (its flag up, it hears us, we are heard): a stuck UAV is never stuck for
        # another stuck one, so two never lower their flags for each other (found with every
        # fault at once: UAVs hovering at their starts, in each other's wide cylinders, all
        # stuck). Once stuck, until that conflict is resolved (a hold's rounds alternate
        # between the standing plan and the probes' one).
        #
        # Standing still means until it reaches us, not over the whole horizon: found by the
        # falsifier (single-band GNSS, no layer clear of the other's widened cylinder), a UAV
        # waiting at its start for a departure 3 s away held where a higher priority's
        # descent passed through it (1.21 m), never stuck because its plan moved later.
        by_rank = False
        coming = False
        reach = -1  # the last point of our plan before the first one it comes to meet us at
        for j in range(k):
            r = (unresolved[j] and enc.avoiding[j] and not deaf[j] and not unheard
                 and rank[j])
            by_rank = by_rank or r
            if not r:
                continue
            # It comes to us: in our cylinder later but not now, or (a cylinder widened by
            # the pair's uncertainty holds it from afar) closing in by over STANDING_M.
            half = half_h + enc.widen_v[j]
            inside_now = in_cylinder(enc.near[j, 0], enc.dz[j, 0], z, half)
            for p in range(1, enc.near.shape[1]):
                if in_cylinder(enc.near[j, p], enc.dz[j, p], z, half) and (
                        not inside_now or enc.dxy[j, p] < enc.dxy[j, 0] - STANDING_M):
                    coming = True
                    reach = max(reach, p)
                    break
        st.stuck[i] = by_rank and (st.stuck[i] or (coming and has_pos and reach >= 0
                                                   and _standing_still(pos, reach)))
    else:
        st.stuck[i] = False
    if not any_unresolved:
        for j in range(k):
            unresolved[j] = False
    if any_deaf:
        for j in range(k):
            if deaf[j]:
                deaf_col[enc.col[j]] = False
    last = st.last_conflict_s[i]
    recent = not math.isnan(last) and now_s - last < hyst
    tight = any_start or any_end or recent or holding
    flags[F_AVOIDING] = tight or z > 0.0
    flags[F_TIGHT] = tight
    flags[F_CEILING] = ceiling_hit
    flags[F_UNHEARD] = unheard
    flags[F_HOLDING] = holding
    flags[F_STUCK] = st.stuck[i]
    first_s = times[first] - now_s if any_start else np.nan
    return NEW_KIND, z, first_s


@kernel(allocates=True)
def decide_rows(st: StrategyRows, rows: np.ndarray, now_s: np.ndarray, times: np.ndarray,
                pos: np.ndarray, has_pos: np.ndarray, climbed_m: np.ndarray,
                own_priority: np.ndarray, e: EncounterRows, e_start: np.ndarray,
                plan: np.ndarray, q_lo: np.ndarray, q_hi: np.ndarray,
                has_probes: np.ndarray, s_start: np.ndarray, s_col: np.ndarray,
                kind: np.ndarray, z_out: np.ndarray, first_out: np.ndarray, flags: np.ndarray,
                masks: np.ndarray) -> None:
    """The decisions of D strategies (rows ``rows`` (D,) of ``st``), each from its plan's
    encounters: deciding UAV j planned at ``now_s[j]`` (its clock) the points ``times[j]``
    (m,) and ``pos[j]`` (m, 3) (``has_pos[j]``: without them it never holds short), has
    climbed ``climbed_m[j]`` of its offset (NaN: all of it), its priority
    ``own_priority[j]``; its encounters are the rows of plan ``plan[j]`` of the encounter
    rows ``e`` (:class:`EncounterRows`, grouped by ``e_start``), its probes' plans
    ``q_lo[j]`` … ``q_hi[j]`` − 1 (``has_probes[j]``: it was handed probes), the silent
    columns it knows of ``s_col[s_start[f]:s_start[f + 1]]`` (f = ``plan[j]``).

    Outputs: ``kind[j]`` (:data:`CALM_KIND`, :data:`SAME_KIND` when every field equals its
    last decision's, else :data:`NEW_KIND`), ``z_out[j]`` the offset, ``first_out[j]`` the
    first conflict's time from now (NaN: none), ``flags[j]`` (7,) (``F_*``), and per
    encounter row ``masks`` (E, 5) (``M_*``): its plan's rows name its decision's UAVs."""
    cols = st.unlisted_s.shape[1]
    deaf_col = np.zeros(max(cols, 1), dtype=np.bool_)
    key = np.empty(KEY_LEN)
    for j in range(rows.shape[0]):
        i = rows[j]
        f = plan[j]
        lo, hi = e_start[f], e_start[f + 1]
        s_lo, s_hi = s_start[f], s_start[f + 1]
        c, z, first_s = _decide_one(
            st, i, now_s[j], times[j], pos[j], has_pos[j], climbed_m[j], own_priority[j], e,
            e_start, f, q_lo[j], q_hi[j], has_probes[j], s_hi - s_lo, deaf_col, flags[j],
            masks[lo:hi])
        z_out[j] = z
        first_out[j] = first_s
        if c == CALM_KIND:
            kind[j] = CALM_KIND
            continue
        n = _key(z, first_s, flags[j], _plan_rows(e, lo, hi), masks[lo:hi], s_col[s_lo:s_hi], key)
        same = n >= 0 and n == st.key_n[i]
        if same:
            for t in range(n):
                if key[t] != st.key[i, t]:
                    same = False
                    break
        kind[j] = SAME_KIND if same else NEW_KIND
        st.key_n[i] = n
        for t in range(max(n, 0)):
            st.key[i, t] = key[t]
