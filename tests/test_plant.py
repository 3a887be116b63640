"""The multirotor plant: physics sanity, motors, ground, wind, and fast == reference path."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uavmpc.plant import G_MPS2, Airframe, AttitudeTarget, GnssNoise, Plant, VehicleState, Wind
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
def test_numba_path_equals_numpy_reference(name: str) -> None:
    af = Airframe.packaged(name)
    n = af.n_rotors
    plants = {
        b: Multirotor(af, position_m=(0.0, 0.0, 2.0), backend=b,
                      wind=Wind(mean_mps=(3.0, -1.0, 0.0), gust_sigma_mps=1.0, seed=3))
        for b in ("numba", "numpy")
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
        a, b = out["numba"], out["numpy"]
        for f in ("position_m", "velocity_mps", "attitude_wxyz", "body_rates_radps"):
            np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=0, atol=1e-9)
    np.testing.assert_allclose(plants["numba"].rotor_speeds_radps,
                               plants["numpy"].rotor_speeds_radps, rtol=1e-12, atol=1e-9)
    # Direct motor commands and ground contact take the same path in both.
    for p in plants.values():
        p.step_motors(np.zeros(n), 1.5)
    xa, xb = plants["numba"]._x, plants["numpy"]._x
    np.testing.assert_allclose(xa[:N_RIGID], xb[:N_RIGID], rtol=0, atol=1e-9)
    assert plants["numba"].landed == plants["numpy"].landed


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
