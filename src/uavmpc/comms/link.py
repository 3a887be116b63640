"""Transports for prediction messages, and the receiver's inbox (SPEC §5.1).

Messages travel as bytes: a real radio or network only ever hands over bytes, and receivers must
decode and validate whatever arrives (:class:`Inbox`).

- :class:`Transport` is the one contract: ``publish`` a broadcast, ``receive`` what arrived.
- :class:`SimulatedLink` is the in-process broadcast medium of the simulated world, on the
  simulated clock: fixed latency plus uniform jitter, random loss, an optional range limit.
- :class:`Inbox` keeps the newest valid message per sender and counts what it rejected.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from uavmpc.comms.auth import check_key, verify
from uavmpc.comms.message import (
    InvalidMessageError,
    PredictionMessage,
    decode,
    validate_on_receipt,
)


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


@dataclass
class LinkStats:
    """Counters of a :class:`SimulatedLink`, per receiver copy of a broadcast.

    Attributes:
        published: ``publish`` calls.
        sent: copies attempted (one per other member per publish).
        delivered: copies handed to receivers by ``receive``.
        dropped: copies lost at random (``loss``).
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


class SimulatedLink:
    """In-process broadcast link on a simulated clock.

    Every member except the sender gets its own copy of each broadcast, decided independently
    (as on a radio channel): first the range check, then loss with probability ``loss``, then a
    delivery delay of ``latency_s + U(0, jitter_s)``. Jitter can reorder messages; receivers
    keep the newest stamp per sender (:class:`Inbox`).

    Range: when ``range_m`` is set, ``position_of(uav_id) -> (3,)`` gives each UAV's position
    (m, ENU) and is queried at *publish* time (a packet flies for milliseconds; the range is
    decided when it is sent). A member without a position (``position_of`` raising ``KeyError``
    or returning ``None``) is out of range.

    Determinism: all randomness comes from ``numpy.random.default_rng(seed)``; draws happen in
    ``publish`` in member-join order, so the same seed and the same call order give the same
    deliveries.

    Args:
        members: ids of the UAVs on the link (more can :meth:`join` later; a member only gets
            copies of broadcasts made after it joined).
        latency_s: fixed delay (s), ≥ 0.
        jitter_s: extra delay, uniform in [0, jitter_s] (s), ≥ 0.
        loss: probability in [0, 1] that a copy is lost.
        range_m: maximum 3-D sender–receiver distance (m) or ``None`` for unlimited.
        position_of: required with ``range_m``.
        seed: seed of the random generator.
    """

    def __init__(self, members: Iterable[str] = (), *, latency_s: float = 0.0,
                 jitter_s: float = 0.0, loss: float = 0.0, range_m: float | None = None,
                 position_of: Callable[[str], np.ndarray | None] | None = None,
                 seed: int | None = 0) -> None:
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
        self.latency_s = float(latency_s)
        self.jitter_s = float(jitter_s)
        self.loss = float(loss)
        self.range_m = None if range_m is None else float(range_m)
        self.position_of = position_of
        self.stats = LinkStats()
        self._rng = np.random.default_rng(seed)
        self._queues: dict[str, list[tuple[float, int, bytes]]] = {}
        self._seq = 0  # FIFO tie-break for equal delivery times
        for uav_id in members:
            self.join(uav_id)

    @property
    def members(self) -> tuple[str, ...]:
        return tuple(self._queues)

    def join(self, uav_id: str) -> None:
        """Add a member (idempotent)."""
        self._queues.setdefault(uav_id, [])

    def publish(self, msg_bytes: bytes, sender_id: str, t_s: float) -> None:
        if not isinstance(msg_bytes, bytes | bytearray):
            raise TypeError(f"msg_bytes: expected bytes, got {type(msg_bytes).__name__}")
        self.join(sender_id)
        payload = bytes(msg_bytes)
        receivers = [r for r in self._queues if r != sender_id]
        self.stats.published += 1
        self.stats.sent += len(receivers)
        if not receivers:
            return
        # Draw for every receiver, in join order, whether or not it is in range: the random
        # stream then does not depend on where the UAVs are, only on the call order.
        lost = self._rng.random(len(receivers)) < self.loss
        delay = self.latency_s + self.jitter_s * self._rng.random(len(receivers))
        in_range = self._in_range(sender_id, receivers)
        for r, is_lost, d, ok in zip(receivers, lost, delay, in_range, strict=True):
            if not ok:
                self.stats.dropped_range += 1
            elif is_lost:
                self.stats.dropped += 1
            else:
                heapq.heappush(self._queues[r], (t_s + float(d), self._seq, payload))
                self._seq += 1

    def inject(self, receiver_id: str, msg_bytes: bytes, at_s: float) -> None:
        """Deliver raw bytes to ``receiver_id`` at ``at_s``, as if from the air (a foreign or
        broken transmitter): no sender, no loss, no random draw; counted as ``injected``."""
        self.join(receiver_id)
        heapq.heappush(self._queues[receiver_id], (float(at_s), self._seq, bytes(msg_bytes)))
        self._seq += 1
        self.stats.injected += 1

    def receive(self, receiver_id: str, t_s: float) -> list[bytes]:
        self.join(receiver_id)
        queue = self._queues[receiver_id]
        out: list[bytes] = []
        while queue and queue[0][0] <= t_s:
            out.append(heapq.heappop(queue)[2])
        self.stats.delivered += len(out)
        return out

    def _in_range(self, sender_id: str, receivers: list[str]) -> list[bool]:
        if self.range_m is None or self.position_of is None:
            return [True] * len(receivers)
        src = self._position(sender_id)
        if src is None:
            return [False] * len(receivers)
        out = []
        for r in receivers:
            dst = self._position(r)
            out.append(dst is not None and float(np.linalg.norm(dst - src)) <= self.range_m)
        return out

    def _position(self, uav_id: str) -> np.ndarray | None:
        assert self.position_of is not None
        try:
            p = self.position_of(uav_id)
        except KeyError:
            return None
        return None if p is None else np.asarray(p, dtype=float).reshape(3)


class Inbox:
    """A receiver's view of the others: the newest valid message per sender.

    Every received byte string is decoded and validated; failures are counted by reason (the
    error text up to the first ':') in :attr:`rejected`, never raised: one bad packet must not
    stop a UAV. Messages from ``own_id`` are ignored (a broadcast medium may echo).

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
    """

    def __init__(self, own_id: str, *, time_reference: Literal["stamp", "receive"] = "stamp",
                 max_future_s: float = 0.5, max_age_s: float = 1.0,
                 key: bytes | None = None) -> None:
        if time_reference not in ("stamp", "receive"):
            raise ValueError(
                f"time_reference: must be 'stamp' or 'receive', got {time_reference!r}")
        if key is not None:
            check_key(key)
            key = bytes(key)
        self.key = key
        self.own_id = own_id
        self.time_reference = time_reference
        self.max_future_s = max_future_s
        self.max_age_s = max_age_s
        self.accepted = 0
        self.superseded = 0  # valid but older than what we hold (reordered by jitter)
        self.rejected: dict[str, int] = {}
        self._latest: dict[str, PredictionMessage] = {}

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
        try:
            if self.key is not None:
                data = verify(data, self.key)
            msg = decode(data)
            if self.time_reference == "stamp":
                validate_on_receipt(msg, now_s, self.max_future_s, self.max_age_s)
        except InvalidMessageError as exc:
            reason = str(exc).split(":", 1)[0]
            self.rejected[reason] = self.rejected.get(reason, 0) + 1
            return None
        if msg.uav_id == self.own_id:
            return None
        held = self._latest.get(msg.uav_id)
        if held is not None and msg.stamp_s <= held.stamp_s:
            self.superseded += 1
            return None
        if self.time_reference == "receive":
            msg = replace(msg, received_s=float(now_s))
        self._latest[msg.uav_id] = msg
        self.accepted += 1
        return msg
