"""The moving deck (a car on a figure-eight track) and the filter that tracks and predicts it
from noisy, lossy position fixes, checked against the car's true path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uavmpc.missions.target_tracking import CtrvFilter, ctrv_step
from uavmpc.plant.ground_vehicle import KMH, FigureEightTrack, GroundVehicle


def test_the_track_is_the_arena_and_the_car_keeps_its_speed() -> None:
    track = FigureEightTrack()
    pts = np.array([track.point(s) for s in np.linspace(0, track.length_of_lap_m, 2000)])
    assert np.ptp(pts[:, 0]) == pytest.approx(90.0, abs=0.05)
    assert np.ptp(pts[:, 1]) == pytest.approx(60.0, abs=0.05)
    car = GroundVehicle(track, speed_mps=15.0 * KMH)
    a, b = car.state(10.0), car.state(10.1)
    assert np.linalg.norm(b.position_m - a.position_m) / 0.1 == pytest.approx(15 * KMH, rel=1e-3)
    assert a.position_m[2] == car.deck_height_m
    # heading and yaw rate agree with the path
    assert math.remainder(b.heading_rad - a.heading_rad, 2 * math.pi) / 0.1 == pytest.approx(
        a.yaw_rate_radps, abs=0.01)


def test_the_deck_is_a_square_that_turns_with_the_car() -> None:
    car = GroundVehicle(deck_size_m=1.5)
    s = car.state(3.0)
    c, sn = math.cos(s.heading_rad), math.sin(s.heading_rad)
    fwd, left = np.array([c, sn, 0.0]), np.array([-sn, c, 0.0])
    assert car.on_deck(3.0, s.position_m + 0.7 * fwd + 0.7 * left)
    assert not car.on_deck(3.0, s.position_m + 0.8 * fwd)
    assert not car.on_deck(3.0, s.position_m + 0.8 * left)


def test_ctrv_is_exact_on_a_circle() -> None:
    x = np.array([0.0, 0.0, 0.0, 2.0, 0.5])  # radius 4 m
    for _ in range(100):
        x = ctrv_step(x, 0.01 * math.pi * 4 / 2.0 * 2 / math.pi)
    y = ctrv_step(np.array([0.0, 0.0, 0.0, 2.0, 0.5]), 2 * math.pi / 0.5)  # one full turn
    assert np.allclose(y[:2], [0.0, 0.0], atol=1e-9)


def _fly_filter(speed_kmh: float, seed: int, seconds: float = 30.0):
    rng = np.random.default_rng(seed)
    car = GroundVehicle(speed_mps=speed_kmh * KMH)
    f = CtrvFilter(fix_sigma_m=0.3)
    errors, ahead2 = [], []
    for k in range(int(seconds * 20)):  # 20 Hz fixes, 15 % dropped
        t = 0.05 * k
        if rng.random() < 0.15:
            continue
        true = car.state(t).position_m[:2]
        f.update(t, true + rng.normal(0.0, 0.3, 2))
        if t > 10.0 and f.ready:
            errors.append(np.linalg.norm(f.x[:2] - true))
            pred = f.predict(np.array([t + 2.0]))[0]
            truth2 = car.state(t + 2.0).position_m[:2]
            ahead2.append(np.linalg.norm(pred[:2] - truth2))
    return f, np.array(errors), np.array(ahead2), car


@pytest.mark.parametrize("speed_kmh", [15.0, 30.0])
def test_the_filter_tracks_the_car_on_its_curves(speed_kmh: float) -> None:
    f, errors, ahead2, car = _fly_filter(speed_kmh, seed=4)
    assert math.sqrt(np.mean(errors**2)) < 0.25  # better than one fix (0.3 m)
    assert abs(f.x[3] - car.speed_mps) < 0.3
    assert f.restarts == 0
    # Two seconds ahead from the estimate: a regression bound for now (measured 1.9–2.1 m at
    # 15 km/h, 5.9–6.6 m at 30 km/h: the turn rate's estimate from 0.3 m fixes dominates).
    assert math.sqrt(np.mean(ahead2**2)) < (2.5 if speed_kmh == 15.0 else 7.5)


@pytest.mark.parametrize("speed_kmh", [15.0, 30.0])
def test_the_turn_rate_model_predicts_the_curves_better_than_straight_lines(
        speed_kmh: float) -> None:
    car = GroundVehicle(speed_mps=speed_kmh * KMH)
    ctrv, straight = [], []
    for t in np.arange(5.0, 60.0, 0.5):
        s = car.state(t)
        x = np.array([*s.position_m[:2], s.heading_rad, s.speed_mps, s.yaw_rate_radps])
        truth = car.state(t + 2.0).position_m[:2]
        ctrv.append(np.linalg.norm(ctrv_step(x, 2.0)[:2] - truth))
        x[4] = 0.0
        straight.append(np.linalg.norm(ctrv_step(x, 2.0)[:2] - truth))
    assert math.sqrt(np.mean(np.square(ctrv))) < 0.5 * math.sqrt(np.mean(np.square(straight)))


def test_bad_fixes_are_rejected_and_counted() -> None:
    f, *_ = _fly_filter(15.0, seed=1, seconds=12.0)
    x = f.x.copy()
    t = f.t_s
    assert not f.update(t + 0.05, f.x[:2] + np.array([25.0, 0.0]))  # a 25 m jump: gated
    assert not f.update(t + 0.10, [float("nan"), 0.0])
    assert not f.update(t - 1.0, f.x[:2])  # out of order
    assert f.rejected >= 3
    assert np.allclose(f.x[[3, 4]], x[[3, 4]], atol=0.05)  # the estimate did not jump
    with pytest.raises(RuntimeError, match="initialised"):
        CtrvFilter().predict(np.array([1.0]))


# ------------------------------------------------------------------ the deck in the plant
def _over_deck(car: GroundVehicle, t: float, height_m: float, along_m: float = 0.0,
               thrust_fraction: float = 0.9):
    """A level F550 ``height_m`` above the deck (``along_m`` ahead of its centre), moving with
    the car, holding ``thrust_fraction`` of its weight."""
    from uavmpc.plant import Airframe, AttitudeTarget, Multirotor

    af = Airframe.named("f550")
    s = car.state(t)
    fwd = np.array([math.cos(s.heading_rad), math.sin(s.heading_rad), 0.0])
    plant = Multirotor(af, position_m=s.position_m + along_m * fwd + [0, 0, height_m],
                       yaw_rad=s.heading_rad, t0_s=t)
    plant.rows.x[plant.row, 3:6] = s.velocity_mps
    q = np.array([math.cos(0.5 * s.heading_rad), 0.0, 0.0, math.sin(0.5 * s.heading_rad)])
    target = AttitudeTarget(attitude_wxyz=q, thrust_n=thrust_fraction * af.mass_kg * 9.80665,
                            body_rates_ff_radps=np.zeros(3))
    return plant, target


def _fly(plant, target, car: GroundVehicle, t0: float, seconds: float, cut_at_s: float = 1e9):
    for k in range(round(seconds / 0.01)):
        t = t0 + 0.01 * k
        plant.set_deck(car.deck_row(t))
        if t - t0 >= cut_at_s:
            plant.cut_motors()
        plant.step(target, 0.01)


def test_a_uav_touches_down_on_the_deck_and_is_carried_along_through_a_turn() -> None:
    car = GroundVehicle()
    t0 = 20.0  # in a curve: the deck turns under the UAV
    assert abs(car.state(t0).yaw_rate_radps) > 0.05
    plant, target = _over_deck(car, t0, 0.3)
    _fly(plant, target, car, t0, 8.0, cut_at_s=1.0)
    touch = plant.deck_touch()
    assert touch.touchdowns == 1 and touch.strikes == 0 and touch.on_deck
    assert t0 < touch.t_s < t0 + 1.0
    # Settling from 0.3 m at 0.9 g: it met the deck at about √(2 · 0.1 g · 0.3) downward.
    assert touch.relative_velocity_mps[2] == pytest.approx(-math.sqrt(2 * 0.981 * 0.3), rel=0.1)
    assert np.linalg.norm(touch.offset_m) < 0.3  # uncontrolled: drag and the curve
    assert plant.landed and not plant.armed
    t_end = t0 + 8.0
    state = plant.state()
    assert car.on_deck(t_end, state.position_m)  # carried 8 s through the turn, still on it
    assert state.position_m[2] == car.deck_height_m
    assert np.allclose(state.velocity_mps[:2], car.state(t_end).velocity_mps[:2], atol=0.2)


def test_a_uav_descending_beside_the_deck_strikes_its_edge() -> None:
    car = GroundVehicle()
    # Its centre 1 m ahead of the deck's centre: off the 1.5 m square, but its rotor disc
    # (0.275 m arms) overlaps the deck.
    plant, target = _over_deck(car, 5.0, 0.5, along_m=1.0, thrust_fraction=0.8)
    _fly(plant, target, car, 5.0, 1.5)
    touch = plant.deck_touch()
    assert touch.strikes == 1 and touch.touchdowns == 0
    # Far from the deck, nothing is met but the ground.
    plant, target = _over_deck(car, 5.0, 0.5, along_m=3.0, thrust_fraction=0.8)
    _fly(plant, target, car, 5.0, 1.5)
    assert plant.deck_touch().strikes == 0 and plant.deck_touch().touchdowns == 0


def test_without_a_deck_the_plant_flies_as_before() -> None:
    car = GroundVehicle()
    a, target = _over_deck(car, 5.0, 0.3)
    b, _ = _over_deck(car, 5.0, 0.3)
    for _ in range(100):
        a.set_deck(None)
        a.step(target, 0.01)
        b.step(target, 0.01)
    assert np.array_equal(a.rows.x, b.rows.x)
    assert a.state().position_m[2] < car.deck_height_m  # fell through where a deck would be
    with pytest.raises(ValueError, match="not finite"):
        a.set_deck(np.full(9, np.nan))
