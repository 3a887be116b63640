"""The multirotor plant: physics sanity, motors, ground, wind, kernels == numpy oracle, and rows
of a shared record flying like standalone vehicles."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from oracles import MultirotorOracle

from uavmpc.estimation.receiver import GnssNoise
from uavmpc.plant import (
    G_MPS2,
    Airframe,
    AttitudeTarget,
    Plant,
    PlantRows,
    VehicleState,
    Wind,
    attitude_target_ok,
    copy_row,
    normalize_quat,
    plant_step,
)
from uavmpc.plant.interface import quat_to_rot, rot_to_quat, yaw_quat
from uavmpc.plant.multirotor import N_RIGID, Multirotor


@pytest.fixture(scope="module")
def f550() -> Airframe:
    return Airframe.packaged("f550")


@pytest.fixture(scope="module")
def no_drag(f550: Airframe) -> Airframe:
    return dataclasses.replace(f550, drag_n_per_mps=np.zeros(3))


def _tilt_deg(q: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, quat_to_rot(q)[2, 2])))


@pytest.mark.parametrize("name, n", [("f550", 6), ("x500", 4)])
def test_packaged_airframes_load(name: str, n: int) -> None:
    af = Airframe.packaged(name)
    assert af.n_rotors == n
    # At hover speed the rotors carry the weight and produce no torque.
    wrench = af.allocation() @ np.full(n, af.hover_omega_radps**2)
    assert wrench[0] == pytest.approx(af.mass_kg * G_MPS2, rel=1e-12)
    np.testing.assert_allclose(wrench[1:], 0.0, atol=1e-12)
    assert 1.5 < af.max_thrust_n / (af.mass_kg * G_MPS2) < 2.5


def test_multirotor_is_a_plant(f550: Airframe) -> None:
    assert isinstance(Multirotor(f550), Plant)


def test_hover_needs_exactly_weight(no_drag: Airframe) -> None:
    plant = Multirotor(no_drag, position_m=(0.0, 0.0, 10.0))
    hover = np.full(6, no_drag.hover_omega_radps)
    s = plant.step_motors(hover, 1.0)
    assert abs(s.position_m[2] - 10.0) < 1e-9
    np.testing.assert_allclose(s.velocity_mps, 0.0, atol=1e-9)
    # 1 % more speed (2 % more thrust) climbs: the test above is not vacuous.
    s2 = plant.step_motors(hover * 1.01, 1.0)
    assert s2.velocity_mps[2] > 0.1


def test_free_fall_accelerates_at_g(no_drag: Airframe) -> None:
    plant = Multirotor(no_drag, position_m=(1.0, 2.0, 100.0), rotors_at_hover=False)
    s = plant.step_motors(np.zeros(6), 2.0)
    assert s.position_m[2] == pytest.approx(100.0 - 0.5 * G_MPS2 * 4.0, abs=1e-9)
    assert s.velocity_mps[2] == pytest.approx(-G_MPS2 * 2.0, abs=1e-9)
    np.testing.assert_allclose(s.position_m[:2], [1.0, 2.0], atol=1e-12)


def test_drag_slows_the_fall(f550: Airframe) -> None:
    plant = Multirotor(f550, position_m=(0.0, 0.0, 1e4), rotors_at_hover=False)
    s = plant.step_motors(np.zeros(6), 60.0)  # time constant m / d ≈ 5.6 s
    terminal = f550.mass_kg * G_MPS2 / f550.drag_n_per_mps[2]
    assert s.velocity_mps[2] == pytest.approx(-terminal, rel=1e-3)


def test_pure_yaw_torque_spins_about_z_only(no_drag: Airframe) -> None:
    tau_z = 0.2
    w2 = np.linalg.pinv(no_drag.allocation()) @ np.array([no_drag.mass_kg * G_MPS2, 0, 0, tau_z])
    omega = np.sqrt(w2)
    plant = Multirotor(no_drag, position_m=(0.0, 0.0, 10.0))
    plant.set_state(plant.state(), rotor_speeds_radps=omega)
    s = plant.step_motors(omega, 1.0)
    np.testing.assert_allclose(s.body_rates_radps[:2], 0.0, atol=1e-9)
    assert s.body_rates_radps[2] == pytest.approx(tau_z / no_drag.inertia_kgm2[2, 2], rel=1e-9)
    assert _tilt_deg(s.attitude_wxyz) < 1e-6
    np.testing.assert_allclose(s.position_m, [0.0, 0.0, 10.0], atol=1e-9)


def test_torque_free_tumble_conserves_angular_momentum(no_drag: Airframe) -> None:
    inertia = np.array([[0.031, 0.002, -0.001], [0.002, 0.040, 0.003], [-0.001, 0.003, 0.058]])
    af = dataclasses.replace(no_drag, inertia_kgm2=inertia)
    plant = Multirotor(af, position_m=(0.0, 0.0, 1000.0), rotors_at_hover=False)
    w0 = np.array([3.0, -2.0, 4.0])
    plant.set_state(
        VehicleState(0.0, np.array([0.0, 0.0, 1000.0]), np.zeros(3),
                     np.array([1.0, 0.0, 0.0, 0.0]), w0),
        rotor_speeds_radps=np.zeros(6),
    )

    def momentum(s: VehicleState) -> tuple[np.ndarray, float]:
        w = s.body_rates_radps
        return s.rotation() @ inertia @ w, 0.5 * w @ inertia @ w

    l0, e0 = momentum(plant.state())
    rates = []
    for _ in range(300):
        s = plant.step_motors(np.zeros(6), 0.01)
        rates.append(s.body_rates_radps)
        ang, e = momentum(s)
        np.testing.assert_allclose(ang, l0, rtol=0, atol=1e-8 * np.linalg.norm(l0))
        assert e == pytest.approx(e0, rel=1e-8)
    # The body rates really do change (the test exercises the gyroscopic term).
    assert np.ptp(np.array(rates), axis=0).max() > 0.5


def test_motor_lag_reaches_63_percent_at_tau(f550: Airframe) -> None:
    plant = Multirotor(f550, position_m=(0.0, 0.0, 100.0), rotors_at_hover=False)
    tau = f550.motor_tau_s
    s_cmd = 600.0
    plant.step_motors(np.full(6, s_cmd), round(tau / 0.002) * 0.002)
    frac = plant.rotor_speeds_radps / s_cmd
    np.testing.assert_allclose(frac, 1.0 - math.exp(-1.0), atol=2e-3)


def test_motor_saturation(f550: Airframe) -> None:
    plant = Multirotor(f550, position_m=(0.0, 0.0, 100.0))
    plant.step_motors(np.full(6, 5.0 * f550.omega_max_radps), 0.5)
    np.testing.assert_allclose(plant.rotor_speeds_radps, f550.omega_max_radps, rtol=1e-6)
    assert np.all(plant.rotor_speeds_radps <= f550.omega_max_radps)


def test_ground_holds_vehicle_with_motors_off(f550: Airframe) -> None:
    plant = Multirotor(f550)
    assert plant.landed
    for _ in range(100):
        s = plant.step_motors(np.zeros(6), 0.02)
        assert s.position_m[2] == 0.0
        np.testing.assert_array_equal(s.velocity_mps, 0.0)


def test_drop_lands_without_bounce_or_nan(f550: Airframe) -> None:
    plant = Multirotor(f550, position_m=(0.0, 0.0, 3.0), rotors_at_hover=False)
    tilted = np.array([0.98, 0.1, 0.15, 0.05])
    tilted = rot_to_quat(quat_to_rot(tilted / np.linalg.norm(tilted)))
    plant.set_state(VehicleState(0.0, np.array([0.0, 0.0, 3.0]), np.array([2.0, 0.0, -5.0]),
                                 tilted, np.array([1.0, -1.0, 0.5])))
    heights = []
    for _ in range(200):
        s = plant.step_motors(np.zeros(6), 0.01)
        heights.append(s.position_m[2])
        assert np.all(np.isfinite(s.position_m)) and s.position_m[2] >= 0.0
    touchdown = next(i for i, h in enumerate(heights) if h == 0.0)
    assert all(h == 0.0 for h in heights[touchdown:])
    assert plant.landed and _tilt_deg(plant.state().attitude_wxyz) < 1e-9


def test_takeoff_from_ground(f550: Airframe) -> None:
    plant = Multirotor(f550)
    target = AttitudeTarget(yaw_quat(0.3), 1.3 * f550.mass_kg * G_MPS2)
    s = plant.step(target, 2.0)
    assert not plant.landed and s.position_m[2] > 1.0


def test_wind_pushes_a_vehicle_with_fixed_attitude(f550: Airframe) -> None:
    plant = Multirotor(f550, position_m=(0.0, 0.0, 50.0), wind=Wind(mean_mps=(4.0, 0.0, 0.0)))
    s = plant.step(AttitudeTarget(np.array([1.0, 0.0, 0.0, 0.0]), f550.mass_kg * G_MPS2), 2.0)
    assert s.velocity_mps[0] > 0.5 and abs(s.velocity_mps[1]) < 1e-6


def test_wind_gusts_statistics_and_seed() -> None:
    w = Wind(mean_mps=(1.0, 2.0, 0.0), gust_sigma_mps=(1.5, 1.0, 0.3), gust_tau_s=1.0, seed=7)
    samples = np.array([w.update(0.5) for _ in range(20000)])
    np.testing.assert_allclose(samples.mean(axis=0), [1.0, 2.0, 0.0], atol=0.1)
    np.testing.assert_allclose(samples.std(axis=0), [1.5, 1.0, 0.3], rtol=0.08)
    lag1 = np.corrcoef(samples[:-1, 0], samples[1:, 0])[0, 1]
    assert lag1 == pytest.approx(math.exp(-0.5), abs=0.03)
    w2 = Wind(mean_mps=(1.0, 2.0, 0.0), gust_sigma_mps=(1.5, 1.0, 0.3), gust_tau_s=1.0, seed=7)
    np.testing.assert_array_equal(w2.update(0.5), samples[0])


def test_step_rejects_partial_substeps(f550: Airframe) -> None:
    with pytest.raises(ValueError, match="substeps"):
        Multirotor(f550).step_motors(np.zeros(6), 0.003)


@pytest.mark.parametrize("name", ["f550", "x500"])
def test_kernels_equal_numpy_oracle(name: str) -> None:
    af = Airframe.packaged(name)
    n = af.n_rotors

    def wind() -> Wind:
        return Wind(mean_mps=(3.0, -1.0, 0.0), gust_sigma_mps=1.0, seed=3)

    plants = {
        "kernel": Multirotor(af, position_m=(0.0, 0.0, 2.0), wind=wind()),
        "oracle": MultirotorOracle(af, position_m=(0.0, 0.0, 2.0), wind=wind()),
    }
    rng = np.random.default_rng(1)
    targets = []
    for k in range(60):  # 0.6 s of varied targets, saturating some of them
        axis = rng.normal(size=3)
        angle = rng.uniform(0.0, 0.6)
        axis /= np.linalg.norm(axis)
        q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
        thrust = af.mass_kg * G_MPS2 * rng.uniform(0.5, 1.8)
        targets.append(AttitudeTarget(q, thrust, rng.normal(size=3) * (k % 2)))
    for tgt in targets:
        out = {b: p.step(tgt, 0.01) for b, p in plants.items()}
        a, b = out["kernel"], out["oracle"]
        for f in ("position_m", "velocity_mps", "attitude_wxyz", "body_rates_radps"):
            np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=0, atol=1e-9)
    np.testing.assert_allclose(plants["kernel"].rotor_speeds_radps,
                               plants["oracle"].rotor_speeds_radps, rtol=1e-12, atol=1e-9)
    # Direct motor commands and ground contact take the same path in both.
    for p in plants.values():
        p.step_motors(np.zeros(n), 1.5)
    kernel = plants["kernel"]
    xa, xb = kernel.rows.x[kernel.row], plants["oracle"].x
    np.testing.assert_allclose(xa[:N_RIGID], xb[:N_RIGID], rtol=0, atol=1e-9)
    assert kernel.landed == plants["oracle"].landed


def _fly_mixed(plant: Multirotor, af: Airframe, seed: int) -> np.ndarray:
    """Take off from the ground, fly varied targets in gusts, then cut the motors and land.
    Returns every state vector, rotor speeds, landed flag and time along the way."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(150):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(0.0, 0.5)
        q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
        target = AttitudeTarget(q, af.mass_kg * G_MPS2 * rng.uniform(0.9, 1.6),
                                rng.normal(size=3) * (k % 2))
        s = plant.step(target, 0.01)
        out.append([*s.position_m, *s.velocity_mps, *s.attitude_wxyz, *s.body_rates_radps,
                    *plant.rotor_speeds_radps, plant.landed, plant.t_s])
    for _ in range(150):
        s = plant.step_motors(np.full(af.n_rotors, 50.0), 0.01)
        out.append([*s.position_m, *s.velocity_mps, *s.attitude_wxyz, *s.body_rates_radps,
                    *plant.rotor_speeds_radps, plant.landed, plant.t_s])
    return np.array(out)


def test_rows_of_a_shared_record_fly_like_standalone_plants() -> None:
    """A hexacopter and a quadrotor as rows 0 and 1 of one record (sized for six rotors) fly
    bit for bit as each one alone; so does the quadrotor stepped by the kernel directly."""
    hexa, quad = Airframe.packaged("f550"), Airframe.packaged("x500")
    assert (hexa.n_rotors, quad.n_rotors) == (6, 4)

    def wind(seed: int) -> Wind:
        return Wind(mean_mps=(2.0, -1.0, 0.0), gust_sigma_mps=0.8, seed=seed)

    shared = PlantRows.empty(2, 6)
    in_rows = [Multirotor(hexa, yaw_rad=0.4, wind=wind(1), rows=shared, row=0),
               Multirotor(quad, position_m=(3.0, 0.0, 0.0), yaw_rad=-1.0, wind=wind(2),
                          rows=shared, row=1)]
    alone = [Multirotor(hexa, yaw_rad=0.4, wind=wind(1)),
             Multirotor(quad, position_m=(3.0, 0.0, 0.0), yaw_rad=-1.0, wind=wind(2))]
    assert in_rows[1].rows is shared and in_rows[1].row == 1
    assert alone[1].rows.x.shape == (1, N_RIGID + 4)
    # Interleaved, so a row that wrote into its neighbour's columns would show.
    flights = {}
    for k, (a, b) in enumerate(zip(in_rows, alone, strict=True)):
        af = (hexa, quad)[k]
        flights[k] = (_fly_mixed(a, af, seed=10 + k), _fly_mixed(b, af, seed=10 + k))
    for a, b in flights.values():
        assert a[:150, 2].max() > 0.5 and a[-1, 2] == 0.0  # took off and landed again
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(shared.x[1, N_RIGID + 4:], 0.0)  # unused columns stay 0

    # A driver stepping row 1 itself with the kernel gets what the object gets.
    driver = PlantRows.empty(2, 6)
    obj = Multirotor(quad, position_m=(0.0, 0.0, 4.0))
    view = Multirotor(quad, position_m=(0.0, 0.0, 4.0), rows=driver, row=1)
    target = AttitudeTarget(yaw_quat(0.2), 1.1 * quad.mass_kg * G_MPS2, np.array([0, 0, 0.1]))
    qd = np.array(target.attitude_wxyz)
    assert attitude_target_ok(qd, target.thrust_n, target.body_rates_ff_radps)
    normalize_quat(qd)
    for _ in range(50):
        s = obj.step(target, 0.01)
        plant_step(1, driver, view.substeps(0.01), qd, target.thrust_n,
                   target.body_rates_ff_radps)
    np.testing.assert_array_equal(view.state().position_m, s.position_m)
    np.testing.assert_array_equal(driver.x[1], np.pad(obj.rows.x[0], (0, 2)))
    assert view.t_s == obj.t_s

    # Rows copy between records of different widths (a driver gathering its vehicles).
    narrow = PlantRows.empty(1, 4)
    copy_row(driver, 1, narrow, 0)
    np.testing.assert_array_equal(narrow.x[0], obj.rows.x[0])
    with pytest.raises(ValueError, match="does not fit"):
        copy_row(shared, 0, narrow, 0)
    with pytest.raises(ValueError, match="rotors"):
        Multirotor(hexa, rows=narrow)
    with pytest.raises(ValueError, match="row 2"):
        Multirotor(quad, rows=narrow, row=2)


def test_target_check_and_normalisation_match_numpy() -> None:
    """The compiled check accepts what the exact norm accepts and normalises within 2 ULP of
    it. The reference is a correctly rounded sum (``math.fsum``), not numpy's dot: which BLAS
    kernel numpy's dot runs (fused multiply-adds or not, in which order) depends on the
    machine, and a test pinned to one machine's bits fails on the next."""
    rng = np.random.default_rng(5)
    for _ in range(2000):
        qd = rng.normal(size=4) * rng.choice([0.1, 0.5, 1.0])
        qd /= rng.uniform(0.8, 1.2) * np.linalg.norm(qd)
        norm = math.sqrt(math.fsum(float(v) * float(v) for v in qd))
        if abs(norm - 0.9) > 1e-12 and abs(norm - 1.1) > 1e-12:  # not on a bound's last bit
            assert attitude_target_ok(qd, 1.0, np.zeros(3)) == (0.9 < norm < 1.1)
        q = qd.copy()
        normalize_quat(q)
        np.testing.assert_array_max_ulp(q, qd / norm, maxulp=2)
    good = np.array([1.0, 0.0, 0.0, 0.0])
    assert attitude_target_ok(good, 10.0, np.zeros(3))
    assert not attitude_target_ok(good, float("inf"), np.zeros(3))
    assert not attitude_target_ok(good, 10.0, np.array([0.0, float("nan"), 0.0]))
    assert not attitude_target_ok(np.full(4, float("nan")), 10.0, np.zeros(3))


def test_rejects_invalid_attitude_target(f550: Airframe) -> None:
    plant = Multirotor(f550, position_m=(0.0, 0.0, 5.0))
    with pytest.raises(ValueError, match="invalid attitude target"):
        plant.step(AttitudeTarget(np.array([1.0, 0.0, 0.0, 0.0]), float("nan")), 0.01)
    with pytest.raises(ValueError, match="invalid attitude target"):
        plant.step(AttitudeTarget(np.zeros(4), 10.0), 0.01)


def test_gnss_noise_statistics_and_seed() -> None:
    truth = VehicleState(0.0, np.array([1.0, 2.0, 3.0]), np.zeros(3), yaw_quat(0.0), np.zeros(3))
    gnss = GnssNoise(position_sigma_m=0.5, velocity_sigma_mps=0.2, bias_sigma_m=0.0, seed=4)
    meas = [gnss.apply(dataclasses.replace(truth, t_s=0.01 * k)) for k in range(20000)]
    pos = np.array([m.position_m for m in meas])
    vel = np.array([m.velocity_mps for m in meas])
    np.testing.assert_allclose(pos.mean(axis=0), truth.position_m, atol=0.02)
    np.testing.assert_allclose(pos.std(axis=0), 0.5, rtol=0.05)
    np.testing.assert_allclose(vel.std(axis=0), 0.2, rtol=0.05)
    assert meas[5].attitude_wxyz is truth.attitude_wxyz
    # The bias wanders slowly: consecutive samples share it.
    biased = GnssNoise(position_sigma_m=0.0, velocity_sigma_mps=0.0, bias_sigma_m=1.0,
                       bias_tau_s=60.0, seed=4)
    a = biased.apply(truth).position_m
    b = biased.apply(dataclasses.replace(truth, t_s=0.01)).position_m
    assert np.linalg.norm(a - truth.position_m) > 0.05 and np.linalg.norm(a - b) < 0.05
    again = GnssNoise(position_sigma_m=0.5, velocity_sigma_mps=0.2, bias_sigma_m=0.0, seed=4)
    np.testing.assert_array_equal(again.apply(truth).position_m, meas[0].position_m)
