"""The autopilot's clock mapped onto ours: offset *and* rate, from MAVLink ``TIMESYNC``.

An autopilot stamps its estimates with its boot clock. On a flight controller that clock is a
crystal (tens of ppm from ours); in PX4's lockstep SITL it is simulated time, which ran 1.2–1.5 %
slower than the wall clock on this project's machine and 3.5 % under load. A mapping that only
tracks an offset then ages every estimate by a second per minute, and the node's staleness
failsafe fires within seconds of arming. So the map is a line, ``t_local = a + b · t_autopilot``,
fitted over a sliding window.

Samples come from two sources:

- **round trips** (primary): we send ``TIMESYNC(tc1=0, ts1=our time)``; the autopilot answers
  ``tc1`` = its time, ``ts1`` echoed (PX4: ``src/modules/mavlink/mavlink_timesync.cpp``). Its time
  is then placed at the midpoint of the round trip, with an error of at most half the round trip;
  only the samples with the shortest round trips in the window are fitted (a loaded host delays
  some replies by tens of milliseconds).
- **one-way stamps** (fallback, for an autopilot that does not answer ``TIMESYNC``): a message's
  sample time against its arrival time. Every arrival is late by the transport's latency, never
  early, so the lower envelope of ``arrival − stamp`` (the earliest arrival per second) is the map.
"""

from __future__ import annotations

import math
from collections import deque
from typing import TypeVar

import numpy as np

__all__ = ["ClockMap"]

#: A sample whose second element is its arrival on our clock.
_Sample = TypeVar("_Sample", bound=tuple[float, ...])

#: Samples older than this (by our clock) leave the fit: long enough to see the rate through
#: jitter, short enough to follow a lockstep simulation whose speed changes with the load.
WINDOW_S = 20.0
#: Below this span of samples the rate is not observable: it is taken as 1 (or kept).
MIN_RATE_SPAN_S = 2.0
#: A round trip longer than this carries no timing information worth having.
MAX_ROUND_TRIP_S = 0.5
#: Round trips within this of the window's shortest are fitted (plus half the shortest).
ROUND_TRIP_SLACK_S = 0.002
#: Rates outside this are not clocks but a fault: the fit keeps its rate.
MAX_RATE_ERROR = 0.2
#: A round trip this far [s] (beyond its own length) from the map is not fitted; this many in a
#: row are a reboot or a time jump, and the map restarts (PX4's own timesync resets likewise
#: after consecutive high deviations: ``src/modules/mavlink/mavlink_timesync.cpp``).
JUMP_S = 1.0
JUMPS_TO_RESTART = 5


class ClockMap:
    """``t_local = a + b · t_autopilot`` [s], fitted to the recent samples.

    :attr:`synced` once there is a map at all; :attr:`rate_known` once the samples span
    :data:`MIN_RATE_SPAN_S` (before that, ``b`` = 1)."""

    def __init__(self, window_s: float = WINDOW_S) -> None:
        self.window_s = float(window_s)
        self._round_trips: deque[tuple[float, float, float]] = deque()  # (t_ap, t_mid, rtt)
        self._one_way: deque[tuple[float, float]] = deque()  # (t_ap, earliest arrival) per s
        self._a = math.nan
        self._b = 1.0
        self._t_ap_ref = 0.0
        self.rate_known = False
        self.round_trip_s = math.nan
        self.resets = 0
        self._jumps = 0

    @property
    def synced(self) -> bool:
        return math.isfinite(self._a)

    @property
    def rate(self) -> float:
        """Our seconds per autopilot second (1.015 when its clock runs 1.5 % slow)."""
        return self._b

    def to_local(self, t_autopilot_s: float) -> float:
        """An autopilot time [s since its boot] on our clock [s]; NaN before any sample."""
        return self._a + self._b * (float(t_autopilot_s) - self._t_ap_ref)

    def add_round_trip(self, sent_s: float, t_autopilot_s: float, received_s: float) -> bool:
        """A TIMESYNC answer: our send and receive times, its time in between. False if the
        sample was refused (negative or over-long round trip)."""
        rtt = received_s - sent_s
        if not (0.0 <= rtt <= MAX_ROUND_TRIP_S and t_autopilot_s > 0.0):
            return False
        if self._jumped(t_autopilot_s, 0.5 * (sent_s + received_s), rtt):
            return False
        self._round_trips.append((t_autopilot_s, 0.5 * (sent_s + received_s), rtt))
        self._trim(self._round_trips, received_s)
        self._fit()
        return True

    def add_one_way(self, t_autopilot_s: float, arrived_s: float) -> None:
        """A stamped message's sample time and arrival time (used while no round trip is)."""
        if t_autopilot_s <= 0.0:
            return
        ow = self._one_way
        # Keep the earliest arrival (relative to its stamp) of each second: the envelope.
        if ow and math.floor(ow[-1][0]) == math.floor(t_autopilot_s):
            if arrived_s - t_autopilot_s < ow[-1][1] - ow[-1][0]:
                ow[-1] = (t_autopilot_s, arrived_s)
        else:
            ow.append((t_autopilot_s, arrived_s))
        self._trim(ow, arrived_s)
        if not self._round_trips:
            self._fit()

    def _trim(self, samples: deque[_Sample], now_s: float) -> None:
        while samples and samples[0][1] < now_s - self.window_s:
            samples.popleft()

    def _jumped(self, t_ap: float, t_local: float, rtt: float) -> bool:
        """True for a sample far from the map (not to be fitted). A single one is an outlier;
        :data:`JUMPS_TO_RESTART` in a row, an autopilot that rebooted: a new map begins."""
        if not self.synced or abs(self.to_local(t_ap) - t_local) <= JUMP_S + rtt:
            self._jumps = 0
            return False
        self._jumps += 1
        if self._jumps < JUMPS_TO_RESTART:
            return True
        self._round_trips.clear()
        self._one_way.clear()
        self._a, self._b, self.rate_known = math.nan, 1.0, False
        self._jumps = 0
        self.resets += 1
        return False

    def _fit(self) -> None:
        if self._round_trips:
            s = np.array(self._round_trips)
            best = float(s[:, 2].min())
            keep = s[:, 2] <= 1.5 * best + ROUND_TRIP_SLACK_S
            t_ap, t_local = s[keep, 0], s[keep, 1]
            self.round_trip_s = best
        else:
            s = np.array(self._one_way)
            t_ap, t_local = s[:, 0], s[:, 1]
        ref = float(t_ap[-1])
        x = t_ap - ref
        b = self._b
        if len(x) >= 3 and float(x.max() - x.min()) >= MIN_RATE_SPAN_S:
            xc = x - x.mean()
            fitted = float(np.dot(xc, t_local - t_local.mean()) / np.dot(xc, xc))
            if abs(fitted - 1.0) <= MAX_RATE_ERROR:
                b = fitted
                self.rate_known = True
        if self._round_trips:
            a = float(np.mean(t_local - b * x))
        else:  # the envelope: no sample may arrive before the map says it was taken
            a = float(np.min(t_local - b * x))
        self._a, self._b, self._t_ap_ref = a, b, ref
