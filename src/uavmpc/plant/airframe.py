"""Airframe parameters: mass, inertia, rotors, drag and the per-airframe controller gains (SPEC §4).

An airframe is data: one TOML file per vehicle in ``uavmpc/data/airframes/`` (or any path),
validated on load. Every error names the field, e.g. ``airframe.mass_kg: must be > 0, got -1.0``,
so a wrong file fails before flight instead of inside the integrator.

Frames: body frame FLU (x forward, y left, z up), world frame ENU (z up). A rotor's ``spin`` is
+1 when it turns counter-clockwise seen from above: its drag torque on the body is then −z
(clockwise), i.e. body yaw torque = −spin · k_m · ω².
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from uavmpc.config import (
    ConfigError,
    describe,
    finite,
    positive,
    read_packaged_toml,
    read_toml,
    reject_unknown,
    take,
)

G_MPS2 = 9.80665
"""Standard gravity [m/s²]; the plant and the controllers use the same value."""

_TOP = {"name", "mass_kg", "inertia", "rotors", "drag", "se3", "attitude",
        "max_touchdown_speed_mps"}
_INERTIA = {"ixx_kgm2", "iyy_kgm2", "izz_kgm2", "ixy_kgm2", "ixz_kgm2", "iyz_kgm2"}
_ROTORS = {
    "arm_length_m",
    "angles_deg",
    "spin",
    "k_f_n_per_radps2",
    "k_m_nm_per_radps2",
    "motor_tau_s",
    "omega_max_radps",
    "omega_idle_radps",
}
_DRAG = {"linear_n_per_mps"}
_SE3 = {
    "kp_n_per_m",
    "kv_n_per_mps",
    "ki_world_n_per_ms",
    "ki_body_n_per_ms",
    "integral_limit_world_ms",
    "integral_limit_body_ms",
    "max_tilt_deg",
    "thrust_min_fraction",
    "thrust_max_fraction",
}
_ATTITUDE = {
    "angle_p_per_s",
    "max_rate_dps",
    "rate_p_per_s",
    "rate_i_per_s2",
    "rate_d",
    "rate_integral_limit_radps2",
    "yaw_weight",
}


def _vector(value: Any, field: str, n: int = 3, *, allow_zero: bool = False) -> np.ndarray:
    """A length-``n`` list of positive (or non-negative) numbers; a scalar is repeated."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        value = [value] * n
    if not isinstance(value, list) or len(value) != n:
        raise ConfigError(f"{field}: must be a number or a list of {n} numbers, got {value!r}")
    out = [positive(v, f"{field}[{i}]", allow_zero=allow_zero) for i, v in enumerate(value)]
    return np.array(out, dtype=float)


def _signed(value: Any, field: str) -> float:
    # finite() compares before converting: math.isfinite() of a TOML integer beyond the float
    # range raises OverflowError.
    return finite(value, field)


def packaged_airframes() -> tuple[str, ...]:
    """The names of the airframes shipped in ``uavmpc/data/airframes`` (sorted)."""
    folder = resources.files("uavmpc.data").joinpath("airframes")
    return tuple(sorted(f.name.removesuffix(".toml") for f in folder.iterdir()
                        if f.name.endswith(".toml")))


@dataclass(frozen=True, eq=False)
class Se3Gains:
    """Gains and limits of the SE(3) controller (SPEC §3); diagonal gains as (3,) [x, y, z].

    Attributes:
        kp_n_per_m: (3,) position gain K_p [N/m].
        kv_n_per_mps: (3,) velocity gain K_v [N/(m/s)].
        ki_world_n_per_ms: (3,) world-frame integral gain K_iw [N/(m·s)].
        ki_body_n_per_ms: (3,) body-frame integral gain K_ib [N/(m·s)].
        integral_limit_world_ms, integral_limit_body_ms: (3,) anti-windup bound on each
            integral ∫e_p dt [m·s].
        max_tilt_rad: largest angle between the thrust axis and world z (0, 80°].
        thrust_min_fraction, thrust_max_fraction: collective-thrust range as fractions of the
            airframe's maximum thrust (the top is kept below 1 to leave room for torques).
    """

    kp_n_per_m: np.ndarray
    kv_n_per_mps: np.ndarray
    ki_world_n_per_ms: np.ndarray
    ki_body_n_per_ms: np.ndarray
    integral_limit_world_ms: np.ndarray
    integral_limit_body_ms: np.ndarray
    max_tilt_rad: float
    thrust_min_fraction: float
    thrust_max_fraction: float

    @classmethod
    def from_table(cls, t: dict[str, Any], prefix: str = "se3") -> Se3Gains:
        if not isinstance(t, dict):
            raise ConfigError(f"{prefix}: must be a table")
        reject_unknown(t, _SE3, prefix)

        def vec(key: str, allow_zero: bool = False) -> np.ndarray:
            return _vector(take(t, key, prefix), f"{prefix}.{key}", allow_zero=allow_zero)

        tmin = positive(
            take(t, "thrust_min_fraction", prefix), f"{prefix}.thrust_min_fraction",
            upper=0.5, allow_zero=True,
        )
        tmax = positive(
            take(t, "thrust_max_fraction", prefix), f"{prefix}.thrust_max_fraction", upper=1.0
        )
        if tmax <= tmin:
            raise ConfigError(f"{prefix}.thrust_max_fraction: must exceed thrust_min_fraction")
        return cls(
            kp_n_per_m=vec("kp_n_per_m"),
            kv_n_per_mps=vec("kv_n_per_mps"),
            ki_world_n_per_ms=vec("ki_world_n_per_ms", allow_zero=True),
            ki_body_n_per_ms=vec("ki_body_n_per_ms", allow_zero=True),
            integral_limit_world_ms=vec("integral_limit_world_ms", allow_zero=True),
            integral_limit_body_ms=vec("integral_limit_body_ms", allow_zero=True),
            max_tilt_rad=math.radians(
                positive(take(t, "max_tilt_deg", prefix), f"{prefix}.max_tilt_deg", upper=80.0)
            ),
            thrust_min_fraction=tmin,
            thrust_max_fraction=tmax,
        )


@dataclass(frozen=True, eq=False)
class AttitudeGains:
    """Gains of the autopilot-like attitude controller; (3,) vectors are [roll, pitch, yaw].

    The rate loop's gains are angular-acceleration gains; the controller multiplies by the
    inertia, so similar numbers suit different airframes.

    Attributes:
        angle_p_per_s: (3,) attitude error [rad] → body-rate setpoint [rad/s].
        max_rate_radps: (3,) body-rate setpoint limit [rad/s].
        rate_p_per_s: (3,) rate error [rad/s] → angular acceleration [rad/s²].
        rate_i_per_s2: (3,) integral of rate error [rad] → angular acceleration [rad/s²].
        rate_d: (3,) derivative of the measured rate [rad/s²] → angular acceleration [rad/s²].
        rate_integral_limit_radps2: (3,) anti-windup bound on the integral's contribution.
        yaw_weight: in (0, 1]; how much of the yaw error is corrected together with roll/pitch
            (PX4's MC_YAW_WEIGHT): tilt is corrected first, so a large heading change does not
            tilt the vehicle beyond its target.
    """

    angle_p_per_s: np.ndarray
    max_rate_radps: np.ndarray
    rate_p_per_s: np.ndarray
    rate_i_per_s2: np.ndarray
    rate_d: np.ndarray
    rate_integral_limit_radps2: np.ndarray
    yaw_weight: float

    @classmethod
    def from_table(cls, t: dict[str, Any], prefix: str = "attitude") -> AttitudeGains:
        if not isinstance(t, dict):
            raise ConfigError(f"{prefix}: must be a table")
        reject_unknown(t, _ATTITUDE, prefix)

        def vec(key: str, allow_zero: bool = False) -> np.ndarray:
            return _vector(take(t, key, prefix), f"{prefix}.{key}", allow_zero=allow_zero)

        return cls(
            angle_p_per_s=vec("angle_p_per_s"),
            max_rate_radps=np.radians(vec("max_rate_dps")),
            rate_p_per_s=vec("rate_p_per_s"),
            rate_i_per_s2=vec("rate_i_per_s2", allow_zero=True),
            rate_d=vec("rate_d", allow_zero=True),
            rate_integral_limit_radps2=vec("rate_integral_limit_radps2", allow_zero=True),
            yaw_weight=positive(take(t, "yaw_weight", prefix), f"{prefix}.yaw_weight", upper=1.0),
        )


@dataclass(frozen=True, eq=False)
class Airframe:
    """One multirotor's physical parameters and controller gains (SI, body frame FLU).

    Attributes:
        name: identifier, e.g. ``"f550"``.
        mass_kg: take-off mass [kg].
        inertia_kgm2: (3, 3) symmetric positive-definite inertia about the centre of mass.
        rotor_xy_m: (n, 2) rotor positions in the body x-y plane [m].
        rotor_spin: (n,) +1 counter-clockwise seen from above, −1 clockwise.
        k_f: rotor thrust coefficient, thrust = k_f ω² [N/(rad/s)²].
        k_m: rotor drag-torque coefficient, torque = k_m ω² [N·m/(rad/s)²].
        motor_tau_s: first-order lag of rotor speed to its command [s].
        omega_max_radps: rotor speed saturation [rad/s].
        omega_idle_radps: lowest speed the mixer commands while flying [rad/s] (the plant's own
            lower bound is 0: motors off).
        drag_n_per_mps: (3,) linear drag in the body frame, F = −R diag(d) Rᵀ (v − wind) [N/(m/s)].
        se3: gains of the SE(3) controller.
        attitude: gains of the attitude controller.
        max_touchdown_speed_mps: the landing gear's limit: a touchdown whose vertical speed
            relative to the surface exceeds it is a hard one.
    """

    name: str
    mass_kg: float
    inertia_kgm2: np.ndarray
    rotor_xy_m: np.ndarray
    rotor_spin: np.ndarray
    k_f: float
    k_m: float
    motor_tau_s: float
    omega_max_radps: float
    omega_idle_radps: float
    drag_n_per_mps: np.ndarray
    se3: Se3Gains
    attitude: AttitudeGains
    max_touchdown_speed_mps: float = 1.0

    @property
    def n_rotors(self) -> int:
        return int(self.rotor_spin.shape[0])

    @property
    def max_thrust_n(self) -> float:
        """Collective thrust with every rotor at ``omega_max_radps`` [N]."""
        return self.n_rotors * self.k_f * self.omega_max_radps**2

    @property
    def hover_omega_radps(self) -> float:
        """Rotor speed at which the rotors together carry the weight [rad/s]."""
        return math.sqrt(self.mass_kg * G_MPS2 / (self.n_rotors * self.k_f))

    def allocation(self) -> np.ndarray:
        """(4, n) matrix A with [T, τx, τy, τz] = A ω² (body frame, N and N·m)."""
        x, y = self.rotor_xy_m[:, 0], self.rotor_xy_m[:, 1]
        # Thrust k_f ω² along +z at (x, y, 0): torque r × F = (y F, −x F, 0).
        return np.vstack(
            [
                np.full(self.n_rotors, self.k_f),
                self.k_f * y,
                -self.k_f * x,
                -self.k_m * self.rotor_spin,
            ]
        )

    @classmethod
    def from_dict(cls, d: dict[str, Any], prefix: str = "airframe") -> Airframe:
        """Validate a parsed airframe file (``prefix`` is used in error messages)."""
        if not isinstance(d, dict):
            raise ConfigError(f"{prefix}: must be a table")
        reject_unknown(d, _TOP, prefix)
        name = take(d, "name", prefix)
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{prefix}.name: must be a non-empty string, got {name!r}")
        mass = positive(take(d, "mass_kg", prefix), f"{prefix}.mass_kg", upper=1000.0)

        inertia = _inertia(take(d, "inertia", prefix), f"{prefix}.inertia")
        rotors = _rotors(take(d, "rotors", prefix), f"{prefix}.rotors")

        p = f"{prefix}.drag"
        dt = take(d, "drag", prefix)
        if not isinstance(dt, dict):
            raise ConfigError(f"{p}: must be a table")
        reject_unknown(dt, _DRAG, p)
        drag = _vector(take(dt, "linear_n_per_mps", p), f"{p}.linear_n_per_mps", allow_zero=True)

        se3 = Se3Gains.from_table(take(d, "se3", prefix), f"{prefix}.se3")
        att = AttitudeGains.from_table(take(d, "attitude", prefix), f"{prefix}.attitude")
        out = cls(
            name=name,
            mass_kg=mass,
            inertia_kgm2=inertia,
            rotor_xy_m=rotors.xy_m,
            rotor_spin=np.array(rotors.spin, dtype=float),
            k_f=rotors.k_f,
            k_m=rotors.k_m,
            motor_tau_s=rotors.motor_tau_s,
            omega_max_radps=rotors.omega_max_radps,
            omega_idle_radps=rotors.omega_idle_radps,
            drag_n_per_mps=drag,
            se3=se3,
            attitude=att,
            max_touchdown_speed_mps=positive(d.get("max_touchdown_speed_mps", 1.0),
                                             f"{prefix}.max_touchdown_speed_mps", upper=20.0),
        )
        usable = out.max_thrust_n * se3.thrust_max_fraction
        if usable <= mass * G_MPS2:
            raise ConfigError(
                f"{prefix}.rotors: usable thrust {usable:.1f} N cannot lift the weight "
                f"{mass * G_MPS2:.1f} N"
            )
        if np.linalg.matrix_rank(out.allocation()) < 4:
            raise ConfigError(f"{prefix}.rotors: geometry cannot produce all three torques")
        return out

    @classmethod
    def from_toml(cls, path: str | Path) -> Airframe:
        """Load and validate an airframe file from disk."""
        return cls.from_dict(read_toml(path))

    @classmethod
    def packaged(cls, name: str) -> Airframe:
        """One of the shipped airframes: ``"f550"`` (hexacopter) or ``"x500"`` (quadrotor).

        Raises:
            ConfigError: ``name`` is not one of :func:`packaged_airframes`.
        """
        known = packaged_airframes()
        # Looked up among the shipped names, never joined into a path: a name such as
        # "../tracker" would read another data file, one with a NUL or of 300 characters
        # would make the OS raise.
        if not isinstance(name, str) or name not in known:
            raise ConfigError(f"airframe {describe(name)}: no such packaged airframe "
                              f"(packaged: {', '.join(known)})")
        return cls.from_dict(read_packaged_toml(f"airframes/{name}.toml"))

    @classmethod
    def named(cls, name_or_path: str | Path) -> Airframe:
        """A packaged airframe by name (``"f550"``), or an airframe file (``….toml``): what
        every command's ``--airframe`` and a scenario's ``airframe`` take.

        Raises:
            ConfigError: an unknown name, or a file that is missing, unreadable or invalid
                (the message names the file).
        """
        if str(name_or_path).endswith(".toml"):
            return cls.from_toml(name_or_path)
        return cls.packaged(str(name_or_path))


def _inertia(it: Any, p: str) -> np.ndarray:
    """The inertia tensor of an airframe's ``[inertia]`` table ``it`` (named ``p``) [kg m²]."""
    if not isinstance(it, dict):
        raise ConfigError(f"{p}: must be a table")
    reject_unknown(it, _INERTIA, p)
    ixx, iyy, izz = (
        positive(take(it, k, p), f"{p}.{k}", upper=1e4)
        for k in ("ixx_kgm2", "iyy_kgm2", "izz_kgm2")
    )
    ixy, ixz, iyz = (
        _signed(it.get(k, 0.0), f"{p}.{k}") for k in ("ixy_kgm2", "ixz_kgm2", "iyz_kgm2")
    )
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if np.min(np.linalg.eigvalsh(inertia)) <= 0.0:
        raise ConfigError(f"{p}: not positive definite (check the products of inertia)")
    # A rigid body's principal moments obey the triangle inequality.
    if ixx + iyy < izz or iyy + izz < ixx or ixx + izz < iyy:
        raise ConfigError(f"{p}: moments violate the triangle inequality ixx + iyy ≥ izz etc.")
    return inertia


class _Rotors(NamedTuple):
    """An airframe's validated ``[rotors]`` table."""

    xy_m: np.ndarray  # (k, 2) rotor positions in the body frame [m]
    spin: list[int]  # ±1 each
    k_f: float
    k_m: float
    motor_tau_s: float
    omega_max_radps: float
    omega_idle_radps: float


def _rotors(rt: Any, p: str) -> _Rotors:
    """An airframe's ``[rotors]`` table ``rt`` (named ``p``), validated."""
    if not isinstance(rt, dict):
        raise ConfigError(f"{p}: must be a table")
    reject_unknown(rt, _ROTORS, p)
    arm = positive(take(rt, "arm_length_m", p), f"{p}.arm_length_m", upper=10.0)
    angles = take(rt, "angles_deg", p)
    if not isinstance(angles, list) or len(angles) < 3:
        raise ConfigError(f"{p}.angles_deg: must be a list of ≥ 3 angles, got {angles!r}")
    ang = np.radians([_signed(a, f"{p}.angles_deg[{i}]") for i, a in enumerate(angles)])
    spin = take(rt, "spin", p)
    if not isinstance(spin, list) or len(spin) != len(angles):
        raise ConfigError(f"{p}.spin: must be a list of {len(angles)} values ±1, got {spin!r}")
    for i, s in enumerate(spin):
        if isinstance(s, bool) or s not in (1, -1):
            raise ConfigError(f"{p}.spin[{i}]: must be +1 or -1, got {s!r}")
    if sum(spin) != 0:
        raise ConfigError(f"{p}.spin: as many rotors must spin each way (sum is {sum(spin)})")
    k_f = positive(take(rt, "k_f_n_per_radps2", p), f"{p}.k_f_n_per_radps2", upper=1.0)
    k_m = positive(take(rt, "k_m_nm_per_radps2", p), f"{p}.k_m_nm_per_radps2", upper=1.0)
    tau = positive(take(rt, "motor_tau_s", p), f"{p}.motor_tau_s", upper=1.0)
    wmax = positive(take(rt, "omega_max_radps", p), f"{p}.omega_max_radps", upper=1e5)
    widle = positive(
        take(rt, "omega_idle_radps", p), f"{p}.omega_idle_radps", upper=wmax, allow_zero=True
    )
    xy = arm * np.column_stack([np.cos(ang), np.sin(ang)])
    return _Rotors(xy, spin, k_f, k_m, tau, wmax, widle)
