"""SE(3) controller + attitude controller + plant in closed loop, kernels == numpy oracles,
controllers as rows of a shared record, and airframe-file validation."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from oracles import AttitudeController, Mixer, Se3Oracle

from uavmpc.config import ConfigError
from uavmpc.control import ControlRows, Se3Controller, se3_row
from uavmpc.estimation.receiver import GnssNoise
from uavmpc.plant import G_MPS2, Airframe, VehicleState, Wind
from uavmpc.plant.attitude import attitude_kernel, mix, mixer_matrices, pack_attitude_gains
from uavmpc.plant.interface import quat_to_rot, rot_to_quat, yaw_quat
from uavmpc.plant.multirotor import Multirotor
from uavmpc.tracker.tracker import TrackerCommand

PERIOD_S = 0.01  # SE(3) at 100 Hz


def hold(p: tuple[float, float, float], heading: float = 0.0) -> TrackerCommand:
    return TrackerCommand(0.0, np.array(p, dtype=float), np.zeros(3), np.zeros(3), heading,
                          0.0, 0.0)


def fly(
    af: Airframe,
    command: Callable[[float], TrackerCommand],
    duration_s: float,
    *,
    start: tuple[float, float, float] = (0.0, 0.0, 5.0),
    wind: Wind | None = None,
    controller: Se3Controller | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Closed loop tracker-command → SE(3) → plant. Returns times, positions (k, 3), attitudes
    (k, 4) after each period, and the attitude targets."""
    plant = Multirotor(af, position_m=start, wind=wind)
    ctl = controller or Se3Controller(af, period_s=PERIOD_S)
    ts, ps, qs, targets = [], [], [], []
    for _ in range(round(duration_s / PERIOD_S)):
        s = plant.state()
        target = ctl.update(command(s.t_s), s)
        s = plant.step(target, PERIOD_S)
        ts.append(s.t_s)
        ps.append(s.position_m)
        qs.append(s.attitude_wxyz)
        targets.append(target)
    return np.array(ts), np.array(ps), np.array(qs), targets


def tilt_deg(q: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, quat_to_rot(q)[2, 2])))


@pytest.fixture(scope="module", params=["f550", "x500"])
def airframe(request: pytest.FixtureRequest) -> Airframe:
    return Airframe.packaged(request.param)


# ---------------------------------------------------------------------------------------------
# SE(3) controller alone
# ---------------------------------------------------------------------------------------------


def test_se3_at_rest_on_target_asks_for_weight_and_heading(airframe: Airframe) -> None:
    ctl = Se3Controller(airframe)
    s = VehicleState(0.0, np.array([1.0, 2.0, 3.0]), np.zeros(3), yaw_quat(0.7), np.zeros(3))
    target = ctl.update(hold((1.0, 2.0, 3.0), heading=0.7), s)
    assert target.thrust_n == pytest.approx(airframe.mass_kg * G_MPS2, rel=1e-12)
    np.testing.assert_allclose(target.attitude_wxyz, yaw_quat(0.7), atol=1e-12)


def test_se3_feedforward_acceleration_tilts_the_right_way(airframe: Airframe) -> None:
    ctl = Se3Controller(airframe)
    s = VehicleState(0.0, np.zeros(3), np.zeros(3), yaw_quat(0.0), np.zeros(3))
    cmd = TrackerCommand(0.0, np.zeros(3), np.zeros(3), np.array([0.0, 2.0, 0.0]), 0.0, 0.0, 0.0)
    r = quat_to_rot(ctl.update(cmd, s).attitude_wxyz)
    b3 = r[:, 2]
    assert b3[1] / b3[2] == pytest.approx(2.0 / G_MPS2, rel=1e-9)
    assert r[0, 0] > 0.99 and abs(r[1, 0]) < 1e-12  # heading 0 kept: b1 in the x-z plane


def test_se3_saturates_thrust_and_limits_tilt(airframe: Airframe) -> None:
    ctl = Se3Controller(airframe)
    s = VehicleState(0.0, np.zeros(3), np.zeros(3), yaw_quat(0.0), np.zeros(3))
    target = ctl.update(hold((100.0, -50.0, 5.0)), s)
    se3 = airframe.se3
    assert target.thrust_n == pytest.approx(se3.thrust_max_fraction * airframe.max_thrust_n)
    assert tilt_deg(target.attitude_wxyz) == pytest.approx(math.degrees(airframe.se3.max_tilt_rad))
    assert ctl.saturated and ctl.tilt_limited
    # Commanding a dive faster than free fall never asks for an upside-down attitude.
    target = ctl.update(hold((0.0, 0.0, -500.0)), s)
    assert target.thrust_n == pytest.approx(se3.thrust_min_fraction * airframe.max_thrust_n)
    assert tilt_deg(target.attitude_wxyz) < 1e-9


def test_integrators_are_clipped_and_frozen_in_saturation(airframe: Airframe) -> None:
    ctl = Se3Controller(airframe)
    s = VehicleState(0.0, np.array([0.0, 0.0, 0.0]), np.zeros(3), yaw_quat(0.0), np.zeros(3))
    ctl.update(hold((0.0, 0.0, 0.05)), s)  # small error: integrates
    assert ctl.integral_world_ms[2] == pytest.approx(-0.05 * PERIOD_S)
    for _ in range(10_000):
        ctl.update(hold((0.0, 0.0, 0.05)), s)
    limit = airframe.se3.integral_limit_world_ms[2]
    assert abs(ctl.integral_world_ms[2]) == pytest.approx(limit)
    ctl.reset()
    for _ in range(100):
        ctl.update(hold((300.0, 0.0, 0.0)), s)  # tilt-limited: no integration
    np.testing.assert_array_equal(ctl.integral_world_ms, 0.0)


def test_se3_kernel_matches_numpy_oracle(airframe: Airframe) -> None:
    """The compiled kernel and the numpy oracle give the same targets, flags and integrator
    states over random commands/states covering the free, tilt-limited, saturated and
    integral-clipped regimes."""
    rng = np.random.default_rng(7)
    fast = Se3Controller(airframe, period_s=PERIOD_S)
    ref = Se3Oracle(airframe, period_s=PERIOD_S)
    counts = {"free": 0, "tilt": 0, "sat": 0, "clipped": 0}

    def compare(cmd: TrackerCommand, s: VehicleState, dt: float | None) -> None:
        a, b = fast.update(cmd, s, dt), ref.update(cmd, s, dt)
        np.testing.assert_allclose(a.attitude_wxyz, b.attitude_wxyz, rtol=0.0, atol=1e-12)
        assert a.thrust_n == pytest.approx(b.thrust_n, rel=1e-12, abs=1e-12)
        assert isinstance(a.thrust_n, float)
        np.testing.assert_allclose(a.body_rates_ff_radps, b.body_rates_ff_radps, rtol=0.0,
                                   atol=1e-12)
        assert (fast.saturated, fast.tilt_limited) == (ref.saturated, ref.tilt_limited)
        for x, y in ((fast.integral_world_ms, ref.integral_world_ms),
                     (fast.integral_body_ms, ref.integral_body_ms)):
            np.testing.assert_allclose(x, y, rtol=0.0, atol=1e-12)
        counts["tilt"] += ref.tilt_limited
        counts["sat"] += ref.saturated
        counts["free"] += not (ref.saturated or ref.tilt_limited)
        counts["clipped"] += bool(
            np.any(np.abs(ref.integral_world_ms) == airframe.se3.integral_limit_world_ms)
            and np.any(np.abs(ref.integral_body_ms) == airframe.se3.integral_limit_body_ms)
        )

    for k in range(600):
        # Mostly small errors (the integrators run), sometimes large ones.
        scale = 0.05 if k % 3 else float(rng.choice([0.5, 5.0, 50.0]))
        q = rng.normal(size=4) if k % 7 == 0 else rng.normal([1.0, 0, 0, 0], [0.0, 0.2, 0.2, 1.0])
        s = VehicleState(0.0, rng.normal(0.0, scale, 3), rng.normal(0.0, scale, 3),
                         q / np.linalg.norm(q), rng.normal(0.0, 0.5, 3))
        cmd = TrackerCommand(0.0, rng.normal(0.0, scale, 3), rng.normal(0.0, scale, 3),
                             rng.normal(0.0, scale, 3), float(rng.uniform(-4.0, 4.0)),
                             float(rng.normal(0.0, 0.5)), 0.0)
        compare(cmd, s, None if k % 2 else float(rng.uniform(0.001, 0.05)))
        if k == 300:
            fast.reset()
            ref.reset()
    # A steady offset winds both integrators up to their limits.
    for _ in range(300):
        q = rng.normal([1.0, 0, 0, 0.3], [0.0, 0.05, 0.05, 0.05])
        s = VehicleState(0.0, np.array([0.1, 0.0, -0.05]) + rng.normal(0.0, 0.01, 3),
                         rng.normal(0.0, 0.05, 3), q / np.linalg.norm(q), np.zeros(3))
        compare(hold((0.0, 0.0, 0.0), float(rng.uniform(-4.0, 4.0))), s, 0.2)
    assert min(counts.values()) >= 30, counts
    # Fresh output arrays each call (the target must not alias the controller's buffers).
    s = VehicleState(0.0, np.zeros(3), np.zeros(3), yaw_quat(0.0), np.zeros(3))
    t1, t2 = fast.update(hold((0.0, 0.0, 0.0)), s), fast.update(hold((1.0, 0.0, 0.0)), s)
    assert t1.attitude_wxyz is not t2.attitude_wxyz
    assert t1.body_rates_ff_radps is not t2.body_rates_ff_radps


def _random_inputs(rng: np.random.Generator, k: int) -> tuple[TrackerCommand, VehicleState]:
    scale = 0.05 if k % 3 else float(rng.choice([0.5, 5.0, 50.0]))
    q = rng.normal([1.0, 0, 0, 0], [0.0, 0.2, 0.2, 1.0])
    s = VehicleState(0.0, rng.normal(0.0, scale, 3), rng.normal(0.0, scale, 3),
                     q / np.linalg.norm(q), rng.normal(0.0, 0.5, 3))
    cmd = TrackerCommand(0.0, rng.normal(0.0, scale, 3), rng.normal(0.0, scale, 3),
                         rng.normal(0.0, scale, 3), float(rng.uniform(-4.0, 4.0)),
                         float(rng.normal(0.0, 0.5)), 0.0)
    return cmd, s


def test_controllers_as_rows_of_a_shared_record_equal_standalone_ones() -> None:
    """Two controllers (a hexacopter's and a quadrotor's) as rows 0 and 1 of one record give
    bit for bit the targets, flags and integrals of two standalone ones; so does the kernel
    called on the row directly."""
    afs = [Airframe.packaged("f550"), Airframe.packaged("x500")]
    shared = ControlRows.empty(2)
    in_rows = [Se3Controller(af, period_s=PERIOD_S, rows=shared, row=i)
               for i, af in enumerate(afs)]
    alone = [Se3Controller(af, period_s=PERIOD_S) for af in afs]
    assert in_rows[1].rows is shared and in_rows[1].row == 1
    assert in_rows[1].thrust_max_n == alone[1].thrust_max_n != alone[0].thrust_max_n
    rng = np.random.default_rng(3)
    flags = set()
    for k in range(400):
        for a, b in zip(in_rows, alone, strict=True):
            cmd, s = _random_inputs(rng, k)
            dt = None if k % 2 else 0.02
            ta, tb = a.update(cmd, s, dt), b.update(cmd, s, dt)
            np.testing.assert_array_equal(ta.attitude_wxyz, tb.attitude_wxyz)
            np.testing.assert_array_equal(ta.body_rates_ff_radps, tb.body_rates_ff_radps)
            assert ta.thrust_n == tb.thrust_n
            assert (a.saturated, a.tilt_limited) == (b.saturated, b.tilt_limited)
            np.testing.assert_array_equal(a.integral_world_ms, b.integral_world_ms)
            np.testing.assert_array_equal(a.integral_body_ms, b.integral_body_ms)
            flags.add((a.saturated, a.tilt_limited))
        if k == 200:
            in_rows[0].reset()
            alone[0].reset()
            np.testing.assert_array_equal(shared.integral_world_ms[0], 0.0)
            assert np.any(shared.integral_world_ms[1] != 0.0)  # its neighbour kept its state
    assert len(flags) >= 3, flags  # free, tilt limited and saturated all occurred
    # A driver calling the kernel on row 1 gets what the object gets.
    cmd, s = _random_inputs(rng, 1)
    q, ff = np.empty(4), np.empty(3)
    thrust = se3_row(1, shared, s.position_m, s.velocity_mps, s.attitude_wxyz, cmd.position_m,
                     cmd.velocity_mps, cmd.acceleration_mps2, cmd.heading_rad,
                     cmd.heading_rate_radps, PERIOD_S, q, ff)
    tb = alone[1].update(cmd, s)
    assert thrust == tb.thrust_n
    np.testing.assert_array_equal(q, tb.attitude_wxyz)
    np.testing.assert_array_equal(ff, tb.body_rates_ff_radps)
    np.testing.assert_array_equal(in_rows[1].integral_body_ms, alone[1].integral_body_ms)
    # The properties are copies: writing into one does not change the controller.
    in_rows[1].integral_world_ms[:] = 99.0
    assert np.all(shared.integral_world_ms[1] != 99.0)
    with pytest.raises(ValueError, match="row 2"):
        Se3Controller(afs[0], rows=shared, row=2)


def _mixers(airframe: Airframe) -> dict[str, Callable[[float, np.ndarray], np.ndarray]]:
    """The compiled mixer (the plant's) and the numpy oracle, as thrust, torque → ω."""
    inverse, lo, hi = mixer_matrices(airframe)
    n = airframe.n_rotors

    def kernel(thrust_n: float, torque_nm: np.ndarray) -> np.ndarray:
        out = np.empty(n)
        mix(thrust_n, *map(float, torque_nm), inverse, n, lo, hi, out)
        return out

    return {"kernel": kernel, "oracle": Mixer(airframe).mix}


@pytest.mark.parametrize("impl", ["kernel", "oracle"])
def test_mixer_reproduces_thrust_and_torque(airframe: Airframe, impl: str) -> None:
    mixer = _mixers(airframe)[impl]
    torque = np.array([0.3, -0.2, 0.05])
    omega = mixer(airframe.mass_kg * G_MPS2, torque)
    wrench = airframe.allocation() @ omega**2
    np.testing.assert_allclose(wrench, [airframe.mass_kg * G_MPS2, *torque], rtol=1e-9, atol=1e-9)
    # Beyond the rotors' reach the yaw torque gives way first, roll stays.
    omega = mixer(0.85 * airframe.max_thrust_n, np.array([0.5, 0.0, 5.0]))
    wrench = airframe.allocation() @ omega**2
    assert wrench[1] == pytest.approx(0.5, rel=0.05)
    assert 0.0 <= wrench[3] < 5.0


def _attitude_loops(airframe: Airframe) -> dict[str, Callable[..., np.ndarray]]:
    """The compiled attitude loop (the plant's) and the numpy oracle, as
    (q, rates, target, thrust, ff, dt) → ω, each with its own state."""
    gains = pack_attitude_gains(airframe.attitude)
    inverse, lo, hi = mixer_matrices(airframe)
    inertia = np.ascontiguousarray(airframe.inertia_kgm2)
    ctrl = np.zeros(7)
    n = airframe.n_rotors

    def kernel(q: np.ndarray, w: np.ndarray, qd: np.ndarray, thrust_n: float, ff: np.ndarray,
               dt_s: float) -> np.ndarray:
        out = np.empty(n)
        attitude_kernel(q, w, qd, thrust_n, ff, ctrl, gains, inertia, inverse, n, lo, hi, dt_s,
                        False, out, np.empty(3))
        return out

    return {"kernel": kernel, "oracle": AttitudeController(airframe).update}


@pytest.mark.parametrize("impl", ["kernel", "oracle"])
def test_attitude_controller_turns_towards_target(airframe: Airframe, impl: str) -> None:
    update = _attitude_loops(airframe)[impl]
    target = rot_to_quat(quat_to_rot(np.array([math.cos(0.1), math.sin(0.1), 0.0, 0.0])))
    omega = update(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), target,
                   airframe.mass_kg * G_MPS2, np.zeros(3), 0.002)
    torque = (airframe.allocation() @ omega**2)[1:]
    assert torque[0] > 0.0 and abs(torque[1]) < 1e-9 * abs(torque[0]) + 1e-12


# ---------------------------------------------------------------------------------------------
# Closed loop
# ---------------------------------------------------------------------------------------------


def test_closed_loop_hover_within_2cm(airframe: Airframe) -> None:
    cmd = hold((0.0, 0.0, 5.0), heading=0.5)
    _, ps, _, _ = fly(airframe, lambda t: cmd, 10.0, start=(0.0, 0.0, 5.0))
    assert np.max(np.linalg.norm(ps - cmd.position_m, axis=1)) < 0.02


def test_closed_loop_recovers_from_offset(airframe: Airframe) -> None:
    cmd = hold((0.5, -0.5, 5.5))
    _, ps, _, _ = fly(airframe, lambda t: cmd, 12.0, start=(0.0, 0.0, 5.0))
    err = np.linalg.norm(ps - cmd.position_m, axis=1)
    assert np.max(err[-100:]) < 0.02 and np.max(ps[:, 2]) < 6.0  # settles, overshoot < 0.5 m


def test_constant_wind_rejected_by_integrators(airframe: Airframe) -> None:
    cmd = hold((0.0, 0.0, 5.0))
    ts, ps, _, _ = fly(airframe, lambda t: cmd, 30.0, wind=Wind(mean_mps=(5.0, 0.0, 0.0)))
    err = np.linalg.norm(ps - cmd.position_m, axis=1)
    assert np.max(err[ts > 20.0]) < 0.05
    # Without the integrators the same wind leaves a visible steady offset (≈ drag / K_p).
    import dataclasses

    no_i = dataclasses.replace(
        airframe, se3=dataclasses.replace(airframe.se3, ki_world_n_per_ms=np.zeros(3),
                                          ki_body_n_per_ms=np.zeros(3)))
    ts, ps, _, _ = fly(no_i, lambda t: cmd, 10.0, wind=Wind(mean_mps=(5.0, 0.0, 0.0)))
    offset = 5.0 * airframe.drag_n_per_mps[0] / airframe.se3.kp_n_per_m[0]
    assert ps[-1, 0] == pytest.approx(offset, rel=0.05) and offset > 0.05


def test_gusty_wind_stays_close(airframe: Airframe) -> None:
    cmd = hold((0.0, 0.0, 5.0))
    _, ps, _, _ = fly(airframe, lambda t: cmd, 20.0,
                      wind=Wind(mean_mps=(4.0, 2.0, 0.0), gust_sigma_mps=1.0, seed=11))
    assert np.max(np.linalg.norm(ps - cmd.position_m, axis=1)) < 0.2


def test_hover_on_rtk_like_gnss_stays_close(airframe: Airframe) -> None:
    plant = Multirotor(airframe, position_m=(0.0, 0.0, 5.0))
    ctl = Se3Controller(airframe)
    gnss = GnssNoise(seed=2)  # RTK-class defaults: ≈ 1–2 cm noise, a few cm slow bias
    cmd = hold((0.0, 0.0, 5.0))
    err = []
    for _ in range(2000):
        s = plant.step(ctl.update(cmd, gnss.apply(plant.state())), PERIOD_S)
        err.append(np.linalg.norm(s.position_m - cmd.position_m))
    # The controller flies the measured position: the true error is about the GNSS bias.
    assert max(err) < 0.1


def test_tilt_limit_holds_during_aggressive_command(airframe: Airframe) -> None:
    limit = math.degrees(airframe.se3.max_tilt_rad)
    cmd = hold((40.0, -30.0, 15.0), heading=2.0)  # a 50 m step with a 115° turn
    _, ps, qs, targets = fly(airframe, lambda t: cmd, 15.0)
    assert max(tilt_deg(t.attitude_wxyz) for t in targets) <= limit + 1e-9
    # The vehicle follows its target with a small overshoot of the attitude loop (it is no
    # hard constraint on the vehicle); the yaw-weighted attitude error keeps the turn from
    # tilting it further.
    assert max(tilt_deg(q) for q in qs) < limit + 2.0
    assert np.linalg.norm(ps[-1] - cmd.position_m) < 0.1


def test_follows_a_moving_command(airframe: Airframe) -> None:
    # A 1 m/s, 2 m radius circle with its feedforward velocity and acceleration.
    w = 0.5

    def circle(t: float) -> TrackerCommand:
        p = np.array([2.0 * math.cos(w * t), 2.0 * math.sin(w * t), 5.0])
        v = np.array([-2.0 * w * math.sin(w * t), 2.0 * w * math.cos(w * t), 0.0])
        a = -w * w * np.array([p[0], p[1], 0.0])
        return TrackerCommand(t, p, v, a, w * t + math.pi / 2, w, 0.0)

    ts, ps, _, _ = fly(airframe, circle, 15.0, start=(2.0, 0.0, 5.0))
    ref = np.array([circle(t).position_m for t in ts])
    assert np.max(np.linalg.norm(ps - ref, axis=1)[ts > 5.0]) < 0.05


# ---------------------------------------------------------------------------------------------
# Airframe files: errors name the field
# ---------------------------------------------------------------------------------------------


def _packaged_text(name: str) -> str:
    return resources.files("uavmpc.data").joinpath(f"airframes/{name}.toml").read_text()


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda s: re.sub(r"^mass_kg = .*$", "", s, flags=re.M), "airframe.mass_kg: missing"),
        (lambda s: re.sub(r"^mass_kg = .*$", "mass_kg = -1.0", s, flags=re.M),
         "airframe.mass_kg: must be > 0, got -1.0"),
        (lambda s: re.sub(r"^ixx_kgm2 = .*$", "ixx_kgm2 = -0.03", s, flags=re.M),
         "airframe.inertia.ixx_kgm2: must be > 0"),
        (lambda s: re.sub(r"^k_f_n_per_radps2 = .*$", "k_f_n_per_radps2 = -8e-6", s, flags=re.M),
         "airframe.rotors.k_f_n_per_radps2: must be > 0"),
        (lambda s: re.sub(r"^kp_n_per_m = \[17.0", "kp_n_per_m = [-17.0", s, flags=re.M),
         "airframe.se3.kp_n_per_m[0]: must be > 0, got -17.0"),
        (lambda s: re.sub(r"^rate_p_per_s = \[20.0, 20.0, 10.0\]", "rate_p_per_s = [20, -20, 10]",
                          s, flags=re.M),
         "airframe.attitude.rate_p_per_s[1]: must be > 0"),
        (lambda s: s.replace("spin = [1, -1, 1, -1, 1, -1]", "spin = [1, 1, 1, -1, 1, -1]"),
         "airframe.rotors.spin: as many rotors"),
        (lambda s: s.replace("[drag]", "[drag]\nlinear = 1.0"), "airframe.drag.linear: unknown"),
        (lambda s: re.sub(r"^omega_max_radps = .*$", "omega_max_radps = 500.0", s, flags=re.M),
         "cannot lift the weight"),
    ],
)
def test_bad_airframe_file_names_the_field(tmp_path: Path, edit: Callable[[str], str],
                                           field: str) -> None:
    text = _packaged_text("f550")
    bad = edit(text)
    assert bad != text
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    with pytest.raises(ConfigError, match=re.escape(field)):
        Airframe.from_toml(path)


def test_missing_file_and_unknown_airframe(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        Airframe.from_toml(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="no such packaged airframe"):
        Airframe.packaged("nope")
