"""Received predictions as arrays: one store of decoded messages, one row of "newest per
sender" per receiving UAV (SPEC §5.1).

A simulated world of N UAVs delivers each broadcast to N − 1 receivers. The bytes are the same
for all of them and decoding is a pure function of the bytes, so a :class:`InboxTable` decodes
each distinct byte string once into a **slot** of its store (:class:`Store`) and each receiver
holds, per sender, the slot of the newest message it accepted (:class:`InboxRows`). The rule
a receiver applies to each copy it gets — reject a future-stamped or stale one, ignore its
own, keep it only if newer than what it holds — is one compiled law, :func:`accept_copies`,
run for a whole tick's deliveries and, through :func:`accept_copy`, for one datagram by
:meth:`uavmpc.comms.link.Inbox.accept` (a view on one row).

Slots are reference-counted by the receivers holding them and reused once nobody does; a
decoded message is therefore never copied per receiver, and memory grows with the number of
distinct messages held, not with N².
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from typing import NamedTuple

import numba
import numpy as np

from uavmpc.comms.message import (
    ENTRY_BYTES,
    MAX_HEARD,
    SCHEMA_VERSION,
    InvalidMessageError,
    PredictionMessage,
    decode,
    id_entry,
    valid_id,
)
from uavmpc.jit import bound, kernel

#: Outcomes of :func:`accept_copies`.
KEPT, SUPERSEDED, FUTURE, STALE, OWN = 0, 1, 2, 3, 4
#: The rejection reasons as :func:`~uavmpc.comms.message.validate_on_receipt` names them.
FUTURE_REASON = "future-stamped"
STALE_REASON = "stale"
#: Garbage is decoded once per distinct byte string; a flood of distinct garbage is bounded.
_MAX_FAILURES_CACHED = 4096
#: A sender's clock, measured against ours (the stamp check): per receiver and sender, the
#: floor of arrival − stamp (its clock offset plus the link's shortest latency, the way NTP's
#: minimum-delay filter reads it) over the copies that arrive, followed at a bounded rate.
#: Stamps are trusted while the floor is within CLOCK_TRUST_S of zero; beyond it the sender's
#: clock is off, and its messages are put on our clock by the floor (error: the shortest
#: latency) instead of being refused as future-stamped or stale — a refused message is a
#: neighbour nobody avoids. (Found by the falsifier: clocks ±0.5 s apart made one UAV refuse
#: every message of two others, 0.94 m.)
CLOCK_TRUST_S = 0.25
#: Only copies within this of our clock measure it: a stamp further off is not a clock
#: offset worth following but a forged or broken one (refused as before).
MAX_CLOCK_OFFSET_S = 2.0
#: The floor rises at most this fast [s/s] (a sender whose clock steps back, or drifts). It
#: starts at the first arrival and falls to a lower one at once, but by more than
#: CLOCK_TRUST_S only when two arrivals in a row say so (to the higher of the two): one
#: garbled stamp later does not move it. (A garbled first stamp does, until the floor has
#: risen back at that rate: an open weakness, a UDP checksum or a signature makes it rare.)
CLOCK_FLOOR_RISE = 0.01


class Store(NamedTuple):
    """Decoded messages, one slot each (C slots of up to M points).

    Attributes:
        times_s: (C, M) absolute times; positions_m: (C, M, 3) ENU; points: (C,) int64 m.
        stamp_s: (C,); col: (C,) int64 sender column; priority: (C,) int64; avoiding: (C,).
        bbox_m: (C, 4) [x_min, x_max, y_min, y_max] of the points; end_velocity_mps: (C, 2)
            the last segment's horizontal velocity (its extrapolation past the end).
        holders: (C,) int64 receivers holding the slot, and one while a sender's side keeps
            it for copies in flight (:meth:`InboxTable.hold`); pinned: (C,) int8 in use by a
            delivery in progress; generation: (C,) int64 bumped when a slot is reused.
        sigma_m: (C, 2) the sender's position uncertainty, horizontal and vertical 1σ [m].
        heard_col: (C, :data:`~uavmpc.comms.message.MAX_HEARD`) int64 the UAVs its heard list
            names, as the table's columns, the first ``heard_n`` (C,) int64 of them (the
            names the table has no column for are left out: none is a receiver's).
    """

    times_s: np.ndarray
    positions_m: np.ndarray
    points: np.ndarray
    stamp_s: np.ndarray
    col: np.ndarray
    priority: np.ndarray
    avoiding: np.ndarray
    bbox_m: np.ndarray
    end_velocity_mps: np.ndarray
    holders: np.ndarray
    pinned: np.ndarray
    generation: np.ndarray
    sigma_m: np.ndarray
    heard_col: np.ndarray
    heard_n: np.ndarray

    @classmethod
    def empty(cls, slots: int, points: int) -> Store:
        return cls(np.zeros((slots, points)), np.zeros((slots, points, 3)),
                   np.zeros(slots, dtype=np.int64), np.zeros(slots),
                   np.full(slots, -1, dtype=np.int64), np.zeros(slots, dtype=np.int64),
                   np.zeros(slots, dtype=np.bool_), np.zeros((slots, 4)), np.zeros((slots, 2)),
                   np.zeros(slots, dtype=np.int64), np.zeros(slots, dtype=np.int8),
                   np.zeros(slots, dtype=np.int64), np.zeros((slots, 2)),
                   np.zeros((slots, MAX_HEARD), dtype=np.int64),
                   np.zeros(slots, dtype=np.int64))


class InboxRows(NamedTuple):
    """N receivers' views of S senders (row = receiver, column = sender).

    Attributes:
        held_slot: (N, S) int64 the store slot of the newest accepted message (−1: none).
        held_stamp_s: (N, S) its stamp; held_received_s: (N, S) its time on the receiver's
            clock when its stamp is not that: its arrival (the receive-time reference), or its
            stamp put on our clock by the sender's measured offset (a sender whose clock is
            off); NaN: the stamp.
        own_col: (N,) int64 each receiver's own column (its echoes are ignored).
        receive_time: (N,) bool the receiver uses the receive-time reference: stamps are then
            only compared with the same sender's stamps.
        max_future_s, max_age_s: (N,) the clock tolerance and the age limit of the stamp check.
        accepted, superseded, future, stale: (N,) int64 counters.
        lag_floor_s: (N, S) the floor of arrival − stamp [s] (NaN: none yet),
            lag_floor_at_s: (N, S) the receiver's clock when it was last updated, and
            lag_low_s: (N, S) an arrival's lag far below it awaiting a second (NaN: none).
    """

    held_slot: np.ndarray
    held_stamp_s: np.ndarray
    held_received_s: np.ndarray
    own_col: np.ndarray
    receive_time: np.ndarray
    max_future_s: np.ndarray
    max_age_s: np.ndarray
    accepted: np.ndarray
    superseded: np.ndarray
    future: np.ndarray
    stale: np.ndarray
    lag_floor_s: np.ndarray
    lag_floor_at_s: np.ndarray
    lag_low_s: np.ndarray


@kernel
def accept_copies(rows: InboxRows, store: Store, receivers: np.ndarray, slots: np.ndarray,
                  now_s: np.ndarray) -> int:
    """The receiver's rule for valid messages, a tick's deliveries in their order: copy k,
    the message in store slot ``slots[k]`` (K,), arriving at row ``receivers[k]`` at that
    row's clock ``now_s[receivers[k]]`` ((N,) per row); a copy of slot −1 (its bytes could
    not be read) or to a receiver past the rows (not a row's) is passed over. Each copy is
    :data:`FUTURE` or
    :data:`STALE` (the stamp check, counted), :data:`OWN` (the receiver's own echo, ignored),
    :data:`SUPERSEDED` (not newer than the one held, counted) or :data:`KEPT` (held from now
    on). Returns the outcome of the last copy (of the only one, :func:`accept_copy`)."""
    return _accept_block(rows, store, receivers, slots, now_s, 0, rows.own_col.shape[0],
                         store.holders)


@kernel(parallel=True)
def accept_copies_threads(rows: InboxRows, store: Store, receivers: np.ndarray,
                          slots: np.ndarray, now_s: np.ndarray, blocks: int) -> None:
    """:func:`accept_copies` with the receivers in ``blocks`` contiguous blocks of rows, one
    per thread: each thread takes the copies of its rows, in their order, and counts the
    slots' holders in an array of its own, added up after (integers: the same counts in any
    order). The same rows and counts for any number of blocks."""
    n = rows.own_col.shape[0]
    nb = max(1, min(n, blocks))
    delta = np.zeros((nb, store.holders.shape[0]), dtype=np.int64)
    for b in numba.prange(nb):
        _accept_block(rows, store, receivers, slots, now_s, b * n // nb, (b + 1) * n // nb,
                      delta[b])
    for b in range(nb):
        for c in range(delta.shape[1]):
            store.holders[c] += delta[b, c]


@kernel
def _accept_block(rows: InboxRows, store: Store, receivers: np.ndarray, slots: np.ndarray,
                  now_s: np.ndarray, r_lo: int, r_hi: int, holders: np.ndarray) -> int:
    """:func:`accept_copies` for the copies whose receiver is in rows [``r_lo``, ``r_hi``),
    the slots' holder counts changed in ``holders`` (C,) (the store's, or a thread's own).

    The rule is written in the loop itself rather than called per copy: a compiled call that
    takes the records increments and decrements the reference count of each of their arrays
    on every call (an atomic operation each), which costs several times the rule itself
    (``python benchmarks/record_calls.py``)."""
    outcome = KEPT
    for k in range(receivers.shape[0]):
        r = receivers[k]
        if r < r_lo or r >= r_hi:
            continue
        slot = slots[k]
        if slot < 0:  # a message that could not be read: the caller counts it rejected
            continue
        t = now_s[r]
        col = store.col[slot]
        stamp = store.stamp_s[slot]
        on_our_clock = math.nan  # the stamp is ours
        if not rows.receive_time[r]:
            lag = t - stamp
            floor = rows.lag_floor_s[r, col]
            if abs(lag) <= MAX_CLOCK_OFFSET_S:
                low = rows.lag_low_s[r, col]  # an arrival far below the floor, unconfirmed
                rows.lag_low_s[r, col] = math.nan
                if math.isnan(floor):
                    floor = lag
                elif lag < floor - CLOCK_TRUST_S:
                    if math.isnan(low):
                        rows.lag_low_s[r, col] = lag
                    else:
                        floor = max(low, lag)
                elif lag < floor:
                    floor = lag
                else:
                    floor = min(lag, floor + CLOCK_FLOOR_RISE * (t - rows.lag_floor_at_s[r, col]))
                rows.lag_floor_s[r, col] = floor
                rows.lag_floor_at_s[r, col] = t
            offset = 0.0  # our clock less the sender's, as far as it is measured
            if not math.isnan(floor) and abs(floor) > CLOCK_TRUST_S \
                    and abs(lag) <= MAX_CLOCK_OFFSET_S:
                offset = floor  # its clock is off: measured, not refused
                on_our_clock = stamp + floor
            elif -lag > rows.max_future_s[r]:
                rows.future[r] += 1
                outcome = FUTURE
                continue
            if lag - offset > rows.max_age_s[r]:
                rows.stale[r] += 1
                outcome = STALE
                continue
        if col == rows.own_col[r]:
            outcome = OWN
            continue
        held = rows.held_slot[r, col]
        if held >= 0 and stamp <= rows.held_stamp_s[r, col]:
            rows.superseded[r] += 1
            outcome = SUPERSEDED
            continue
        if held >= 0:
            holders[held] -= 1
        holders[slot] += 1
        rows.held_slot[r, col] = slot
        rows.held_stamp_s[r, col] = stamp
        if rows.receive_time[r]:
            rows.held_received_s[r, col] = t
        elif not (math.isnan(on_our_clock) and math.isnan(rows.held_received_s[r, col])):
            rows.held_received_s[r, col] = on_our_clock  # (else NaN already: a store less)
        rows.accepted[r] += 1
        outcome = KEPT
    return outcome


@kernel(allocates=True)
def accept_copy(rows: InboxRows, store: Store, r: int, slot: int, now_s: float) -> int:
    """:func:`accept_copies` for one message (store ``slot``) arriving at row ``r`` at its
    clock ``now_s``: its outcome."""
    clock = np.empty(rows.own_col.shape[0])
    clock[r] = now_s
    return accept_copies(rows, store, np.full(1, r), np.full(1, slot), clock)


@kernel
def _bbox(times: np.ndarray, pos: np.ndarray, n: int, box: np.ndarray, vend: np.ndarray
          ) -> None:
    box[0] = box[1] = pos[0, 0]
    box[2] = box[3] = pos[0, 1]
    for k in range(1, n):
        box[0] = min(box[0], pos[k, 0])
        box[1] = max(box[1], pos[k, 0])
        box[2] = min(box[2], pos[k, 1])
        box[3] = max(box[3], pos[k, 1])
    dt = times[n - 1] - times[n - 2]
    vend[0] = (pos[n - 1, 0] - pos[n - 2, 0]) / dt
    vend[1] = (pos[n - 1, 1] - pos[n - 2, 1]) / dt


@kernel
def fill_slot(store: Store, slot: int, col: int, m: int, stamp_s: float, priority: int,
              avoiding: bool, sigma_h_m: float, sigma_v_m: float) -> None:
    """A message into store ``slot``, its ``m`` times and positions written there already:
    its sender's column ``col``, its fields, and what the search derives from its plan (the
    box of its points, its end's velocity)."""
    store.points[slot] = m
    store.stamp_s[slot] = stamp_s
    store.col[slot] = col
    store.priority[slot] = priority
    store.avoiding[slot] = avoiding
    store.sigma_m[slot, 0] = sigma_h_m
    store.sigma_m[slot, 1] = sigma_v_m
    _bbox(store.times_s[slot], store.positions_m[slot], m, store.bbox_m[slot],
          store.end_velocity_mps[slot])


class InboxTable:
    """The store and the rows of N receivers (ids ``receivers``, in row order).

    Senders get a column the first time they are seen (the receivers themselves first, in
    order); the arrays grow as needed. ``time_reference``, ``max_future_s``, ``max_age_s``:
    as :class:`~uavmpc.comms.link.Inbox` documents them, the same for every row.
    """

    def __init__(self, receivers: Sequence[str], *, time_reference: str = "stamp",
                 max_future_s: float = 0.5, max_age_s: float = 1.0, points: int = 40) -> None:
        if time_reference not in ("stamp", "receive"):
            raise ValueError(
                f"time_reference: must be 'stamp' or 'receive', got {time_reference!r}")
        self.receivers = list(receivers)
        self.time_reference = time_reference
        self.max_future_s = float(max_future_s)
        self.max_age_s = float(max_age_s)
        self.ids: list[str] = []
        self.cols: dict[str, int] = {}
        n = len(self.receivers)
        self.rows = self._rows(n, max(4, n))
        #: (S, :data:`~uavmpc.comms.message.ENTRY_BYTES`) uint8 each column's id as a message
        #: lists it (:func:`~uavmpc.comms.message.id_entry`; zeros for an id no message may
        #: carry): what a compiled broadcast writes into its heard list.
        self.entries = np.zeros((self.rows.held_slot.shape[1], ENTRY_BYTES), dtype=np.uint8)
        self.store = Store.empty(max(8, 2 * n), points)
        #: Per store slot: its message's heard list by name when it was decoded (it may name
        #: UAVs the table has no column for); None when it was written from columns
        #: (the store's ``heard_col``). :meth:`heard_ids` reads either.
        self.heard: list[tuple[str, ...] | None] = [()] * self.store.holders.shape[0]
        for r, uid in enumerate(self.receivers):
            self.rows.own_col[r] = self.col_of(uid)
        #: Rejections the stamp check does not count (decoding, signatures), per row.
        self.reasons: list[dict[str, int]] = [{} for _ in range(n)]
        self._free: list[int] = list(range(self.store.holders.shape[0] - 1, -1, -1))
        self._decoded: dict[bytes, tuple[int, int] | str] = {}
        self._failures = 0

    def _rows(self, n: int, s: int) -> InboxRows:
        return InboxRows(np.full((n, s), -1, dtype=np.int64), np.zeros((n, s)),
                         np.full((n, s), np.nan), np.zeros(n, dtype=np.int64),
                         np.full(n, self.time_reference == "receive"),
                         np.full(n, self.max_future_s), np.full(n, self.max_age_s),
                         np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                         np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                         np.full((n, s), np.nan), np.zeros((n, s)),
                         np.full((n, s), np.nan))

    # ------------------------------------------------------------------ senders
    def col_of(self, uav_id: str) -> int:
        """The column of ``uav_id`` (a new one the first time)."""
        col = self.cols.get(uav_id)
        if col is None:
            col = len(self.ids)
            self.ids.append(uav_id)
            self.cols[uav_id] = col
            if col >= self.rows.held_slot.shape[1]:
                self._grow_columns(2 * col)
            if valid_id(uav_id):
                self.entries[col] = np.frombuffer(id_entry(uav_id), dtype=np.uint8)
        return col

    def _grow_columns(self, s: int) -> None:
        old = self.rows
        n, s0 = old.held_slot.shape
        new = self._rows(n, s)
        new.held_slot[:, :s0] = old.held_slot
        new.held_stamp_s[:, :s0] = old.held_stamp_s
        new.held_received_s[:, :s0] = old.held_received_s
        new.lag_floor_s[:, :s0] = old.lag_floor_s
        new.lag_floor_at_s[:, :s0] = old.lag_floor_at_s
        new.lag_low_s[:, :s0] = old.lag_low_s
        for name in ("own_col", "receive_time", "max_future_s", "max_age_s", "accepted",
                     "superseded", "future", "stale"):
            getattr(new, name)[:] = getattr(old, name)
        self.rows = new
        entries = np.zeros((s, ENTRY_BYTES), dtype=np.uint8)
        entries[:s0] = self.entries
        self.entries = entries

    # ------------------------------------------------------------------ messages
    def slot_for(self, data: bytes) -> int:
        """The store slot holding the message ``data`` decodes to (decoded once per distinct
        byte string while its slot lives, or written by the sender's side and kept with
        :meth:`hold`), pinned until :meth:`unpin`; raises
        :class:`~uavmpc.comms.message.InvalidMessageError` naming the problem."""
        hit = self._decoded.get(data)
        if isinstance(hit, str):
            raise InvalidMessageError(hit)
        if hit is not None and self.store.generation[hit[0]] == hit[1]:
            self.store.pinned[hit[0]] = 1
            return hit[0]
        try:
            msg = decode(data)
        except InvalidMessageError as exc:
            if self._failures >= _MAX_FAILURES_CACHED:
                self._decoded = {k: v for k, v in self._decoded.items() if not isinstance(v, str)}
                self._failures = 0
            self._decoded[bytes(data)] = str(exc)
            self._failures += 1
            raise
        slot = self.put(msg)
        self._remember(data, slot)
        return slot

    def _remember(self, data: bytes, slot: int) -> None:
        """``data`` decodes to the message in ``slot`` (while the slot is not reused)."""
        if len(self._decoded) > 4 * self.store.holders.shape[0]:
            gen = self.store.generation
            self._decoded = {k: v for k, v in self._decoded.items()
                             if isinstance(v, str) or gen[v[0]] == v[1]}
        self._decoded[bytes(data)] = (slot, int(self.store.generation[slot]))

    def put(self, msg: PredictionMessage) -> int:
        """Write a valid message into a free slot (pinned until :meth:`unpin`)."""
        slot = self.reserve(msg.points)
        st = self.store
        m = msg.points
        st.times_s[slot, :m] = msg.times_s
        st.positions_m[slot, :m] = msg.positions_m
        bound(fill_slot)(st, slot, self.col_of(msg.uav_id), m, msg.stamp_s, msg.priority,
                         msg.avoiding, *msg.position_sigma_m)
        cols = [c for c in map(self.cols.get, msg.heard) if c is not None]
        st.heard_col[slot, :len(cols)] = cols
        st.heard_n[slot] = len(cols)
        self.heard[slot] = msg.heard
        return slot

    def heard_ids(self, slot: int) -> tuple[str, ...]:
        """The heard list of the message in ``slot``, by name."""
        names = self.heard[slot]
        if names is not None:
            return names
        cols = self.store.heard_col[slot, :self.store.heard_n[slot]].tolist()
        return tuple(map(self.ids.__getitem__, cols))

    def reserve(self, points: int) -> int:
        """A free slot for a message of ``points`` points, pinned until :meth:`unpin`: the
        caller writes its times and positions, then :func:`fill_slot`, and its heard list
        (the store's ``heard_col`` and ``heard_n``; or :attr:`heard`)."""
        if points > self.store.times_s.shape[1]:
            self._grow_store(self.store.holders.shape[0], points)
        slot = self._allocate()
        self.heard[slot] = None
        self.store.pinned[slot] = 1
        return slot

    def hold(self, slots: np.ndarray, data: Sequence[bytes]) -> None:
        """Keep each of ``slots`` (R,) (the message ``data[j]`` decodes to, written by the
        caller) while copies of it are in flight: :meth:`slot_for` finds it without
        decoding, and no other message takes the slot until :meth:`let_go`."""
        self.store.holders[slots] += 1
        for d, slot in zip(data, slots.tolist(), strict=True):
            self._remember(d, slot)

    def let_go(self, slot: int) -> None:
        """The copies of a slot :meth:`hold` kept are all delivered."""
        self.store.holders[slot] -= 1

    def unpin(self) -> None:
        """End of a delivery: slots nobody holds may be reused."""
        self.store.pinned[:] = 0

    def _allocate(self) -> int:
        st = self.store
        while self._free:
            slot = self._free.pop()
            if st.holders[slot] == 0 and not st.pinned[slot]:
                st.generation[slot] += 1
                return slot
        free = np.flatnonzero((st.holders == 0) & (st.pinned == 0))
        if free.size == 0:
            c = st.holders.shape[0]
            self._grow_store(2 * c, st.times_s.shape[1])
            free = np.arange(c, 2 * c)
        self._free = free[::-1].tolist()
        return self._allocate()

    def _grow_store(self, slots: int, points: int) -> None:
        old = self.store
        c = old.times_s.shape[0]
        new = Store.empty(slots, points)
        for arr, dst in zip(old, new, strict=True):
            dst[tuple(slice(0, k) for k in arr.shape)] = arr
        self.store = new
        self.heard.extend([()] * (slots - c))

    def message(self, r: int, col: int) -> PredictionMessage | None:
        """Row ``r``'s message from column ``col`` as an object (None if it holds none)."""
        slot = int(self.rows.held_slot[r, col])
        if slot < 0:
            return None
        st = self.store
        m = int(st.points[slot])
        rec = float(self.rows.held_received_s[r, col])
        return PredictionMessage(SCHEMA_VERSION, self.ids[col], int(st.priority[slot]),
                                 float(st.stamp_s[slot]), st.times_s[slot, :m],
                                 st.positions_m[slot, :m], bool(st.avoiding[slot]),
                                 None if np.isnan(rec) else rec, self.heard_ids(slot),
                                 (float(st.sigma_m[slot, 0]), float(st.sigma_m[slot, 1])))


class LatestView(Mapping[str, PredictionMessage]):
    """Row ``r`` of an :class:`InboxTable` as "the newest message per sender" (column order),
    the objects built when first asked for and kept while the row holds the same message."""

    def __init__(self, table: InboxTable, r: int) -> None:
        self._table = table
        self._r = r
        self._cache: dict[int, tuple[int, float, PredictionMessage]] = {}

    def _cols(self) -> np.ndarray:
        t = self._table
        held = t.rows.held_slot[self._r, :len(t.ids)]
        return np.flatnonzero(held >= 0)

    def __getitem__(self, uav_id: str) -> PredictionMessage:
        t = self._table
        col = t.cols.get(uav_id)
        if col is None:
            raise KeyError(uav_id)
        slot = int(t.rows.held_slot[self._r, col])
        if slot < 0:
            raise KeyError(uav_id)
        rec = float(t.rows.held_received_s[self._r, col])
        hit = self._cache.get(col)
        if hit is not None and hit[0] == slot and (
                hit[1] == rec or (math.isnan(hit[1]) and math.isnan(rec))):
            return hit[2]
        msg = t.message(self._r, col)
        assert msg is not None
        self._cache[col] = (slot, rec, msg)
        return msg

    def remember(self, col: int, msg: PredictionMessage) -> None:
        """The object just accepted for ``col`` (returned by the same lookup from now on)."""
        t = self._table
        rec = float(t.rows.held_received_s[self._r, col])
        self._cache[col] = (int(t.rows.held_slot[self._r, col]), rec, msg)

    def __iter__(self) -> Iterator[str]:
        ids = self._table.ids
        return iter([ids[c] for c in self._cols()])

    def __len__(self) -> int:
        return int(self._cols().size)

    def __contains__(self, uav_id: object) -> bool:
        col = self._table.cols.get(uav_id) if isinstance(uav_id, str) else None
        return col is not None and self._table.rows.held_slot[self._r, col] >= 0
