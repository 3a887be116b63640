"""Who comes near whom: the received predictions aligned with ours, for many receivers at once.

Each avoidance update of a UAV compares its own plan with the newest prediction it received
from every other UAV (:mod:`uavmpc.avoidance.proximity`). With hundreds of UAVs most of those
are far away, and comparing all of them would cost O(N²) alignments per round. Two facts make
the comparison cheap without changing its result:

- **A bounding box decides most pairs.** A received prediction, aligned in time and
  extrapolated for at most ``timeout_s`` past its end, stays inside the box of its points and
  of its extrapolated end point. If that box, widened by the cylinder radius, does not meet the
  box of our plan, no point of the pair can be horizontally within the radius: the pair has no
  near point and changes nothing in the decision. That test is part of the law
  (:func:`encounter_rows` applies it to every pair it looks at).
- **A spatial index finds the pairs whose boxes can meet.** A hashed grid over the boxes of the
  messages the receivers hold gives each receiver its candidates
  (:func:`build_grid`, :func:`grid_candidates`); ``use_index=False`` looks at every sender
  instead. Both give the same rows, bit for bit (tested): the index only saves work.

The result per receiver are its **encounters**: the senders with a fresh prediction (or a
silent one at its last known plan) that come horizontally near at some point of our horizon,
with those points and our height minus theirs. The strategy decides from them alone
(:class:`uavmpc.avoidance.strategy.HeightOffsetStrategy.decide`); every receiver still decides
from what its own inbox holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from uavmpc.avoidance.proximity import near_and_dz
from uavmpc.comms.inbox import InboxRows, InboxTable, Store
from uavmpc.comms.message import MAX_HEARD
from uavmpc.jit import bound, kernel, thread_count

#: Boxes are widened by this much more than the radius: the aligned points are computed with
#: a rounding the box bounds do not share, and a pair must never be pruned by round-off.
BOX_MARGIN_M = 1e-3
_HASH_X = 73856093
_HASH_Y = 19349663


@dataclass(frozen=True, eq=False)
class Encounters:
    """The others that come near, aligned with our prediction (k senders, m points).

    Attributes:
        ids: (k,) sender ids; priority: (k,) int64; avoiding: (k,) bool (their flags).
        silent_row: (k,) bool the row is a silent UAV's last known plan.
        near_xy: (k, m) bool known and horizontally within the pair's radius (for a silent
            UAV: widened by how far it can have left its plan).
        dz_m: (k, m) our z (without offset) minus theirs.
        silent: every sender heard from recently whose newest prediction is stale now (near
            or not), in column order.
        announced_xy: (k, m) bool near along the plan as announced, within the pair's radius
            without a silent UAV's widening (default: ``near_xy``). The way up is checked
            against this: a guess where a silent UAV may be does not hold a climb away from
            a known conflict.
        hears_us: (k,) bool their message lists us among the UAVs they hear
            (:attr:`~uavmpc.comms.PredictionMessage.heard`; default: all do).
        widen_v_m: (k,) how much the pair's half height is widened for both UAVs' vertical
            position uncertainty [m] (default 0; the horizontal widening is in ``near_xy``).
        dxy_m: (k, m) the horizontal distance between us and them at each point [m] (it
            tells a UAV we move away from from one we come closer to first; default: unknown,
            inf).
    """

    ids: tuple[str, ...]
    priority: np.ndarray
    avoiding: np.ndarray
    silent_row: np.ndarray
    near_xy: np.ndarray
    dz_m: np.ndarray
    silent: tuple[str, ...] = ()
    announced_xy: np.ndarray | None = None
    hears_us: np.ndarray | None = None
    widen_v_m: np.ndarray | None = None
    dxy_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.announced_xy is None:
            object.__setattr__(self, "announced_xy", self.near_xy)
        if self.hears_us is None:
            object.__setattr__(self, "hears_us", np.ones(len(self.ids), dtype=bool))
        if self.widen_v_m is None:
            object.__setattr__(self, "widen_v_m", np.zeros(len(self.ids)))
        if self.dxy_m is None:
            object.__setattr__(self, "dxy_m", np.full(self.near_xy.shape, np.inf))


@kernel
def _inflated_box(store: Store, slot: int, extrapolate_s: float, out: np.ndarray) -> None:
    """The box of a prediction's points and of its extrapolated end (where its alignment can
    put it), into ``out`` (4,)."""
    n = store.points[slot]
    b = store.bbox_m[slot]
    ex = store.positions_m[slot, n - 1, 0] + store.end_velocity_mps[slot, 0] * extrapolate_s
    ey = store.positions_m[slot, n - 1, 1] + store.end_velocity_mps[slot, 1] * extrapolate_s
    out[0] = min(b[0], ex)
    out[1] = max(b[1], ex)
    out[2] = min(b[2], ey)
    out[3] = max(b[3], ey)


@kernel
def _own_box(pos: np.ndarray, out: np.ndarray) -> None:
    out[0] = out[1] = pos[0, 0]
    out[2] = out[3] = pos[0, 1]
    for k in range(1, pos.shape[0]):
        out[0] = min(out[0], pos[k, 0])
        out[1] = max(out[1], pos[k, 0])
        out[2] = min(out[2], pos[k, 1])
        out[3] = max(out[3], pos[k, 1])


@kernel
def _hash(cx: int, cy: int, mask: int) -> int:
    return ((cx * _HASH_X) ^ (cy * _HASH_Y)) & mask


_FRESH, _SILENT, _IGNORED = 0, 1, 2


@kernel
def _reference_s(stamp_s: float, received_s: float) -> float:
    """The time on the receiver's clock a held message is from: its stamp ``stamp_s``, or
    ``received_s`` when known (not NaN): its arrival with the receive-time reference, or its
    stamp put on our clock by the sender's measured offset (:mod:`uavmpc.comms.inbox`).

    This and :func:`_standing` take numbers, not the records: they run for every column of
    a row, and a compiled call that takes a record increments and decrements the reference
    count of each of its arrays (an atomic operation each) on every call."""
    if not math.isnan(received_s):
        return received_s
    return stamp_s


@kernel
def _standing(ref_s: float, now_s: float, timeout_s: float, silent_hold_s: float) -> int:
    """:data:`_FRESH` (a message from ``ref_s``, :func:`_reference_s`, within ``timeout_s``
    of ``now_s``), :data:`_SILENT` (stale, at most ``silent_hold_s`` old) or
    :data:`_IGNORED` (older, or stamped too far ahead)."""
    age = now_s - ref_s
    if abs(age) <= timeout_s:
        return _FRESH
    return _SILENT if 0.0 < age <= silent_hold_s else _IGNORED


@kernel
def heard_from_all(rows: InboxRows, r: int, cols: np.ndarray, now_s: float,
                   use_received: bool, timeout_s: float, silent_hold_s: float) -> bool:
    """Row ``r`` holds a prediction from every column of ``cols`` (K,) that its encounters
    take into account: fresh, or silent at most ``silent_hold_s`` old (:func:`encounter_rows`
    with the same parameters)."""
    for c in cols:
        if rows.held_slot[r, c] < 0:
            return False
        ref = _reference_s(rows.held_stamp_s[r, c], rows.held_received_s[r, c])
        if _standing(ref, now_s, timeout_s, silent_hold_s) == _IGNORED:
            return False
    return True


@kernel(allocates=True)
def heard_columns(rows: InboxRows, store: Store, r: int, now_s: float, use_received: bool,
                  timeout_s: float, silent_hold_s: float, own_x: float, own_y: float,
                  out: np.ndarray) -> int:
    """The columns whose plans row ``r`` counts (fresh, or silent at most ``silent_hold_s``
    old: :func:`heard_from_all`), its own excepted, into ``out`` (L,); returns how many.
    When more are held than ``out`` takes, the L whose held prediction starts nearest to
    (``own_x``, ``own_y``) horizontally, nearest first; otherwise in column order."""
    s_count = rows.held_slot.shape[1]
    cols = np.empty(s_count, dtype=np.int64)
    n = 0
    for c in range(s_count):
        if c == rows.own_col[r] or rows.held_slot[r, c] < 0:
            continue
        ref = _reference_s(rows.held_stamp_s[r, c], rows.held_received_s[r, c])
        if _standing(ref, now_s, timeout_s, silent_hold_s) == _IGNORED:
            continue
        cols[n] = c
        n += 1
    limit = out.shape[0]
    if n <= limit:
        out[:n] = cols[:n]
        return n
    if limit == 0:
        return 0
    d2 = np.empty(n)
    for j in range(n):
        slot = rows.held_slot[r, cols[j]]
        dx = store.positions_m[slot, 0, 0] - own_x
        dy = store.positions_m[slot, 0, 1] - own_y
        d2[j] = dx * dx + dy * dy
    # The first L of a stable sort by distance (ties in column order), without sorting all
    # n: those nearer than the L-th smallest distance, then those at it in column order
    # until L, then these L sorted (a 1 000-UAV world: 999 held, 64 listed).
    kth = np.partition(d2, limit - 1)[limit - 1]
    sel = np.empty(limit, dtype=np.int64)
    k = 0
    for j in range(n):
        if d2[j] < kth:
            sel[k] = j
            k += 1
    for j in range(n):
        if k == limit:
            break
        if d2[j] == kth:
            sel[k] = j
            k += 1
    order = np.argsort(d2[sel], kind="mergesort")  # stable: ties stay in column order
    for j in range(limit):
        out[j] = cols[sel[order[j]]]
    return limit


@kernel(allocates=True)
def build_grid(store: Store, extrapolate_s: float, cell_m: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """A hashed grid of cells ``cell_m`` wide over the inflated boxes of the held slots
    (``holders`` > 0): (bucket starts (H + 1,), slots by bucket). A slot is listed in the
    bucket of every cell its box covers (a bucket may also hold other cells' slots: the
    candidates are a superset, and the law's box test decides)."""
    c = store.holders.shape[0]
    box = np.empty(4)
    cells = 0
    for s in range(c):
        if store.holders[s] > 0:
            _inflated_box(store, s, extrapolate_s, box)
            nx = math.floor(box[1] / cell_m) - math.floor(box[0] / cell_m) + 1
            ny = math.floor(box[3] / cell_m) - math.floor(box[2] / cell_m) + 1
            cells += nx * ny
    h = 16
    while h < 2 * cells:
        h *= 2
    mask = h - 1
    start = np.zeros(h + 1, dtype=np.int64)
    for phase in range(2):
        fill = start.copy()
        entries = np.empty(max(cells, 1), dtype=np.int64)
        for s in range(c):
            if store.holders[s] <= 0:
                continue
            _inflated_box(store, s, extrapolate_s, box)
            x0, x1 = math.floor(box[0] / cell_m), math.floor(box[1] / cell_m)
            y0, y1 = math.floor(box[2] / cell_m), math.floor(box[3] / cell_m)
            for cx in range(x0, x1 + 1):
                for cy in range(y0, y1 + 1):
                    b = _hash(cx, cy, mask)
                    if phase == 0:
                        start[b + 1] += 1
                    else:
                        entries[fill[b]] = s
                        fill[b] += 1
        if phase == 0:
            for b in range(h):
                start[b + 1] += start[b]
        else:
            return start, entries
    return start, np.empty(0, dtype=np.int64)  # not reached


@kernel
def grid_candidates(rows: InboxRows, store: Store, r: int, box: np.ndarray, cell_m: float,
                    start: np.ndarray, entries: np.ndarray, mark: np.ndarray, stamp: int,
                    out: np.ndarray) -> int:
    """The columns of row ``r`` whose held slot is listed in a cell of ``box`` (4,) (already
    widened by the radius); written into ``out``, sorted; returns their count. ``mark``
    (S,) int64: scratch, set to ``stamp`` for the columns found."""
    mask = start.shape[0] - 2
    x0, x1 = math.floor(box[0] / cell_m), math.floor(box[1] / cell_m)
    y0, y1 = math.floor(box[2] / cell_m), math.floor(box[3] / cell_m)
    k = 0
    for cx in range(x0, x1 + 1):
        for cy in range(y0, y1 + 1):
            b = _hash(cx, cy, mask)
            for e in range(start[b], start[b + 1]):
                s = entries[e]
                col = store.col[s]
                if mark[col] != stamp and rows.held_slot[r, col] == s:
                    mark[col] = stamp
                    out[k] = col
                    k += 1
    _sort_head(out, k)
    return k


@kernel
def _sift_down(a: np.ndarray, root: int, end: int) -> None:
    """Restore the max-heap below ``root`` in ``a[:end]``."""
    while 2 * root + 1 < end:
        child = 2 * root + 1
        if child + 1 < end and a[child] < a[child + 1]:
            child += 1
        if a[root] >= a[child]:
            return
        a[root], a[child] = a[child], a[root]
        root = child


@kernel
def _sort_head(a: np.ndarray, k: int) -> None:
    """Sort ``a[:k]`` in place, ascending (a heapsort: numba's sort allocates)."""
    for root in range(k // 2 - 1, -1, -1):
        _sift_down(a, root, k)
    for end in range(k - 1, 0, -1):
        a[0], a[end] = a[end], a[0]
        _sift_down(a, 0, end)


class SearchScratch(NamedTuple):
    """One block's work arrays of the search (:func:`_encounter_block`), made once per call
    and block (:func:`search_scratch`) so that the per-pair kernels allocate nothing: a kernel
    that allocates counts the references of every array it passes on
    (:func:`uavmpc.jit.kernel`), here around every pair looked at (about 766 000 atomic
    operations per search of a 300-UAV round before, docs/scale.md).

    Attributes:
        box_own, box: (4,) our plan's box and a sender's [x0, x1, y0, y1] [m].
        shifted: (P,) a sender's prediction times on our clock [s] (P: the store's points).
        near, near_announced: (m,) bool; dz, dxy: (m,) [m]; aligned: (m, 3) [m]: one pair's
            points (:func:`~uavmpc.avoidance.proximity.near_and_dz`).
        cand: (C,) int64 the candidate columns of a receiver; mark: (C,) int64 the receiver
            that last listed a column (C: the inbox table's columns).
    """

    box_own: np.ndarray
    box: np.ndarray
    shifted: np.ndarray
    near: np.ndarray
    near_announced: np.ndarray
    dz: np.ndarray
    dxy: np.ndarray
    aligned: np.ndarray
    cand: np.ndarray
    mark: np.ndarray


@kernel(allocates=True)
def search_scratch(m: int, points: int, cols: int) -> SearchScratch:
    """Fresh :class:`SearchScratch` for plans of ``m`` points, stored predictions of
    ``points`` and ``cols`` inbox columns."""
    return SearchScratch(np.empty(4), np.empty(4), np.empty(points),
                         np.empty(m, dtype=np.bool_), np.empty(m, dtype=np.bool_),
                         np.empty(m), np.empty(m), np.empty((m, 3)),
                         np.empty(cols, dtype=np.int64), np.full(cols, -1, dtype=np.int64))


@kernel
def silent_reach_m(age_s: float, speed_mps: float, accel_mps2: float) -> float:
    """How far a UAV flying within horizontal limits ``speed_mps`` and ``accel_mps2`` gets in
    ``age_s`` from rest [m]: how far a silent UAV can be from its last plan had it set off on
    a new leg the moment that plan went stale (a UAV braking against its plan could part
    from it twice as fast; the cylinder's margin covers that). 0 when either limit is 0."""
    if age_s <= 0.0 or speed_mps <= 0.0 or accel_mps2 <= 0.0:
        return 0.0
    t_a = speed_mps / accel_mps2
    if age_s <= t_a:
        return 0.5 * accel_mps2 * age_s * age_s
    return 0.5 * speed_mps * t_a + speed_mps * (age_s - t_a)


@kernel
def _pair_radius(radius: float, ov_start: np.ndarray, ov_col: np.ndarray,
                 ov_radius: np.ndarray, j: int, col: int) -> float:
    """Receiver j's cylinder radius against column ``col``: its override, else ``radius``."""
    for o in range(ov_start[j], ov_start[j + 1]):
        if ov_col[o] == col:
            return ov_radius[o]
    return radius


@kernel
def pair_widening_m(own_sigma_m: float, other_sigma_m: float, sigma_k: float) -> float:
    """How much a pair's radius (or half height) widens for both UAVs' position uncertainty
    (1σ each, horizontal or vertical; docs/safety.md, A3): ``sigma_k`` √(σ_own² + σ_other²)
    [m], exactly 0 when neither has any."""
    if own_sigma_m == 0.0 and other_sigma_m == 0.0:
        return 0.0
    return sigma_k * math.sqrt(own_sigma_m * own_sigma_m + other_sigma_m * other_sigma_m)


@kernel
def _encounter(rows: InboxRows, store: Store, r: int, col: int, silent: np.bool_, ref: float,
               radius: float, announced_radius: float, extrapolate_s: float,
               own_times: np.ndarray, own_pos: np.ndarray, sc: SearchScratch,
               own_sigma_v_m: float, sigma_k: float, ne: np.int64,
               e_col: np.ndarray, e_silent: np.ndarray, e_near: np.ndarray,
               e_announced: np.ndarray, e_dz: np.ndarray, e_dxy: np.ndarray,
               e_hears: np.ndarray, e_widen_v: np.ndarray) -> np.int64:
    """Row ``r``'s message from ``col`` against our plan (box test, then the cylinder's
    horizontal test at ``radius``); written as encounter row ``ne`` when it comes near (and
    fits the outputs), with the points near at ``announced_radius`` ≤ ``radius`` (the plan as
    announced, without a silent sender's widening) in ``e_announced``, whether its heard list
    names row ``r`` in ``e_hears``, and the pair's vertical widening (:func:`pair_widening_m`
    of ``own_sigma_v_m`` and the sender's) in ``e_widen_v``. Returns the new row count."""
    box_own, box, shifted = sc.box_own, sc.box, sc.shifted
    near, dz, dxy = sc.near, sc.dz, sc.dxy
    slot = rows.held_slot[r, col]
    _inflated_box(store, slot, extrapolate_s, box)
    reach = radius + BOX_MARGIN_M
    if (box[0] - reach > box_own[1] or box[1] + reach < box_own[0]
            or box[2] - reach > box_own[3] or box[3] + reach < box_own[2]):
        return ne
    n = store.points[slot]
    stamp = rows.held_stamp_s[r, col]
    # With the receive-time fallback the prediction is moved onto our clock: its stamp is
    # taken to be the moment we received it (error: the link latency).
    for k in range(n):
        shifted[k] = store.times_s[slot, k] + (ref - stamp)
    near_and_dz(shifted[:n], store.positions_m[slot, :n], own_times, extrapolate_s, own_pos,
                radius, near, dz, dxy, sc.aligned)
    hit = False
    for k in range(near.shape[0]):
        hit = hit or near[k]
    if not hit:
        return ne
    if ne < e_col.shape[0]:
        e_col[ne] = col
        e_silent[ne] = silent
        for k in range(near.shape[0]):  # loops: a row assignment may copy (an allocation)
            e_near[ne, k] = near[k]
            e_dz[ne, k] = dz[k]
            e_dxy[ne, k] = dxy[k]
        me = rows.own_col[r]
        hears = False
        for k in range(store.heard_n[slot]):
            hears = hears or store.heard_col[slot, k] == me
        e_hears[ne] = hears
        e_widen_v[ne] = pair_widening_m(own_sigma_v_m, store.sigma_m[slot, 1], sigma_k)
        if announced_radius < radius:
            near_and_dz(shifted[:n], store.positions_m[slot, :n], own_times, extrapolate_s,
                        own_pos, announced_radius, sc.near_announced, dz, dxy, sc.aligned)
            for k in range(near.shape[0]):
                e_announced[ne, k] = sc.near_announced[k]
        else:
            for k in range(near.shape[0]):
                e_announced[ne, k] = near[k]
    return ne + 1


@kernel
def _encounter_block(rows: InboxRows, store: Store, due: np.ndarray, j0: int, j1: int,
                     own_times: np.ndarray, own_pos: np.ndarray, now_s: np.ndarray,
                     timeout_s: float, silent_hold_s: float, use_received: bool,
                     silent_radius_m: float, silent_speed_mps: float, silent_accel_mps2: float,
                     radius_m: np.ndarray, ov_start: np.ndarray, ov_col: np.ndarray,
                     ov_radius: np.ndarray, own_sigma_h_m: np.ndarray,
                     own_sigma_v_m: np.ndarray, sigma_k: float, use_index: bool, cell_m: float,
                     start: np.ndarray, entries: np.ndarray, sigma_max: float,
                     sc: SearchScratch, e_start: np.ndarray, e_col: np.ndarray,
                     e_silent: np.ndarray, e_near: np.ndarray, e_announced: np.ndarray,
                     e_dz: np.ndarray, e_dxy: np.ndarray, e_hears: np.ndarray,
                     e_widen_v: np.ndarray, s_start: np.ndarray,
                     s_col: np.ndarray) -> tuple[np.int64, np.int64]:
    """:func:`encounter_rows` for the receivers ``due[j0:j1]``, with the grid (``start``,
    ``entries``: :func:`build_grid`, when ``use_index``) and the widest sender's horizontal σ
    ``sigma_max`` given, in the work arrays ``sc`` (:func:`search_scratch`, its ``mark``
    fresh: −1): their rows written from the start of the outputs ``e_*``, ``s_col`` (and
    counted past their ends), ``e_start[j]`` and ``s_start[j]`` counted from there.
    Returns (encounter rows, silent entries) of the block."""
    n_cols = rows.held_slot.shape[1]
    cap_s = s_col.shape[0]
    # Typed int64 and bool from the start: a literal would have _encounter compiled once more
    # for it (a first run's compile time).
    ne = np.int64(0)
    ns = np.int64(0)
    silent, fresh = np.bool_(True), np.bool_(False)
    box_own, box, cand = sc.box_own, sc.box, sc.cand
    for j in range(j0, j1):
        r = due[j]
        now = now_s[j]
        e_start[j] = ne
        s_start[j] = ns
        _own_box(own_pos[j], box_own)
        # Silence is not absence (docs/safety.md, A1). It is a property of the sender's last
        # message, near or not (the release waits for every silent UAV heard from recently).
        # Silent senders are looked at here, all of them: their widened cylinders reach
        # beyond the index's boxes.
        for col in range(n_cols):
            if rows.held_slot[r, col] < 0:
                continue
            ref = _reference_s(rows.held_stamp_s[r, col], rows.held_received_s[r, col])
            if _standing(ref, now, timeout_s, silent_hold_s) != _SILENT:
                continue
            if ns < cap_s:
                s_col[ns] = col
            ns += 1
            widen = pair_widening_m(own_sigma_h_m[j], store.sigma_m[rows.held_slot[r, col], 0],
                                    sigma_k)
            announced = _pair_radius(radius_m[j], ov_start, ov_col, ov_radius, j, col) + widen
            radius = max(announced, silent_radius_m + silent_reach_m(
                now - ref - timeout_s, silent_speed_mps, silent_accel_mps2))
            ne = _encounter(rows, store, r, col, silent, ref, radius, announced, timeout_s,
                            own_times[j], own_pos[j], sc, own_sigma_v_m[j], sigma_k, ne, e_col,
                            e_silent, e_near, e_announced, e_dz, e_dxy, e_hears, e_widen_v)
        r_max = radius_m[j]
        for o in range(ov_start[j], ov_start[j + 1]):
            r_max = max(r_max, ov_radius[o])
        r_max += sigma_k * math.sqrt(own_sigma_h_m[j] ** 2 + sigma_max ** 2)
        if use_index:
            for a in range(4):
                box[a] = box_own[a] + (r_max + BOX_MARGIN_M) * (1.0 if a % 2 else -1.0)
            n_cand = grid_candidates(rows, store, r, box, cell_m, start, entries, sc.mark, j,
                                     cand)
        else:
            n_cand = 0
            for col in range(n_cols):
                if rows.held_slot[r, col] >= 0:
                    cand[n_cand] = col
                    n_cand += 1
        for c in range(n_cand):
            col = cand[c]
            ref = _reference_s(rows.held_stamp_s[r, col], rows.held_received_s[r, col])
            if _standing(ref, now, timeout_s, silent_hold_s) != _FRESH:
                continue
            widen = pair_widening_m(own_sigma_h_m[j], store.sigma_m[rows.held_slot[r, col], 0],
                                    sigma_k)
            radius = _pair_radius(radius_m[j], ov_start, ov_col, ov_radius, j, col) + widen
            ne = _encounter(rows, store, r, col, fresh, ref, radius, radius, timeout_s,
                            own_times[j], own_pos[j], sc, own_sigma_v_m[j], sigma_k, ne, e_col,
                            e_silent, e_near, e_announced, e_dz, e_dxy, e_hears, e_widen_v)
    return ne, ns


@kernel(allocates=True)
def encounter_rows(rows: InboxRows, store: Store, due: np.ndarray, own_times: np.ndarray,
                   own_pos: np.ndarray, now_s: np.ndarray, timeout_s: float,
                   silent_hold_s: float, use_received: bool, silent_radius_m: float,
                   silent_speed_mps: float, silent_accel_mps2: float, radius_m: np.ndarray,
                   ov_start: np.ndarray, ov_col: np.ndarray, ov_radius: np.ndarray,
                   own_sigma_h_m: np.ndarray, own_sigma_v_m: np.ndarray, sigma_k: float,
                   use_index: bool, cell_m: float, e_start: np.ndarray, e_col: np.ndarray,
                   e_silent: np.ndarray, e_near: np.ndarray, e_announced: np.ndarray,
                   e_dz: np.ndarray, e_dxy: np.ndarray, e_hears: np.ndarray,
                   e_widen_v: np.ndarray, s_start: np.ndarray,
                   s_col: np.ndarray) -> tuple[np.int64, np.int64]:
    """The encounters of the receivers ``due`` (R,) (rows of ``rows``), each at its clock
    ``now_s`` (R,) with its plan (``own_times`` (R, m), ``own_pos`` (R, m, 3), z without the
    offset climbed), and its cylinder radius ``radius_m`` (R,) with per-sender overrides
    (receiver j's: ``ov_col[ov_start[j]:ov_start[j + 1]]``, ``ov_radius``), widened for the
    pair's horizontal position uncertainty by ``sigma_k`` √(σ_own² + σ_sender²) (receiver j's
    σ: ``own_sigma_h_m[j]``, the sender's: its message's, docs/safety.md A3).

    Per receiver, as :class:`Encounters` rows: ``e_col``, ``e_silent``, ``e_near`` (·, m),
    ``e_announced`` (·, m: near along the plan as announced, without a silent sender's
    widening), ``e_dz`` (·, m), ``e_dxy`` (·, m: the horizontal distance, as
    :attr:`Encounters.dxy_m`), ``e_hears`` (its heard list names the receiver, as
    :attr:`Encounters.hears_us`) and ``e_widen_v`` (the pair's vertical widening for the
    receiver's ``own_sigma_v_m[j]`` and the sender's σ, as :attr:`Encounters.widen_v_m`)
    from ``e_start[j]`` to ``e_start[j + 1]``, the silent senders
    first, then the fresh ones, each in column order; and every silent column in
    ``s_col[s_start[j]:s_start[j + 1]]``. A message counts when its time reference (stamp, or
    its receive time with ``use_received``) is within ``timeout_s`` of now; a stale one is
    "silent" when it is at most ``silent_hold_s`` old, else ignored. A silent sender comes
    near when its last plan comes within its radius, as a fresh one, or when it could have
    come within ``silent_radius_m``: that radius widened by :func:`silent_reach_m` of the time
    since its message went stale (its age minus ``timeout_s``; at ``silent_speed_mps``,
    ``silent_accel_mps2``), as it may have left that plan since and nobody has heard where
    to. (Within ``timeout_s`` a plan is taken as it is: the next one is due.)

    Returns (encounter rows, silent entries); when either exceeds its output's capacity,
    nothing is written past it and the caller retries with larger outputs."""
    start = np.zeros(2, dtype=np.int64)
    entries = np.zeros(0, dtype=np.int64)
    if use_index:
        start, entries = build_grid(store, timeout_s, cell_m)
    ne, ns = _encounter_block(rows, store, due, 0, due.shape[0], own_times, own_pos, now_s,
                              timeout_s, silent_hold_s, use_received, silent_radius_m,
                              silent_speed_mps, silent_accel_mps2, radius_m, ov_start, ov_col,
                              ov_radius, own_sigma_h_m, own_sigma_v_m, sigma_k, use_index,
                              cell_m, start, entries, _sigma_max(store),
                              search_scratch(own_times.shape[1], store.times_s.shape[1],
                                             rows.held_slot.shape[1]), e_start, e_col,
                              e_silent, e_near, e_announced, e_dz, e_dxy, e_hears, e_widen_v,
                              s_start, s_col)
    e_start[due.shape[0]] = ne
    s_start[due.shape[0]] = ns
    return ne, ns


@kernel(parallel=True)
def encounter_rows_threads(rows: InboxRows, store: Store, due: np.ndarray,
                           own_times: np.ndarray, own_pos: np.ndarray, now_s: np.ndarray,
                           timeout_s: float, silent_hold_s: float, use_received: bool,
                           silent_radius_m: float, silent_speed_mps: float,
                           silent_accel_mps2: float, radius_m: np.ndarray,
                           ov_start: np.ndarray, ov_col: np.ndarray, ov_radius: np.ndarray,
                           own_sigma_h_m: np.ndarray, own_sigma_v_m: np.ndarray,
                           sigma_k: float, use_index: bool, cell_m: float,
                           e_start: np.ndarray, e_col: np.ndarray, e_silent: np.ndarray,
                           e_near: np.ndarray, e_announced: np.ndarray, e_dz: np.ndarray,
                           e_dxy: np.ndarray, e_hears: np.ndarray, e_widen_v: np.ndarray,
                           s_start: np.ndarray, s_col: np.ndarray,
                           blocks: int) -> tuple[np.int64, np.int64]:
    """:func:`encounter_rows` with the receivers in ``blocks`` ≥ 1 contiguous blocks, one per
    thread (the caller passes :func:`uavmpc.jit.thread_count`): the same outputs, bit for bit.

    Each block writes its rows into its own equal share of the outputs, which are then moved
    together in receiver order. When a block's rows exceed its share, nothing is moved and
    the counts returned are ``blocks`` × the largest block's, more than the outputs hold: the
    caller retries with larger outputs, as for :func:`encounter_rows`."""
    r_count = due.shape[0]
    nb = max(1, min(r_count, blocks))
    start = np.zeros(2, dtype=np.int64)
    entries = np.zeros(0, dtype=np.int64)
    if use_index:
        start, entries = build_grid(store, timeout_s, cell_m)
    sigma_max = _sigma_max(store)
    share_e = e_col.shape[0] // nb
    share_s = s_col.shape[0] // nb
    ne_b = np.zeros(nb, dtype=np.int64)
    ns_b = np.zeros(nb, dtype=np.int64)
    for b in numba.prange(nb):
        e0, s0 = b * share_e, b * share_s
        ne_b[b], ns_b[b] = _encounter_block(
            rows, store, due, b * r_count // nb, (b + 1) * r_count // nb, own_times, own_pos,
            now_s, timeout_s, silent_hold_s, use_received, silent_radius_m, silent_speed_mps,
            silent_accel_mps2, radius_m, ov_start, ov_col, ov_radius, own_sigma_h_m,
            own_sigma_v_m, sigma_k, use_index, cell_m, start, entries, sigma_max,
            search_scratch(own_times.shape[1], store.times_s.shape[1], rows.held_slot.shape[1]),
            e_start,
            e_col[e0:e0 + share_e], e_silent[e0:e0 + share_e], e_near[e0:e0 + share_e],
            e_announced[e0:e0 + share_e], e_dz[e0:e0 + share_e], e_dxy[e0:e0 + share_e],
            e_hears[e0:e0 + share_e], e_widen_v[e0:e0 + share_e], s_start,
            s_col[s0:s0 + share_s])
    if ne_b.max() > share_e or ns_b.max() > share_s:
        return nb * ne_b.max(), nb * ns_b.max()
    ne = np.int64(0)
    ns = np.int64(0)
    for b in range(nb):
        e0, s0 = b * share_e, b * share_s
        for j in range(b * r_count // nb, (b + 1) * r_count // nb):
            e_start[j] += ne
            s_start[j] += ns
        # Moved down (ne ≤ e0): a forward copy never overwrites what it has yet to move.
        # Element by element: a row assignment copies through a new array (numba cannot
        # tell that the rows never overlap), four per encounter.
        for i in range(ne_b[b]):
            e_col[ne + i] = e_col[e0 + i]
            e_silent[ne + i] = e_silent[e0 + i]
            for k in range(e_near.shape[1]):
                e_near[ne + i, k] = e_near[e0 + i, k]
                e_announced[ne + i, k] = e_announced[e0 + i, k]
                e_dz[ne + i, k] = e_dz[e0 + i, k]
                e_dxy[ne + i, k] = e_dxy[e0 + i, k]
            e_hears[ne + i] = e_hears[e0 + i]
            e_widen_v[ne + i] = e_widen_v[e0 + i]
        for i in range(ns_b[b]):
            s_col[ns + i] = s_col[s0 + i]
        ne += ne_b[b]
        ns += ns_b[b]
    e_start[r_count] = ne
    s_start[r_count] = ns
    return ne, ns


@kernel
def _sigma_max(store: Store) -> float:
    """The widest sender's horizontal position uncertainty: what the index's boxes must
    reach."""
    sigma_max = 0.0
    for s in range(store.sigma_m.shape[0]):
        sigma_max = max(sigma_max, store.sigma_m[s, 0])
    return sigma_max


#: With this many senders or more, ``use_index=None`` finds candidates through the grid (below
#: it, looking at every sender costs less than building the grid).
AUTO_INDEX_SENDERS = 32
_NO_COLS = np.zeros(0, dtype=np.int64)
_NO_RADII = np.zeros(0)
_NOBODY: dict[int, Encounters] = {}


def _nobody(m: int, silent: tuple[str, ...]) -> Encounters:
    """No encounter (arrays shared: an Encounters is never written to)."""
    enc = _NOBODY.get(m)
    if enc is None:
        enc = Encounters((), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.bool_),
                         np.zeros(0, dtype=np.bool_), np.zeros((0, m), dtype=np.bool_),
                         np.zeros((0, m)))
        _NOBODY[m] = enc
    if silent:
        return Encounters(enc.ids, enc.priority, enc.avoiding, enc.silent_row, enc.near_xy,
                          enc.dz_m, silent, enc.announced_xy)
    return enc


class EncounterOutputs(NamedTuple):
    """The outputs of one call of :func:`encounter_rows`, in its arguments' order (R
    receivers, E encounter rows, S silent entries, m points; see :func:`encounter_rows`)."""

    e_start: np.ndarray  # (R + 1,) int64
    e_col: np.ndarray  # (E,) int64
    e_silent: np.ndarray  # (E,) bool
    e_near: np.ndarray  # (E, m) bool
    e_announced: np.ndarray  # (E, m) bool
    e_dz: np.ndarray  # (E, m) [m]
    e_dxy: np.ndarray  # (E, m) [m]
    e_hears: np.ndarray  # (E,) bool
    e_widen_v: np.ndarray  # (E,) [m]
    s_start: np.ndarray  # (R + 1,) int64
    s_col: np.ndarray  # (S,) int64


class FoundRows:
    """What one call of :func:`encounter_rows` found for receivers ``due`` (R,): views of its
    outputs (:meth:`EncounterFinder.find_rows`)."""

    def __init__(self, table: InboxTable, due: np.ndarray, out: EncounterOutputs) -> None:
        self.table = table
        self.due = due
        self.out = out
        r_count = due.shape[0]
        e_start, s_start = out.e_start, out.s_start
        #: (R,) bool the receiver found nobody near and nobody silent.
        self.quiet = ((e_start[1:r_count + 1] == e_start[:r_count])
                      & (s_start[1:r_count + 1] == s_start[:r_count]))
        self._senders: tuple[np.ndarray, np.ndarray] | None = None

    def sender_flags(self) -> tuple[np.ndarray, np.ndarray]:
        """(E,) each encounter row's sender's priority and flag, from the messages held
        (looked up once for all rows: a round's decisions take slices)."""
        if self._senders is None:
            o = self.out
            r_count = self.due.shape[0]
            receiver = np.repeat(self.due, np.diff(o.e_start[:r_count + 1]))
            slots = self.table.rows.held_slot[receiver, o.e_col[:receiver.shape[0]]]
            st = self.table.store
            self._senders = st.priority[slots], st.avoiding[slots]
        return self._senders

    def encounters(self, j: int) -> Encounters:
        """Receiver ``j``'s encounters (views of the call's outputs)."""
        o = self.out
        ids = self.table.ids
        a, b = int(o.e_start[j]), int(o.e_start[j + 1])
        sa, sb = int(o.s_start[j]), int(o.s_start[j + 1])
        silent = tuple(ids[c] for c in o.s_col[sa:sb].tolist()) if sb > sa else ()
        if a == b:  # nobody near (most UAVs, most of the time)
            return _nobody(o.e_near.shape[1], silent)
        priority, avoiding = self.sender_flags()
        return Encounters(
            tuple(map(ids.__getitem__, o.e_col[a:b].tolist())), priority[a:b],
            avoiding[a:b], o.e_silent[a:b], o.e_near[a:b], o.e_dz[a:b], silent,
            o.e_announced[a:b], o.e_hears[a:b], o.e_widen_v[a:b], o.e_dxy[a:b])


class EncounterFinder:
    """Runs :func:`encounter_rows` for the receivers of one :class:`InboxTable` and hands out
    :class:`Encounters` (its output arrays are kept and grown between rounds).

    Args:
        table: the receivers' inboxes.
        timeout_s, silent_hold_s, use_received, silent_radius_m, silent_speed_mps,
            silent_accel_mps2: the strategy's parameters (``timeout_s``, ``silent_hold_s``,
            ``time_reference == "receive"``, ``silent_radius_m``, ``silent_speed_mps``,
            ``silent_accel_mps2``).
        use_index: find candidates with the grid (True), look at every sender (False), or
            choose by the number of senders (None, default: :data:`AUTO_INDEX_SENDERS`).
        cell_m: the grid's cell size (default: 2 × the largest radius, at least 16 m).
    """

    def __init__(self, table: InboxTable, *, timeout_s: float, silent_hold_s: float,
                 use_received: bool, silent_radius_m: float = 0.0,
                 silent_speed_mps: float = 0.0, silent_accel_mps2: float = 0.0,
                 use_index: bool | None = None,
                 cell_m: float | None = None, sigma_k: float = 0.0) -> None:
        self.table = table
        #: Pairs widen by this many σ of their position uncertainty (:func:`pair_widening_m`).
        self.sigma_k = float(sigma_k)
        self.timeout_s = float(timeout_s)
        self.silent_hold_s = float(silent_hold_s)
        self.use_received = bool(use_received)
        self.silent_radius_m = float(silent_radius_m)
        self.silent_speed_mps = float(silent_speed_mps)
        self.silent_accel_mps2 = float(silent_accel_mps2)
        self.use_index = None if use_index is None else bool(use_index)
        self.cell_m = cell_m
        #: The receivers' blocks, one per thread (None: numba's thread count, see
        #: :func:`uavmpc.jit.set_threads`); the same rows for any number.
        self.blocks: int | None = None
        self._cap_e = 16
        self._cap_s = 16

    def find_rows(self, due: np.ndarray, own_times: np.ndarray, own_pos: np.ndarray,
                  now_s: np.ndarray, radius_m: np.ndarray,
                  overrides: list[dict[int, float]] | None = None,
                  own_sigma_m: np.ndarray | None = None) -> FoundRows:
        """:meth:`find` as rows: which receivers found nobody near or silent, and each one's
        :class:`Encounters` when asked for (a round builds them only for the receivers that
        must decide)."""
        r_count = due.shape[0]
        sig = np.zeros((r_count, 2)) if own_sigma_m is None else np.asarray(own_sigma_m, float)
        m = own_times.shape[1]
        ov_start = np.zeros(r_count + 1, dtype=np.int64)
        ov_col, ov_radius = _NO_COLS, _NO_RADII
        if overrides is not None and any(overrides):
            cols: list[int] = []
            radii: list[float] = []
            for j, ov in enumerate(overrides):
                cols.extend(ov)
                radii.extend(ov.values())
                ov_start[j + 1] = len(cols)
            ov_col = np.array(cols, dtype=np.int64)
            ov_radius = np.array(radii, dtype=float)
        cell = self.cell_m
        if cell is None:
            cell = max(16.0, 2.0 * float(max(radius_m.max(initial=0.0),
                                             ov_radius.max(initial=0.0))))
        t = self.table
        while True:
            out = self._buffers(r_count, m)
            use_index = (self.use_index if self.use_index is not None
                         else len(t.ids) >= AUTO_INDEX_SENDERS)
            args = (t.rows, t.store, due, own_times, own_pos, now_s, self.timeout_s,
                    self.silent_hold_s, self.use_received, self.silent_radius_m,
                    self.silent_speed_mps, self.silent_accel_mps2, radius_m, ov_start, ov_col,
                    ov_radius, np.ascontiguousarray(sig[:, 0]),
                    np.ascontiguousarray(sig[:, 1]), self.sigma_k, use_index, cell, *out)
            # The receivers on threads when there are several of each.
            blocks = thread_count() if self.blocks is None else self.blocks
            if blocks > 1 and r_count > 1:
                ne, ns = bound(encounter_rows_threads)(*args, blocks)
            else:
                ne, ns = bound(encounter_rows)(*args)
            if ne <= self._cap_e and ns <= self._cap_s:
                break
            self._cap_e = max(self._cap_e, 2 * ne)
            self._cap_s = max(self._cap_s, 2 * ns)
        return FoundRows(self.table, due, out)

    def find(self, due: np.ndarray, own_times: np.ndarray, own_pos: np.ndarray,
             now_s: np.ndarray, radius_m: np.ndarray,
             overrides: list[dict[int, float]] | None = None,
             own_sigma_m: np.ndarray | None = None) -> list[Encounters]:
        """The encounters of each receiver row in ``due`` (R,), see :func:`encounter_rows`
        (``overrides``: per receiver, column → radius; ``own_sigma_m`` (R, 2): each
        receiver's own position uncertainty, horizontal and vertical 1σ [m], default 0)."""
        found = self.find_rows(due, own_times, own_pos, now_s, radius_m, overrides,
                               own_sigma_m)
        return [found.encounters(j) for j in range(due.shape[0])]

    def heard(self, row: int, now_s: float, own_xy_m: np.ndarray,
              limit: int = MAX_HEARD) -> tuple[str, ...]:
        """(docs/safety.md, A2.) The ids whose plans receiver ``row`` counts at ``now_s`` (its
        clock): every sender it holds a fresh or recently silent prediction of, near or not —
        what its next message lists (:attr:`~uavmpc.comms.PredictionMessage.heard`). Beyond
        ``limit``, the nearest to ``own_xy_m`` (2,) [m, ENU] first."""
        t = self.table
        out = np.empty(limit, dtype=np.int64)
        n = heard_columns(t.rows, t.store, int(row), float(now_s), self.use_received,
                          self.timeout_s, self.silent_hold_s, float(own_xy_m[0]),
                          float(own_xy_m[1]), out)
        return tuple(map(t.ids.__getitem__, out[:n].tolist()))

    def _buffers(self, r_count: int, m: int) -> EncounterOutputs:
        """The outputs of one call, fresh: the encounters it returns are views of them."""
        ce, cs = self._cap_e, self._cap_s
        return EncounterOutputs(
            np.empty(r_count + 1, dtype=np.int64), np.empty(ce, dtype=np.int64),
            np.empty(ce, dtype=np.bool_), np.empty((ce, m), dtype=np.bool_),
            np.empty((ce, m), dtype=np.bool_), np.empty((ce, m)), np.empty((ce, m)),
            np.empty(ce, dtype=np.bool_), np.empty(ce),
            np.empty(r_count + 1, dtype=np.int64), np.empty(cs, dtype=np.int64))
