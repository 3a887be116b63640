"""ZenohTransport: real Zenoh peers in one process, on 127.0.0.1 only, multicast off."""

import socket
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

pytest.importorskip("zenoh")

from uavmpc.comms.auth import sign
from uavmpc.comms.link import Inbox, Transport
from uavmpc.comms.message import SCHEMA_VERSION, PredictionMessage, encode
from uavmpc.comms.zenoh_link import ZenohTransport

pytestmark = pytest.mark.realtime  # flies on the wall clock

KEY = b"k" * 32
PROBE = b"probe"


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ep() -> str:
    return f"tcp/127.0.0.1:{_free_port()}"


def _wait(cond: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def _recv(t: ZenohTransport) -> list[bytes]:
    """``receive``, without the discovery probes that may still be in flight."""
    return [x for x in t.receive(t.own_id, 0.0) if x != PROBE]


def _msg(uav_id: str, stamp: float, priority: int = 1) -> PredictionMessage:
    times = stamp + np.arange(40) * 0.2
    pos = np.column_stack([np.linspace(0, 10, 40), np.zeros(40), np.full(40, 5.0)])
    return PredictionMessage(SCHEMA_VERSION, uav_id, priority, stamp, times, pos, True)


def _connected(sender: ZenohTransport, receivers: list[ZenohTransport], timeout_s: float = 5.0,
               ) -> None:
    """Publish probes from ``sender`` until every receiver has one (discovery is async)."""
    got = {r.own_id: False for r in receivers}

    def ready() -> bool:
        sender.publish(PROBE, sender.own_id, 0.0)
        time.sleep(0.03)
        for r in receivers:
            if r.receive(r.own_id, 0.0):
                got[r.own_id] = True
        return all(got.values())

    assert _wait(ready, timeout_s), f"no discovery within {timeout_s} s: {got}"


@pytest.fixture
def trio() -> Iterator[list[ZenohTransport]]:
    """uav1 ← uav2 ← uav3: a chain of connects; gossip and brokering do the rest."""
    e1, e2 = _ep(), _ep()
    swarm = f"t{_free_port()}"  # a fresh swarm per test: no cross-talk between tests
    a = ZenohTransport("uav1", swarm=swarm, listen=[e1])
    b = ZenohTransport("uav2", swarm=swarm, listen=[e2], connect=[e1])
    c = ZenohTransport("uav3", swarm=swarm, connect=[e2])
    ts = [a, b, c]
    try:
        for t in ts:
            _connected(t, [o for o in ts if o is not t])
        time.sleep(0.05)
        for t in ts:  # forget the probes
            t.receive(t.own_id, 0.0)
        yield ts
    finally:
        for t in ts:
            t.close()


def test_is_a_transport(trio) -> None:
    assert all(isinstance(t, Transport) for t in trio)


def test_predictions_reach_the_others_and_not_self(trio) -> None:
    a, b, c = trio
    data = encode(_msg("uav1", 100.0))
    a.publish(data, "uav1", 100.0)
    got: dict[str, list[bytes]] = {"uav2": [], "uav3": []}

    def arrived() -> bool:
        for t in (b, c):
            got[t.own_id] += _recv(t)
        return all(got.values())

    assert _wait(arrived)
    assert got == {"uav2": [data], "uav3": [data]}
    time.sleep(0.1)
    assert _recv(a) == []
    assert a.stats.published >= 1


def test_inbox_polls_a_zenoh_transport_with_signed_messages(trio) -> None:
    a, b, _ = trio
    inbox = Inbox("uav2", key=KEY, max_age_s=1e9)
    a.publish(sign(encode(_msg("uav1", 50.0)), KEY), "uav1", 50.0)
    a.publish(encode(_msg("uav1", 51.0)), "uav1", 51.0)  # unsigned: rejected
    assert _wait(lambda: inbox.poll(b, 52.0) is not None
                 and inbox.accepted + inbox.rejected_total >= 2)
    assert inbox.latest["uav1"].stamp_s == 50.0
    assert inbox.rejected == {"unsigned message": 1}


def test_receive_is_bounded_and_overflow_counted() -> None:
    e1 = _ep()
    swarm = f"t{_free_port()}"
    with ZenohTransport("rx", swarm=swarm, listen=[e1], max_pending=20, max_per_receive=8) as rx, \
            ZenohTransport("tx", swarm=swarm, connect=[e1]) as tx:
        _connected(tx, [rx])
        _wait(lambda: not rx.receive("rx", 0.0), 0.3)
        before = rx.stats.received
        n = 50
        for i in range(n):
            tx.publish(i.to_bytes(4, "little"), "tx", 0.0)
        assert _wait(lambda: rx.stats.received - before >= n - 5)  # best effort: allow a few
        time.sleep(0.1)
        first = rx.receive("rx", 0.0)
        assert len(first) == 8
        assert rx.stats.dropped_overflow >= rx.stats.received - before - 20
        assert rx.stats.dropped_overflow > 0
        rest = rx.receive("rx", 0.0) + rx.receive("rx", 0.0) + rx.receive("rx", 0.0)
        assert len(rest) == 12  # 20 kept in all: the newest
        seq = [int.from_bytes(x, "little") for x in first + rest]
        assert seq == sorted(seq) and seq[-1] == n - 1
        assert rx.receive("rx", 0.0) == []


def test_generic_put_and_subscribe(trio) -> None:
    a, b, c = trio
    swarm = a.swarm
    states = c.subscribe("*/state")
    mission = c.subscribe("uav1/mission", maxlen=2)
    everything = b.subscribe("**")

    def until_heard(put: Callable[[], None], *subs) -> None:
        """Put until every sub has something: a new subscription takes a moment to reach the
        publishers, and what is put before that is not delivered to it."""
        def heard() -> bool:
            put()
            time.sleep(0.03)
            return all(s.pending for s in subs)
        assert _wait(heard)
        time.sleep(0.05)

    until_heard(lambda: a.put("state", b"s1"), states, everything)
    until_heard(lambda: b.put("state", b"s2"), states)
    until_heard(lambda: a.put("mission", b"m1"), mission, everything)
    got = states.drain()
    assert {k for k, _ in got} == {f"uavmpc/{swarm}/uav1/state", f"uavmpc/{swarm}/uav2/state"}
    assert {p for _, p in got} == {b"s1", b"s2"}
    assert set(mission.drain()) == {(f"uavmpc/{swarm}/uav1/mission", b"m1")}
    keys = {k for k, _ in everything.drain()}
    assert keys == {f"uavmpc/{swarm}/uav1/state", f"uavmpc/{swarm}/uav1/mission"}  # not own
    # A full subscription keeps the newest.
    for i in range(5):
        a.put("mission", bytes([i]))
    assert _wait(lambda: mission.dropped >= 3)
    time.sleep(0.05)
    assert [p for _, p in mission.drain(limit=5)] == [b"\x03", b"\x04"]
    assert mission.drain() == []


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"own_id": "uav 1"}, "own_id"),
    ({"own_id": ""}, "own_id"),
    ({"own_id": "x" * 33}, "own_id"),
    ({"own_id": "a/b"}, "own_id"),
    ({"swarm": "*"}, "swarm"),
    ({"listen": ["127.0.0.1:7447"]}, "must start with tcp/, udp/ or tls/"),
    ({"listen": "tcp/127.0.0.1:7447"}, "wrap it in a list"),
    ({"connect": ["quic/127.0.0.1:7447"]}, "must start with tcp/, udp/ or tls/"),
    ({"connect": ["tcp/127.0.0.1"]}, "host>:<port"),
    ({"connect": ["tcp/127.0.0.1:70000"]}, "65535"),
    ({"max_pending": 0}, "max_pending"),
    ({"max_per_receive": 0}, "max_per_receive"),
    ({"config_overrides": {"listen/endpoints": '["tcp/0.0.0.0:1"]'}}, "listen="),
    ({"config_overrides": {"no/such/key": "1"}}, "no/such/key"),
])
def test_bad_arguments_are_value_errors(kwargs, match) -> None:
    args = {"own_id": "uav1", **kwargs}
    with pytest.raises(ValueError, match=match):
        ZenohTransport(args.pop("own_id"), **args)


def test_bad_topics_ids_and_close_is_idempotent() -> None:
    t = ZenohTransport("uav1", swarm="lonely")
    with pytest.raises(ValueError, match="topic"):
        t.put("a/*", b"")
    with pytest.raises(ValueError, match="keyexpr_suffix"):
        t.subscribe("a b")
    with pytest.raises(ValueError, match="sender_id"):
        t.publish(b"x", "uav2", 0.0)
    with pytest.raises(ValueError, match="receiver_id"):
        t.receive("uav2", 0.0)
    with pytest.raises(TypeError):
        t.publish("text", "uav1", 0.0)  # type: ignore[arg-type]
    t.close()
    t.close()
    assert t.closed
    assert t.receive("uav1", 0.0) == []
    with pytest.raises(RuntimeError, match="closed"):
        t.publish(b"x", "uav1", 0.0)
