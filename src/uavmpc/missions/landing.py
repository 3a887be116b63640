"""Landing on a moving ground vehicle (SPEC §6, *moving_target_landing*).

The UAV sees the vehicle only through position fixes. A :class:`CtrvFilter` estimates the
vehicle's state and predicts its path over the tracker's horizon; that predicted path, lifted
above the deck by the height the manoeuvre wants at each time, is the desired trajectory handed
to the tracker at every step, so the tracker plans on where the deck *will be*.

The manoeuvre is a small state machine (:class:`Phase`)::

    WAIT ──(track ready)──> APPROACH ──(synchronised for sync_hold_s)──> DESCEND
                               ^                                            │
                               └──(back at approach height)── ABORT <──(off bounds, sharp turn)
    DESCEND ──(land detector)──> LANDED (motors cut)

* APPROACH flies the predicted path at ``approach_height_m`` above the deck, plus an offset
  that starts at where the UAV is and closes at ``approach_speed_mps`` relative to the
  vehicle (a trapezoid: ``approach_accel_mps2`` up and down), so the UAV arrives over the
  deck at the deck's velocity instead of chasing it and overshooting; the offset is planned
  again when the UAV falls more than ``replan_distance_m`` behind (a turn it could not follow);
* it is synchronised when the horizontal distance from the deck's centre is under
  ``sync_radius_m``, the relative horizontal speed under ``sync_speed_mps`` and the vehicle's
  turn rate under ``max_turn_rate_radps``;
* DESCEND lowers the wanted height at ``descend_speed_mps`` down to ``sink_m`` below the
  deck's top (pressing onto it, so the thrust drops and the land detector sees a rest);
* it aborts when the distance exceeds ``abort_radius_m``, the relative speed
  ``abort_speed_mps``, or the turn rate ``max_turn_rate_radps``: the wanted height climbs back at
  ``climb_speed_mps``;
* LANDED: the motors are cut.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from uavmpc.config import ConfigError, from_table, positive
from uavmpc.missions.mission import MissionInput, MissionOutput
from uavmpc.missions.target_tracking import CtrvFilter
from uavmpc.plant.ground_vehicle import DeckTouch
from uavmpc.reference import Reference

__all__ = ["LandingMission", "LandingParams", "Phase", "landing_outcome"]


#: While coming down the mission is stepped at the control rate, to react to the contact.
CONTACT_PERIOD_S = 0.01
#: The approach's closing profile is tabulated at this step, for at most this many steps.
_CLOSE_DT_S = 0.05
_CLOSE_MAX = 4000


class Phase(enum.Enum):
    WAIT = "wait"
    APPROACH = "approach"
    DESCEND = "descend"
    ABORT = "abort"
    LANDED = "landed"


@dataclass(frozen=True)
class LandingParams:
    """The landing manoeuvre (SI; heights above the deck's top, distances horizontal).

    Attributes:
        deck_height_m: the deck's top above the ground (known to the mission).
        approach_height_m: height of the approach and of a climb after an abort.
        approach_speed_mps, approach_accel_mps2: closing speed and acceleration relative to
            the vehicle during the approach.
        replan_distance_m: how far behind the UAV may fall before the approach is planned
            again.
        sync_radius_m, sync_speed_mps, sync_hold_s: synchronised when within both bounds
            for this long.
        descend_speed_mps: how fast the wanted height drops, down to ``flare_height_m``;
            touchdown_speed_mps: below it (the flare: a soft touchdown).
        commit_height_m: below this height a descent is not aborted any more for the relative
            speed or a turn (finishing is safer than climbing out from a few centimetres); it
            still is when off the deck.
        sink_m: the wanted height's floor below the deck's top.
        abort_radius_m, abort_speed_mps: bounds that abort a descent.
        max_turn_rate_radps: no descent while the vehicle turns faster (estimated).
        climb_speed_mps: climb after an abort.
        fix_sigma_m: the filter's assumed fix noise.
        turn_decay_s: the predicted path's turn rate decays with this time constant (see
            :meth:`~uavmpc.missions.target_tracking.CtrvFilter.predict`).
        period_s: the mission's step (a new desired trajectory each step).
        horizon_s, sample_period_s: span and spacing of the desired trajectory.
    """

    deck_height_m: float = 1.5
    approach_height_m: float = 2.0
    approach_speed_mps: float = 7.0
    approach_accel_mps2: float = 2.0
    replan_distance_m: float = 3.0
    sync_radius_m: float = 0.3
    sync_speed_mps: float = 0.8
    sync_hold_s: float = 0.5
    descend_speed_mps: float = 1.0
    flare_height_m: float = 0.6
    touchdown_speed_mps: float = 0.4
    commit_height_m: float = 0.3
    sink_m: float = 0.5
    abort_radius_m: float = 0.55
    abort_speed_mps: float = 1.5
    max_turn_rate_radps: float = 0.4
    climb_speed_mps: float = 1.5
    fix_sigma_m: float = 0.3
    turn_decay_s: float = 2.0
    period_s: float = 0.1
    horizon_s: float = 8.5
    sample_period_s: float = 0.1

    def __post_init__(self) -> None:
        p = "landing"
        for f in fields(self):
            zero = f.name in ("deck_height_m", "sink_m", "sync_hold_s", "commit_height_m")
            object.__setattr__(self, f.name, positive(getattr(self, f.name), f"{p}.{f.name}",
                                                      upper=1000.0, allow_zero=zero))
        if self.abort_radius_m < self.sync_radius_m:
            raise ConfigError(f"{p}.abort_radius_m: must be ≥ sync_radius_m = "
                              f"{self.sync_radius_m}, got {self.abort_radius_m}")
        if self.abort_speed_mps < self.sync_speed_mps:
            raise ConfigError(f"{p}.abort_speed_mps: must be ≥ sync_speed_mps = "
                              f"{self.sync_speed_mps}, got {self.abort_speed_mps}")
        if self.sample_period_s > self.horizon_s:
            raise ConfigError(f"{p}.sample_period_s: must be ≤ horizon_s = {self.horizon_s}")

    @classmethod
    def from_dict(cls, table: dict[str, Any], prefix: str = "landing") -> LandingParams:
        """From a TOML table; missing fields take their defaults, unknown ones are errors."""
        return from_table(cls, table, prefix)


class LandingMission:
    """Track the vehicle from fixes, follow its predicted path, land on its deck
    (:class:`~uavmpc.missions.mission.Mission`).

    Attributes:
        phase: where the manoeuvre is; transitions: ``[(t_s, phase name), ...]``.
        aborts: descents aborted, by reason.
        filter: the vehicle's track.
    """

    def __init__(self, params: LandingParams | None = None) -> None:
        self.params = params if params is not None else LandingParams()
        self.filter = CtrvFilter(fix_sigma_m=self.params.fix_sigma_m)
        self.phase = Phase.WAIT
        self.transitions: list[tuple[float, str]] = []
        self.aborts: dict[str, int] = {}
        self._height_m = self.params.approach_height_m  # wanted height above the deck now
        self._synced_since: float | None = None
        self._last_s: float | None = None
        #: When the UAV first came over the deck (within the synchronisation bounds).
        self.first_over_deck_s: float | None = None
        #: The approach's closing offset: start time, direction (2,), remaining distance
        #: table (every _CLOSE_DT_S from the start).
        self._close: tuple[float, np.ndarray, np.ndarray] | None = None
        n = round(self.params.horizon_s / self.params.sample_period_s) + 1
        self._ahead_s = self.params.sample_period_s * np.arange(n)

    # ------------------------------------------------------------------ the mission
    @property
    def period_s(self) -> float:
        """How often to step it: every control period while coming down (the contact must cut
        the motors at once, or the UAV slides across the deck), else ``params.period_s``."""
        if self.phase in (Phase.DESCEND, Phase.ABORT):
            return CONTACT_PERIOD_S
        return self.params.period_s

    def step(self, inp: MissionInput) -> MissionOutput:
        for fix in inp.fixes:
            self.filter.update(fix.t_s, fix.position_m)
        now = inp.t_s
        if self.phase is Phase.LANDED:
            return MissionOutput(cut_motors=True)
        if inp.landed and self.phase in (Phase.DESCEND, Phase.ABORT):
            # Touching something while coming down (the deck, or the ground beside it): done.
            self._enter(now, Phase.LANDED)
            return MissionOutput(cut_motors=True)
        if self._last_s is not None and now < self._last_s + self.params.period_s - 1e-9:
            return MissionOutput()  # between plans: only the contact was watched
        dt = 0.0 if self._last_s is None else max(now - self._last_s, 0.0)
        self._last_s = now
        if not self.filter.ready:
            return MissionOutput()
        car = self.filter.predict(np.array([now]))[0]
        if self.phase is Phase.WAIT:
            self._enter(now, Phase.APPROACH)
            self._plan_closing(now, inp, car)
        self._advance(now, dt, inp, car)
        return MissionOutput(reference=self._reference(now))

    def summary(self) -> dict[str, Any]:
        return {"phase": self.phase.value, "aborts": dict(self.aborts),
                "transitions": [[round(t, 3), p] for t, p in self.transitions],
                "fixes_accepted": self.filter.accepted, "fixes_rejected": self.filter.rejected,
                "track_restarts": self.filter.restarts}

    @property
    def approach_started_s(self) -> float | None:
        """When the approach began (the first desired trajectory), or None."""
        for t, p in self.transitions:
            if p == Phase.APPROACH.value:
                return t
        return None

    # ------------------------------------------------------------------ internals
    def _enter(self, now: float, phase: Phase) -> None:
        self.phase = phase
        self.transitions.append((now, phase.value))
        self._synced_since = None

    def _advance(self, now: float, dt: float, inp: MissionInput, car: np.ndarray) -> None:
        prm = self.params
        p = np.asarray(inp.estimate.position_m, dtype=float)
        v = np.asarray(inp.estimate.velocity_mps, dtype=float)
        car_v = car[3] * np.array([math.cos(car[2]), math.sin(car[2])])
        distance = float(np.hypot(*(p[:2] - car[:2])))
        rel_speed = float(np.hypot(*(v[:2] - car_v)))
        turning = abs(car[4]) > prm.max_turn_rate_radps
        if self.phase is Phase.APPROACH:
            self._height_m = prm.approach_height_m
            over = distance <= prm.sync_radius_m and rel_speed <= prm.sync_speed_mps
            if over and self.first_over_deck_s is None:
                self.first_over_deck_s = now
            if self._closing_offset(np.array([now]))[0].any():
                pass  # still closing in
            elif distance > prm.replan_distance_m:
                self._plan_closing(now, inp, car)
            elif over and not turning:
                if self._synced_since is None:
                    self._synced_since = now
                if now - self._synced_since >= prm.sync_hold_s:
                    self._enter(now, Phase.DESCEND)
            else:
                self._synced_since = None
        elif self.phase is Phase.DESCEND:
            reason = ("off the deck" if distance > prm.abort_radius_m
                      else "relative speed" if rel_speed > prm.abort_speed_mps
                      else "sharp turn" if turning else None)
            # Committed below commit_height_m to finish despite speed or a turn; never when
            # off the deck (found in the campaign: a committed UAV went down beside it).
            if reason is not None and (reason == "off the deck"
                                       or self._height_m > prm.commit_height_m):
                self.aborts[reason] = self.aborts.get(reason, 0) + 1
                self._enter(now, Phase.ABORT)
            else:
                self._height_m = float(self._descent(np.array([dt]))[0])
        if self.phase is Phase.ABORT:
            self._height_m = min(self._height_m + prm.climb_speed_mps * dt,
                                 prm.approach_height_m)
            if self._height_m >= prm.approach_height_m:
                self._enter(now, Phase.APPROACH)

    def _reference(self, now: float) -> Reference:
        """The predicted path over the horizon, at the height the phase wants at each time."""
        prm = self.params
        times = now + self._ahead_s
        path = self.filter.predict(times, prm.turn_decay_s)
        if self.phase is Phase.DESCEND:
            height = self._descent(self._ahead_s)
        elif self.phase is Phase.ABORT:
            height = np.minimum(self._height_m + prm.climb_speed_mps * self._ahead_s,
                                prm.approach_height_m)
        else:
            height = np.full(times.shape, self._height_m)
        xy = path[:, :2] + self._closing_offset(times)
        points = np.column_stack([xy, prm.deck_height_m + height, path[:, 2]])
        return Reference.sampled(points, prm.sample_period_s, now)

    def _descent(self, ahead_s: np.ndarray) -> np.ndarray:
        """The wanted height ``ahead_s`` seconds from now while descending: at
        ``descend_speed_mps`` down to the flare height, then at ``touchdown_speed_mps`` down to
        ``sink_m`` below the deck's top."""
        prm = self.params
        h0, flare = self._height_m, prm.flare_height_m
        fast_s = max(h0 - flare, 0.0) / prm.descend_speed_mps
        h = np.where(ahead_s <= fast_s, h0 - prm.descend_speed_mps * ahead_s,
                     min(h0, flare) - prm.touchdown_speed_mps * (ahead_s - fast_s))
        return np.maximum(h, -prm.sink_m)

    def _plan_closing(self, now: float, inp: MissionInput, car: np.ndarray) -> None:
        """Plan the approach's offset from the vehicle: from where the UAV is now to zero,
        closing along a trapezoid of relative speed (starting from the UAV's current closing
        speed)."""
        prm = self.params
        rel = np.asarray(inp.estimate.position_m, dtype=float)[:2] - car[:2]
        distance = float(np.hypot(*rel))
        if distance < 1e-6:
            self._close = None
            return
        u = rel / distance
        car_v = car[3] * np.array([math.cos(car[2]), math.sin(car[2])])
        rel_v = np.asarray(inp.estimate.velocity_mps, dtype=float)[:2] - car_v
        speed = float(np.clip(-(rel_v @ u), -prm.approach_speed_mps, prm.approach_speed_mps))
        remaining = [distance]
        d, a = distance, prm.approach_accel_mps2
        while d > 0.0 and len(remaining) < _CLOSE_MAX:
            braking = speed > 0.0 and d <= speed * speed / (2.0 * a)
            speed = speed - a * _CLOSE_DT_S if braking else min(speed + a * _CLOSE_DT_S,
                                                               prm.approach_speed_mps)
            d = max(d - max(speed, 0.0) * _CLOSE_DT_S if speed > 0 or braking
                    else d - speed * _CLOSE_DT_S, 0.0)
            if braking and speed <= 0.0:
                d = 0.0
            remaining.append(d)
        self._close = (now, u, np.array(remaining))

    def _closing_offset(self, times: np.ndarray) -> np.ndarray:
        """(m, 2) the approach's offset from the vehicle at ``times`` (zero once closed)."""
        out = np.zeros((times.shape[0], 2))
        if self._close is None:
            return out
        t0, u, table = self._close
        k = np.clip((times - t0) / _CLOSE_DT_S, 0.0, table.shape[0] - 1.0)
        d = np.interp(k, np.arange(table.shape[0]), table)
        return d[:, None] * u[None, :]


def landing_outcome(mission: LandingMission, touch: DeckTouch, max_touchdown_speed_mps: float,
                    on_deck_at_end: bool, end_s: float) -> dict[str, Any]:
    """How a landing went (``summary.json``'s landing fields).

    ``landed``: the first touchdown was on the deck's top, not hard (relative vertical speed
    within ``max_touchdown_speed_mps``, the airframe's limit), no rotor struck the deck's edge,
    and the UAV still rests on the deck at the end. ``time_to_land_s`` runs from the start of
    the approach to that touchdown; ``phases_s`` says where the time went (until the
    touchdown, else until ``end_s``, the end of the run): ``closing`` from the start of the
    approach until the UAV first came over the deck (within the synchronisation bounds),
    ``approach`` the rest of the time spent approaching (holding synchronised, waiting out
    turns, coming back after an abort), ``descend``, ``abort``."""
    start = mission.approach_started_s
    vz = None if touch.t_s is None else float(-touch.relative_velocity_mps[2])
    hard = vz is not None and vz > max_touchdown_speed_mps
    landed = (touch.touchdowns >= 1 and not hard and touch.strikes == 0 and on_deck_at_end)
    t_land = None if (touch.t_s is None or start is None) else float(touch.t_s - start)
    phases: dict[str, float] = {}
    marks = [*mission.transitions]
    end = touch.t_s if touch.t_s is not None else end_s
    for (t0, phase), nxt in zip(marks, [*marks[1:], (end, "")], strict=False):
        if phase in (Phase.WAIT.value, Phase.LANDED.value):
            continue
        t1 = min(nxt[0], end)
        if t1 > t0:
            phases[phase] = round(phases.get(phase, 0.0) + t1 - t0, 3)
    over = mission.first_over_deck_s
    if start is not None and "approach" in phases:
        closing = (min(over, end) if over is not None else end) - start
        phases["approach"] = round(phases["approach"] - closing, 3)
        phases = {"closing": round(closing, 3), **phases}
    touchdown = None
    if touch.t_s is not None:
        rv = touch.relative_velocity_mps
        touchdown = {
            "t_s": float(touch.t_s),
            "relative_speed_mps": float(np.linalg.norm(rv)),
            "vertical_speed_mps": vz,
            "horizontal_speed_mps": float(np.hypot(rv[0], rv[1])),
            "offset_m": [float(touch.offset_m[0]), float(touch.offset_m[1])],
            "offset_from_centre_m": float(np.linalg.norm(touch.offset_m)),
            "hard": bool(hard),
        }
    elsewhere = mission.phase is Phase.LANDED and not on_deck_at_end
    return {"landed": bool(landed), "time_to_land_s": t_land, "touchdown": touchdown,
            "landed_elsewhere": bool(elsewhere),
            "touchdowns": touch.touchdowns, "edge_strikes": touch.strikes,
            "on_deck_at_end": bool(on_deck_at_end),
            "max_touchdown_speed_mps": float(max_touchdown_speed_mps),
            "approach_started_s": start, "phases_s": phases, **mission.summary()}
