"""Every plug-in of the package through its declared contract.

Each kind of plug-in has a contract (a ``typing.Protocol``): resolution strategies
(:class:`~uavmpc.avoidance.ResolutionStrategy` and the whole contract of the built-in ones,
:class:`~uavmpc.avoidance.EncounterStrategy`), the tracker's QP solvers
(:class:`~uavmpc.solvers.AxisQpSolver`), missions (:class:`~uavmpc.missions.mission.Mission`,
:class:`~uavmpc.missions.mission.CommandedMission`), plants
(:class:`~uavmpc.plant.interface.Plant`), a node's vehicle drivers
(:class:`~uavmpc.drivers.node.VehicleDriver`) and transports
(:class:`~uavmpc.comms.link.Transport`). Here each built-in implementation is an instance of its
contract and answers each of its methods with the declared types and shapes on a small real
input; the drivers check the contracts with ``isinstance`` (no ``hasattr`` probing), so a
plug-in that honours only the base contract is tested to be treated as such.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import socket
import time
from collections.abc import Callable

import numpy as np
import pytest

import uavmpc.avoidance
import uavmpc.solvers
from uavmpc import scenarios
from uavmpc.avoidance import (
    AvoidanceDecision,
    AvoidanceParams,
    EncounterStrategy,
    HeightOffsetStrategy,
    ResolutionStrategy,
)
from uavmpc.avoidance.encounters import EncounterFinder, Encounters
from uavmpc.comms.link import Inbox, SimulatedLink, Transport
from uavmpc.comms.message import SCHEMA_VERSION, PredictionMessage, encode
from uavmpc.config import ConfigError
from uavmpc.drivers.node import SimulatedVehicle, VehicleDriver
from uavmpc.missions.formation import SHAPES, FormationFollower, FormationSpec
from uavmpc.missions.landing import LandingMission, LandingParams
from uavmpc.missions.mission import CommandedMission, Mission, MissionInput, MissionOutput
from uavmpc.onboard import OnboardStack
from uavmpc.plant import Airframe
from uavmpc.plant.airframe import G_MPS2
from uavmpc.plant.interface import AttitudeTarget, Plant, VehicleState
from uavmpc.plant.multirotor import Multirotor
from uavmpc.plant.sensors import TargetFix
from uavmpc.reference import Reference
from uavmpc.scenarios.run import RunSpec
from uavmpc.solvers import AxisQpSolver, BatchAxisSolver, ClarabelSolver, DaqpSolver, QpResult
from uavmpc.solvers.contract import check_solution
from uavmpc.tracker import CondensedModel, TrackerConfig

AF = Airframe.packaged("f550")

# ---------------------------------------------------------------- resolution strategies

#: Every built-in strategy (one factory from the avoidance parameters, as a world takes it).
STRATEGIES: list[Callable[[AvoidanceParams], EncounterStrategy]] = [HeightOffsetStrategy]

#: 21 points, 0.2 s apart: a prediction of 4 s.
REL_S = 0.2 * np.arange(21)


def _exported_classes(module, suffix: str) -> set[type]:
    """The concrete classes a package exports whose names end with ``suffix``."""
    out = set()
    for name in module.__all__:
        obj = getattr(module, name)
        if inspect.isclass(obj) and name.endswith(suffix) \
                and not getattr(obj, "_is_protocol", False):
            out.add(obj)
    return out


def test_every_exported_strategy_is_tested_here() -> None:
    assert _exported_classes(uavmpc.avoidance, "Strategy") == set(STRATEGIES)


def _head_on(now: float, *, other_priority: int = 1) -> tuple[np.ndarray, np.ndarray,
                                                                PredictionMessage]:
    """Our prediction along +x at 5 m, and another UAV's along −x at the same height: they
    meet 2 s from now."""
    times = now + REL_S
    own = np.column_stack([-10.0 + 5.0 * REL_S, np.zeros_like(REL_S), np.full_like(REL_S, 5.0)])
    theirs = own * np.array([-1.0, 1.0, 1.0])
    msg = PredictionMessage(SCHEMA_VERSION, "other", other_priority, now, times, theirs, True)
    return times, own, msg


def _check_decision(d: AvoidanceDecision) -> None:
    """The declared types of a decision."""
    assert isinstance(d, AvoidanceDecision)
    assert isinstance(d.z_offset_m, float) and d.z_offset_m >= 0.0
    assert isinstance(d.avoiding, bool) and isinstance(d.ceiling_hit, bool)
    for ids in (d.conflicts, d.yielding_to, d.unresolved, d.waiting_for, d.silent):
        assert isinstance(ids, tuple) and all(isinstance(i, str) for i in ids)
    assert set(d.yielding_to) <= set(d.conflicts)
    assert d.first_conflict_s is None or isinstance(d.first_conflict_s, float)
    assert isinstance(d.horizontal_scale, float) and 0.0 < d.horizontal_scale <= 1.0


@pytest.mark.parametrize("make", STRATEGIES)
def test_a_built_in_strategy_honours_the_whole_contract(make) -> None:
    s = make(AvoidanceParams())
    assert isinstance(s, ResolutionStrategy) and isinstance(s, EncounterStrategy)
    assert isinstance(s.params, AvoidanceParams)
    assert isinstance(s.pair_radius_m, dict)


@pytest.mark.parametrize("make", STRATEGIES)
def test_update_yields_to_a_higher_priority_head_on(make) -> None:
    prm = AvoidanceParams()
    now = 100.0
    times, own, msg = _head_on(now)
    d = make(prm).update(now, "own", 2, times, own, {"other": msg})
    _check_decision(d)
    assert d.conflicts == ("other",) and d.yielding_to == ("other",) and d.unresolved == ()
    assert d.z_offset_m == prm.dz_m  # one step clears a head-on at one height
    assert d.first_conflict_s == pytest.approx(1.6)  # 2 s, less the cylinder's 5 m radius
    assert d.horizontal_scale == prm.horizontal_scale
    # With the priorities the other way round the other climbs, we only slow down.
    times, own, msg = _head_on(now, other_priority=3)
    d = make(prm).update(now, "own", 2, times, own, {"other": msg})
    _check_decision(d)
    assert d.conflicts == ("other",) and d.yielding_to == () and d.z_offset_m == 0.0
    # Nobody: nominal limits, no offset.
    quiet = make(prm).update(now, "own", 2, times, own, {})
    _check_decision(quiet)
    assert quiet == AvoidanceDecision()


@pytest.mark.parametrize("make", STRATEGIES)
def test_update_refuses_a_prediction_of_the_wrong_shape(make) -> None:
    times, own, _ = _head_on(0.0)
    with pytest.raises(ValueError, match=r"\(m, 3\)"):
        make(AvoidanceParams()).update(0.0, "own", 2, times, own[:, :2], {})
    with pytest.raises(ValueError, match=r"\(m,\)"):
        make(AvoidanceParams()).update(0.0, "own", 2, times[None], own, {})


def _inbox_with(msg: PredictionMessage, now: float, prm: AvoidanceParams) -> Inbox:
    inbox = Inbox("own", time_reference=prm.time_reference, max_age_s=prm.timeout_s)
    assert inbox.accept(encode(msg), now) is not None
    return inbox


@pytest.mark.parametrize("make", STRATEGIES)
def test_decide_on_the_found_encounters_is_update(make) -> None:
    """finder → find (with overrides) → decide gives what update gives on the same messages,
    with a per-pair radius in force: the world's and the stack's path is the nodes' one."""
    prm = AvoidanceParams()
    now = 50.0
    times, own, msg = _head_on(now)
    # 4 m abreast: outside the pair's reduced radius only.
    own = own + np.array([0.0, 4.0, 0.0])
    inbox = _inbox_with(msg, now, prm)
    for radius, expect in ((None, ("other",)), (2.5, ())):
        by_update, by_decide = make(prm), make(prm)
        if radius is not None:
            by_update.pair_radius_m["other"] = radius
            by_decide.pair_radius_m["other"] = radius
        finder = by_decide.finder(inbox.table)
        assert isinstance(finder, EncounterFinder)
        overrides = by_decide.overrides(inbox.table)
        assert isinstance(overrides, dict)
        assert all(isinstance(c, int) and isinstance(r, float) for c, r in overrides.items())
        assert overrides == ({} if radius is None
                             else {inbox.table.col_of("other"): radius})
        found = finder.find(np.zeros(1, dtype=np.int64), times[None], own[None],
                            np.array([now]), np.array([prm.radius_m]), [overrides])
        assert isinstance(found, list) and len(found) == 1
        enc = found[0]
        assert isinstance(enc, Encounters)
        k = len(enc.ids)
        assert enc.near_xy.shape == enc.dz_m.shape == (k, times.size)
        assert enc.near_xy.dtype == bool and enc.priority.shape == (k,)
        decided = by_decide.decide(now, "own", 2, times, enc)
        _check_decision(decided)
        assert decided.conflicts == expect
        assert decided == by_update.update(now, "own", 2, times, own, inbox.latest)


@pytest.mark.parametrize("make", STRATEGIES)
def test_rest_is_a_calm_decision_with_nobody_near_or_nothing(make) -> None:
    """rest(now) at rest: True, and what decide on nobody near would decide (the calm
    decision) and leave behind; after a climb, False and nothing changed, until the offset
    is released."""
    prm = AvoidanceParams()
    times, own, msg = _head_on(10.0)
    nobody = Encounters((), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool),
                        np.zeros(0, dtype=bool), np.zeros((0, times.size), dtype=bool),
                        np.zeros((0, times.size)))
    resting, deciding = make(prm), make(prm)
    assert resting.rest(10.0) is True
    assert deciding.decide(10.0, "own", 2, times, nobody) == AvoidanceDecision()
    for s in (resting, deciding):
        assert s.update(10.1, "own", 2, times, own, {"other": msg}).z_offset_m == prm.dz_m
    assert resting.rest(10.2) is False  # an offset to release: decide must run
    assert resting.update(10.2, "own", 2, times, own, {}) == deciding.update(
        10.2, "own", 2, times, own, {})
    later = 10.2 + prm.release_hysteresis_s + prm.dz_m / prm.release_rate_mps + 1.0
    for s in (resting, deciding):
        s.update(later, "own", 2, times, own, {})
    assert resting.rest(later + 1.0) is True  # released: at rest again
    assert deciding.decide(later + 1.0, "own", 2, times, nobody) == AvoidanceDecision()


@pytest.mark.parametrize("make", STRATEGIES)
def test_rest_is_idempotent_until_the_next_decision(make) -> None:
    """Once rest has said True, asking again later changes nothing and says True again (a
    driver skips asking: OnboardBatch.resting); after a climb it is False until released."""
    prm = AvoidanceParams()
    times, own, msg = _head_on(10.0)
    s = make(prm)
    assert s.update(10.0, "own", 2, times, own, {"other": msg}).z_offset_m == prm.dz_m
    later = 10.0 + prm.release_hysteresis_s + prm.dz_m / prm.release_rate_mps + 1.0
    s.update(later, "own", 2, times, own, {})
    assert s.rest(later + 0.1) is True
    before = dict(vars(s))
    for t in (later + 0.2, later + 60.0):
        assert s.rest(t) is True
        assert vars(s) == before


@pytest.mark.parametrize("make", STRATEGIES)
def test_limit_offset_caps_the_climb(make) -> None:
    prm = AvoidanceParams()
    now = 10.0
    times, own, msg = _head_on(now)
    s = make(prm)
    assert s.limit_offset(prm.dz_m / 2) is None  # no step of Δz fits under it
    d = s.update(now, "own", 2, times, own, {"other": msg})
    _check_decision(d)
    assert d.ceiling_hit and d.z_offset_m == 0.0 and d.unresolved == ("other",)
    with pytest.raises(ValueError, match="ceiling_m"):
        s.limit_offset(-1.0)
    with pytest.raises(ValueError, match="ceiling_m"):
        s.limit_offset(math.nan)


@pytest.mark.parametrize("make", STRATEGIES)
def test_with_no_layer_left_it_holds_short_and_goes_on_once_the_way_is_clear(make) -> None:
    """docs/safety.md, A6: time as well as height. ``hold_probes`` is None until a hold,
    then (D, m, 3): the plan from before the hold, taken up again now or up to
    ``hold_delay_s`` later, from where the UAV holds."""
    prm = AvoidanceParams()
    now = 10.0
    times, own, msg = _head_on(now)
    s = make(prm)
    s.limit_offset(prm.dz_m / 2)  # no layer fits under the ceiling
    assert s.hold_probes(now, times, own[0]) is None
    d = s.update(now, "own", 2, times, own, {"other": msg})
    _check_decision(d)
    assert d.ceiling_hit and d.unresolved == ("other",) and d.holding and d.avoiding
    later = now + 0.1
    probes = s.hold_probes(later, times + 0.1, own[0])
    assert isinstance(probes, np.ndarray) and probes.shape == (4, times.size, 3)  # 0..3 s late
    assert np.allclose(probes[0], own)  # going on at once: the plan as it was
    assert np.allclose(probes[:, 0], own[0])  # each waits where it holds
    assert np.allclose(probes[3, :15], own[0])  # 3 s late: still there for 3 s
    # the other still coming head-on: it holds; once nobody is in the way, it goes on
    assert s.update(later, "own", 2, times + 0.1, own, {"other": msg}).holding
    gone = s.update(later + 0.1, "own", 2, times + 0.2, own, {})
    assert not gone.holding and s.hold_probes(later + 0.1, times, own[0]) is None
    # a stack that does not hand over its plan never holds (decide without positions)
    s = make(prm)
    s.limit_offset(prm.dz_m / 2)
    inbox = _inbox_with(msg, now, prm)
    enc = s.finder(inbox.table).find(np.zeros(1, dtype=np.int64), times[None], own[None],
                                     np.array([now]), np.array([prm.radius_m]), [{}])[0]
    assert not s.decide(now, "own", 2, times, enc).holding


@pytest.mark.parametrize("make", STRATEGIES)
def test_decide_starts_a_second_climb_from_where_the_uav_is(make) -> None:
    """``climbed_m``: how much of the offset in force is climbed; the type is declared."""
    prm = AvoidanceParams()
    now = 0.0
    times, own, msg = _head_on(now)
    s = make(prm)
    inbox = _inbox_with(msg, now, prm)
    enc = s.finder(inbox.table).find(np.zeros(1, dtype=np.int64), times[None], own[None],
                                     np.array([now]), np.array([prm.radius_m]),
                                     [s.overrides(inbox.table)])[0]
    d = s.decide(now, "own", 2, times, enc, climbed_m=0.0)
    _check_decision(d)
    assert d.z_offset_m == prm.dz_m


class _UpdateOnly:
    """A plug-in that honours the base contract only (its own law: never avoid)."""

    def __init__(self, params: AvoidanceParams) -> None:
        self.params = params
        self.calls: list[tuple[float, str, int, tuple[int, ...], tuple[int, ...]]] = []

    def update(self, now_s, own_id, own_priority, times, positions, others):
        self.calls.append((now_s, own_id, own_priority, np.shape(times), np.shape(positions)))
        return AvoidanceDecision()


def test_a_strategy_with_only_update_is_handed_the_messages() -> None:
    s = _UpdateOnly(AvoidanceParams())
    assert isinstance(s, ResolutionStrategy) and not isinstance(s, EncounterStrategy)
    stack = OnboardStack(AF, position_m=[0.0, 0.0, 5.0], heading_rad=0.0, t0_s=0.0,
                         uav_id="uav1", priority=1, avoidance=s)
    assert stack.params is s.params  # the stack flies the strategy's parameters
    stack.set_mission(Reference.goto(5.0, 0.0, 5.0, 0.0, start_s=0.0))
    for k in range(30):
        stack.tick(0.01 * k, _state([0.0, 0.0, 5.0], t=0.01 * k))
    assert s.calls, "the stack never asked the strategy"
    _, own_id, priority, t_shape, p_shape = s.calls[0]
    m = stack.tracker.config.steps
    assert (own_id, priority, t_shape, p_shape) == ("uav1", 1, (m,), (m, 3))


def test_a_formation_refuses_a_strategy_without_per_pair_radii() -> None:
    from uavmpc.drivers.world import World

    with pytest.raises(ConfigError, match="_UpdateOnly has no per-pair radii"):
        World(RunSpec(scenarios.load("formation")), strategy=_UpdateOnly)


# ---------------------------------------------------------------- QP solvers

#: Every solver of the tracker's axis QPs.
AXIS_SOLVERS = [BatchAxisSolver, DaqpSolver, ClarabelSolver]


def test_every_exported_axis_solver_is_tested_here() -> None:
    # BatchQpSolver solves K problems at once (the compiled tick's own contract); its
    # one-problem face is BatchAxisSolver.
    exported = _exported_classes(uavmpc.solvers, "Solver") - {uavmpc.solvers.BatchQpSolver}
    assert exported == set(AXIS_SOLVERS)


@pytest.fixture(scope="module")
def model() -> CondensedModel:
    return CondensedModel.build(TrackerConfig.from_toml())


def _bounds(model: CondensedModel, a_max: float, v_max: float, s0: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """The tracker's bounds for state ``s0`` (2m + 1,): |u| ≤ a_max, |v| ≤ v_max."""
    m = model.config.steps
    hi = np.concatenate([np.full(m, a_max), np.full(m + 1, v_max)])
    free = np.concatenate([np.zeros(m), model.constraint_free @ s0])
    return -hi - free, hi - free


@pytest.mark.parametrize("make", AXIS_SOLVERS)
def test_an_axis_solver_honours_its_contract(make, model: CondensedModel) -> None:
    solver = make(model)
    assert isinstance(solver, AxisQpSolver) and isinstance(solver.name, str) and solver.name
    m = model.config.steps
    s0 = np.array([0.0, 1.0, 0.0])
    # Far from the reference: the limits bind.
    f = model.f_state @ s0 + model.f_ref @ np.full(m, 50.0)
    lower, upper = _bounds(model, 2.5, 8.3, s0)
    assert lower.shape == (m + model.constraint_matrix.shape[0],)
    res = solver.solve(f, lower, upper)
    assert isinstance(res, QpResult) and res.ok and isinstance(res.status, str)
    assert isinstance(res.iterations, int) and res.iterations >= 0
    assert res.inputs.shape == (m,) and res.inputs.dtype == np.float64
    assert check_solution(model, res.inputs, lower, upper) is None
    assert res.inputs[0] == pytest.approx(2.5, abs=1e-6)  # full acceleration towards it
    # Near it, with loose bounds: the unconstrained optimum −H⁻¹ f.
    f = model.f_state @ s0 + model.f_ref @ np.full(m, 0.5)
    lower, upper = _bounds(model, 100.0, 100.0, s0)
    res = solver.solve(f, lower, upper)
    assert res.ok
    np.testing.assert_allclose(res.inputs, -np.linalg.solve(model.hessian, f), atol=1e-7)


# ---------------------------------------------------------------- missions

def _state(p, v=(0.0, 0.0, 0.0), t: float = 0.0) -> VehicleState:
    return VehicleState(t_s=t, position_m=np.asarray(p, float), velocity_mps=np.asarray(v, float),
                        attitude_wxyz=np.array([1.0, 0, 0, 0]), body_rates_radps=np.zeros(3))


def _leader_plan(stamp: float) -> PredictionMessage:
    times = stamp + 0.01 + REL_S
    pos = np.column_stack([3.0 * (times - stamp), np.zeros_like(times), np.full_like(times, 10.0)])
    return PredictionMessage(SCHEMA_VERSION, "leader", 1, stamp, times, pos, True)


def _formation() -> FormationFollower:
    return FormationFollower(FormationSpec(leader="leader", followers=("f1", "f2")), "f1")


def _lander() -> LandingMission:
    return LandingMission(LandingParams())


#: Every built-in mission type, with an input it acts on (a new reference).
MISSIONS = {
    "formation": (_formation, lambda t: MissionInput(t, _state([0, -6, 10], [3, 0, 0], t),
                                                     False, {"leader": _leader_plan(t - 0.1)})),
    "landing": (_lander, lambda t: MissionInput(t, _state([-20, 0, 8], t=t), False, {},
                                                [TargetFix(t - 0.2, np.array([0.0, 0.0])),
                                                 TargetFix(t - 0.1, np.array([0.5, 0.0])),
                                                 TargetFix(t, np.array([1.0, 0.0]))])),
}


def test_every_mission_type_is_tested_here() -> None:
    import uavmpc.missions.formation as formation
    import uavmpc.missions.landing as landing

    found = {obj for mod in (formation, landing) for _, obj in inspect.getmembers(mod)
             if inspect.isclass(obj) and obj.__module__ == mod.__name__
             and callable(getattr(obj, "step", None)) and hasattr(obj, "summary")}
    assert found == {FormationFollower, LandingMission}


@pytest.mark.parametrize("kind", sorted(MISSIONS))
def test_a_mission_honours_its_contract(kind: str) -> None:
    make, inputs = MISSIONS[kind]
    mission = make()
    assert isinstance(mission, Mission)
    assert isinstance(mission.period_s, float) and mission.period_s > 0.0
    outs = []
    t = 10.0
    for _ in range(4):
        out = mission.step(inputs(t))
        assert isinstance(out, MissionOutput) and isinstance(out.cut_motors, bool)
        assert out.reference is None or isinstance(out.reference, Reference)
        outs.append(out)
        t += mission.period_s
    ref = next(o.reference for o in outs if o.reference is not None)
    assert ref.points.shape == (ref.times_s.size, 4) and np.all(np.diff(ref.times_s) > 0)
    assert not any(o.cut_motors for o in outs)  # airborne, not landed
    summary = mission.summary()
    assert isinstance(summary, dict) and json.loads(json.dumps(summary)) == summary


def test_commands_reach_only_a_commanded_mission() -> None:
    assert not isinstance(_lander(), CommandedMission)
    f = _formation()
    assert isinstance(f, CommandedMission)
    shape = next(s for s in SHAPES if s != f.spec.shape)
    cmd = json.dumps({"shape": shape, "at_s": 20.0}).encode()
    assert f.command(cmd, 10.0) is True
    assert f.command(cmd, 10.5) is False  # a repeat
    with pytest.raises(ValueError, match="shape must be one of"):
        f.command(b'{"shape": "circle"}', 11.0)
    with pytest.raises(ValueError, match="not JSON"):
        f.command(b"\xff", 11.0)


# ---------------------------------------------------------------- plants

def _hover() -> AttitudeTarget:
    return AttitudeTarget(np.array([1.0, 0.0, 0.0, 0.0]), AF.mass_kg * G_MPS2)


def _check_state(s: VehicleState) -> None:
    assert isinstance(s, VehicleState) and isinstance(s.t_s, float)
    for a, n in ((s.position_m, 3), (s.velocity_mps, 3), (s.attitude_wxyz, 4),
                 (s.body_rates_radps, 3)):
        assert a.shape == (n,) and np.all(np.isfinite(a))
    assert np.linalg.norm(s.attitude_wxyz) == pytest.approx(1.0)


def test_the_simulated_multirotor_is_a_plant() -> None:
    plant = Multirotor(AF, position_m=[1.0, 2.0, 5.0], yaw_rad=0.3)
    assert isinstance(plant, Plant)
    s0 = plant.state()
    _check_state(s0)
    assert np.array_equal(s0.position_m, [1.0, 2.0, 5.0])
    s = s0
    for _ in range(50):
        s = plant.step(_hover(), 0.01)
    _check_state(s)
    assert s.t_s == pytest.approx(s0.t_s + 0.5)
    assert np.linalg.norm(s.position_m - s0.position_m) < 0.05  # hover thrust holds it


# ---------------------------------------------------------------- vehicle drivers

def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_simulated_vehicle_is_a_vehicle_driver() -> None:
    v = SimulatedVehicle(AF, [0.0, 0.0, 5.0], 0.0)
    assert isinstance(v, VehicleDriver)
    assert v.commanding is True and v.flying is True and v.done is False
    assert isinstance(v.ground_z_m, float)
    first = v.start()
    _check_state(first)
    assert v.update(0.0) is first
    v.actuate(0.0, _hover(), None)
    after = v.update(0.01)
    _check_state(after)
    assert after.t_s > first.t_s
    assert isinstance(v.report(), dict)
    v.land(0.02)
    assert v.done is True
    assert v.close() is None


def test_the_px4_vehicle_is_a_vehicle_driver() -> None:
    pytest.importorskip("pymavlink")
    from uavmpc.drivers.px4.vehicle import Px4Vehicle

    v = Px4Vehicle(f"udpout://127.0.0.1:{_free_udp_port()}", AF)
    try:
        assert isinstance(v, VehicleDriver)
        # Nobody answers: not ours to command, to fly, nor done; nothing to fly on.
        assert (v.commanding, v.flying, v.done) == (False, False, False)
        assert v.ground_z_m == 0.0 and isinstance(v.ground_z_m, float)
        assert v.update(0.0) is None
        v.actuate(0.0, _hover(), None)  # before the autopilot is heard: nothing is sent
        v.abort(0.1, "test")
        v.land(0.2)
        report = v.report()
        assert isinstance(report, dict) and report["phase"] == "connecting"
        assert report["setpoints_sent"] == 0
        json.dumps(report)
    finally:
        v.close()


# ---------------------------------------------------------------- transports

def test_the_simulated_link_is_a_transport() -> None:
    link = SimulatedLink(["a", "b", "c"], latency_s=0.05)
    assert isinstance(link, Transport)
    assert link.publish(b"hello", "a", 1.0) is None
    assert link.receive("b", 1.0) == []  # still in flight
    got = link.receive("b", 1.1)
    assert isinstance(got, list) and got == [b"hello"]
    assert link.receive("b", 1.2) == []  # taken
    assert link.receive("c", 1.2) == [b"hello"] and link.receive("a", 1.2) == []


def test_the_zenoh_transport_is_a_transport() -> None:
    pytest.importorskip("zenoh")
    from uavmpc.comms.zenoh_link import ZenohTransport

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ep = f"tcp/127.0.0.1:{port}"
    swarm = f"contracts{port}"
    with ZenohTransport("rx", swarm=swarm, listen=[ep]) as rx, \
            ZenohTransport("tx", swarm=swarm, connect=[ep]) as tx:
        assert isinstance(rx, Transport) and isinstance(tx, Transport)
        got: list[bytes] = []
        deadline = time.monotonic() + 10.0
        while not got and time.monotonic() < deadline:  # until the session is up
            assert tx.publish(b"probe", "tx", 0.0) is None
            time.sleep(0.05)
            got = rx.receive("rx", 0.0)
        assert isinstance(got, list) and got and all(g == b"probe" for g in got)
        assert tx.receive("tx", 0.0) == []  # never our own


def test_a_contract_change_is_noticed_here() -> None:
    """The members each contract declares (a method added to one needs a test above)."""
    def members(proto) -> set[str]:
        return {n for n in vars(proto) if not n.startswith("_")} | set(
            getattr(proto, "__annotations__", {}))

    assert members(ResolutionStrategy) == {"params", "update"}
    assert members(EncounterStrategy) == {"pair_radius_m", "limit_offset", "finder",
                                          "overrides", "decide", "hold_probes", "rest"}
    assert members(AxisQpSolver) == {"name", "solve"}
    assert members(Mission) == {"period_s", "step", "summary"}
    assert members(CommandedMission) == {"command"}
    assert members(Plant) == {"state", "step"}
    assert members(Transport) == {"publish", "receive"}
    assert members(VehicleDriver) == {"commanding", "flying", "done", "ground_z_m",
                                      "position_sigma_m", "start", "update", "actuate", "land",
                                      "abort", "report", "close"}
    assert dataclasses.is_dataclass(AvoidanceDecision)
