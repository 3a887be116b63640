"""The autopilot's clock on ours (:class:`uavmpc.drivers.px4.clock.ClockMap`), on synthetic
clocks: what TIMESYNC round trips and one-way stamps tell, and what they must not."""

from __future__ import annotations

import numpy as np

from uavmpc.drivers.px4.clock import JUMPS_TO_RESTART, ClockMap

T0 = 1.8e9  # our clock (Unix seconds)
RATE = 1.0 / 0.986  # our seconds per autopilot second: lockstep SITL running 1.4 % slow


def _px4_time(t_local: float, boot: float = T0) -> float:
    return (t_local - boot) / RATE


def test_round_trips_give_offset_and_rate_despite_slow_replies() -> None:
    rng = np.random.default_rng(1)
    clock = ClockMap()
    for k in range(150):  # 30 s at 5 Hz; one reply in five delayed by a loaded host
        sent = T0 + 10.0 + 0.2 * k
        out, back = rng.uniform(5e-5, 2e-4, 2)
        if k % 5 == 0:
            back += rng.uniform(0.01, 0.05)
        clock.add_round_trip(sent, _px4_time(sent + out), sent + out + back)
    assert clock.rate_known and abs(clock.rate - RATE) < 2e-5
    for t in (T0 + 20.0, T0 + 39.0):  # an estimate sampled at our time t maps back onto t
        assert abs(clock.to_local(_px4_time(t)) - t) < 3e-4


def test_one_way_stamps_map_by_their_earliest_arrivals() -> None:
    """Without TIMESYNC: every message arrives late by the link's latency, never early."""
    rng = np.random.default_rng(2)
    clock = ClockMap()
    arrivals = []
    for k in range(900):  # 30 s of 30 Hz estimates, latency 0.5 ms to tens of ms
        t = T0 + 5.0 + k / 30.0
        arrived = t + 5e-4 + rng.exponential(0.01)
        arrivals.append((_px4_time(t), arrived))
        clock.add_one_way(_px4_time(t), arrived)
    assert abs(clock.rate - RATE) < 1e-3
    t_ap, arrived = np.array(arrivals[-600:]).T  # the window the map was fitted on
    mapped = np.array([clock.to_local(x) for x in t_ap])
    # Within a millisecond of the earliest arrivals, never later than a sample's own arrival
    # by more (the envelope, not the mean: a mean would sit ~10 ms late, the mean latency).
    assert np.all(mapped <= arrived + 1e-3)
    sampled = T0 + 5.0 + np.arange(300, 900) / 30.0
    assert np.abs(mapped - sampled).max() < 2e-3


def test_one_wild_reply_is_ignored_and_a_reboot_restarts_the_map() -> None:
    clock = ClockMap()
    for k in range(50):
        sent = T0 + 0.2 * k
        clock.add_round_trip(sent, _px4_time(sent), sent + 1e-4)
    before = clock.to_local(_px4_time(T0 + 9.0))
    sent = T0 + 10.0
    assert not clock.add_round_trip(sent, 999.0, sent + 1e-4)  # forged or corrupt: ignored
    assert clock.to_local(_px4_time(T0 + 9.0)) == before and clock.resets == 0
    reboot = T0 + 10.2  # the autopilot's clock starts again from zero
    for k in range(JUMPS_TO_RESTART + 5):
        sent = reboot + 0.2 * (k + 1)
        clock.add_round_trip(sent, _px4_time(sent, boot=reboot), sent + 1e-4)
    assert clock.resets == 1 and not clock.rate_known  # 1 s of new samples: rate not seen yet
    t = reboot + 0.2 * (JUMPS_TO_RESTART + 5)
    assert abs(clock.to_local(_px4_time(t, boot=reboot)) - t) < 0.02  # 1.4 % of the span
