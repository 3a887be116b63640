"""The watch over the safety argument's assumptions (uavmpc.assumptions): the uncertainty a
UAV states from its autopilot's and its tracking error, the bounds that make it hold, and a
node that holds while one is broken and resumes when it is back."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from waiting import wait_until

from uavmpc.assumptions import (
    DEAD_AFTER_S,
    TRACKING_WINDOW_S,
    AssumptionWatch,
    Bounds,
    failsafe_prediction,
)
from uavmpc.avoidance import HeightOffsetStrategy
from uavmpc.comms.message import SCHEMA_VERSION, PredictionMessage
from uavmpc.comms.state import NodeState
from uavmpc.comms.zenoh_link import ZenohTransport
from uavmpc.drivers.node import Node, SimulatedVehicle, warm_up
from uavmpc.drivers.px4.vehicle import _position_sigma
from uavmpc.drivers.swarm import free_ports
from uavmpc.onboard import OnboardStack
from uavmpc.plant import Airframe, VehicleState
from uavmpc.reference import Reference
from uavmpc.supervisor import Supervisor


def test_the_stated_uncertainty_covers_the_estimate_and_the_tracking_lag() -> None:
    w = AssumptionWatch(uncertainty_k=2.0)
    assert w.stated_sigma_m() == (0.0, 0.0)
    w.estimate(0.3, 0.4)
    w.tracking(10.0, (1.0, 0.0, 5.0), (0.0, 0.0, 6.2))  # 1 m behind, 1.2 m below its plan
    h, v = w.stated_sigma_m()
    assert h == pytest.approx(math.hypot(0.3, 1.0 / 2.0))
    assert v == pytest.approx(math.hypot(0.4, 1.2 / 2.0))
    assert 2.0 * v >= 1.2  # k σ covers the lag: the layer counts when the vehicle is there
    # a lag older than the window no longer counts; a NaN σ keeps the last one stated
    w.tracking(10.0 + TRACKING_WINDOW_S + 0.1, (0.0, 0.0, 5.0), (0.0, 0.0, 5.0))
    w.estimate(math.nan, math.nan)
    assert w.stated_sigma_m() == pytest.approx((0.3, 0.4))
    assert w.broken(11.2) == ()


def test_each_broken_assumption_is_named_with_its_numbers_and_counted_once() -> None:
    w = AssumptionWatch(2.0, Bounds(sigma_h_m=1.0, sigma_v_m=1.0, tracking_m=2.0, age_s=0.3))
    w.estimate(0.5, 1.4)
    w.tracking(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), airborne=False)  # on the ground
    w.tracking(0.1, (0.0, 0.0, 2.0), (0.0, 0.0, 5.0))  # taking off: lagging by design
    assert w.broken(0.1) == ("A3 estimate: vertical σ 1.40 m > 1 m",)
    w.tracking(0.5, (0.0, 0.0, 5.0), (0.3, 0.0, 5.0))  # caught up: A4 is judged from now on
    w.tracking(1.0, (0.0, 0.0, 5.0), (3.0, 0.0, 5.0))
    w.heard("uav2", stamp_s=0.0, received_s=0.05)
    w.heard("uav2", stamp_s=0.5, received_s=0.95)  # arrived 0.45 s old
    broken = w.broken(1.0)
    assert [b.split(":")[0] for b in broken] == ["A3 estimate", "A4 vehicle", "A1/A5 link"]
    assert "1.40 m > 1 m" in broken[0] and "uav2" in broken[2]
    w.broken(1.1)  # the same episode
    assert w.breaks == {"A3 estimate": 1, "A4 vehicle": 1, "A1/A5 link": 1}
    rep = w.report()
    assert rep["worst"]["sigma_v_m"] == 1.4 and rep["peers"]["uav2"]["heard"] == 2
    assert rep["peers"]["uav2"]["loss"] == 0.0 and rep["peers"]["uav2"]["age_max_s"] == 0.45


def test_a_peer_s_loss_is_counted_from_its_stamps() -> None:
    w = AssumptionWatch(2.0)
    for k in (0, 1, 3, 4, 7, 8, 9):  # 10 broadcasts at 0.5 s, 3 lost
        w.heard("uav2", stamp_s=0.5 * k, received_s=0.5 * k + 0.01)
    w.heard("uav2", stamp_s=4.5, received_s=4.6)  # a copy of the last: not counted again
    assert w.report()["peers"]["uav2"]["loss"] == pytest.approx(0.3)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, True])
def test_bounds_are_checked(bad: float) -> None:
    with pytest.raises(ValueError, match=r"bounds\.tracking_m"):
        Bounds(tracking_m=bad)


def test_odometry_s_covariance_gives_the_estimate_s_sigma() -> None:
    cov = [math.nan] * 21
    cov[0], cov[6], cov[11] = 0.04, 0.09, 0.25
    assert _position_sigma(cov) == pytest.approx((0.3, 0.5))
    assert all(math.isnan(s) for s in _position_sigma([math.nan] * 21))
    assert all(math.isnan(s) for s in _position_sigma([-1.0] * 21))
    assert all(math.isnan(s) for s in _position_sigma(None))


def test_a_pause_keeps_the_mission_and_what_is_commanded_meanwhile() -> None:
    stack = OnboardStack(Airframe.packaged("f550"), position_m=(0.0, 0.0, 5.0))
    sup = Supervisor(stack)
    go = Reference.goto(20.0, 0.0, 5.0)
    sup.fly(go)
    hover = Reference.goto(0.0, 0.0, 5.0)
    sup.pause(hover)
    assert stack.tracker.reference is hover and sup.paused is go
    later = Reference.goto(0.0, 20.0, 5.0)
    sup.fly(later)  # commanded while paused: waits
    assert stack.tracker.reference is hover and sup.paused is later
    sup.resume()
    assert stack.tracker.reference is later and sup.paused is None
    sup.pause(hover)
    back = Reference.goto(1.0, 1.0, 5.0)
    sup.failsafe(back)  # the way back into the geofence comes first
    assert stack.tracker.reference is back and sup.paused is None


class _VehicleWithSigma(SimulatedVehicle):
    """The node's simulated plant, stating the 1σ a test sets (as an autopilot would)."""

    position_sigma_m = (0.1, 0.1)


@pytest.mark.realtime
def test_a_node_holds_while_its_estimate_is_too_uncertain_and_says_so() -> None:
    ports = free_ports(2)
    swarm = f"t{ports[0]}"
    eps = [f"tcp/127.0.0.1:{p}" for p in ports]
    af = Airframe.packaged("f550")
    warm_up(af)  # cold, the node's first tick would compile for a minute
    vehicle = _VehicleWithSigma(af, (0.0, 0.0, 5.0), 0.0)
    with ZenohTransport("uav1", swarm=swarm, listen=[eps[0]]) as tx, \
            ZenohTransport("obs", swarm=swarm, listen=[eps[1]], connect=[eps[0]]) as obs:
        states = obs.subscribe("uav1/state", maxlen=100_000)
        node = Node("uav1", 1, af, tx, start_m=(0.0, 0.0, 5.0), vehicle=vehicle)
        node.set_mission(Reference.goto(40.0, 0.0, 5.0))
        thread = threading.Thread(target=node.run, args=(60.0,), daemon=True)
        thread.start()
        try:
            last: list[NodeState] = []

            def heard() -> NodeState | None:
                for _, p in states.drain():
                    last[:] = [NodeState.decode(p)]
                return last[0] if last else None

            wait_until(lambda: (s := heard()) is not None and s.position_m[0] > 3.0, 20.0,
                       f"the node to set off (last state heard: {last})")
            assert node.stack is not None
            # the stated σ is the estimate's, widened by the (small) tracking error
            assert 0.1 <= node.stack.position_sigma_m[0] < 0.2
            vehicle.position_sigma_m = (0.1, 2.5)  # EKF2 loses its height
            s = wait_until(lambda: (s := heard()) is not None and s.broken and s, 5.0,
                           "the node to say which assumption broke")
            assert s.broken[0].startswith("A3 estimate: vertical σ 2.50 m")
            # braking from its speed (a little past the stopping point, and back) it settles
            held = wait_until(lambda: (h := heard()) is not None and h.t_s > s.t_s + 3.0
                              and abs(h.velocity_mps[0]) < 0.05 and h, 15.0, "the node to hold")
            x_held = held.position_m[0]
            later = wait_until(lambda: (s := heard()) is not None and s.t_s > held.t_s + 1.0
                               and s, 5.0, "a second of holding")
            assert abs(later.position_m[0] - x_held) < 0.2 and later.broken
            vehicle.position_sigma_m = (0.1, 0.1)
            wait_until(lambda: (s := heard()) is not None and not s.broken
                       and s.position_m[0] > x_held + 3.0, 20.0, "the mission to resume")
        finally:
            node.stop()
            thread.join(timeout=10)
    rep = node.stats.assumptions
    assert rep["breaks"] == {"A3 estimate": 1} and rep["worst"]["sigma_v_m"] == 2.5
    assert np.isfinite(rep["worst"]["tracking_m"])


# ---------------------------------------------------------------------------- a dead peer

def _last(stamp: float, start: tuple[float, float, float],
          velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> PredictionMessage:
    rel = np.cumsum(np.r_[0.01, np.full(39, 0.2)])
    pos = np.asarray(start) + rel[:, None] * np.asarray(velocity)
    return PredictionMessage(SCHEMA_VERSION, "uav2", 2, stamp, stamp + rel, pos, True, stamp,
                             ("uav1",), (0.2, 0.3))


def test_a_dead_peer_is_where_its_failsafe_can_take_it_and_everyone_gives_way() -> None:
    last = _last(100.0, (10.0, 0.0, 6.4), velocity=(2.0, 0.0, 0.0))
    now = 100.0 + DEAD_AFTER_S + 0.5
    p = failsafe_prediction(last, now, uncertainty_k=2.0)
    assert p is not None and not p.avoiding and p.stamp_s == now and p.priority == 2
    age = now - 100.0
    # drifting level at its last velocity, descending at the slower failsafe rate
    assert p.positions_m[0, 0] == pytest.approx(10.0 + 2.0 * age, abs=1e-6)
    assert p.positions_m[0, 2] == pytest.approx(6.4 - 0.6 * (age - 0.01 - 1.0), abs=1e-6)
    assert p.positions_m[-1, 2] == pytest.approx(6.4 - 0.6 * (age - 0.01 + 7.8 - 1.0))
    # its reach beyond that, as a 1σ that k σ covers: a velocity off its plan's (which flew
    # straight and level: the margin alone) for the time since, a second ahead
    assert 2.0 * p.position_sigma_m[0] >= 0.5 * (age + 1.0) - 1e-9
    # from 6.4 m at 0.6 m/s it is down after 1 + 10.7 s; two seconds later, no longer assumed
    assert failsafe_prediction(last, 100.0 + 1.0 + 6.4 / 0.6 + 2.1, 2.0) is None


def test_a_higher_priority_gives_way_to_a_peer_taken_for_dead() -> None:
    """Before, a UAV that outranked a silent peer flew on through where its vehicle was: its
    last plan, silent, counts, but only those it outranks yield to it."""

    def climbed(held: PredictionMessage) -> float:
        stack = OnboardStack(Airframe.packaged("f550"), position_m=(0.0, 0.0, 5.0),
                             t0_s=100.0, uav_id="uav1", priority=1,
                             avoidance=HeightOffsetStrategy())
        stack.set_mission(Reference.goto(30.0, 0.0, 5.0))
        here = VehicleState(100.0, np.array([0.0, 0.0, 5.0]), np.zeros(3),
                            np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))
        stack.tick(100.0, here)
        assert stack.inbox.assume(held, held.stamp_s)  # held since it was sent
        for k in range(1, 30):
            stack.tick(100.0 + 0.01 * k, here)
        return stack.tracker.z_offset_m

    last = _last(97.0, (12.0, 0.0, 5.0))  # hovering in its path, unheard for 3 s
    assert climbed(last) == 0.0  # silent: it outranks uav2 and flies on
    assumed = failsafe_prediction(last, 100.0, 2.0)
    assert assumed is not None
    assert climbed(assumed) >= 3.0  # taken for dead: it gives way
