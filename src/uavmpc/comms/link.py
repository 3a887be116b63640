"""Transports for prediction messages, and the receiver's inbox (SPEC §5.1).

Messages travel as bytes: a real radio or network only ever hands over bytes, and receivers must
decode and validate whatever arrives (:class:`Inbox`).

- :class:`Transport` is the one contract: ``publish`` a broadcast, ``receive`` what arrived.
- :class:`SimulatedLink` is the in-process broadcast medium of the simulated world, on the
  simulated clock: fixed latency plus uniform jitter, random loss (independent, or in bursts),
  an optional range limit.
- :class:`Inbox` keeps the newest valid message per sender and counts what it rejected.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple, Protocol, runtime_checkable

import numba
import numpy as np

from uavmpc.comms.auth import Roster, check_key, unseal, verify
from uavmpc.comms.inbox import (
    FUTURE_REASON,
    KEPT,
    STALE_REASON,
    InboxTable,
    LatestView,
    accept_copy,
)
from uavmpc.comms.message import InvalidMessageError, PredictionMessage
from uavmpc.jit import bound, kernel, thread_count


@runtime_checkable
class Transport(Protocol):
    """A broadcast medium for encoded messages (unconfirmed: no ack, no retransmission)."""

    def publish(self, msg_bytes: bytes, sender_id: str, t_s: float) -> None:
        """Broadcast ``msg_bytes`` from ``sender_id`` at time ``t_s`` (s)."""
        ...

    def receive(self, receiver_id: str, t_s: float) -> list[bytes]:
        """Everything delivered to ``receiver_id`` by time ``t_s`` and not yet taken, oldest
        delivery first."""
        ...


class Samples(Protocol):
    """A queue of samples on one topic pattern (what a network subscription delivers)."""

    def drain(self, limit: int | None = None) -> list[tuple[str, bytes]]:
        """Up to ``limit`` queued (key, payload) pairs, oldest first (all with None)."""
        ...


class NetworkTransport(Transport, Protocol):
    """A transport between processes (:class:`~uavmpc.comms.zenoh_link.ZenohTransport`):
    besides the predictions' broadcast, named topics under the swarm's key space, which a
    node puts its state on and takes its missions and commands from."""

    def put(self, topic: str, payload: bytes) -> None:
        """Put ``payload`` on this sender's ``topic`` (best effort)."""
        ...

    def subscribe(self, keyexpr_suffix: str, maxlen: int = 1024) -> Samples:
        """Queue the samples on the swarm's ``keyexpr_suffix`` (at most ``maxlen``)."""
        ...


@dataclass
class LinkStats:
    """Counters of a :class:`SimulatedLink`, per receiver copy of a broadcast.

    Attributes:
        published: ``publish`` calls.
        sent: copies attempted (one per other member per publish).
        delivered: copies handed to receivers by ``receive``.
        dropped: copies lost at random (``loss``; in bursts too, with ``burst_len``).
        dropped_range: copies not delivered because the receiver was out of range.
        injected: raw byte strings delivered by :meth:`SimulatedLink.inject`.
    """

    published: int = 0
    sent: int = 0
    delivered: int = 0
    dropped: int = 0
    dropped_range: int = 0
    injected: int = 0

    @property
    def in_flight(self) -> int:
        """Copies scheduled but not yet received."""
        return (self.sent + self.injected - self.delivered - self.dropped
                - self.dropped_range)


def _burst_thresholds(loss: float, burst_len: float) -> np.ndarray:
    """The Gilbert channel of loss rate ``loss`` and mean burst ``burst_len`` (copies), as the
    loss thresholds of a uniform draw in [0, 1) by previous state: (no copy yet, Good, Bad) →
    (P, p, 1 − r) with r = 1 / burst_len, p = P r / (1 − P) (see :class:`SimulatedLink`)."""
    if not (math.isfinite(burst_len) and burst_len >= 1.0):
        raise ValueError(f"burst_len: must be 0 (independent losses) or a finite mean burst "
                         f"length ≥ 1 (copies), got {burst_len}")
    if not (0.0 <= loss < 1.0):
        raise ValueError(f"burst_len: needs loss < 1 (a channel always Bad has no bursts), "
                         f"got burst_len={burst_len:g} with loss={loss:g}")
    r = 1.0 / burst_len
    p = loss * r / (1.0 - loss)
    if p > 1.0 + 1e-12:  # rounding at the limit L = P / (1 − P) is not an error
        raise ValueError(f"burst_len={burst_len:g} with loss={loss:g} needs P(good→bad) = "
                         f"{p:.3g} > 1 (bursts that short cannot lose that much: need "
                         f"burst_len ≥ loss / (1 − loss) = {loss / (1.0 - loss):.3g})")
    return np.array([loss, min(p, 1.0), 1.0 - r])


class InFlight(NamedTuple):
    """The copies a :class:`SimulatedLink` has in flight: one chunk per broadcast, in sending
    order, each chunk's copies sorted by (delivery time, sequence number) — the order a heap
    per receiver would give. Grown as needed.

    Attributes:
        at_s: (Q,) when each copy is due [s]; seq: (Q,) int64 its sequence number (ties of
            equal times go in sending order); receiver: (Q,) int64 its receiver's member index
            (−1: taken by :meth:`SimulatedLink.receive` already).
        pos, end: (C,) int64 a chunk's copies not yet delivered are [pos, end); sender: (C,)
            int64 its sender (−1: bytes injected); payload: (C,) int64 its payload id; taken:
            (C,) bool some of its copies were taken by ``receive``.
    """

    at_s: np.ndarray
    seq: np.ndarray
    receiver: np.ndarray
    pos: np.ndarray
    end: np.ndarray
    sender: np.ndarray
    payload: np.ndarray
    taken: np.ndarray

    @classmethod
    def empty(cls, copies: int, chunks: int) -> InFlight:
        """Room for ``copies`` copies in ``chunks`` chunks (only the queue's used part is
        ever read: nothing is initialised)."""
        return cls(np.empty(copies), np.empty(copies, dtype=np.int64),
                   np.empty(copies, dtype=np.int64), np.empty(chunks, dtype=np.int64),
                   np.empty(chunks, dtype=np.int64), np.empty(chunks, dtype=np.int64),
                   np.empty(chunks, dtype=np.int64), np.empty(chunks, dtype=np.bool_))


@kernel
def stable_order(keys: np.ndarray, n: int, order: np.ndarray, bucket: np.ndarray) -> None:
    """``order[:n]``: the indices of ``keys[:n]`` in ascending order, equal keys in index
    order (``np.argsort(keys[:n], kind="stable")``), in expected linear time for keys spread
    like a link's delivery times: a bucket per key by where it lies between the smallest and
    the largest (monotone in the key, so equal keys share a bucket), filled in index order,
    each bucket then sorted by insertion. ``bucket`` (n + 1,) int64: work."""
    if n == 0:
        return
    lo = hi = keys[0]
    for i in range(1, n):
        lo = min(lo, keys[i])
        hi = max(hi, keys[i])
    if not hi > lo:  # all equal (or not finite): index order
        for i in range(n):
            order[i] = i
        return
    scale = n / (hi - lo)
    bucket[:] = 0
    for i in range(n):
        bucket[min(int((keys[i] - lo) * scale), n - 1) + 1] += 1
    for b in range(n):
        bucket[b + 1] += bucket[b]
    for i in range(n):  # bucket[b]: where bucket b's next index goes
        b = min(int((keys[i] - lo) * scale), n - 1)
        order[bucket[b]] = i
        bucket[b] += 1
    for i in range(1, n):  # insertion: moves only within a bucket, never past an equal key
        cur = order[i]
        j = i - 1
        while j >= 0 and keys[order[j]] > keys[cur]:
            order[j + 1] = order[j]
            j -= 1
        order[j + 1] = cur


@kernel
def _draw_copies(j: int, s: int, draws: np.ndarray, loss: float, thresholds: np.ndarray,
                 burst: bool, state: np.ndarray, in_range: np.ndarray, ranged: bool,
                 latency_s: float, jitter_s: float, t_s: float, at: np.ndarray,
                 rcv: np.ndarray) -> tuple[int, int, int]:
    """Broadcast ``j`` from member ``s``, as :func:`queue_copies` draws it: its copies' times
    and receivers, in receiver order, into ``at`` and ``rcv`` (n − 1,); returns (copies,
    lost, out of range). Steps the sender's row of ``state`` only."""
    n1 = draws.shape[2]
    c = 0
    lost_n = 0
    out_n = 0
    for k in range(n1):
        r = k if k < s else k + 1
        lost = draws[j, 0, k] < (thresholds[state[s, r] + 1] if burst else loss)
        near = in_range[j, k] if ranged else True
        if burst and near:  # out of range nothing was sent: the chain keeps its state
            state[s, r] = 1 if lost else 0
        if not near:
            out_n += 1
        elif lost:
            lost_n += 1
        else:
            at[c] = t_s + (latency_s + jitter_s * draws[j, 1, k])
            rcv[c] = r
            c += 1
    return c, lost_n, out_n


@kernel
def _place_copies(q: InFlight, used: int, c: int, seq: int, at: np.ndarray, rcv: np.ndarray,
                  order: np.ndarray, bucket: np.ndarray) -> None:
    """``c`` copies (``at``, ``rcv``, in receiver order) into the queue from ``used`` on,
    sorted by time, equal times in receiver order, numbered from ``seq`` in receiver order.
    ``order`` (≥ c,), ``bucket`` (≥ c + 1,): work."""
    stable_order(at, c, order, bucket)
    for i in range(c):
        q.at_s[used + i] = at[order[i]]
        q.seq[used + i] = seq + order[i]
        q.receiver[used + i] = rcv[order[i]]


@kernel
def _open_chunk(q: InFlight, chunk: int, used: int, c: int, sender: int, pid: int) -> None:
    """Chunk ``chunk``: the ``c`` copies from ``used`` on of payload ``pid`` from ``sender``."""
    q.pos[chunk] = used
    q.end[chunk] = used + c
    q.sender[chunk] = sender
    q.payload[chunk] = pid
    q.taken[chunk] = False


@kernel
def _number_chunks(q: InFlight, chunks: int, used: int, seq: int, pid: int,
                   senders: np.ndarray, counts: np.ndarray, pids: np.ndarray,
                   start: np.ndarray, first: np.ndarray) -> tuple[int, int]:
    """The broadcasts' chunks, in sending order, after ``chunks`` chunks and ``used`` copies:
    broadcast j's ``counts[j]`` copies start at ``start[j]`` and are numbered from
    ``first[j]`` (sequence numbers from ``seq`` on); a broadcast with copies gets the next
    payload id from ``pid`` on in ``pids[j]`` (−1 without). Returns (chunks, used)."""
    for j in range(senders.shape[0]):
        c = counts[j]
        start[j] = used
        first[j] = seq
        if c == 0:
            pids[j] = -1
            continue
        _open_chunk(q, chunks, used, c, senders[j], pid)
        pids[j] = pid
        pid += 1
        seq += c
        used += c
        chunks += 1
    return chunks, used


@kernel(allocates=True)
def queue_copies(q: InFlight, chunks: int, used: int, draws: np.ndarray, senders: np.ndarray,
                 loss: float, thresholds: np.ndarray, burst: bool, state: np.ndarray,
                 in_range: np.ndarray, ranged: bool, latency_s: float, jitter_s: float,
                 t_s: float, first_pid: int, first_seq: int, pids: np.ndarray,
                 counts: np.ndarray, at: np.ndarray, rcv: np.ndarray
                 ) -> tuple[int, int, int, int, float]:
    """The copies of broadcasts from ``senders`` (B,) at ``t_s`` onto the queue, a chunk
    each after its ``chunks`` chunks and ``used`` copies (room for B × (n − 1) more): for
    broadcast j and the k-th other member r in join order, the draws ``draws[j, 0, k]`` (lost
    below ``loss``, or with ``burst`` below ``thresholds[state[s, r] + 1]``, the pair's
    chain then stepping if r is in range) and ``draws[j, 1, k]`` (the delay ``latency_s +
    jitter_s`` × draw); with ``ranged``, ``in_range[j, k]`` says whether r is in range. A
    broadcast with copies gets the next payload id from ``first_pid`` on in ``pids[j]`` (−1
    without), its copies' count in ``counts[j]``, and sequence numbers from ``first_seq`` on
    in receiver order. ``at`` (≥ B, n − 1), ``rcv`` (≥ B, n − 1) int64: work. Returns
    (chunks, used, copies lost, copies out of range, the earliest time of the copies
    queued (inf without any)).

    Three passes: each broadcast drawn into its row of the work arrays, the chunks numbered
    in sending order, each broadcast's copies sorted into its place (what
    :func:`queue_copies_threads` does with the first and the last on threads)."""
    b = senders.shape[0]
    n1 = draws.shape[2]
    lost_n = 0
    out_n = 0
    for j in range(b):
        counts[j], lost, out = _draw_copies(j, senders[j], draws, loss, thresholds, burst,
                                            state, in_range, ranged, latency_s, jitter_s, t_s,
                                            at[j], rcv[j])
        lost_n += lost
        out_n += out
    start = np.empty(b, dtype=np.int64)
    first = np.empty(b, dtype=np.int64)
    chunks, used = _number_chunks(q, chunks, used, first_seq, first_pid, senders, counts, pids,
                                  start, first)
    order = np.empty(n1, dtype=np.int64)
    bucket = np.empty(n1 + 1, dtype=np.int64)
    for j in range(b):
        if counts[j]:  # equal times in sending order
            _place_copies(q, start[j], counts[j], first[j], at[j], rcv[j], order, bucket)
    return chunks, used, lost_n, out_n, _first_due(q, counts, start)


@kernel
def _first_due(q: InFlight, counts: np.ndarray, start: np.ndarray) -> float:
    """The earliest time of the copies just placed (each broadcast's first: they are sorted;
    inf without any)."""
    first = np.inf
    for j in range(counts.shape[0]):
        if counts[j]:
            first = min(first, q.at_s[start[j]])
    return first


@kernel(parallel=True)
def queue_copies_threads(q: InFlight, chunks: int, used: int, draws: np.ndarray,
                         senders: np.ndarray, loss: float, thresholds: np.ndarray, burst: bool,
                         state: np.ndarray, in_range: np.ndarray, ranged: bool,
                         latency_s: float, jitter_s: float, t_s: float, first_pid: int,
                         first_seq: int, pids: np.ndarray, counts: np.ndarray,
                         at: np.ndarray, rcv: np.ndarray, blocks: int
                         ) -> tuple[int, int, int, int, float]:
    """:func:`queue_copies` with its first and last passes on threads, ``blocks`` contiguous
    blocks of broadcasts each. The same queue, ids, counts and chains for any number of
    blocks. With ``burst``, ``senders`` must be distinct (each broadcast steps its sender's
    chains only)."""
    b = senders.shape[0]
    n1 = draws.shape[2]
    nb = max(1, min(b, blocks))
    lost = np.empty(b, dtype=np.int64)
    out = np.empty(b, dtype=np.int64)
    for blk in numba.prange(nb):
        for j in range(blk * b // nb, (blk + 1) * b // nb):
            counts[j], lost[j], out[j] = _draw_copies(
                j, senders[j], draws, loss, thresholds, burst, state, in_range, ranged,
                latency_s, jitter_s, t_s, at[j], rcv[j])
    start = np.empty(b, dtype=np.int64)
    first = np.empty(b, dtype=np.int64)
    chunks, used = _number_chunks(q, chunks, used, first_seq, first_pid, senders, counts, pids,
                                  start, first)
    for blk in numba.prange(nb):
        order = np.empty(n1, dtype=np.int64)
        bucket = np.empty(n1 + 1, dtype=np.int64)
        for j in range(blk * b // nb, (blk + 1) * b // nb):
            if counts[j]:
                _place_copies(q, start[j], counts[j], first[j], at[j], rcv[j], order, bucket)
    return chunks, used, int(lost.sum()), int(out.sum()), _first_due(q, counts, start)


@kernel
def take_copies(q: InFlight, chunks: int, t_s: float, seen: np.ndarray, rcv_out: np.ndarray,
                which_out: np.ndarray, at_out: np.ndarray, seq_out: np.ndarray,
                pid_out: np.ndarray, count_out: np.ndarray) -> tuple[int, int, bool]:
    """Every copy due by ``t_s`` and not taken by ``receive``, out of the first ``chunks``
    chunks in sending order: its receiver, its payload's index among the payloads taken,
    its time and sequence number into the outputs (K,); each payload taken (ascending ids:
    one chunk each, in sending order) and its number of copies into ``pid_out`` and
    ``count_out`` (P,). Returns (K, P, whether the copies are in delivery order already: no
    two of their chunks from one sender, none injected). ``seen`` (members,): all False,
    left so."""
    n = 0
    g = 0
    ordered = True
    for c in range(chunks):
        pos, end = q.pos[c], q.end[c]
        if pos >= end or q.at_s[pos] > t_s:
            continue
        stop = pos
        first = n
        while stop < end and q.at_s[stop] <= t_s:
            if q.receiver[stop] >= 0:
                rcv_out[n] = q.receiver[stop]
                which_out[n] = g
                at_out[n] = q.at_s[stop]
                seq_out[n] = q.seq[stop]
                n += 1
            stop += 1
        q.pos[c] = stop
        if n > first:
            pid_out[g] = q.payload[c]
            count_out[g] = n - first
            g += 1
        s = q.sender[c]
        if s < 0 or seen[s]:
            ordered = False
        else:
            seen[s] = True
    for c in range(chunks):
        if q.sender[c] >= 0:
            seen[q.sender[c]] = False
    return n, g, ordered


@kernel
def sweep_copies(q: InFlight, chunks: int) -> tuple[int, float]:
    """Forget the chunks delivered in full (the others keep their order); returns (chunks
    left, the earliest time one of their copies is due: inf without)."""
    live = 0
    nxt = math.inf
    for c in range(chunks):
        pos, end = q.pos[c], q.end[c]
        while pos < end and q.receiver[pos] < 0:
            pos += 1
        if pos >= end:
            continue
        nxt = min(nxt, q.at_s[pos])
        q.pos[live] = pos
        q.end[live] = end
        q.sender[live] = q.sender[c]
        q.payload[live] = q.payload[c]
        q.taken[live] = q.taken[c]
        live += 1
    return live, nxt


@kernel
def move_copies(q: InFlight, chunks: int, into: InFlight) -> int:
    """The first ``chunks`` chunks' undelivered copies, in order, to the front of ``into``
    (at least as large, or ``q`` itself: a copy only ever moves towards the front); returns
    how many copies it then holds."""
    used = 0
    for c in range(chunks):
        pos, end = q.pos[c], q.end[c]
        into.pos[c] = used
        for i in range(pos, end):
            into.at_s[used] = q.at_s[i]
            into.seq[used] = q.seq[i]
            into.receiver[used] = q.receiver[i]
            used += 1
        into.end[c] = used
        into.sender[c] = q.sender[c]
        into.payload[c] = q.payload[c]
        into.taken[c] = q.taken[c]
    return used


#: From this many copies on, :class:`SimulatedLink` queues a tick's broadcasts on threads
#: (:func:`queue_copies_threads`) when it has several: below, starting them costs more than
#: they save.
THREADED_COPIES = 2048


def _at_least(work: np.ndarray, n: int) -> np.ndarray:
    """``work`` if it holds ``n`` elements, else a larger one of its type (at least twice
    as large: grown now and then, never shrunk; its pages stay mapped from call to call)."""
    if work.shape[0] >= n:
        return work
    return np.empty(max(n, 2 * work.shape[0]), dtype=work.dtype)


class Due(NamedTuple):
    """The copies a :meth:`SimulatedLink.take_due` hands over, in delivery order.

    Attributes:
        receivers: (K,) int64 each copy's receiver (its index in the link's members).
        which: (K,) int64 each copy's payload, as an index into ``payloads``.
        payloads: (P,) int64 the payload ids of these copies, ascending (sending order).
        copies: (P,) int64 how many of the copies are of each.
    """

    receivers: np.ndarray
    which: np.ndarray
    payloads: np.ndarray
    copies: np.ndarray


#: Arguments of :func:`queue_copies` without a range or bursts.
_NO_RANGE = np.zeros((0, 0), dtype=np.bool_)
_NO_THRESHOLDS = np.zeros(3)


class SimulatedLink:
    """In-process broadcast link on a simulated clock.

    Every member except the sender gets its own copy of each broadcast, decided independently
    (as on a radio channel): first the range check, then loss with probability ``loss``
    (independently, or in bursts: below), then a delivery delay of ``latency_s + U(0,
    jitter_s)``. Jitter can reorder messages; receivers
    keep the newest stamp per sender (:class:`Inbox`).

    Burst loss: field radios lose packets in bursts (a fade, a blocked line of sight), and
    bursts are what hurts a prediction-sharing avoidance: one lost prediction is covered by the
    previous one, several consecutive predictions of one neighbour missing leave it planning
    against an ageing (then stale) trajectory. With ``burst_len`` > 0 every directed pair
    (sender → receiver) has its own two-state Markov chain (the simple Gilbert model): Good (the
    copy arrives) or Bad (the copy is lost). Its stationary probability of Bad is ``loss`` = P
    and its mean sojourn in Bad is ``burst_len`` = L copies, so

        r = P(Bad → Good) = 1 / L,        p = P(Good → Bad) = P · r / (1 − P),

    which needs P < 1 and p ≤ 1 (L ≥ P / (1 − P)). The chain takes one step per copy the pair
    sends *in range*: a copy to a receiver out of range does not touch the channel, and the
    pair's chain stays frozen until it is in range again. The state of a pair's first copy is
    drawn from the stationary distribution (Bad with probability P), so the loss rate is P from
    the first broadcast on. Chains of different pairs are independent, including two receivers
    of one sender: a burst is a property of a path, not of the transmitter. ``burst_len`` = 0
    is the independent loss above (mean run of losses 1 / (1 − P)).

    Range: when ``range_m`` is set, ``position_of(uav_id) -> (3,)`` gives each UAV's position
    (m, ENU) and is queried at *publish* time (a packet flies for milliseconds; the range is
    decided when it is sent). A member without a position (``position_of`` raising ``KeyError``
    or returning ``None``) is out of range.

    Determinism: all randomness comes from ``numpy.random.default_rng(seed)``; draws happen in
    ``publish`` in member-join order, so the same seed and the same call order give the same
    deliveries. Each publish draws one uniform per other member for the loss (the i.i.d. test,
    or the step of the pair's chain) and one for the jitter, whatever ``burst_len`` is;
    :meth:`publish_many` (a tick's broadcasts at once) draws exactly what its broadcasts
    published one by one would.

    Args:
        members: ids of the UAVs on the link (more can :meth:`join` later; a member only gets
            copies of broadcasts made after it joined).
        latency_s: fixed delay (s), ≥ 0.
        jitter_s: extra delay, uniform in [0, jitter_s] (s), ≥ 0.
        loss: probability in [0, 1] that a copy is lost (with ``burst_len`` > 0: the long-run
            fraction lost, < 1).
        burst_len: mean length of a burst of losses, in copies of one pair: 0 (independent
            losses) or ≥ 1.
        range_m: maximum 3-D sender–receiver distance (m) or ``None`` for unlimited.
        position_of: required with ``range_m``.
        seed: seed of the random generator.
    """

    def __init__(self, members: Iterable[str] = (), *, latency_s: float = 0.0,
                 jitter_s: float = 0.0, loss: float = 0.0, range_m: float | None = None,
                 position_of: Callable[[str], np.ndarray | None] | None = None,
                 seed: int | None = 0, burst_len: float = 0.0) -> None:
        for name, v in (("latency_s", latency_s), ("jitter_s", jitter_s)):
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name}: must be finite and ≥ 0, got {v}")
        if not (0.0 <= loss <= 1.0):
            raise ValueError(f"loss: must be a probability in [0, 1], got {loss}")
        if range_m is not None:
            if not (range_m > 0.0):
                raise ValueError(f"range_m: must be > 0 or None, got {range_m}")
            if position_of is None:
                raise ValueError("range_m: needs position_of(uav_id) to know where UAVs are")
        self.burst_len = float(burst_len)
        #: Loss thresholds of a uniform draw, by chain state + 1: first copy (stationary: P),
        #: after Good (p), after Bad (1 − r: a Bad pair stays Bad unless the draw is ≥ 1 − r).
        self._thresholds: np.ndarray | None = None
        if self.burst_len != 0.0:
            self._thresholds = _burst_thresholds(float(loss), self.burst_len)
        self.latency_s = float(latency_s)
        self.jitter_s = float(jitter_s)
        self.loss = float(loss)
        self.range_m = None if range_m is None else float(range_m)
        self.position_of = position_of
        self.stats = LinkStats()
        self._rng = np.random.default_rng(seed)
        self._members: dict[str, int] = {}
        #: The copies in flight (its first ``_chunks`` chunks and ``_used`` copies).
        self._q = InFlight.empty(256, 16)
        self._chunks = 0
        self._used = 0
        self._seen = np.zeros(0, dtype=np.bool_)  # take_copies' scratch, one per member
        #: Work arrays kept from call to call (their pages stay mapped): the draws of
        #: publish_many, queue_copies' copies, and take_copies' outputs (receivers,
        #: payload indices, times as their bits, sequence numbers).
        self._draws = np.empty(0)
        self._work_at = np.empty(0)
        self._work_rcv = np.empty(0, dtype=np.int64)
        self._taken = np.empty(0, dtype=np.int64)
        self._payloads: dict[int, bytes] = {}
        self._copies_left: dict[int, int] = {}
        self._next_payload = 0
        self._seq = 0  # FIFO tie-break for equal delivery times
        # Burst model: the state of each pair's chain, [sender, receiver]: −1 no copy yet, 0
        # Good, 1 Bad. Capacity doubles as members join (a 1000-UAV swarm joins one by one).
        self._state = np.full((1, 1), -1, dtype=np.int8)
        #: No copy is due before this time (a lower bound).
        self.next_due_s = math.inf
        for uav_id in members:
            self.join(uav_id)

    @property
    def members(self) -> tuple[str, ...]:
        return tuple(self._members)

    def join(self, uav_id: str) -> None:
        """Add a member (idempotent)."""
        if uav_id not in self._members:
            self._members[uav_id] = len(self._members)
            n, cap = len(self._members), self._state.shape[0]
            if self._thresholds is not None and n > cap:
                grown = np.full((max(n, 2 * cap), max(n, 2 * cap)), -1, dtype=np.int8)
                grown[:cap, :cap] = self._state
                self._state = grown

    def publish(self, msg_bytes: bytes, sender_id: str, t_s: float) -> None:
        self.publish_many((msg_bytes,), (sender_id,), t_s)

    def publish_many(self, payloads: Sequence[bytes], sender_ids: Sequence[str],
                     t_s: float) -> np.ndarray:
        """Broadcasts at ``t_s``: ``payloads[b]`` from ``sender_ids[b]``, exactly as
        :meth:`publish` one after the other (the same draws, the same copies), in one pass
        over all of them (a world's broadcasts of a tick). Returns (B,) int64 each one's
        payload id (:meth:`holds`), −1 for one with no copy in flight (all lost)."""
        for data in payloads:
            if not isinstance(data, bytes | bytearray):
                raise TypeError(f"msg_bytes: expected bytes, got {type(data).__name__}")
        b = len(payloads)
        if len(sender_ids) != b:
            raise ValueError(f"publish_many: {b} payloads but {len(sender_ids)} senders")
        members = self._members
        index = [members.get(s, -1) for s in sender_ids]
        if b > 1 and (-1 in index
                      or (self._thresholds is not None and len(set(index)) < b)):
            # A sender joining changes how many draws the next broadcast takes, and a sender
            # twice steps its chains between its two broadcasts: one by one.
            return np.concatenate([self.publish_many((data,), (sender_id,), t_s)
                                   for data, sender_id in zip(payloads, sender_ids,
                                                              strict=True)])
        if -1 in index:  # one broadcast, from a new member
            self.join(sender_ids[0])
            index = [members[sender_ids[0]]]
        n = len(members)
        self.stats.published += b
        self.stats.sent += b * (n - 1)
        if n == 1 or b == 0:
            return np.full(b, -1, dtype=np.int64)
        senders = np.array(index, dtype=np.int64)
        # Draw for every receiver, in join order, whether or not it is in range: the random
        # stream then does not depend on where the UAVs are, only on the call order. Per
        # broadcast: n − 1 uniforms for the loss, then n − 1 for the jitter.
        copies = b * (n - 1)
        self._draws = _at_least(self._draws, 2 * copies)
        draws = self._rng.random(out=self._draws[:2 * copies]).reshape(b, 2, n - 1)
        ranged = self.range_m is not None
        in_range = (np.stack([self._in_range(sender_id, np.delete(np.arange(n), s))
                              for sender_id, s in zip(sender_ids, senders.tolist(),
                                                      strict=True)])
                    if ranged else _NO_RANGE)
        self._room(b * (n - 1), b)
        pids = np.empty(b, dtype=np.int64)
        counts = np.empty(b, dtype=np.int64)
        burst = self._thresholds is not None
        self._work_at = _at_least(self._work_at, copies)
        self._work_rcv = _at_least(self._work_rcv, copies)
        args = (self._q, self._chunks, self._used, draws, senders, self.loss,
                self._thresholds if self._thresholds is not None else _NO_THRESHOLDS, burst,
                self._state, in_range, ranged, self.latency_s, self.jitter_s, float(t_s),
                self._next_payload, self._seq, pids, counts,
                self._work_at[:copies].reshape(b, n - 1),
                self._work_rcv[:copies].reshape(b, n - 1))
        threads = thread_count()
        if threads > 1 and b > 1 and copies >= THREADED_COPIES:
            self._chunks, used, lost, out, first = bound(queue_copies_threads)(*args, threads)
        else:
            self._chunks, used, lost, out, first = bound(queue_copies)(*args)
        self.stats.dropped += lost
        self.stats.dropped_range += out
        self.next_due_s = min(self.next_due_s, first)
        self._seq += used - self._used
        self._used = used
        for j, (pid, count) in enumerate(zip(pids.tolist(), counts.tolist(), strict=True)):
            if pid >= 0:
                self._payloads[pid] = bytes(payloads[j])
                self._copies_left[pid] = count
                self._next_payload = pid + 1
        return pids

    def _room(self, copies: int, chunks: int) -> None:
        """Room in the queue for ``copies`` more copies in ``chunks`` more chunks: the
        undelivered ones moved to the front of arrays large enough when there is not."""
        q = self._q
        if (self._used + copies <= q.at_s.shape[0]
                and self._chunks + chunks <= q.pos.shape[0]):
            return
        left = int(np.sum(q.end[:self._chunks] - q.pos[:self._chunks]))
        if 2 * (left + copies) <= q.at_s.shape[0] and self._chunks + chunks <= q.pos.shape[0]:
            self._used = move_copies(q, self._chunks, q)  # in place: half of it is free
            return
        # Four times what is needed: moved again only after several more ticks' copies.
        into = InFlight.empty(max(q.at_s.shape[0], 4 * (left + copies)),
                              max(q.pos.shape[0], 4 * (self._chunks + chunks)))
        self._used = move_copies(q, self._chunks, into)
        self._q = into

    def _queue(self, at_s: np.ndarray, receivers: np.ndarray, payload: bytes, count: int,
               sender: int | None) -> None:
        """One chunk of ``count`` copies (due at ``at_s``, to ``receivers``, in sending
        order) of a new payload."""
        self._room(count, 1)
        pid = self._next_payload
        self._next_payload += 1
        self._payloads[pid] = payload
        self._copies_left[pid] = count
        order = np.argsort(at_s, kind="stable")  # equal times keep the sending order
        q, c, u = self._q, self._chunks, self._used
        q.at_s[u:u + count] = at_s[order]
        q.seq[u:u + count] = self._seq + order
        q.receiver[u:u + count] = receivers[order]
        q.pos[c], q.end[c] = u, u + count
        q.sender[c] = -1 if sender is None else sender
        q.payload[c] = pid
        q.taken[c] = False
        self._seq += count
        self._chunks += 1
        self._used += count
        self.next_due_s = min(self.next_due_s, float(at_s[order[0]]))

    def inject(self, receiver_id: str, msg_bytes: bytes, at_s: float) -> None:
        """Deliver raw bytes to ``receiver_id`` at ``at_s``, as if from the air (a foreign or
        broken transmitter): no sender, no loss, no random draw; counted as ``injected``."""
        self.join(receiver_id)
        self._queue(np.array([float(at_s)]), np.array([self._members[receiver_id]]),
                    bytes(msg_bytes), 1, None)
        self.stats.injected += 1

    def receive(self, receiver_id: str, t_s: float) -> list[bytes]:
        self.join(receiver_id)
        if t_s < self.next_due_s:
            return []
        r = self._members[receiver_id]
        due: list[tuple[float, int, int]] = []
        q = self._q
        for c in range(self._chunks):
            pos, end = int(q.pos[c]), int(q.end[c])
            stop = pos + int(np.searchsorted(q.at_s[pos:end], t_s, side="right"))
            mine = np.flatnonzero(q.receiver[pos:stop] == r) + pos
            if mine.size:
                pid = int(q.payload[c])
                due.extend((float(q.at_s[k]), int(q.seq[k]), pid) for k in mine.tolist())
                q.receiver[mine] = -1  # delivered: a receiver index no one has
                q.taken[c] = True
        due.sort()
        self._drop_delivered()
        self.stats.delivered += len(due)
        out = []
        for _, _, pid in due:
            out.append(self._payloads[pid])
            self.release(np.array([pid]))
        return out

    def take_due(self, t_s: float) -> Due | None:
        """Every copy due by ``t_s``, for all receivers at once (:class:`Due`), or None if
        nothing is due. Each receiver gets its copies of one sender in delivery order (by
        time, then sending order); copies of different senders are independent.
        :meth:`payload` gives the bytes of an id while copies of it are in flight or just
        taken; :meth:`release` drops them once read."""
        if t_s < self.next_due_s:
            return None
        if self._seen.shape[0] < len(self._members):
            self._seen = np.zeros(len(self._members), dtype=np.bool_)
        u, c = self._used, self._chunks
        self._taken = _at_least(self._taken, 4 * u)
        rcv, which, at_bits, seq = self._taken[:4 * u].reshape(4, u)
        at = at_bits.view(np.float64)
        pids, copies = np.empty(c, dtype=np.int64), np.empty(c, dtype=np.int64)
        k, g, ordered = bound(take_copies)(self._q, c, float(t_s), self._seen, rcv, which, at, seq,
                                    pids, copies)
        self._drop_delivered()
        if not k:
            return None
        rcv, which = rcv[:k].copy(), which[:k].copy()
        if not ordered:
            # Two due broadcasts of one sender (or injected bytes, whose sender is unknown):
            # their copies must keep the delivery order between them.
            order = np.lexsort((seq[:k], at[:k]))
            rcv, which = rcv[order], which[order]
        self.stats.delivered += k
        return Due(rcv, which, pids[:g], copies[:g])

    def holds(self, pid: int) -> bool:
        """Copies of payload ``pid`` are still in flight or just taken (not released)."""
        return pid in self._payloads

    def payload(self, pid: int) -> bytes:
        """The bytes of payload ``pid`` (see :meth:`take_due`)."""
        return self._payloads[int(pid)]

    def release(self, payload_ids: np.ndarray, copies: np.ndarray | None = None) -> list[int]:
        """The copies of ``payload_ids`` were read: forget their bytes after the last one.
        ``payload_ids``: one entry per copy, or, with ``copies``, distinct ids and how many
        copies of each. Returns the ids whose last copies these were (:meth:`holds` them no
        more)."""
        if copies is not None:
            counts: Iterable[tuple[int, int]] = zip(payload_ids.tolist(), copies.tolist(),
                                                    strict=True)
        elif payload_ids.shape[0] > 16:
            ids, n = np.unique(payload_ids, return_counts=True)
            counts = zip(ids.tolist(), n.tolist(), strict=True)
        else:
            tally: dict[int, int] = {}
            for pid in payload_ids.tolist():
                tally[pid] = tally.get(pid, 0) + 1
            counts = tally.items()
        gone = []
        left_of = self._copies_left
        for pid, c in counts:
            left = left_of[pid] - c
            if left:
                left_of[pid] = left
            else:
                del left_of[pid]
                del self._payloads[pid]
                gone.append(pid)
        return gone

    def _drop_delivered(self) -> None:
        """Forget the chunks delivered in full; the next due time."""
        self._chunks, self.next_due_s = bound(sweep_copies)(self._q, self._chunks)

    def _in_range(self, sender_id: str, receivers: np.ndarray) -> np.ndarray:
        if self.range_m is None or self.position_of is None:
            return np.ones(receivers.shape[0], dtype=bool)
        src = self._position(sender_id)
        if src is None:
            return np.zeros(receivers.shape[0], dtype=bool)
        ids = list(self._members)
        out = np.zeros(receivers.shape[0], dtype=bool)
        for k, r in enumerate(receivers.tolist()):
            dst = self._position(ids[r])
            out[k] = dst is not None and float(np.linalg.norm(dst - src)) <= self.range_m
        return out

    def _position(self, uav_id: str) -> np.ndarray | None:
        assert self.position_of is not None
        try:
            p = self.position_of(uav_id)
        except KeyError:
            return None
        return None if p is None else np.asarray(p, dtype=float).reshape(3)


#: The channel predictions are sealed for (:func:`uavmpc.comms.auth.seal`).
PREDICTION_CHANNEL = "prediction"


class Inbox:
    """A receiver's view of the others: the newest valid message per sender.

    Every received byte string is decoded and validated; failures are counted by reason (the
    error text up to the first ':') in :attr:`rejected`, never raised: one bad packet must not
    stop a UAV. Messages from ``own_id`` are ignored (a broadcast medium may echo).

    The inbox is a view on one row of an :class:`~uavmpc.comms.inbox.InboxTable` (by default a
    table of its own; a simulated world passes every UAV its row of one shared table), and
    :meth:`accept` applies the table's compiled rule (:func:`~uavmpc.comms.inbox.accept_copy`).

    Args:
        own_id: the receiving UAV.
        time_reference: ``"stamp"`` (synchronised clocks: future-stamped and stale messages are
            rejected against the receiver's clock) or ``"receive"`` (unsynchronised clocks:
            stamps are only compared with the same sender's stamps; ``received_s`` is set on
            every kept message for the avoidance's receive-time fallback).
        max_future_s, max_age_s: see :func:`~uavmpc.comms.message.validate_on_receipt`.
        key: the swarm's shared key (:mod:`uavmpc.comms.auth`): when set, only messages signed
            with it are accepted (others are counted as ``"unsigned message"`` or ``"forged
            message (bad signature)"``); senders then publish ``sign(encode(msg), key)``.
        roster: the swarm's roster of identities (:mod:`uavmpc.comms.auth`), instead of a
            key: only predictions signed by the UAV they claim to be from are accepted (a
            member's own id only: ``"wrong identity"``; an operator's or a stranger's key:
            ``"not allowed"``, ``"unknown signer"``); senders publish
            ``seal(encode(msg), "prediction", identity, seq)``.
        table, row: the shared table and this receiver's row in it (its settings are the
            table's).
    """

    def __init__(self, own_id: str, *, time_reference: Literal["stamp", "receive"] = "stamp",
                 max_future_s: float = 0.5, max_age_s: float = 1.0,
                 key: bytes | None = None, table: InboxTable | None = None,
                 row: int = 0, roster: Roster | None = None) -> None:
        if key is not None:
            check_key(key)
            key = bytes(key)
            if roster is not None:
                raise ValueError("an inbox takes a shared key or a roster, not both")
        self.key = key
        self.roster = roster
        self.own_id = own_id
        if table is None:
            table = InboxTable([own_id], time_reference=time_reference,
                               max_future_s=max_future_s, max_age_s=max_age_s)
            row = 0
        elif table.receivers[row] != own_id:
            raise ValueError(f"row {row} of the inbox table is {table.receivers[row]!r}, "
                             f"not {own_id!r}")
        self.table = table
        self.row = int(row)
        self.time_reference = table.time_reference
        self.max_future_s = table.max_future_s
        self.max_age_s = table.max_age_s
        self._latest = LatestView(table, self.row)

    @property
    def accepted(self) -> int:
        return int(self.table.rows.accepted[self.row])

    @property
    def superseded(self) -> int:
        """Valid but not newer than what it holds (reordered by jitter)."""
        return int(self.table.rows.superseded[self.row])

    @property
    def rejected(self) -> dict[str, int]:
        """Rejected messages by reason."""
        rows = self.table.rows
        out = dict(self.table.reasons[self.row])
        for reason, count in ((FUTURE_REASON, rows.future[self.row]),
                              (STALE_REASON, rows.stale[self.row])):
            if count:
                out[reason] = out.get(reason, 0) + int(count)
        return out

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    @property
    def latest(self) -> Mapping[str, PredictionMessage]:
        """The newest message per sender (stale ones included: the strategy ignores those)."""
        return self._latest

    def poll(self, transport: Transport, now_s: float) -> Mapping[str, PredictionMessage]:
        """Receive from ``transport`` and :meth:`accept` everything; returns :attr:`latest`."""
        for data in transport.receive(self.own_id, now_s):
            self.accept(data, now_s)
        return self._latest

    def accept(self, data: bytes, now_s: float) -> PredictionMessage | None:
        """Verify (with a key), decode, validate and keep one message; ``None`` if rejected or
        not newer."""
        table = self.table
        signer = None
        try:
            if self.key is not None:
                data = verify(data, self.key)
            elif self.roster is not None:
                sealed = unseal(data, PREDICTION_CHANNEL, self.roster)
                if self.roster[sealed.signer_id].role != "uav":
                    raise InvalidMessageError(
                        f"not allowed: {sealed.signer_id!r} is not a UAV of the roster")
                data, signer = sealed.data, sealed.signer_id
            if not isinstance(data, bytes | bytearray | memoryview):
                raise InvalidMessageError(f"data: expected bytes, got {type(data).__name__}")
            slot = table.slot_for(bytes(data))
        except InvalidMessageError as exc:
            self.count_rejected(str(exc))
            return None
        try:
            if signer is not None:
                claimed = table.ids[int(table.store.col[slot])]
                if claimed != signer:
                    self.count_rejected(f"wrong identity: a prediction of {claimed!r} signed "
                                        f"by {signer!r}")
                    return None
            if not math.isfinite(now_s):
                raise ValueError(f"now_s: must be finite, got {now_s}")
            outcome = accept_copy(table.rows, table.store, self.row, slot, float(now_s))
        finally:
            table.unpin()
        if outcome != KEPT:
            return None
        col = int(table.store.col[slot])
        msg = self._latest[table.ids[col]]
        return msg

    def assume(self, msg: PredictionMessage, now_s: float) -> bool:
        """Hold ``msg`` as its sender's newest, a prediction this UAV made itself (never on
        the link, so not verified): what it assumes of a peer
        whose node died (:func:`uavmpc.assumptions.failsafe_prediction`). A message the
        sender sends later supersedes it as any newer message does. Returns whether it is
        held (False: the inbox holds a newer one)."""
        table = self.table
        try:
            slot = table.put(msg)
            outcome = accept_copy(table.rows, table.store, self.row, slot, float(now_s))
        finally:
            table.unpin()
        return outcome == KEPT

    def count_rejected(self, error: str) -> None:
        """Count one rejection by its reason (the error text up to the first ':')."""
        reasons = self.table.reasons[self.row]
        reason = error.split(":", 1)[0]
        reasons[reason] = reasons.get(reason, 0) + 1
