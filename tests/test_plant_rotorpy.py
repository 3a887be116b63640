"""Independent check of the plant against RotorPy (test-only dependency; skipped if missing).

Same quadrotor parameters, aerodynamics off in both, the same zero-order-held rotor-speed
commands (varying thrust and torques about all axes, so the vehicle rolls, pitches, yaws and
translates), 6 s of flight. RotorPy integrates with a tight-tolerance DOP853, so the
difference measures our fixed-step RK4 and any modelling disagreement.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uavmpc.plant import G_MPS2, Airframe, VehicleState
from uavmpc.plant.interface import quat_to_rot
from uavmpc.plant.multirotor import Multirotor

rotorpy_multirotor = pytest.importorskip("rotorpy.vehicles.multirotor")

DURATION_S = 6.0
PERIOD_S = 0.01


def _rotorpy_params(af: Airframe) -> dict:
    j = af.inertia_kgm2
    return {
        "mass": af.mass_kg,
        "Ixx": j[0, 0], "Iyy": j[1, 1], "Izz": j[2, 2],
        "Ixy": j[0, 1], "Ixz": j[0, 2], "Iyz": j[1, 2],
        "num_rotors": af.n_rotors,
        "rotor_pos": {f"r{i}": np.array([x, y, 0.0]) for i, (x, y) in enumerate(af.rotor_xy_m)},
        # RotorPy's yaw torque is +dir·k_m ω²; ours is −spin·k_m ω².
        "rotor_directions": -af.rotor_spin,
        "rotor_speed_min": 0.0,
        "rotor_speed_max": af.omega_max_radps,
        "k_eta": af.k_f,
        "k_m": af.k_m,
        "tau_m": af.motor_tau_s,
        "motor_noise_std": 0.0,
    }


def _commands(af: Airframe, t: float) -> np.ndarray:
    """Rotor speeds for hover thrust ± 10 % and cosine torques about all three axes.

    Cosines (not sines) so the body rates they cause have zero mean: the vehicle rocks (up to
    ≈ 45° tilt) and yaws back and forth instead of tumbling away (open loop, nothing stabilizes
    it; in a tumble both simulators' tiny differences grow without bound).
    """
    thrust = af.mass_kg * G_MPS2 * (1.0 + 0.1 * math.sin(2 * math.pi * 0.4 * t))
    torque = [0.12 * math.cos(2 * math.pi * 0.7 * t), 0.10 * math.cos(2 * math.pi * 0.9 * t),
              0.05 * math.cos(2 * math.pi * 0.5 * t)]
    w2 = np.linalg.pinv(af.allocation()) @ np.array([thrust, *torque])
    return np.sqrt(w2)


def test_plant_matches_rotorpy() -> None:
    af = Airframe.packaged("x500")
    af = dataclasses.replace(af, drag_n_per_mps=np.zeros(3))
    ours = Multirotor(af, position_m=(0.0, 0.0, 100.0))
    hover = af.hover_omega_radps
    theirs = rotorpy_multirotor.Multirotor(
        _rotorpy_params(af),
        initial_state={
            "x": np.array([0.0, 0.0, 100.0]), "v": np.zeros(3),
            "q": np.array([0.0, 0.0, 0.0, 1.0]), "w": np.zeros(3), "wind": np.zeros(3),
            "rotor_speeds": np.full(4, hover),
        },
        control_abstraction="cmd_motor_speeds",
        aero=False,
        enable_ground=False,
        integrator_kwargs={"method": "DOP853", "rtol": 1e-10, "atol": 1e-10},
    )
    # RotorPy hard-codes g = 9.81; use the same gravity as ours for an identical model.
    theirs.g = G_MPS2
    theirs.weight = np.array([0.0, 0.0, -af.mass_kg * G_MPS2])
    state = dict(theirs.initial_state)

    max_pos, max_att_deg, max_tilt = 0.0, 0.0, 0.0
    t = 0.0
    for _ in range(round(DURATION_S / PERIOD_S)):
        cmd = _commands(af, t)
        s: VehicleState = ours.step_motors(cmd, PERIOD_S)
        state = theirs.step(state, {"cmd_motor_speeds": cmd}, PERIOD_S)
        t += PERIOD_S
        max_pos = max(max_pos, float(np.linalg.norm(s.position_m - state["x"])))
        qx, qy, qz, qw = state["q"]
        r_theirs = quat_to_rot(np.array([qw, qx, qy, qz]))
        r_rel = s.rotation().T @ r_theirs
        angle = math.degrees(math.acos(min(1.0, max(-1.0, (np.trace(r_rel) - 1.0) / 2.0))))
        max_att_deg = max(max_att_deg, angle)
        max_tilt = max(max_tilt, math.degrees(math.acos(min(1.0, s.rotation()[2, 2]))))
    print(f"RotorPy vs uavmpc over {DURATION_S} s: max position difference {max_pos:.3e} m, "
          f"max attitude difference {max_att_deg:.3e} deg (max tilt flown {max_tilt:.1f} deg, "
          f"travelled {np.linalg.norm(s.position_m - [0, 0, 100]):.1f} m)")
    assert max_tilt > 5.0  # the flight really was excited
    assert max_pos < 1e-4
    assert max_att_deg < 1e-4
