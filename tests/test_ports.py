"""The ports a swarm picks for its nodes: free for both TCP (Zenoh) and UDP (MAVLink), and
outside the range the system hands out to sockets bound to port 0."""

from __future__ import annotations

import socket

from uavmpc.drivers.swarm import _PICK_PORTS, free_ports


def test_free_ports_are_distinct_bindable_for_tcp_and_udp_and_below_the_ephemeral_range() -> None:
    ports = free_ports(20)
    assert len(set(ports)) == 20
    assert all(_PICK_PORTS[0] <= p <= _PICK_PORTS[1] for p in ports)
    for p in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as t, \
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            t.bind(("127.0.0.1", p))
            u.bind(("127.0.0.1", p))


def test_a_port_taken_for_udp_only_is_not_picked(monkeypatch) -> None:
    (free,) = free_ports(1)
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        try:
            taken.bind(("127.0.0.1", free - 1))
        except OSError:
            pass  # taken already: not to be picked either way
        monkeypatch.setattr("uavmpc.drivers.swarm._PICK_PORTS", (free - 1, free))
        assert free_ports(1) == [free]
    finally:
        taken.close()
