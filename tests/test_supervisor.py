"""The per-UAV supervisor (uavmpc.supervisor): the launch hold, the mission beside the stack
and its motor cut, the geofence's failsafe and ceiling — one object that the world and a node
both drive."""

from __future__ import annotations

import numpy as np
import pytest

from uavmpc.avoidance import AvoidanceParams, HeightOffsetStrategy
from uavmpc.comms.inbox import InboxTable
from uavmpc.comms.message import decode
from uavmpc.geofence import Geofence, GeofenceError
from uavmpc.missions.mission import MissionInput, MissionOutput
from uavmpc.onboard import OnboardBatch, OnboardStack
from uavmpc.plant import Airframe
from uavmpc.plant.interface import heading_of
from uavmpc.plant.multirotor import Multirotor
from uavmpc.reference import Reference
from uavmpc.scenarios.run import RunSpec
from uavmpc.supervisor import FenceGuard, Supervisor

AIRFRAME = Airframe.packaged("f550")
FENCE = Geofence.box((0.0, 50.0), (-25.0, 25.0), (1.0, 10.0))


class LandWhereYouAre:
    """A user's mission (the :class:`~uavmpc.missions.mission.Mission` protocol): descend
    where it is, and cut the motors once the land detector says it touches."""

    period_s = 0.1

    def __init__(self) -> None:
        self.inputs: list[MissionInput] = []

    def step(self, inp: MissionInput) -> MissionOutput:
        self.inputs.append(inp)
        if inp.landed:
            return MissionOutput(cut_motors=True)
        x, y, _z = (float(v) for v in inp.estimate.position_m)
        return MissionOutput(reference=Reference.goto(x, y, 0.0, start_s=inp.t_s))


def _pair(params: AvoidanceParams | None = None) -> tuple[list[OnboardStack], InboxTable]:
    """Two UAVs 20 m apart head-on, each stack a row of one inbox table (as in the world)."""
    prm = params if params is not None else AvoidanceParams()
    batch = OnboardBatch(None, 2)
    table = InboxTable(["a", "b"], time_reference=prm.time_reference, max_age_s=prm.timeout_s,
                       points=batch.tracker.config.steps)
    starts = ((0.0, 0.0, 5.0), (20.0, 0.0, 5.0))
    stacks = [OnboardStack(AIRFRAME, position_m=p, uav_id=uid, priority=k,
                           avoidance=HeightOffsetStrategy(prm), params=prm, batch=batch, row=k,
                           inbox_table=table, broadcast_phase_s=0.25 * k)
              for k, (uid, p) in enumerate(zip("ab", starts, strict=True))]
    return stacks, table


def _fly(stacks: list[OnboardStack], plants: list[Multirotor], seconds: float,
         t0: float = 0.0) -> float:
    """Fly the stacks against their plants, each hearing the other at once; returns the
    time reached."""
    inboxes: list[list[bytes]] = [[], []]
    t = t0
    for k in range(round(seconds / stacks[0].period_s)):
        t = t0 + k * stacks[0].period_s
        outs = [s.tick(t, p.state(), box) for s, p, box in zip(stacks, plants, inboxes,
                                                               strict=True)]
        inboxes = [[o.outgoing] if o.outgoing else [] for o in reversed(outs)]
        for s, p, o in zip(stacks, plants, outs, strict=True):
            p.step(o.target, s.period_s)
    return t


def test_a_held_uav_launches_only_once_it_has_heard_its_peer() -> None:
    stacks, table = _pair()
    a, b = stacks
    sup = Supervisor(a)
    mission = Reference.goto(20.0, 0.0, 5.0)
    sup.hold(mission, Reference.goto(0.0, 0.0, 5.0))
    assert not sup.launched and sup.held is mission
    peer = [table.col_of("b")]
    assert not sup.heard_from(0.0, peer) and sup.unheard(0.0, peer) == peer
    # It hovers where it starts while the mission waits.
    assert np.allclose(a.tracker.reference.points[:, :3], [[0.0, 0.0, 5.0]])
    b.set_mission(Reference.goto(0.0, 0.0, 5.0))
    plant_b = Multirotor(AIRFRAME, position_m=(20.0, 0.0, 5.0))
    out = b.tick(0.0, plant_b.state())
    sent = out.outgoing if out.outgoing is not None else b.emit(0.3)
    assert sent is not None
    a.receive(0.3, [sent])
    assert sup.heard_from(0.3, peer) and sup.unheard(0.3, peer) == []
    sup.launch()
    assert sup.launched and sup.held is None
    assert np.allclose(a.tracker.reference.points[:, :3], [[20.0, 0.0, 5.0]])


def test_the_failsafe_engages_once_at_the_fence_and_stops_the_mission() -> None:
    stack = OnboardStack(AIRFRAME, position_m=(-5.0, 0.0, 5.0), uav_id="u")
    mission = LandWhereYouAre()
    sup = Supervisor(stack, mission=mission, fence=FenceGuard(FENCE))
    outside = np.array([-5.0, 0.0, 5.0])
    assert sup.watch_fence(1.0, outside, 0.0)
    ref = stack.tracker.reference
    # Back in, 2 m (the inset) inside the wall x = 0, from the UAV's time on, holding.
    assert np.allclose(ref.points[:, :3], [[2.0, 0.0, 5.0]]) and ref.times_s[0] == 1.0
    assert sup.mission is None and not sup.mission_due(5.0)
    assert not sup.watch_fence(1.1, np.array([-6.0, 0.0, 5.0]), 0.0)  # the same breach
    report = sup.fence.report()
    assert report["breaches"] == 1 and report["holding"]
    assert report["worst_outside_m"] == pytest.approx(6.0)
    # Inside again: nothing to do; a new mission inside the volume ends the hold.
    assert not sup.watch_fence(2.0, np.array([2.0, 0.0, 5.0]), 0.0)
    sup.fence.check_mission(Reference.goto(30.0, 0.0, 5.0))
    assert not sup.fence.report()["holding"]
    with pytest.raises(GeofenceError, match="outside"):
        sup.fence.check_mission(Reference.goto(60.0, 0.0, 5.0))


def test_the_mission_steps_at_its_period_and_a_motor_cut_turns_the_stack_to_follow() -> None:
    plant = Multirotor(AIRFRAME, position_m=(3.0, 4.0, 2.0))
    stack = OnboardStack(AIRFRAME, position_m=(3.0, 4.0, 2.0), uav_id="u",
                         avoidance=HeightOffsetStrategy())
    mission = LandWhereYouAre()
    sup = Supervisor(stack, mission=mission)
    assert sup.mission_due(0.0)
    assert not sup.step_mission(0.0, 0.5, plant.state())
    assert mission.inputs[0].t_s == 0.5  # the UAV's own clock
    assert np.allclose(stack.tracker.reference.points[:, :3], [[3.0, 4.0, 0.0]])
    assert not sup.mission_due(0.05) and sup.mission_due(0.1)
    stack.tick(0.5, plant.state())
    assert stack.cooperative
    rest = plant.state()
    assert sup.step_mission(0.1, 0.6, rest, touching=True)  # the first cut: the driver cuts
    assert sup.motors_cut and not stack.cooperative
    assert stack.steering.decision is None
    # It broadcasts where it rests, flag down.
    assert np.allclose(stack.tracker.reference.points[:, :3], [rest.position_m])
    assert not sup.step_mission(0.2, 0.7, rest, touching=True)  # cut already
    sent = stack.emit(10.0)
    assert sent is not None and decode(sent).avoiding is False


def test_the_ceiling_caps_the_climb_over_the_mission_flown() -> None:
    stacks, _table = _pair()
    plants = [Multirotor(AIRFRAME, position_m=p) for p in ((0.0, 0.0, 5.0), (20.0, 0.0, 5.0))]
    sups = [Supervisor(s, fence=FenceGuard(FENCE)) for s in stacks]
    for sup, goal in zip(sups, ((20.0, 0.0, 5.0), (0.0, 0.0, 5.0)), strict=True):
        sup.fly(Reference.goto(*goal))
    _fly(stacks, plants, 4.0)
    ceiling = FENCE.offset_ceiling_m(np.array([5.0]))
    assert 0.0 < ceiling < 5.0  # below the ceiling, less its margin
    decisions = [s.steering.decision for s in stacks]
    climbed = max(s.report().max_z_offset_m for s in stacks)
    assert any(d is not None and d.avoiding for d in decisions)  # they met
    assert 0.0 < climbed <= ceiling + 1e-9
    # A lower ceiling over a higher mission: no room to climb.
    stacks2, _ = _pair()
    plants2 = [Multirotor(AIRFRAME, position_m=p) for p in ((0.0, 0.0, 5.0), (20.0, 0.0, 5.0))]
    for s, goal in zip(stacks2, ((20.0, 0.0, 9.0), (0.0, 0.0, 9.0)), strict=True):
        Supervisor(s, fence=FenceGuard(FENCE)).fly(Reference.goto(*goal))
    _fly(stacks2, plants2, 4.0)
    low = FENCE.offset_ceiling_m(np.array([9.0]))
    assert low < ceiling
    assert any(s.steering.decision is not None and s.steering.decision.avoiding
               for s in stacks2)
    assert all(s.report().max_z_offset_m <= low + 1e-9 for s in stacks2)


def test_the_ceiling_follows_the_estimator_s_uncertainty_stated_after_the_mission_was_set(
        ) -> None:
    """A node hears its autopilot's σ only once it flies, after the mission was set (real
    PX4: 0.32 m vertical, while its estimate was 1.2 m under the truth at the top layer). The
    ceiling is lowered by uncertainty_k σ_v of the estimator from then on, rises again when σ
    falls, and does not follow the tracking error added to what the UAV states."""
    stacks, _table = _pair()
    sup = Supervisor(stacks[0], fence=FenceGuard(FENCE))
    sup.fly(Reference.goto(20.0, 0.0, 5.0))
    room = FENCE.offset_ceiling_m(np.array([5.0]))
    assert stacks[0].avoidance.offset_ceiling_m == pytest.approx(room)
    k = stacks[0].params.uncertainty_k
    sup.state_sigma((0.2, 0.9), 0.5)  # stated: σ widened by the tracking error
    assert stacks[0].position_sigma_m == (0.2, 0.9)
    assert stacks[0].avoidance.offset_ceiling_m == pytest.approx(room - k * 0.5)
    sup.state_sigma((0.2, 10.0), 10.0)  # more than the room: no climb at all, never negative
    assert stacks[0].avoidance.offset_ceiling_m == 0.0
    sup.state_sigma((0.2, 0.1), 0.1)
    assert stacks[0].avoidance.offset_ceiling_m == pytest.approx(room - k * 0.1)
    with pytest.raises(ValueError, match="estimate_sigma_v_m"):
        sup.state_sigma((0.2, 0.1), float("nan"))
    # without a fence, σ is stated and there is no ceiling to follow
    free = Supervisor(stacks[1])
    free.state_sigma((0.3, 0.4), 0.4)
    assert stacks[1].position_sigma_m == (0.3, 0.4)


def test_a_trajectory_is_lowered_under_the_ceiling_by_the_estimator_s_uncertainty() -> None:
    """Where its estimate is at a mission's 9 m, a UAV 2σ_v uncertain may truly be above the
    10 m ceiling: the trajectory it flies is lowered to the margin under the ceiling less
    k σ_v (times kept, lower points untouched), follows σ as it changes, and the fence
    reports the most it was lowered. Without σ the mission is flown as commanded."""
    stacks, _table = _pair()
    sup = Supervisor(stacks[0], fence=FenceGuard(FENCE))
    k = stacks[0].params.uncertainty_k
    mission = Reference(np.array([0.0, 4.0, 8.0]),
                        np.array([[0.0, 0.0, 5.0, 0.0], [10.0, 0.0, 9.0, 0.0],
                                  [20.0, 0.0, 8.5, 0.0]]))
    sup.fly(mission)
    flown = stacks[0].tracker.reference
    assert flown is mission  # σ 0: the margin alone (10 − 1 = 9 m) holds it
    sup.state_sigma((0.2, 0.5), 0.5)
    flown = stacks[0].tracker.reference
    top = FENCE.max_altitude_m - FENCE.margin_m - k * 0.5
    np.testing.assert_allclose(flown.points[:, 2], [5.0, top, top])
    np.testing.assert_array_equal(flown.times_s, mission.times_s)
    np.testing.assert_array_equal(flown.points[:, [0, 1, 3]], mission.points[:, [0, 1, 3]])
    assert stacks[0].avoidance.offset_ceiling_m == 0.0
    sup.state_sigma((0.2, 0.55), 0.55)  # a wander under the tolerance sets nothing again
    assert stacks[0].tracker.reference is flown
    sup.state_sigma((0.2, 10.0), 10.0)  # never under the floor's margin
    assert stacks[0].tracker.reference.points[:, 2].min() == pytest.approx(
        FENCE.min_altitude_m + FENCE.margin_m)
    sup.state_sigma((0.2, 0.0), 0.0)  # σ falls: the mission as commanded again
    np.testing.assert_array_equal(stacks[0].tracker.reference.points, mission.points)
    assert sup.fence is not None
    assert sup.fence.report()["capped_m"] == pytest.approx(9.0 - (
        FENCE.min_altitude_m + FENCE.margin_m))
    # A trajectory its driver gave the stack since (a node's landing) is left alone.
    landing = Reference.goto(20.0, 0.0, 2.0)
    stacks[0].set_mission(landing)
    sup.state_sigma((0.2, 1.0), 1.0)
    assert stacks[0].tracker.reference is landing


def test_in_the_world_single_band_gnss_flies_a_mission_at_the_ceiling_lower() -> None:
    """A mission 1 m under a 30 m ceiling, flown on single-band GNSS (σ_v 2.5 m): the world's
    UAVs state that σ before their missions are set, so each flies the margin under the
    ceiling less k σ_v, and its truth stays under the ceiling (found by the falsifier: walks
    to 29 m flew to 34.7 m by their truth)."""
    from test_geofence import _swap

    from uavmpc import scenarios
    from uavmpc.drivers.world import World
    from uavmpc.estimation.observer import ObserverParams
    from uavmpc.scenarios.faults import FaultSpec

    data = _swap({"box": [-40, -20, 40, 20], "min_altitude_m": 1.0, "max_altitude_m": 30.0})
    for u in data["uavs"]:
        u["start"][2] = 20.0
        u["goto"][2] = 29.0
    world = World(RunSpec(scenarios.from_dict(data), seed=3, faults=FaultSpec(gnss="single")))
    res = world.run(20.0)
    sigma_v = ObserverParams.preset("single").position_sigma_m[1]
    top = 30.0 - 1.0 - world.params.uncertainty_k * sigma_v
    for u in world.uavs:
        assert u.stack.tracker.reference.points[:, 2].max() == pytest.approx(top)
    assert all(r["capped_m"] == pytest.approx(29.0 - top)
               for r in res.sections["geofence"].values())
    assert res.positions_m[:, :, 2].max() < 30.0


def test_the_world_and_a_node_take_the_same_failsafe_decision() -> None:
    """The world looks at every UAV's margin at once and hands each its own; a node asks its
    supervisor alone: the same way back for a UAV found outside."""
    from test_geofence import _swap

    from uavmpc import scenarios
    from uavmpc.drivers.world import World

    fence = {"box": [-30, -10, 30, 10], "min_altitude_m": 1.0, "max_altitude_m": 10.0}
    world = World(RunSpec(scenarios.from_dict(_swap(fence, start1=(-40.0, 0.0, 5.0))), seed=1))
    res = world.run(0.01)  # one tick: the failsafe looks after it
    u = world.uavs[0]
    assert res.sections["geofence"]["uav1"]["breaches"] == 1
    assert u.supervisor.mission is None
    in_world = u.stack.tracker.reference
    # A node's supervisor at the same place, on its own stack.
    stack = OnboardStack(AIRFRAME, position_m=(-40.0, 0.0, 5.0), uav_id="uav1",
                         avoidance=HeightOffsetStrategy())
    sup = Supervisor(stack, fence=FenceGuard(world.geofence))
    state = u.plant.state()
    assert sup.watch_fence(float(in_world.times_s[0]), world.plants.x[0, 0:3].copy(),
                           float(heading_of(state.attitude_wxyz)))
    alone = stack.tracker.reference
    assert np.array_equal(alone.points, in_world.points)
    assert np.array_equal(alone.times_s, in_world.times_s)
