"""Where a simulated vehicle really is: its simulator's ground truth over MAVLink (issue 51).

An autopilot's estimate is not where the vehicle is. Against PX4 v1.16's SIH, EKF2's height
read 0.65–0.69 m low in a hover, and closest approaches computed from estimates differed from
the truth by up to 0.4 m either way. So wherever a simulator knows the truth, separation and
collisions are judged on it.

PX4's SIH SITL sends the truth itself: its start-up script (``etc/init.d-posix/px4-rc.mavlink``)
starts, for ``PX4_SIMULATOR=sihsim``, a MAVLink instance of its own that streams
``HIL_STATE_QUATERNION`` at 25 Hz to UDP 127.0.0.1:19410 + i (instance i, from port
19450 + i). That stream (``src/modules/mavlink/streams/HIL_STATE_QUATERNION.hpp``) reads
``vehicle_global_position_groundtruth`` and friends: latitude and longitude in 1e-7 degrees,
altitude in millimetres, velocity in cm/s, and leaves ``time_usec`` at 0, so a sample is
stamped when it arrives (loopback: well under a millisecond). It flows whether or not a node
flies the vehicle, so a vehicle whose node died is still followed.

The stand-in PX4 (:mod:`uavmpc.drivers.px4.sitl`) sends the same message from its plant, the
same way (:func:`truth_message`), and the simulated-plant nodes need none: their state is
their plant's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavmpc.drivers.px4.dialect import mavlink
from uavmpc.drivers.px4.endpoint import MavlinkEndpoint
from uavmpc.drivers.px4.frames import enu_to_geodetic, enu_to_ned, geodetic_to_enu

__all__ = ["TRUTH_PORT_BASE", "TruthListener", "TruthSample", "truth_message"]

#: PX4 SIH SITL sends instance i's ground truth to UDP 127.0.0.1:TRUTH_PORT_BASE + i.
TRUTH_PORT_BASE = 19410
#: The rate of that stream (``mavlink stream -r 25 -s HIL_STATE_QUATERNION``) [Hz].
TRUTH_RATE_HZ = 25.0


@dataclass(frozen=True)
class TruthSample:
    """One ground-truth sample: ``t_s`` when it arrived [s, Unix], from MAVLink system
    ``system_id``, ``position_m`` (3,) in the world's ENU frame [m]."""

    t_s: float
    system_id: int
    position_m: np.ndarray


class TruthListener:
    """Receives ``HIL_STATE_QUATERNION`` on UDP 127.0.0.1:``port`` and places each sample in
    the world whose ENU origin is ``geo_origin`` = (lat [deg], lon [deg], alt [m AMSL]).

    Raises:
        OSError: the port cannot be listened on (the message names it).
    """

    def __init__(self, port: int, geo_origin: tuple[float, float, float]) -> None:
        self.geo_origin = tuple(float(v) for v in geo_origin)
        self.link = MavlinkEndpoint(f"udp://127.0.0.1:{int(port)}", system_id=255,
                                    component_id=191)
        #: Samples that could not be placed (non-finite or off the globe).
        self.refused = 0

    def poll(self) -> list[TruthSample]:
        """Every sample that arrived since the last call (never blocks)."""
        out: list[TruthSample] = []
        for msg, _sender, arrived in self.link.receive():
            if msg.get_type() != "HIL_STATE_QUATERNION":
                continue
            try:
                p = geodetic_to_enu(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3,
                                    self.geo_origin)
            except ValueError:
                self.refused += 1
                continue
            out.append(TruthSample(arrived, int(msg.get_srcSystem()), p))
        return out

    def close(self) -> None:
        self.link.close()


def truth_message(position_m: np.ndarray, velocity_mps: np.ndarray,
                  attitude_wxyz_ned: np.ndarray,
                  geo_origin: tuple[float, float, float]) -> mavlink.MAVLink_message:
    """``HIL_STATE_QUATERNION`` as PX4's SIH sends it: the true ENU ``position_m`` (3,) and
    ``velocity_mps`` (3,) in the world about ``geo_origin``, the attitude already in NED/FRD
    (w, x, y, z); ``time_usec`` 0 and no rates or accelerations, as PX4 leaves or fills them."""
    lat, lon, alt = enu_to_geodetic(np.asarray(position_m, float), geo_origin)
    v = enu_to_ned(np.asarray(velocity_mps, float))
    q = [float(x) for x in attitude_wxyz_ned]

    def cm(x: float) -> int:
        return max(-32768, min(32767, round(x * 100.0)))

    return mavlink.MAVLink_hil_state_quaternion_message(
        0, q, 0.0, 0.0, 0.0, round(float(lat) * 1e7), round(float(lon) * 1e7),
        round(float(alt) * 1e3), cm(v[0]), cm(v[1]), cm(v[2]), 0, 0, 0, 0, 0)

