"""Prediction messages on the wire, and the simulated lossy link (SPEC §5.1)."""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from uavmpc.avoidance import HeightOffsetStrategy
from uavmpc.comms import (
    Inbox,
    InvalidMessageError,
    PredictionMessage,
    SimulatedLink,
    Transport,
    decode,
    encode,
    validate_on_receipt,
)
from uavmpc.comms.message import MAX_MESSAGE_BYTES, SCHEMA_VERSION

REL = np.cumsum(np.r_[0.01, np.full(39, 0.2)])
NOW = 1.7e9  # GNSS/Unix-like absolute time: stamps must survive at full precision


def make(uav_id: str = "uav_1", priority: int = 3, stamp: float = NOW, avoiding: bool = True,
         m: int = 40, seed: int = 0, heard: tuple[str, ...] = (),
         sigma: tuple[float, float] = (0.0, 0.0)) -> PredictionMessage:
    rng = np.random.default_rng(seed)
    times = stamp + np.cumsum(rng.uniform(0.01, 0.3, m))
    return PredictionMessage(SCHEMA_VERSION, uav_id, priority, stamp, times,
                             rng.normal(0.0, 100.0, (m, 3)), avoiding, heard=heard,
                             position_sigma_m=sigma)


VALID = encode(make())
#: The same, having heard two UAVs: b"\x02" b"\x02u2" b"\x03uav"
HEARD = encode(make(heard=("u2", "uav")))
HDR = 21  # bytes before the id
ID_LEN = len("uav_1")
T0 = HDR + ID_LEN  # offset of times_s
P0 = T0 + 8 * 40  # offset of positions_m


def patched(data: bytes, offset: int, fmt: str, value: object) -> bytes:
    out = bytearray(data)
    struct.pack_into(fmt, out, offset, value)
    return bytes(out)


# ---------------------------------------------------------------- message


def test_round_trip_is_bit_exact() -> None:
    for msg in (make(), make("A-b_9" * 6 + "zz", -(2**31), avoiding=False, m=2, seed=1),
                make("x", 2**31 - 1, m=200, seed=2, heard=tuple(f"u{i}" for i in range(64))),
                make(heard=("y" * 32, "b", "a"), sigma=(1.53, 2.55))):
        data = encode(msg)
        back = decode(data)
        assert (back.version, back.uav_id, back.priority, back.avoiding) == (
            msg.version, msg.uav_id, msg.priority, msg.avoiding)
        assert struct.pack("<d", back.stamp_s) == struct.pack("<d", msg.stamp_s)
        assert back.times_s.tobytes() == msg.times_s.tobytes()
        assert back.positions_m.tobytes() == msg.positions_m.tobytes()
        assert back.heard == msg.heard  # in its order
        assert back.position_sigma_m == msg.position_sigma_m
        assert encode(back) == data
    assert len(VALID) == HDR + ID_LEN + 32 * 40 + 16 + 1
    assert HEARD == VALID[:-1] + b"\x02\x02u2\x03uav"


@given(st.lists(st.floats(-1e5, 1e5, allow_nan=False), min_size=6, max_size=600),
       st.floats(-1e10, 1e10, allow_nan=False), st.booleans(),
       st.lists(st.from_regex(r"[A-Za-z0-9_-]{1,32}", fullmatch=True), max_size=64,
                unique=True),
       st.tuples(st.floats(0.0, 100.0), st.floats(0.0, 100.0)), st.integers(-2**31, 2**31 - 1))
@settings(max_examples=200, deadline=None)
def test_round_trip_property(values: list[float], stamp: float, avoiding: bool,
                             heard: list[str], sigma: tuple[float, float], priority: int) -> None:
    """decode(encode(m)) is m, field for field and bit for bit (a simulated world's receivers
    take the sender's message rather than decode its bytes again: InboxTable.slot_for)."""
    m = len(values) // 3
    pos = np.array(values[: 3 * m]).reshape(m, 3)
    if not 2 <= m <= 200:
        return
    heard = [h for h in heard if h != "p"]
    msg = PredictionMessage(SCHEMA_VERSION, "p", priority, stamp,
                            np.arange(m) * 0.2 + stamp, pos, avoiding, heard=tuple(heard),
                            position_sigma_m=sigma)
    back = decode(encode(msg))
    for name in ("version", "uav_id", "priority", "stamp_s", "avoiding", "received_s", "heard",
                 "position_sigma_m"):
        assert getattr(back, name) == getattr(msg, name), name
    for name in ("times_s", "positions_m"):
        a, b = getattr(back, name), getattr(msg, name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"", "truncated: 0 bytes"),
        (VALID[:10], "truncated: 10 bytes, shorter than the 21-byte header"),
        (VALID[:-1], "truncated: 1322 bytes, expected 1323"),
        (VALID + b"\0", "oversized: 1324 bytes, expected 1323"),
        (patched(VALID, P0 + 24 * 40, "<d", -0.1), r"position_sigma_m: each must be in \[0, 100\]"),
        (patched(VALID, P0 + 24 * 40 + 8, "<d", float("nan")), "position_sigma_m: must be finite"),
        (HEARD[:-1], r"heard\[1\]: id length 3 outside \[1, 32\] or past the end"),
        (HEARD[:-4], r"truncated: .* the heard list's entry 1 is missing"),
        (patched(HEARD, len(VALID) - 1, "<B", 65), "heard: 65 UAVs, more than 64"),
        (patched(HEARD, len(VALID), "<B", 0), r"heard\[0\]: id length 0"),
        (patched(HEARD, len(VALID) + 1, "<B", 0xC3), r"heard\[0\]: not ASCII"),
        (patched(HEARD, len(VALID) + 1, "<B", ord(" ")), "must be 1–32 characters"),
        (VALID[:-1] + b"\x02\x02u2\x02u2", "heard: an id listed twice"),
        (VALID[:-1] + b"\x01\x05uav_1", "heard: the sender 'uav_1' lists itself"),
        (VALID * 7, "oversized: .* more than the"),
        (b"XXXX" + VALID[4:], "magic"),
        (patched(VALID, 4, "<B", 1), "version: unsupported schema version 1"),
        (patched(VALID, 4, "<B", 0), "version: unsupported schema version 0"),
        (patched(VALID, 5, "<B", 0x81), "flags: unknown bits"),
        (patched(VALID, 6, "<B", 0), r"uav_id: length 0 outside \[1, 32\]"),
        (patched(VALID, 6, "<B", 33), r"uav_id: length 33"),
        (patched(VALID, 7, "<H", 1), r"points: m=1 outside \[2, 200\]"),
        (patched(VALID, 7, "<H", 201), r"points: m=201 outside \[2, 200\]"),
        (patched(VALID, HDR, "<B", ord(" ")), "uav_id: must be"),
        (patched(VALID, HDR, "<B", 0xC3), "uav_id: not ASCII"),
        (patched(VALID, 13, "<d", float("nan")), "stamp_s: must be finite"),
        (patched(VALID, T0 + 8 * 5, "<d", float("inf")), r"times_s\[5\]: non-finite"),
        (patched(VALID, P0 + 8 * 7, "<d", float("nan")), r"positions_m\[2\]: non-finite"),
        (patched(VALID, T0 + 8 * 3, "<d", NOW), r"times_s: must increase strictly, times_s\[2\]"),
        (patched(VALID, P0 + 8 * 4, "<d", 2e5), r"positions_m\[1\]: .* absurd-position"),
    ],
)
def test_malformed_bytes_are_rejected_naming_the_problem(data: bytes, match: str) -> None:
    with pytest.raises(InvalidMessageError, match=match):
        decode(data)


def test_constructor_validates_too() -> None:
    t = NOW + REL
    with pytest.raises(InvalidMessageError, match="uav_id"):
        PredictionMessage(SCHEMA_VERSION, "a" * 33, 1, NOW, t, np.zeros((40, 3)), True)
    with pytest.raises(InvalidMessageError, match=r"positions_m: must have shape \(40, 3\)"):
        PredictionMessage(SCHEMA_VERSION, "a", 1, NOW, t, np.zeros((40, 2)), True)
    with pytest.raises(InvalidMessageError, match="priority: must be an integer"):
        PredictionMessage(SCHEMA_VERSION, "a", 1.5, NOW, t, np.zeros((40, 3)), True)
    with pytest.raises(InvalidMessageError, match="version: unsupported"):
        PredictionMessage(1, "a", 1, NOW, t, np.zeros((40, 3)), True)
    with pytest.raises(InvalidMessageError, match="heard: must be a tuple"):
        PredictionMessage(SCHEMA_VERSION, "a", 1, NOW, t, np.zeros((40, 3)), True, heard="b")
    with pytest.raises(InvalidMessageError, match="heard: 65 UAVs"):
        PredictionMessage(SCHEMA_VERSION, "a", 1, NOW, t, np.zeros((40, 3)), True,
                          heard=tuple(f"u{i}" for i in range(65)))
    # The heard list's ids are checked in one match of the list joined by NUL: an id that
    # holds a NUL, or is empty, must not slip through the join.
    for heard, bad in ((("b\x00c",), "b\x00c"), (("b", ""), ""), (("",), ""), (("b", 7), 7),
                       (("b", "c" * 33), "c" * 33)):
        with pytest.raises(InvalidMessageError, match=re.escape(f"got {bad!r}")):
            PredictionMessage(SCHEMA_VERSION, "a", 1, NOW, t, np.zeros((40, 3)), True,
                              heard=heard)
    assert PredictionMessage(SCHEMA_VERSION, "a", 1, NOW, t, np.zeros((40, 3)), True,
                             heard=("b", "c" * 32, "d-_9")).heard == ("b", "c" * 32, "d-_9")
    # The message keeps its own read-only copy: the sender may reuse its buffers.
    pos = np.zeros((40, 3))
    msg = PredictionMessage(SCHEMA_VERSION, "a", 1, NOW, t, pos, True)
    pos[0, 0] = 99.0
    assert msg.positions_m[0, 0] == 0.0 and not msg.positions_m.flags.writeable


def test_future_stamped_and_stale_messages_are_rejected_on_receipt() -> None:
    msg = make(stamp=NOW)
    assert validate_on_receipt(msg, NOW - 0.4) is msg  # within the clock tolerance
    with pytest.raises(InvalidMessageError, match=r"future-stamped: .* 0\.600 s ahead"):
        validate_on_receipt(msg, NOW - 0.6)
    with pytest.raises(InvalidMessageError, match=r"stale: .* 1\.500 s old"):
        validate_on_receipt(msg, NOW + 1.5)
    assert validate_on_receipt(msg, NOW + 1.5, max_age_s=2.0) is msg


@given(st.binary(max_size=MAX_MESSAGE_BYTES + 64))
@settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_fuzz_random_bytes_only_raise_invalid_message(data: bytes) -> None:
    for candidate in (data, b"UAVP\x01" + data):  # the second passes the magic/version gate
        try:
            decode(candidate)
        except InvalidMessageError:
            pass


@given(st.lists(st.tuples(st.integers(0, len(VALID) - 1), st.integers(0, 255)),
                min_size=1, max_size=8),
       st.integers(0, len(VALID) + 16), st.binary(max_size=16))
@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_fuzz_mutated_valid_messages_only_raise_invalid_message(
        edits: list[tuple[int, int]], cut: int, tail: bytes) -> None:
    data = bytearray(VALID)
    for pos, value in edits:
        data[pos] = value
    mutated = bytes(data[:cut]) + tail
    try:
        msg = decode(mutated)
    except InvalidMessageError:
        return
    # Whatever survives is a fully valid message that re-encodes to the same bytes.
    assert encode(msg) == mutated
    assert np.all(np.diff(msg.times_s) > 0) and np.all(np.abs(msg.positions_m) <= 1e5)


# ---------------------------------------------------------------- link


def test_loss_rate_matches_with_a_seed() -> None:
    link = SimulatedLink(["a", "b"], loss=0.3, seed=11)
    for k in range(5000):
        link.publish(b"%d" % k, "a", 0.01 * k)
    got = link.receive("b", 1e9)
    assert link.stats.sent == 5000
    assert link.stats.dropped / 5000 == pytest.approx(0.3, abs=0.03)
    assert link.stats.delivered == len(got) == 5000 - link.stats.dropped
    assert link.stats.in_flight == 0
    assert link.receive("a", 1e9) == []  # a sender does not hear itself


def test_latency_and_jitter_stay_in_bounds_and_fill_the_interval() -> None:
    fixed, jitter = 0.05, 0.1
    link = SimulatedLink(["a", "b"], latency_s=fixed, jitter_s=jitter, seed=5)
    n = 2000
    for k in range(n):
        link.publish(k.to_bytes(2, "little"), "a", 10.0)
    assert link.receive("b", 10.0 + fixed - 1e-9) == []
    delays = np.full(n, np.nan)
    for step in range(1, 101):  # poll every 1 ms
        t = 10.0 + fixed + step * jitter / 100
        for data in link.receive("b", t):
            delays[int.from_bytes(data, "little")] = t - 10.0
    assert not np.isnan(delays).any()  # all arrived by fixed + jitter
    assert delays.min() >= fixed and delays.max() <= fixed + jitter + 1e-9
    assert np.mean(delays) == pytest.approx(fixed + jitter / 2, abs=0.005)
    assert np.std(delays) == pytest.approx(jitter / np.sqrt(12), rel=0.1)


def trace(seed: int) -> list[tuple[str, float, bytes]]:
    link = SimulatedLink(["a", "b", "c"], latency_s=0.02, jitter_s=0.2, loss=0.4, seed=seed)
    out = []
    for k in range(300):
        t = 0.05 * k
        link.publish(b"a%d" % k, "a", t)
        link.publish(b"c%d" % k, "c", t)
        for r in ("a", "b", "c"):
            out += [(r, t, d) for d in link.receive(r, t)]
    return out


def test_link_is_deterministic_per_seed() -> None:
    assert trace(1) == trace(1)
    assert trace(1) != trace(2)
    # Jitter larger than the publish period reorders some messages.
    b_from_a = [int(d[1:]) for r, _, d in trace(1) if r == "b" and d.startswith(b"a")]
    assert b_from_a != sorted(b_from_a)


def test_range_limit_uses_positions_at_publish_time() -> None:
    where = {"a": np.zeros(3), "b": np.array([60.0, 0, 0]), "c": np.array([0, 150.0, 0])}
    link = SimulatedLink(["a", "b", "c", "silent"], range_m=100.0,
                         position_of=lambda u: where.get(u), seed=0)
    link.publish(b"1", "a", 0.0)
    assert link.receive("b", 1.0) == [b"1"]
    assert link.receive("c", 1.0) == []
    assert link.receive("silent", 1.0) == []  # no position known: out of range
    assert link.stats.dropped_range == 2 and link.stats.dropped == 0
    where["c"] = np.array([0, 99.0, 0])
    link.publish(b"2", "a", 2.0)
    assert link.receive("c", 3.0) == [b"2"]
    with pytest.raises(ValueError, match="position_of"):
        SimulatedLink(range_m=10.0)


@pytest.mark.parametrize("loss, burst_len, ranged", [
    (0.0, 0.0, False), (0.3, 0.0, False), (0.3, 3.0, False), (0.2, 0.0, True), (0.2, 2.0, True)])
def test_a_ticks_broadcasts_at_once_draw_and_deliver_as_one_by_one(loss: float, burst_len: float,
                                                                   ranged: bool) -> None:
    """``publish_many`` is the world's tick of broadcasts: the same random draws, copies,
    chain states and statistics as ``publish`` called for each in turn, also when a sender
    joins in the middle of a tick or sends twice in one."""
    rng = np.random.default_rng(0)
    ids = [f"u{i}" for i in range(10)]
    where = {u: rng.normal(size=3) * 40.0 for u in [*ids, "late"]}
    kw = dict(latency_s=0.05, jitter_s=0.02, loss=loss, burst_len=burst_len, seed=4,
              range_m=60.0 if ranged else None, position_of=where.get if ranged else None)
    one, many = SimulatedLink(ids, **kw), SimulatedLink(ids, **kw)
    got: dict[str, list] = {"one": [], "many": []}
    for k in range(200):
        t = 0.01 * k
        senders = [u for u in ids if rng.random() < 0.3]
        if k == 100:
            senders += ["late", senders[0] if senders else "u0"]  # a newcomer; one twice
        data = [f"{s}-{k}-{j}".encode() for j, s in enumerate(senders)]
        for d, s in zip(data, senders, strict=True):
            one.publish(d, s, t)
        many.publish_many(data, senders, t)
        for name, link in (("one", one), ("many", many)):
            due = link.take_due(t)
            if due is not None:
                pids = due.payloads[due.which]  # each copy's payload id, in delivery order
                assert np.array_equal(due.payloads, np.unique(pids))
                assert np.array_equal(due.copies, np.bincount(due.which))
                got[name].append((k, due.receivers.tolist(), [link.payload(p) for p in pids]))
                gone = link.release(due.payloads, due.copies)
                # It names exactly the payloads these copies were the last of.
                assert gone == [p for p in due.payloads.tolist() if not link.holds(p)]
    assert got["one"] == got["many"] and len(got["one"]) > 100
    assert vars(one.stats) == vars(many.stats)
    assert (one.stats.dropped > 0) == (loss > 0.0)
    assert (one.stats.dropped_range > 0) == ranged
    with pytest.raises(ValueError, match="2 payloads but 1 senders"):
        many.publish_many([b"x", b"y"], ["u0"], 3.0)


def _tick_by_tick(link: SimulatedLink, ids: list[str], seed: int, ticks: int = 150) -> list:
    """What ``link`` delivers, tick by tick, when a random third of ``ids`` broadcast at
    each tick (several at once: ``publish_many``) and a receiver takes its copies by hand
    now and then (``receive``, which marks them taken in the queue)."""
    rng = np.random.default_rng(seed)
    got = []
    for k in range(ticks):
        t = 0.01 * k
        senders = [u for u in ids if rng.random() < 0.3]
        link.publish_many([f"{s}-{k}".encode() for s in senders], senders, t)
        if k % 7 == 3:
            got.append(("receive", k, link.receive(ids[k % len(ids)], t)))
        due = link.take_due(t)
        if due is not None:
            got.append((k, due.receivers.tolist(), due.which.tolist(),
                        [link.payload(p) for p in due.payloads], due.copies.tolist()))
            link.release(due.payloads, due.copies)
    return got


@pytest.mark.parametrize("blocks", [1, 2, 3, 7])
@pytest.mark.parametrize("loss, burst_len, ranged", [
    (0.0, 0.0, False), (0.3, 3.0, False), (0.2, 2.0, True)])
def test_a_ticks_copies_on_threads_are_queued_as_on_one(
        monkeypatch: pytest.MonkeyPatch, loss: float, burst_len: float, ranged: bool,
        blocks: int) -> None:
    """The link's threaded queue (a tick's broadcasts drawn and sorted in blocks) gives the
    deliveries (their order, the chains' losses) and the statistics of the
    serial ones, for any number of blocks (run here with the blocks given, on any machine)."""
    import uavmpc.comms.link as link_module

    ids = [f"u{i}" for i in range(12)]
    rng = np.random.default_rng(1)
    where = {u: rng.normal(size=3) * 40.0 for u in ids}
    kw = dict(latency_s=0.03, jitter_s=0.04, loss=loss, burst_len=burst_len, seed=9,
              range_m=60.0 if ranged else None, position_of=where.get if ranged else None)
    serial = SimulatedLink(ids, **kw)
    want = _tick_by_tick(serial, ids, 5)
    def queue(*args: object) -> tuple[int, int, int, int, float]:
        return link_module.queue_copies_threads(*args, blocks)

    monkeypatch.setattr(link_module, "queue_copies", queue)
    threaded = SimulatedLink(ids, **kw)
    assert _tick_by_tick(threaded, ids, 5) == want and len(want) > 100
    assert vars(threaded.stats) == vars(serial.stats)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.25, 0.5, 2.0e9 + 0.07])),
                max_size=300), st.booleans())
def test_the_links_delivery_order_is_a_stable_sort(keys: list[float], spread: bool) -> None:
    """The order a broadcast's copies are queued in (by delivery time, equal times in
    sending order) is numpy's stable argsort, ties and all."""
    from uavmpc.comms.link import stable_order

    k = np.array(keys) * (1.0 if spread else 1e-12) + 1.7e9
    order = np.empty(len(keys), dtype=np.int64)
    stable_order(k, len(keys), order, np.empty(len(keys) + 1, dtype=np.int64))
    assert order.tolist() == np.argsort(k, kind="stable").tolist()


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(["uav7", "A" * 32, "A" * 33, "bad id", ""]),
       st.integers(-(2**31) - 2, 2**31 + 1),
       st.sampled_from([0.0, 1.7e9, float("nan"), float("inf")]),
       st.sampled_from([0.0, 2.5, 100.0, 100.000001, -0.1, float("nan"), float("inf")]),
       st.sampled_from([0.0, 100.0, 101.0, float("nan")]),
       st.sampled_from([1, 2, 40, 200, 201]),
       st.sampled_from(["good", "repeat", "nan time", "nan position", "absurd"]))
def test_the_compiled_writers_gate_is_the_messages_own_checks(
        uav_id: str, priority: int, stamp: float, sigma_h: float, sigma_v: float, m: int,
        case: str) -> None:
    """fields_valid (the gate before a compiled broadcast writes a message without building
    it) accepts exactly the values PredictionMessage accepts: a gate looser than the
    constructor would send bytes receivers refuse."""
    from uavmpc.comms.message import fields_valid, valid_id

    times = 1.0 + np.arange(m, dtype=float)
    pos = np.zeros((m, 3))
    if case == "repeat" and m > 1:
        times[-1] = times[-2]
    elif case == "nan time":
        times[0] = np.nan
    elif case == "nan position":
        pos[-1, 2] = np.nan
    elif case == "absurd":
        pos[0, 0] = 2.0e5
    try:
        PredictionMessage(SCHEMA_VERSION, uav_id, priority, stamp, times, pos, True,
                          position_sigma_m=(sigma_h, sigma_v))
        accepted = True
    except InvalidMessageError:
        accepted = False
    id_len = len(uav_id) if valid_id(uav_id) else 0
    assert fields_valid(id_len, priority, stamp, sigma_h, sigma_v, times, pos) == accepted


def test_link_rejects_bad_parameters() -> None:
    for kwargs, match in (({"loss": 1.5}, "loss"), ({"latency_s": -0.1}, "latency_s"),
                          ({"jitter_s": float("nan")}, "jitter_s")):
        with pytest.raises(ValueError, match=match):
            SimulatedLink(**kwargs)
    assert isinstance(SimulatedLink(), Transport)


# ---------------------------------------------------------------- inbox


def test_inbox_keeps_newest_per_sender_and_counts_rejections() -> None:
    inbox = Inbox("me")
    now = NOW + 0.1
    assert inbox.accept(encode(make("a", stamp=NOW)), now) is not None
    assert inbox.accept(encode(make("a", stamp=NOW - 0.2)), now) is None  # reordered, older
    assert inbox.accept(encode(make("me", stamp=NOW)), now) is None  # our own echo
    assert inbox.accept(VALID[:-3], now) is None
    assert inbox.accept(patched(VALID, 4, "<B", 9), now) is None
    assert inbox.accept(encode(make("b", stamp=NOW + 5.0)), now) is None  # future-stamped
    assert inbox.accept(encode(make("c", stamp=NOW - 3.0)), now) is None  # stale
    assert set(inbox.latest) == {"a"} and inbox.latest["a"].stamp_s == NOW
    assert inbox.superseded == 1 and inbox.accepted == 1
    assert inbox.rejected == {"truncated": 1, "version": 1, "future-stamped": 1, "stale": 1}
    assert inbox.rejected_total == 4


def test_a_sender_whose_clock_is_off_is_measured_and_put_on_our_clock_not_refused() -> None:
    """A sender whose clock runs 0.8 s ahead of ours, over a link of 0.1–0.3 s: its stamps
    look 0.5–0.7 s in the future, beyond the 0.5 s tolerance. Refusing them would make it a
    neighbour nobody avoids (the falsifier found 0.94 m so). The inbox measures the offset
    (the floor of arrival − stamp; a big step down only when two arrivals in a row say so)
    and puts its messages on our clock: each is taken to be from its stamp plus that floor,
    off by the shortest latency only. One garbled stamp from a synchronised sender moves
    nothing."""
    inbox = Inbox("me")
    ahead = 0.8
    latencies = [0.3, 0.1, 0.2, 0.25, 0.15]
    kept = []
    for k in range(40):  # 4 s at 10 Hz
        sent = NOW + 0.1 * k  # our clock
        msg = inbox.accept(encode(make("a", stamp=sent + ahead)), sent + latencies[k % 5])
        kept.append(msg is not None)
        if k >= 1:  # measured from the second on: every message kept, on our clock
            assert msg is not None, k
            # late by at most the latencies seen so far from its send time, and by the
            # shortest (0.1 s) once that has come after the measuring pair (k = 6)
            late = msg.received_s - sent
            assert 0.0 <= late <= (0.1 if k >= 6 else 0.3) + 0.02, (k, late)
    assert all(kept)  # (the first within the 0.5 s tolerance by its stamp: 0.3 s late)
    # a copy of its delayed by 1.2 s more than the shortest is stale, as on a true clock
    assert inbox.accept(encode(make("a", stamp=NOW + 3.0 + ahead)), NOW + 3.0 + 1.4) is None
    assert inbox.rejected.get("stale") == 1
    # a synchronised sender: its stamps are taken as they are, and one garbled stamp
    # (1.5 s ahead) is refused and leaves its clock trusted
    for k in range(5):
        msg = inbox.accept(encode(make("b", stamp=NOW + 0.1 * k)), NOW + 0.1 * k + 0.05)
        assert msg is not None and msg.received_s is None
    futures = inbox.rejected.get("future-stamped", 0)
    assert inbox.accept(encode(make("b", stamp=NOW + 0.5 + 1.5)), NOW + 0.5) is None
    assert inbox.rejected.get("future-stamped") == futures + 1
    later = inbox.accept(encode(make("b", stamp=NOW + 0.6)), NOW + 0.65)
    assert later is not None and later.received_s is None
    assert inbox.accept(encode(make("c", stamp=NOW + 3600.0)), NOW) is None  # no clock is


def test_inbox_receive_mode_ignores_foreign_clocks_and_records_receive_time() -> None:
    inbox = Inbox("me", time_reference="receive")
    msg = inbox.accept(encode(make("a", stamp=NOW + 3600.0)), 12.5)  # an hour off: fine
    assert msg is not None and msg.received_s == 12.5


def test_lossy_link_to_strategy_end_to_end() -> None:
    """Two UAVs head-on over a 30 % lossy, jittery link: the lower priority still climbs."""
    link = SimulatedLink(["a", "b"], latency_s=0.01, jitter_s=0.05, loss=0.3, seed=4)
    inboxes = {u: Inbox(u) for u in "ab"}
    strat = {u: HeightOffsetStrategy() for u in "ab"}
    prio = {"a": 1, "b": 2}
    start = {"a": (-30.0, 0.0, 10.0), "b": (30.0, 0.0, 10.0)}
    vel = {"a": (5.0, 0.0, 0.0), "b": (-5.0, 0.0, 0.0)}
    offsets = {"a": 0.0, "b": 0.0}
    for k in range(40):  # 4 s at 10 Hz, broadcast at 2 Hz
        now = 0.1 * k
        times = now + REL
        nominal = {u: np.asarray(start[u]) + times[:, None] * np.asarray(vel[u]) for u in "ab"}
        if k % 5 == 0:
            for u in "ab":
                sent = PredictionMessage(SCHEMA_VERSION, u, prio[u], now, times,
                                         nominal[u] + [0.0, 0.0, offsets[u]], True)
                link.publish(encode(sent), u, now)
        for u in "ab":
            others = inboxes[u].poll(link, now)
            offsets[u] = strat[u].update(now, u, prio[u], times, nominal[u], others).z_offset_m
    assert offsets == {"a": 0.0, "b": 3.0}
    assert link.stats.sent == 16 and link.stats.delivered + link.stats.dropped == 16


# --------------------------------------------------------------------------- node state
def test_a_node_state_round_trips_and_a_bad_one_is_refused_by_name() -> None:
    import json

    from uavmpc.comms.state import InvalidStateError, NodeState

    s = NodeState(t_s=1.7e9, position_m=(1.0, 2.0, 5.0), velocity_mps=(0.5, 0.0, 0.0),
                  heading_rad=0.3, command_m=(1.1, 2.0, 8.0), z_offset_m=3.0, avoiding=True,
                  conflicts=("uav2",), yielding_to=("uav2",), waiting_for=())
    assert NodeState.decode(s.encode()) == s
    good = json.loads(s.encode())
    for change, field in [({"position_m": [0.0, float("nan"), 1.0]}, "position_m"),
                          ({"position_m": [0.0, 1.0]}, "position_m"),
                          ({"t_s": True}, "t_s"), ({"avoiding": 1}, "avoiding"),
                          ({"yielding_to": ["a b"]}, "yielding_to"),
                          ({"z_offset_m": 1e9}, "z_offset_m"), ({"extra": 1}, "extra")]:
        payload = json.dumps({**good, **change}).encode()
        with pytest.raises(InvalidStateError, match=rf"^state\.{field}"):
            NodeState.decode(payload)
    missing = {k: v for k, v in good.items() if k != "command_m"}
    with pytest.raises(InvalidStateError, match=r"^state\.command_m: missing"):
        NodeState.decode(json.dumps(missing).encode())
    for junk in (b"", b"[1]", b"\xff", b"[" * 100_000):
        with pytest.raises(InvalidStateError, match=r"^state"):
            NodeState.decode(junk)
