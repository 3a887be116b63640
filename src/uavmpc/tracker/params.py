"""Tracker parameters: dynamic limits (changeable in flight) and the fixed MPC set-up."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from uavmpc.config import (
    ConfigError,
    positive,
    read_packaged_toml,
    read_toml,
    reject_unknown,
    take,
)

#: Sanity bounds for limits: beyond any multirotor, small enough to catch unit mistakes.
MAX_SPEED_MPS = 100.0
MAX_ACCEL_MPS2 = 100.0
MAX_HEADING_RATE_RADPS = 20.0
MAX_HEADING_ACCEL_RADPS2 = 100.0

#: Axis order used everywhere in the tracker.
AXES = ("x", "y", "z", "heading")


@dataclass(frozen=True)
class DynamicLimits:
    """Box limits of the virtual UAV, per motion class (SPEC §2.3). All strictly positive.

    Horizontal limits apply to x and y separately (a box, as in the reference design), vertical
    ones to z up (ascend) and down (descend), heading ones to the heading axis (rad/s, rad/s²).
    The commanded acceleration (the QP input) obeys the same bound as the acceleration.
    """

    horizontal_speed_mps: float = 8.3
    horizontal_accel_mps2: float = 2.5
    ascend_speed_mps: float = 2.0
    ascend_accel_mps2: float = 1.5
    descend_speed_mps: float = 1.5
    descend_accel_mps2: float = 1.0
    heading_rate_radps: float = 1.0
    heading_accel_radps2: float = 2.0

    def __post_init__(self) -> None:
        for f in fields(self):
            upper = {
                "heading_rate_radps": MAX_HEADING_RATE_RADPS,
                "heading_accel_radps2": MAX_HEADING_ACCEL_RADPS2,
            }.get(f.name, MAX_SPEED_MPS if "speed" in f.name else MAX_ACCEL_MPS2)
            object.__setattr__(
                self, f.name, positive(getattr(self, f.name), f"limits.{f.name}", upper=upper)
            )

    @classmethod
    def from_dict(cls, table: dict[str, Any], prefix: str = "limits") -> DynamicLimits:
        names = [f.name for f in fields(cls)]
        reject_unknown(table, set(names), prefix)
        return cls(**{k: take(table, k, prefix) for k in names})

    def scaled(self, horizontal: float = 1.0, vertical: float = 1.0) -> DynamicLimits:
        """A copy with horizontal and/or vertical limits multiplied (e.g. halved when avoiding)."""
        return DynamicLimits(
            self.horizontal_speed_mps * horizontal,
            self.horizontal_accel_mps2 * horizontal,
            self.ascend_speed_mps * vertical,
            self.ascend_accel_mps2 * vertical,
            self.descend_speed_mps * vertical,
            self.descend_accel_mps2 * vertical,
            self.heading_rate_radps,
            self.heading_accel_radps2,
        )

    def velocity_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper), each (4,) for axes x, y, z, heading."""
        h, up, down, r = (self.horizontal_speed_mps, self.ascend_speed_mps,
                          self.descend_speed_mps, self.heading_rate_radps)
        return np.array([-h, -h, -down, -r]), np.array([h, h, up, r])

    def acceleration_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper), each (4,) for axes x, y, z, heading."""
        h, up, down, r = (self.horizontal_accel_mps2, self.ascend_accel_mps2,
                          self.descend_accel_mps2, self.heading_accel_radps2)
        return np.array([-h, -h, -down, -r]), np.array([h, h, up, r])


@dataclass(frozen=True)
class TrackerConfig:
    """The fixed set-up of the MPC tracker (SPEC §2.1–2.3).

    Attributes:
        steps: number of prediction steps m.
        first_step_s: length of step 1, equal to the tracker period (the tracker runs at
            ``1 / first_step_s`` Hz), so the first predicted state is the next command.
        step_s: length of steps 2…m.
        tau_s: time constant of the lag from commanded to actual acceleration.
        q_position, q_velocity, q_acceleration, q_input, q_input_rate: QP weights (SPEC §2.3;
            the velocity term tracks the reference's own velocity, clipped to the limits).
        limits: the nominal dynamic limits.
        solver: "batchqp" (default: our compiled dual active-set solver,
            :mod:`uavmpc.solvers.batchqp`, run inside the tracker's compiled tick), "daqp"
            (DAQP, through the solver contract) or "clarabel" (interior point, the reference).
        iter_limit: solver iteration limit (a failure beyond it triggers the safe fallback).
    """

    steps: int = 40
    first_step_s: float = 0.01
    step_s: float = 0.2
    tau_s: float = 0.1
    q_position: float = 5000.0
    q_velocity: float = 6000.0
    q_acceleration: float = 20.0
    q_input: float = 1.0
    q_input_rate: float = 0.0
    limits: DynamicLimits = DynamicLimits()
    solver: str = "batchqp"
    iter_limit: int = 1000

    def __post_init__(self) -> None:
        if isinstance(self.steps, bool) or not isinstance(self.steps, int) or not (
            2 <= self.steps <= 400
        ):
            raise ConfigError(f"horizon.steps: must be an integer in [2, 400], got {self.steps!r}")
        positive(self.first_step_s, "horizon.first_step_s", upper=1.0)
        positive(self.step_s, "horizon.step_s", upper=10.0)
        positive(self.tau_s, "model.tau_s", upper=10.0)
        positive(self.q_position, "weights.position")
        positive(self.q_velocity, "weights.velocity", allow_zero=True)
        positive(self.q_acceleration, "weights.acceleration", allow_zero=True)
        positive(self.q_input, "weights.input")
        positive(self.q_input_rate, "weights.input_rate", allow_zero=True)
        if self.solver not in ("batchqp", "daqp", "clarabel"):
            raise ConfigError(
                f"solver.name: must be 'batchqp', 'daqp' or 'clarabel', got {self.solver!r}")
        if isinstance(self.iter_limit, bool) or not isinstance(self.iter_limit, int) or (
            self.iter_limit < 1
        ):
            raise ConfigError(
                f"solver.iter_limit: must be a positive integer, got {self.iter_limit!r}")
        if not isinstance(self.limits, DynamicLimits):
            raise ConfigError("limits: must be a DynamicLimits")

    @property
    def step_lengths_s(self) -> np.ndarray:
        """(m,) length of each prediction step."""
        return np.concatenate([[self.first_step_s], np.full(self.steps - 1, self.step_s)])

    @property
    def horizon_times_s(self) -> np.ndarray:
        """(m,) time of each predicted state, relative to now."""
        return np.cumsum(self.step_lengths_s)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrackerConfig:
        reject_unknown(data, {"horizon", "model", "weights", "limits", "solver"}, "tracker")
        hz = data.get("horizon", {})
        reject_unknown(hz, {"steps", "first_step_s", "step_s"}, "horizon")
        model = data.get("model", {})
        reject_unknown(model, {"tau_s"}, "model")
        w = data.get("weights", {})
        reject_unknown(
            w, {"position", "velocity", "acceleration", "input", "input_rate"}, "weights")
        solver = data.get("solver", {})
        reject_unknown(solver, {"name", "iter_limit"}, "solver")
        d = cls()
        return cls(
            steps=hz.get("steps", d.steps),
            first_step_s=hz.get("first_step_s", d.first_step_s),
            step_s=hz.get("step_s", d.step_s),
            tau_s=model.get("tau_s", d.tau_s),
            q_position=w.get("position", d.q_position),
            q_velocity=w.get("velocity", d.q_velocity),
            q_acceleration=w.get("acceleration", d.q_acceleration),
            q_input=w.get("input", d.q_input),
            q_input_rate=w.get("input_rate", d.q_input_rate),
            limits=DynamicLimits.from_dict(data["limits"]) if "limits" in data else d.limits,
            solver=solver.get("name", d.solver),
            iter_limit=solver.get("iter_limit", d.iter_limit),
        )

    @classmethod
    def from_toml(cls, path: str | Path | None = None) -> TrackerConfig:
        """Load from a TOML file; ``None`` loads the packaged defaults (data/tracker.toml)."""
        data = read_packaged_toml("tracker.toml") if path is None else read_toml(path)
        return cls.from_dict(data)
