"""uavmpc's ENU/FLU conventions against PX4's NED/FRD: each map once, each a round trip, and the
state and setpoints across real MAVLink frames (pymavlink's codec) back to what they were."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("pymavlink")

from uavmpc.drivers.px4 import frames
from uavmpc.drivers.swarm import free_ports
from uavmpc.plant import Airframe, AttitudeTarget, VehicleState
from uavmpc.plant.interface import heading_of, quat_to_rot, yaw_quat

finite = st.floats(-1e3, 1e3, allow_nan=False)
vectors = st.lists(finite, min_size=3, max_size=3).map(np.array)
unit = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1).map(lambda q: np.array(q) / np.linalg.norm(q))

ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])


@given(vectors)
def test_world_and_body_vectors_round_trip(v: np.ndarray) -> None:
    assert np.array_equal(frames.ned_to_enu(frames.enu_to_ned(v)), v)
    assert np.array_equal(frames.frd_to_flu(frames.flu_to_frd(v)), v)
    assert np.allclose(frames.enu_to_ned(v), ENU_TO_NED @ v)


@given(unit)
def test_attitude_round_trips_and_is_the_rotation_between_the_frames(q: np.ndarray) -> None:
    q_ned = frames.enu_flu_quat_to_ned_frd(q)
    assert np.isclose(np.linalg.norm(q_ned), 1.0)
    assert np.allclose(frames.ned_frd_quat_to_enu_flu(q_ned), q, atol=1e-12)
    # R_ned_frd = T · R_enu_flu · B, and a body vector lands on the same world vector.
    assert np.allclose(quat_to_rot(q_ned), ENU_TO_NED @ quat_to_rot(q) @ FRD_TO_FLU, atol=1e-12)
    v_flu = np.array([0.3, -1.2, 2.0])
    assert np.allclose(quat_to_rot(q_ned) @ frames.flu_to_frd(v_flu),
                       frames.enu_to_ned(quat_to_rot(q) @ v_flu), atol=1e-12)


@given(unit)
def test_heading_of_any_attitude_maps_as_the_heading_conversion_says(q: np.ndarray) -> None:
    q_ned = frames.enu_flu_quat_to_ned_frd(q)
    tilt = quat_to_rot(q)[:, 0]
    if np.hypot(tilt[0], tilt[1]) < 1e-3:
        return  # nose straight up or down: no heading
    expected = frames.heading_enu_to_ned(float(heading_of(q)))
    assert math.isclose(math.remainder(float(heading_of(q_ned)) - expected, 2 * math.pi), 0.0,
                        abs_tol=1e-9)


@given(st.floats(-10, 10))
def test_heading_round_trips_and_east_is_ninety_degrees(h: float) -> None:
    back = frames.heading_ned_to_enu(frames.heading_enu_to_ned(h))
    assert math.isclose(math.remainder(back - h, 2 * math.pi), 0.0, abs_tol=1e-12)
    assert math.isclose(frames.heading_enu_to_ned(0.0), math.pi / 2)
    assert np.allclose(frames.enu_flu_quat_to_ned_frd(yaw_quat(0.0)),
                       [math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])


# --- geodetic ↔ ENU (PX4's azimuthal equidistant map on its sphere) ------------------------

origins = st.tuples(st.floats(-85.0, 85.0), st.floats(-180.0, 180.0), st.floats(-400.0, 5000.0))
local = st.lists(st.floats(-5000.0, 5000.0), min_size=3, max_size=3).map(np.array)
PX4_HOME = (47.397742, 8.545594, 488.0)


@given(origins, local)
def test_enu_to_geodetic_and_back_is_the_same_point_to_a_millimetre(origin, p) -> None:
    lat, lon, alt = frames.enu_to_geodetic(p, origin)
    assert -90.0 <= lat <= 90.0 and -180.0 <= lon < 180.0
    assert np.allclose(frames.geodetic_to_enu(lat, lon, alt, origin), p, atol=1e-3, rtol=0)


@given(origins, st.floats(-0.04, 0.04), st.floats(-0.04, 0.04), st.floats(-100.0, 100.0))
def test_geodetic_to_enu_and_back_is_the_same_point(origin, dlat, dlon, dalt) -> None:
    lat = float(np.clip(origin[0] + dlat, -90.0, 90.0))
    p = frames.geodetic_to_enu(lat, origin[1] + dlon, origin[2] + dalt, origin)
    back = frames.enu_to_geodetic(p, origin)
    assert math.isclose(back[0], lat, abs_tol=1e-9)
    assert math.isclose(math.remainder(back[1] - (origin[1] + dlon), 360.0), 0.0, abs_tol=1e-8)
    assert math.isclose(back[2], origin[2] + dalt, abs_tol=1e-9)


@given(origins, local)
def test_the_horizontal_distance_is_the_great_circle_distance(origin, p) -> None:
    """Azimuthal equidistant: |(east, north)| from the origin is the distance on the sphere."""
    lat, lon, _ = frames.enu_to_geodetic(p, origin)
    phi0, phi = math.radians(origin[0]), math.radians(lat)
    dlon = math.radians(lon - origin[1])
    hav = math.sin((phi - phi0) / 2) ** 2 + math.cos(phi0) * math.cos(phi) * math.sin(dlon / 2) ** 2
    great_circle = 2 * frames.EARTH_RADIUS_M * math.asin(math.sqrt(hav))
    assert math.isclose(math.hypot(p[0], p[1]), great_circle, abs_tol=1e-3)


def test_known_values_on_px4s_sphere() -> None:
    # one degree of latitude is 2π·6 371 000 / 360 = 111 194.93 m straight north
    e, n, u = frames.geodetic_to_enu(PX4_HOME[0] + 1.0, PX4_HOME[1], PX4_HOME[2] + 10.0,
                                     PX4_HOME)
    assert abs(e) < 1e-6 and math.isclose(n, 111194.93, abs_tol=0.01) and u == 10.0
    # along the equator the map is the arc length too, east positive
    e, n, _ = frames.geodetic_to_enu(0.0, 0.01, 0.0, (0.0, 0.0, 0.0))
    assert math.isclose(e, 1111.9493, abs_tol=1e-3) and abs(n) < 1e-9
    # the origin itself, and a point 100 m east at Zürich's latitude
    assert np.array_equal(frames.geodetic_to_enu(*PX4_HOME, PX4_HOME), [0.0, 0.0, 0.0])
    lat, lon, alt = frames.enu_to_geodetic(np.array([100.0, 0.0, 0.0]), PX4_HOME)
    assert math.isclose(lon - PX4_HOME[1],
                        math.degrees(100.0 / (frames.EARTH_RADIUS_M
                                              * math.cos(math.radians(PX4_HOME[0])))),
                        rel_tol=1e-6)
    assert math.isclose(lat, PX4_HOME[0], abs_tol=1e-8) and alt == PX4_HOME[2]


def test_geodetic_conversions_vectorise() -> None:
    p = np.array([[0.0, 0.0, 0.0], [10.0, -20.0, 3.0], [-3000.0, 4000.0, -50.0]])
    lat, lon, alt = frames.enu_to_geodetic(p, PX4_HOME)
    assert lat.shape == lon.shape == alt.shape == (3,)
    back = frames.geodetic_to_enu(lat, lon, alt, PX4_HOME)
    assert back.shape == (3, 3) and np.allclose(back, p, atol=1e-6)
    for i in range(3):
        assert np.allclose(frames.geodetic_to_enu(lat[i], lon[i], alt[i], PX4_HOME), p[i],
                           atol=1e-6)


@pytest.mark.parametrize("call, match", [
    (lambda: frames.geodetic_to_enu(91.0, 0.0, 0.0, PX4_HOME), r"latitude.*\[-90, 90\]"),
    (lambda: frames.geodetic_to_enu(float("nan"), 0.0, 0.0, PX4_HOME), "latitude must be finite"),
    (lambda: frames.geodetic_to_enu(0.0, float("inf"), 0.0, PX4_HOME), "longitude must be fin"),
    (lambda: frames.geodetic_to_enu(0.0, 0.0, 0.0, (-90.5, 0.0, 0.0)), "origin latitude"),
    (lambda: frames.geodetic_to_enu(0.0, 0.0, 0.0, (0.0, 0.0)), r"origin must be \(lat_deg"),
    (lambda: frames.geodetic_to_enu(0.0, 180.0, 0.0, (0.0, 0.0, 0.0)), "antipode"),
    (lambda: frames.enu_to_geodetic(np.array([1.0, 2.0]), PX4_HOME), r"shape \(\.\.\., 3\)"),
    (lambda: frames.enu_to_geodetic(np.array([1.0, np.nan, 0.0]), PX4_HOME), "finite"),
    (lambda: frames.enu_to_geodetic([0.0, 0.0, 0.0], ("a", 0.0, 0.0)), "origin must be a numb"),
])
def test_geodetic_conversions_reject_bad_input_clearly(call, match) -> None:
    with pytest.raises(ValueError, match=match):
        call()


def _pair(origin: tuple[float, float, float]):
    from uavmpc.drivers.px4.sitl import StandInPx4
    from uavmpc.drivers.px4.vehicle import Px4Vehicle

    af = Airframe.packaged("f550")
    # A port free a moment ago can be taken by another test worker before we bind it: retry
    # with a fresh one (this test is about the frames, not about port allocation).
    for attempt in range(5):
        (port,) = free_ports(1)
        try:
            vehicle = Px4Vehicle(f"udp://127.0.0.1:{port}", af, origin_m=origin,
                                 hover_thrust=0.5, system_id=1)
            break
        except OSError as exc:
            if "in use" not in str(exc) or attempt == 4:
                raise
    sitl = StandInPx4(af, f"udpout://127.0.0.1:{port}", position_m=origin)
    return vehicle, sitl


def _wire(sender, receiver_endpoint, message):
    """Pack with the sender's codec, parse with the receiver's: the real MAVLink 2 frame."""
    data = message.pack(sender.mav)
    (decoded,) = receiver_endpoint.mav.parse_buffer(data)
    return decoded


@settings(max_examples=25, deadline=None)
@given(vectors, vectors, unit, vectors)
def test_a_state_crosses_odometry_and_comes_back(p, v, q, w) -> None:
    vehicle, sitl = _pair((10.0, -4.0, 0.0))
    try:
        true = VehicleState(0.0, p + sitl.origin_m, v * 0.01, q, w * 0.001)
        sitl.plant.set_state(true)
        s = sitl.plant.state()  # after the ground contact had its say
        msg = _wire(sitl.link, vehicle.link, sitl.odometry_message(1.0, s, s))
        vehicle._on_odometry(msg, 1.0)
        est = vehicle._odom[1]
        # float32 on the wire
        assert np.allclose(est.position_m, s.position_m, rtol=1e-6, atol=1e-4)
        assert np.allclose(est.velocity_mps, s.velocity_mps, rtol=1e-6, atol=1e-5)
        assert min(np.abs(est.attitude_wxyz - s.attitude_wxyz).max(),
                   np.abs(est.attitude_wxyz + s.attitude_wxyz).max()) < 1e-6
        assert np.allclose(est.body_rates_radps, s.body_rates_radps, atol=1e-5)
    finally:
        vehicle.close()
        sitl.link.close()


@settings(max_examples=25, deadline=None)
@given(vectors, vectors, vectors, st.floats(-3.1, 3.1), st.floats(-2.0, 2.0))
def test_a_position_target_crosses_set_position_target_and_comes_back(p, v, a, heading, rate):
    """What the node sends in position mode and while its estimate is stale."""
    from uavmpc.tracker.tracker import TrackerCommand

    vehicle, sitl = _pair((10.0, -4.0, 0.0))
    try:
        cmd = TrackerCommand(0.0, p + sitl.origin_m, v, a, heading, rate, 0.0)
        sitl._on_position_target(_wire(vehicle.link, sitl.link,
                                       vehicle.position_target_message(1.0, cmd)), 1.0)
        hold = sitl.setpoint.values
        assert np.allclose(hold.position_m, cmd.position_m, rtol=1e-6, atol=1e-4)
        assert np.allclose(hold.velocity_mps, v, rtol=1e-6, atol=1e-5)
        assert np.allclose(hold.acceleration_mps2, a, rtol=1e-6, atol=1e-5)
        assert abs(math.remainder(hold.heading_rad - heading, math.tau)) < 1e-6
        assert math.isclose(hold.heading_rate_radps, rate, abs_tol=1e-6)
    finally:
        vehicle.close()
        sitl.link.close()


@settings(max_examples=25, deadline=None)
@given(unit, st.floats(0.0, 30.0), st.floats(-2.0, 2.0))
def test_an_attitude_target_crosses_set_attitude_target_and_comes_back(q, thrust, yaw_rate):
    vehicle, sitl = _pair((0.0, 0.0, 0.0))
    try:
        target = AttitudeTarget(q, thrust, np.array([0.0, 0.0, yaw_rate]))
        msg = vehicle.attitude_target_message(1.0, target)
        sitl._on_attitude_target(_wire(vehicle.link, sitl.link, msg), 1.0)
        q_ned, rates, thrust_norm = sitl.setpoint.values
        back_q = frames.ned_frd_quat_to_enu_flu(q_ned)
        assert min(np.abs(back_q - q).max(), np.abs(back_q + q).max()) < 1e-6
        mg = sitl.airframe.mass_kg * 9.80665
        expected = min(thrust / mg * 0.5, 1.0)
        assert math.isclose(thrust_norm, expected, rel_tol=1e-6, abs_tol=1e-7)
        assert np.allclose(frames.frd_to_flu(rates), [0.0, 0.0, yaw_rate], atol=1e-6)
    finally:
        vehicle.close()
        sitl.link.close()
