"""Collision avoidance (SPEC §5.2–5.3): proximity in time, and the height-offset strategy."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uavmpc.avoidance import (
    AvoidanceDecision,
    AvoidanceParams,
    HeightOffsetStrategy,
    ResolutionStrategy,
    align,
    align_batch,
    conflict_points,
    cylinder_conflicts,
    first_conflict_time,
)
from uavmpc.comms import PredictionMessage
from uavmpc.comms.message import SCHEMA_VERSION
from uavmpc.config import ConfigError

#: The tracker's horizon: 0.01 s then 39 × 0.2 s.
REL = np.cumsum(np.r_[0.01, np.full(39, 0.2)])
NOW = 1000.0
P = AvoidanceParams()
UP = np.array([0.0, 0.0, 1.0])
UP3 = 3.0 * UP


def line(t: np.ndarray, start: tuple[float, float, float],
         velocity: tuple[float, float, float], t0: float = NOW) -> np.ndarray:
    """(m, 3) positions of a straight-line flight through ``start`` at ``t0``."""
    return np.asarray(start) + (t - t0)[:, None] * np.asarray(velocity)


def msg(uav_id: str, priority: int, positions: np.ndarray, stamp: float = NOW,
        avoiding: bool = True, times: np.ndarray | None = None,
        received_s: float | None = None) -> PredictionMessage:
    t = stamp + REL if times is None else times
    return PredictionMessage(SCHEMA_VERSION, uav_id, priority, stamp, t, positions, avoiding,
                             received_s)


def hover(xyz: tuple[float, float, float]) -> np.ndarray:
    return np.tile(np.asarray(xyz, dtype=float), (REL.size, 1))


# ---------------------------------------------------------------- proximity


def test_crossing_straight_lines_conflict_only_in_the_analytic_window() -> None:
    t = NOW + REL
    a = line(t, (-20.0, 0.0, 10.0), (5.0, 0.0, 0.0))  # east, at (0, 0) at NOW + 4
    b = line(t, (0.0, -20.0, 10.0), (0.0, 5.0, 0.0))  # north, same place, same time
    c = conflict_points(t, a, t, b)
    # Distance 5√2·|t − 4| ≤ 5  ⇔  |t − 4| ≤ 1/√2.
    expected = np.abs(REL - 4.0) <= 1.0 / np.sqrt(2.0)
    np.testing.assert_array_equal(c, expected)
    assert first_conflict_time(t, c) == pytest.approx(NOW + REL[expected][0])
    # 3 m of height difference is outside the half height (2.995 m): no conflict at all.
    assert not conflict_points(t, a, t, b + UP3).any()
    assert first_conflict_time(t, conflict_points(t, a, t, b + UP3)) is None


def test_cylinder_boundaries_are_inclusive() -> None:
    own = np.zeros((4, 3))
    other = np.array([[5.0, 0, 0], [5.0001, 0, 0], [0, 0, 2.995], [0, 0, -2.996]])
    np.testing.assert_array_equal(cylinder_conflicts(own, other, 5.0, 5.99),
                                  [True, False, True, False])


def test_old_prediction_is_aligned_in_time_where_index_to_index_misses_the_conflict() -> None:
    """Head-on at 5 m/s each (meet at NOW + 4 s); the other climbs at 4 m/s through our height.

    Its message is 0.7 s old. Aligned in time, the climb crosses our height while we are
    horizontally within R_p (t ∈ [3.5, 4.5]): a conflict. Compared index to index, its plan
    looks 0.7 s late and the crossing falls outside the horizontal window: no conflict.
    """
    t = NOW + REL
    own = line(t, (-20.0, 0.0, 30.0), (5.0, 0.0, 0.0))
    stamp = NOW - 0.7
    t_other = stamp + REL

    def other_at(tt: np.ndarray) -> np.ndarray:
        return np.c_[20.0 - 5.0 * (tt - NOW), 0.0 * tt, 30.0 + 4.0 * (tt - NOW - 4.95)]

    aligned = conflict_points(t, own, t_other, other_at(t_other))
    truth = cylinder_conflicts(own, other_at(t), P.radius_m, P.height_m)
    index_to_index = cylinder_conflicts(own, other_at(t_other), P.radius_m, P.height_m)
    assert truth.any()
    np.testing.assert_array_equal(aligned, truth)
    assert not index_to_index.any()


def test_old_level_head_on_gives_the_true_first_conflict_time() -> None:
    t = NOW + REL
    own = line(t, (-20.0, 0.0, 10.0), (5.0, 0.0, 0.0))
    t_other = NOW - 0.7 + REL
    other = line(t_other, (20.0, 0.0, 10.0), (-5.0, 0.0, 0.0))
    # True: distance 40 − 10 t ≤ 5 from t = 3.5 s; first sample ≥ 3.5 is 3.61 s.
    assert first_conflict_time(t, conflict_points(t, own, t_other, other)) - NOW == (
        pytest.approx(3.61))
    # Index to index it would be ≥ 3.85 s: 0.35 s (3.5 m of closing) too late.
    idx = cylinder_conflicts(own, other, 5.0, 5.99)
    assert first_conflict_time(t, idx) - NOW == pytest.approx(4.01)


def test_outside_the_span_first_point_is_held_and_the_end_is_extrapolated_then_unknown() -> None:
    times = np.array([10.0, 11.0, 12.0])
    pos = np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0]])
    at = np.array([9.0, 10.5, 12.0, 12.5, 13.0, 13.01])
    out, known = align(times, pos, at, extrapolate_s=1.0)
    np.testing.assert_allclose(out[:, 0], [0.0, 0.5, 3.0, 4.0, 5.0, 5.02])
    np.testing.assert_array_equal(known, [True, True, True, True, True, False])
    # Unknown points never count as a conflict, even if the extrapolation passes through us.
    own = np.c_[out[:, 0], np.zeros(6), np.zeros(6)]
    np.testing.assert_array_equal(
        conflict_points(at, own, times, pos, extrapolate_s=1.0), known)


def test_batched_alignment_equals_per_sender_interpolation() -> None:
    rng = np.random.default_rng(3)
    k, n = 7, 40
    times = np.sort(rng.uniform(0.0, 8.0, (k, n)), axis=1) + rng.uniform(-1, 1, (k, 1))
    pos = rng.normal(0.0, 50.0, (k, n, 3))
    at = np.linspace(0.5, 7.5, 40)  # inside every span is not guaranteed: clamp-before only
    at = np.clip(at, times[:, 0].max(), times[:, -1].min())
    out, known = align_batch(times, pos, at, 1.0)
    assert known.all()
    for i in range(k):
        for ax in range(3):
            np.testing.assert_allclose(out[i, :, ax], np.interp(at, times[i], pos[i, :, ax]),
                                       rtol=1e-12, atol=1e-9)


def test_conflict_only_at_the_horizon_end_is_detected() -> None:
    t = NOW + REL
    # They close at 10 m/s and come within R_p = 5 m exactly at the last point (7.81 s).
    own = line(t, (-(5.0 * 7.81 + 2.5), 0.0, 10.0), (5.0, 0.0, 0.0))
    other = line(t, (5.0 * 7.81 + 2.5, 0.0, 10.0), (-5.0, 0.0, 0.0))
    c = conflict_points(t, own, t, other)
    assert c[-1] and not c[:-1].any()
    d = HeightOffsetStrategy().update(NOW, "b", 2, t, own, {"a": msg("a", 1, other)})
    assert d.conflicts == ("a",) and d.z_offset_m == P.dz_m
    assert d.first_conflict_s == pytest.approx(REL[-1])


# ---------------------------------------------------------------- strategy


def head_on(z_other: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    t = NOW + REL
    return (line(t, (-20.0, 0.0, 10.0), (5.0, 0.0, 0.0)),
            line(t, (20.0, 0.0, z_other), (-5.0, 0.0, 0.0)))


def test_equal_altitudes_lower_priority_climbs_one_dz_higher_priority_only_slows() -> None:
    a, b = head_on()
    t = NOW + REL
    hi, lo = HeightOffsetStrategy(), HeightOffsetStrategy()
    d_hi = hi.update(NOW, "a", 1, t, a, {"b": msg("b", 2, b)})
    d_lo = lo.update(NOW, "b", 2, t, b, {"a": msg("a", 1, a)})
    assert d_hi.first_conflict_s == pytest.approx(3.61)
    assert replace(d_hi, first_conflict_s=None) == AvoidanceDecision(
        z_offset_m=0.0, avoiding=True, conflicts=("b",),
        horizontal_scale=0.5, climb_speed_mps=5.0, climb_accel_mps2=3.0)
    assert d_lo.z_offset_m == 3.0 and d_lo.yielding_to == ("a",) and d_lo.unresolved == ()
    assert d_lo.avoiding and d_lo.horizontal_scale == 0.5 and not d_lo.ceiling_hit
    # Next round the others see b's raised prediction: no conflict left for either.
    d_hi = hi.update(NOW + 0.5, "a", 1, t, a, {"b": msg("b", 2, b + UP3)})
    d_lo = lo.update(NOW + 0.5, "b", 2, t, b, {"a": msg("a", 1, a)})
    assert d_hi.conflicts == () and d_hi.z_offset_m == 0.0
    assert d_lo.conflicts == () and d_lo.z_offset_m == 3.0


def test_a_decision_like_the_last_one_is_that_one_and_a_different_one_is_new() -> None:
    """The stack skips a decision it steers by already (``Steering.apply``): a round that
    decides what the last one did hands back that very object, field for field the same."""
    a, b = head_on()
    t = NOW + REL
    hi = HeightOffsetStrategy()
    first = hi.update(NOW, "a", 1, t, a, {"b": msg("b", 2, b)})
    again = hi.update(NOW, "a", 1, t, a, {"b": msg("b", 2, b)})
    assert again is first and first.conflicts == ("b",)
    # b has climbed: no conflict any more, a new decision (built by field name, as read).
    other = hi.update(NOW, "a", 1, t, a, {"b": msg("b", 2, b + UP3)})
    assert other is not first and other == AvoidanceDecision(
        z_offset_m=0.0, avoiding=True, horizontal_scale=0.5, climb_speed_mps=5.0,
        climb_accel_mps2=3.0)


def test_a_strategy_bound_to_a_batch_row_decides_as_its_unbound_twin() -> None:
    """A strategy's state moves with it into a batch's row (``bind``, what an onboard stack
    does): the offset, the conflict history and the acknowledgement's clocks, by UAV id; it
    decides from then on exactly as a twin that was never bound, and the row it left is
    free again."""
    from uavmpc.avoidance.strategy import StrategyTable

    a, b = head_on()
    prm = AvoidanceParams(ack_grace_s=2.0)
    bound_one, twin = HeightOffsetStrategy(prm), HeightOffsetStrategy(prm)
    def deaf_b(now: float) -> PredictionMessage:  # b does not list a: a's clock of it runs
        return replace(msg("b", 2, b, stamp=now), heard=())

    for s in (bound_one, twin):
        first = s.update(NOW, "a", 1, NOW + REL, a, {"b": deaf_b(NOW)})
        assert first.z_offset_m == 0.0 and first.conflicts == ("b",)  # a outranks b
    home = StrategyTable(3)
    home.col_of("x")  # columns of its own: b is not the first one
    old_home = bound_one.home
    bound_one.bind(home, 2)
    assert bound_one.home is home and bound_one.row == 2 and home.bound.tolist() == [
        False, False, True] and not old_home.bound[0]
    for k in range(1, 8):  # b stays deaf to a: after ack_grace_s, a yields to it and climbs
        now = NOW + 0.5 * k
        d1 = bound_one.update(now, "a", 1, now + REL, a, {"b": deaf_b(now)})
        d2 = twin.update(now, "a", 1, now + REL, a, {"b": deaf_b(now)})
        assert d1 == d2
    assert d1.deaf == ("b",) and d1.z_offset_m == 3.0 and bound_one.z_offset_m == 3.0


def test_three_way_conflict_stacks_offsets_by_priority() -> None:
    """Priorities 1, 2, 3 converge on one point at one height → offsets 0, Δz, 2Δz."""
    angles = {"u1": 0.0, "u2": 2 * np.pi / 3, "u3": 4 * np.pi / 3}  # 120° apart
    prio = {"u1": 1, "u2": 2, "u3": 3}

    def nominal(u: str, t: np.ndarray) -> np.ndarray:  # all reach the origin at NOW + 4 s
        a = angles[u]
        return line(t, (-20 * np.cos(a), -20 * np.sin(a), 10.0),
                    (5 * np.cos(a), 5 * np.sin(a), 0.0))

    strat = {u: HeightOffsetStrategy() for u in angles}
    offsets = dict.fromkeys(angles, 0.0)
    history = []
    for rnd in range(4):  # everyone broadcasts, then every UAV decides on what it received
        now = NOW + 0.5 * rnd
        t = now + REL
        inbox = {u: msg(u, prio[u], nominal(u, t) + offsets[u] * UP, stamp=now)
                 for u in angles}
        for u in angles:
            offsets[u] = strat[u].update(now, u, prio[u], t, nominal(u, t), inbox).z_offset_m
        history.append(dict(offsets))
    # Round 1: 2 and 3 both climb one Δz; round 2: 3 sees 2 at its new height and climbs again.
    assert history[0] == {"u1": 0.0, "u2": 3.0, "u3": 3.0}
    assert history[-1] == {"u1": 0.0, "u2": 3.0, "u3": 6.0}


def test_uav_with_its_flag_down_is_yielded_to_whatever_its_priority() -> None:
    a, b = head_on()
    t = NOW + REL
    d = HeightOffsetStrategy().update(NOW, "a", 1, t, a, {"x": msg("x", 9, b, avoiding=False)})
    assert d.z_offset_m == 3.0 and d.yielding_to == ("x",)
    # Same UAV with its flag up: priority 1 does not yield to 9.
    d = HeightOffsetStrategy().update(NOW, "a", 1, t, a, {"x": msg("x", 9, b)})
    assert d.z_offset_m == 0.0 and d.conflicts == ("x",) and d.yielding_to == ()


def test_own_messages_and_those_too_old_or_from_the_future_are_ignored() -> None:
    a, b = head_on()
    t = NOW + REL
    s = HeightOffsetStrategy()
    gone = msg("a", 1, b, stamp=NOW - P.silent_hold_s - 0.05)
    assert s.update(NOW, "b", 2, t, a, {"a": gone}).conflicts == ()
    ahead = msg("a", 1, b, stamp=NOW + 1.05, times=t)
    assert s.update(NOW, "b", 2, t, a, {"a": ahead}).conflicts == ()
    assert s.update(NOW, "b", 2, t, a, {"b": msg("b", 1, b)}).conflicts == ()
    # Stale but recent (silent): its last plan still counts.
    silent = msg("a", 1, b, stamp=NOW - 1.05)
    assert HeightOffsetStrategy().update(NOW, "b", 2, t, a, {"a": silent}).conflicts == ("a",)
    fresh = msg("a", 1, b, stamp=NOW - 0.95)
    assert s.update(NOW, "b", 2, t, a, {"a": fresh}).conflicts == ("a",)


def test_receive_time_fallback_aligns_on_the_receivers_clock() -> None:
    a, _ = head_on()
    t = NOW + REL
    skew = 5000.0  # the sender's clock is far off: its stamps are useless here
    other_t = NOW - 0.7 + REL
    b = line(other_t, (20.0, 0.0, 10.0), (-5.0, 0.0, 0.0))
    m = msg("a", 1, b, stamp=NOW - 0.7 + skew, times=other_t + skew, received_s=NOW - 0.7)
    # By its stamp it is from the future, far off (beyond any clock the inbox measures: it
    # would hold no time of ours for it).
    unplaced = msg("a", 1, b, stamp=NOW - 0.7 + skew, times=other_t + skew)
    assert HeightOffsetStrategy().update(NOW, "b", 2, t, a, {"a": unplaced}).conflicts == ()
    # With a time of ours (the receive-time reference, or a clock the inbox measured off),
    # that time is its reference in either mode.
    assert HeightOffsetStrategy().update(NOW, "b", 2, t, a, {"a": m}).conflicts == ("a",)
    recv = HeightOffsetStrategy(AvoidanceParams(time_reference="receive"))
    d = recv.update(NOW, "b", 2, t, a, {"a": m})
    assert d.conflicts == ("a",) and d.first_conflict_s == pytest.approx(3.61)
    # Staleness also uses the receive time.
    assert recv.update(NOW + 1.0, "b", 2, t + 1.0, a, {"a": m}).conflicts == ()


def run_release(strategy: HeightOffsetStrategy, conflict_until: float, flicker: bool,
                dt: float = 0.1, t_end: float = 12.0) -> list[tuple[float, AvoidanceDecision]]:
    """A hovering higher-priority UAV sits in our path until ``conflict_until`` (s after NOW);
    with ``flicker`` every other message is lost (its last message then goes stale)."""
    own = hover((0.0, 0.0, 10.0))
    out = []
    last_msg: PredictionMessage | None = None
    for k in range(round(t_end / dt) + 1):
        now = NOW + k * dt
        rel = now - NOW
        if rel < conflict_until and not (flicker and k % 12 >= 6):
            last_msg = msg("h", 1, hover((1.0, 0.0, 10.0)), stamp=now)
        if rel >= conflict_until:
            last_msg = msg("h", 1, hover((40.0, 0.0, 10.0)), stamp=now)  # moved away
        others = {} if last_msg is None else {"h": last_msg}
        out.append((rel, strategy.update(now, "o", 2, now + REL, own, others)))
    return out


def test_release_waits_for_the_hysteresis_then_is_rate_limited() -> None:
    hist = run_release(HeightOffsetStrategy(), conflict_until=3.0, flicker=False)
    z = np.array([d.z_offset_m for _, d in hist])
    rel = np.array([r for r, _ in hist])
    assert z.max() == 3.0
    # Climbing over the hovering UAV ends the conflict, but it stays under us until it leaves
    # at 3.0 s: last seen at 2.9 s, so the offset is held until 4.9 s …
    assert np.all(z[(rel > 0.05) & (rel <= 4.9 + 1e-9)] == 3.0)
    # … then released at 2 m/s: 0.2 m per 0.1 s update, down to 0 in 1.5 s.
    after = (rel > 4.9 + 1e-9) & (rel < 6.4 - 1e-9)
    np.testing.assert_allclose(z[after], 3.0 - 2.0 * (rel[after] - 4.9), atol=1e-9)
    assert np.all(np.diff(z[rel > 1.0]) <= 1e-12)  # monotone: no oscillation
    final = hist[-1][1]
    assert final == AvoidanceDecision()  # nominal: no offset, not avoiding, nominal limits
    # Limits were restored when the release began, the flag stays up until the offset is 0.
    d_mid = dict(hist)[rel[after][2]]
    assert d_mid.horizontal_scale == 1.0 and d_mid.climb_speed_mps is None and d_mid.avoiding


def test_flickering_conflict_does_not_make_the_offset_oscillate() -> None:
    """Messages lost 0.6 s in every 1.2 s: the conflict disappears (stale) and comes back;
    the hysteresis keeps the offset and the tightened limits steady until it really ends."""
    hist = run_release(HeightOffsetStrategy(AvoidanceParams(timeout_s=0.3)),
                       conflict_until=6.0, flicker=True)
    stale_gaps = [r for r, d in hist if 0.5 < r < 6.0 and not d.conflicts]
    assert stale_gaps  # the flicker is real: some updates saw no conflict
    in_conflict_phase = [d for r, d in hist if 0.05 < r < 6.0]
    assert all(d.z_offset_m == 3.0 and d.horizontal_scale == 0.5 for d in in_conflict_phase)
    z = np.array([d.z_offset_m for _, d in hist])
    assert np.all(np.diff(z[1:]) <= 1e-12) and z[-1] == 0.0


def test_release_does_not_descend_into_a_uav_on_the_way_down() -> None:
    t = NOW + REL
    own = hover((0.0, 0.0, 10.0))
    s = HeightOffsetStrategy()
    s.update(NOW, "o", 5, t, own, {"a": msg("a", 1, hover((0, 0, 10.0)))})
    s.update(NOW + 0.1, "o", 5, t + 0.1, own, {"a": msg("a", 1, hover((0, 0, 13.0)),
                                                       stamp=NOW + 0.1)})
    assert s.z_offset_m == 6.0
    # The higher-priority UAV leaves; a lower-priority one hovers in our path at nominal + 2 m:
    # no conflict at +6 m (Δz = 4 m), but there would be one on the way down.
    low = hover((1.0, 0.0, 12.0))
    for k in range(2, 80):
        now = NOW + 0.1 * k
        d = s.update(now, "o", 5, now + REL, own, {"l": msg("l", 9, low, stamp=now)})
        assert d.conflicts == () and d.z_offset_m == 6.0 and d.horizontal_scale == 0.5
    # It leaves too: release after the hysteresis, down to 0.
    away = hover((100.0, 0.0, 12.0))
    zs = []
    for k in range(80, 160):
        now = NOW + 0.1 * k
        zs.append(s.update(now, "o", 5, now + REL, own,
                           {"l": msg("l", 9, away, stamp=now)}).z_offset_m)
    assert zs[19] == 6.0 and zs[21] < 6.0 and zs[-1] == 0.0


def test_release_stops_when_a_uav_appears_below() -> None:
    own = hover((0.0, 0.0, 10.0))
    s = HeightOffsetStrategy(AvoidanceParams(release_hysteresis_s=0.0))
    s.update(NOW, "o", 5, NOW + REL, own, {"a": msg("a", 1, hover((0, 0, 10.0)))})
    s.update(NOW + 0.1, "o", 5, NOW + 0.1 + REL, own, {})  # hysteresis 0: release starts
    s.update(NOW + 0.6, "o", 5, NOW + 0.6 + REL, own, {})
    assert s.z_offset_m == pytest.approx(3.0 - 2.0 * 0.6)
    # A lower-priority UAV pops up 2.5 m under our nominal height: outside the cylinder now
    # (Δz = 4.3 m) but inside it at offset 0. The release holds at the current offset.
    low = msg("l", 9, hover((0.0, 0.0, 7.5)), stamp=NOW + 1.0)
    for now in (NOW + 1.0, NOW + 1.5):
        d = s.update(now, "o", 5, now + REL, own, {"l": low})
        assert d.z_offset_m == pytest.approx(1.8) and d.conflicts == ()


def test_ceiling_is_reported_and_offset_bounded() -> None:
    t = NOW + REL
    own = hover((0.0, 0.0, 10.0))
    params = AvoidanceParams(max_offset_m=7.0)  # room for two corrections (6 m), not three
    others = {f"h{i}": msg(f"h{i}", i, hover((0.5, 0.0, 10.0 + 3.0 * i))) for i in range(3)}
    d = HeightOffsetStrategy(params).update(NOW, "o", 9, t, own, others)
    # No offset under the ceiling is clear, and the way up is blocked by h1 and h2: hold.
    assert d.ceiling_hit and d.z_offset_m == 0.0 and d.unresolved == ("h0",)
    assert d.yielding_to == ("h0",) and d.waiting_for == ("h1", "h2")
    # With room (default 30 m) 9 m would be clear, but not the way there through h1 and h2.
    d = HeightOffsetStrategy().update(NOW, "o", 9, t, own, others)
    assert not d.ceiling_hit and d.z_offset_m == 0.0 and d.waiting_for == ("h1", "h2")
    # Without the stack above, the same conflict is cleared at 3 m at once.
    d = HeightOffsetStrategy().update(NOW, "o", 9, t, own, {"h0": others["h0"]})
    assert d.z_offset_m == 3.0 and d.waiting_for == () and d.unresolved == ()


def test_a_climb_waits_for_a_uav_passing_through_the_layer_above() -> None:
    """Found in the 24 h campaign (trial 125): a UAV yielding to a conflict 8 s ahead climbed
    two layers at once, through the layer of a UAV crossing over it 1.6 s later (0.64 m)."""
    t = NOW + REL
    own = line(t, (0.0, 0.0, 10.0), (6.0, 0.0, 0.0))  # us (priority 5), at layer 0
    # uav4 one layer up (+3 m: no conflict), head-on, right above us 1.6 s from now.
    over = msg("u4", 4, line(t, (20.0, 0.0, 13.0), (-6.5, 0.0, 0.0)))
    # uav3 at our layer, in conflict 7.8 s ahead: we must yield (climb) …
    far = msg("u3", 3, hover((6.0 * 7.8, 0.0, 10.0)))
    others = {"u4": over, "u3": far}
    s = HeightOffsetStrategy()
    d = s.update(NOW, "u5", 5, t, own, others)
    assert d.yielding_to == ("u3",)
    # … but +3 m is uav4's layer, +6 m is clear, and the way to it crosses uav4: wait.
    assert d.z_offset_m == 0.0 and d.waiting_for == ("u4",) and d.unresolved == ("u3",)
    assert d.avoiding and d.horizontal_scale < 1.0  # slowed down meanwhile
    # Once uav4 has passed (3.5 s later, 20 m behind us), the climb goes ahead.
    later = NOW + 3.5
    t2 = later + REL
    own2 = line(t2, (6.0 * 3.5, 0.0, 10.0), (6.0, 0.0, 0.0), later)
    over2 = msg("u4", 4, line(t2, (20.0 - 6.5 * 3.5, 0.0, 13.0), (-6.5, 0.0, 0.0), later),
                stamp=later)
    far2 = msg("u3", 3, hover((6.0 * 7.8, 0.0, 10.0)), stamp=later)
    d = s.update(later, "u5", 5, t2, own2, {"u4": over2, "u3": far2})
    assert d.z_offset_m == 3.0 and d.waiting_for == () and d.yielding_to == ("u3",)


def test_offsets_accumulate_in_multiples_of_dz() -> None:
    t = NOW + REL
    own = hover((0.0, 0.0, 10.0))
    s = HeightOffsetStrategy()
    zs = []
    for i, z in enumerate((10.0, 13.0, 16.0)):  # the higher-priority UAV keeps following us
        d = s.update(NOW + 0.5 * i, "o", 2, t + 0.5 * i, own,
                     {"h": msg("h", 1, hover((0, 0, z)), stamp=NOW + 0.5 * i)})
        zs.append(d.z_offset_m)
    assert zs == [3.0, 6.0, 9.0]


def test_params_are_validated_with_named_fields() -> None:
    with pytest.raises(ConfigError, match=r"avoidance\.dz_m: must be > height_m / 2"):
        AvoidanceParams(dz_m=2.9)
    with pytest.raises(ConfigError, match=r"avoidance\.radius_m"):
        AvoidanceParams(radius_m=-1.0)
    with pytest.raises(ConfigError, match=r"avoidance\.horizontal_scale"):
        AvoidanceParams(horizontal_scale=1.5)
    with pytest.raises(ConfigError, match="time_reference"):
        AvoidanceParams(time_reference="gps")
    with pytest.raises(ConfigError, match="max_offset_m: must be ≥ dz_m"):
        AvoidanceParams(max_offset_m=2.0)
    with pytest.raises(ConfigError, match=r"avoidance\.radius: unknown field"):
        AvoidanceParams.from_dict({"radius": 5.0})
    assert AvoidanceParams.from_dict({"dz_m": 4}).dz_m == 4.0


def test_strategy_honours_the_protocol_and_rejects_bad_shapes() -> None:
    s = HeightOffsetStrategy()
    assert isinstance(s, ResolutionStrategy)
    with pytest.raises(ValueError, match=r"positions \(m, 3\)"):
        s.update(NOW, "o", 1, NOW + REL, np.zeros((40, 2)), {})


def test_the_offset_is_not_released_onto_a_uav_that_went_silent() -> None:
    """Found in the 24 h campaign with 30 % loss (trial 48): ten messages in a row from uav3
    were lost, uav4 saw no conflict any more, released its offset and came down onto uav3."""
    own = hover((0.0, 0.0, 10.0))
    s = HeightOffsetStrategy()
    h = hover((1.0, 0.0, 10.0))
    d = s.update(NOW, "o", 2, NOW + REL, own, {"h": msg("h", 1, h)})
    assert d.z_offset_m == 3.0
    # h goes silent where it was. Its last message is stale after 1 s and no evidence of
    # anything, but it was heard 10 s ago at most: no release, so no descent onto it.
    for k in range(1, 100):
        now = NOW + 0.1 * k
        d = s.update(now, "o", 2, now + REL, own, {"h": msg("h", 1, h)})
        assert d.z_offset_m == 3.0, now - NOW
        assert d.silent == (("h",) if now - NOW > 1.0 + 1e-9 else ())
    # Silent for longer than silent_hold_s: taken as gone, and the offset is released.
    released = []
    for k in range(101, 160):
        now = NOW + 0.1 * k
        released.append(s.update(now, "o", 2, now + REL, own, {"h": msg("h", 1, h)}).z_offset_m)
    assert released[-1] == 0.0
    # The old behaviour (silent_hold_s = 0) released 2 s after the last message.
    old = HeightOffsetStrategy(AvoidanceParams(silent_hold_s=0.0))
    old.update(NOW, "o", 2, NOW + REL, own, {"h": msg("h", 1, h)})
    for k in range(1, 50):
        now = NOW + 0.1 * k
        z = old.update(now, "o", 2, now + REL, own, {"h": msg("h", 1, h)}).z_offset_m
    assert z == 0.0


def test_a_new_offset_must_be_clear_of_silent_uavs_too() -> None:
    """Found in the 24 h campaign with 30 % loss (trial 78): uav5 had missed two messages of
    uav2, one layer up, and climbed into that layer to yield to uav1."""
    own = hover((0.0, 0.0, 10.0))
    h = msg("h", 1, hover((1.0, 0.0, 10.0)))  # fresh, in conflict: we must climb
    up = msg("u2", 2, hover((2.0, 0.0, 13.0)), stamp=NOW - 1.5)  # silent for 1.5 s, +3 m
    d = HeightOffsetStrategy().update(NOW, "o", 5, NOW + REL, own, {"h": h, "u2": up})
    assert d.silent == ("u2",) and d.yielding_to == ("h",)
    # +3 m is u2's layer as last heard; +6 m would cross it on the way: wait.
    assert d.z_offset_m == 0.0 and d.waiting_for == ("u2",)
    # Silent for longer than silent_hold_s: no longer evidence, +3 m is taken.
    gone = msg("u2", 2, hover((2.0, 0.0, 13.0)), stamp=NOW - 11.0)
    d = HeightOffsetStrategy().update(NOW, "o", 5, NOW + REL, own, {"h": h, "u2": gone})
    assert d.z_offset_m == 3.0 and d.silent == ()


def test_a_silent_uav_counts_where_it_can_have_gone_since_its_last_plan() -> None:
    """Found in the 24 h campaign with burst loss (trial 25): uav5 hovered at a waypoint 9 m
    beside uav3's announced path; neither heard the other for 5 s, uav5 set off for its next
    waypoint across that path, and they met head-on. Stale for 3 s (4 s old, the timeout 1 s),
    uav5 may be anywhere within ½ · a · t² (capped by the speed) of its last plan:
    uav3's path is within reach, so the UAV that must yield climbs, and the other slows
    down. Just stale (1.1 s old), the plan counts as announced."""
    path = line(NOW + REL, (-20.0, 0.0, 10.0), (5.0, 0.0, 0.0))  # uav3, still heard
    beside = hover((0.0, 9.0, 10.0))  # uav5's last plan, 9 m off the path
    t = NOW + REL
    # Fresh, uav5's plan is clear of the path (9 m > R_p) ...
    d = HeightOffsetStrategy().update(NOW, "uav5", 5, t, beside, {"uav3": msg("uav3", 3, path)})
    assert d.conflicts == () and d.z_offset_m == 0.0
    # ... but when uav5 has not heard uav3 for 4 s, it cannot know uav3 kept to it.
    old_path = line(NOW - 4.0 + REL, (-40.0, 0.0, 10.0), (5.0, 0.0, 0.0), t0=NOW - 4.0)
    d = HeightOffsetStrategy().update(NOW, "uav5", 5, t, beside,
                                      {"uav3": msg("uav3", 3, old_path, stamp=NOW - 4.0)})
    assert d.silent == ("uav3",) and d.yielding_to == ("uav3",) and d.z_offset_m == 3.0
    # uav3 has not heard uav5 for 4 s either: it keeps its height and slows down.
    silent_beside = hover((0.0, 9.0, 10.0))
    d = HeightOffsetStrategy().update(NOW, "uav3", 3, t, path,
                                      {"uav5": msg("uav5", 5, silent_beside, stamp=NOW - 4.0)})
    assert d.conflicts == ("uav5",) and d.z_offset_m == 0.0
    assert d.horizontal_scale == P.horizontal_scale
    just = HeightOffsetStrategy().update(NOW, "uav3", 3, t, path,
                                         {"uav5": msg("uav5", 5, silent_beside, stamp=NOW - 1.1)})
    assert just.silent == ("uav5",) and just.conflicts == ()
    # Without the widening (the limits 0), the silent plan is taken as it was announced.
    still = HeightOffsetStrategy(replace(P, silent_speed_mps=0.0))
    d = still.update(NOW, "uav5", 5, t, beside,
                     {"uav3": msg("uav3", 3, old_path, stamp=NOW - 4.0)})
    assert d.conflicts == () and d.z_offset_m == 0.0


def test_a_climb_ends_clear_of_everyone_when_it_can() -> None:
    """Found in the 24 h campaign with burst loss (trial 24): uav3, yielding to uav2, took the
    lowest layer clear of uav2, which was uav4's; uav4 (the lower priority, which should have
    made way) had not heard uav3 for 3 s and flew on into it. A layer clear of everyone is
    taken when there is one; the lower one only when there is none."""
    t = NOW + REL
    own = line(t, (-20.0, 0.0, 10.0), (5.0, 0.0, 0.0))
    h = msg("h", 1, hover((5.0, 0.0, 10.0)))  # we must yield: conflict 4–6 s ahead
    low = msg("l", 4, line(t, (40.0, 0.0, 13.0), (-5.0, 0.0, 0.0)))  # +3 m, meets us at 5.5 s
    d = HeightOffsetStrategy().update(NOW, "o", 3, t, own, {"h": h, "l": low})
    assert d.yielding_to == ("h",) and d.z_offset_m == 6.0
    # Without l, +3 m; with l the only way under the ceiling, +3 m too.
    assert HeightOffsetStrategy().update(NOW, "o", 3, t, own, {"h": h}).z_offset_m == 3.0
    capped = HeightOffsetStrategy(replace(P, max_offset_m=5.0))
    assert capped.update(NOW, "o", 3, t, own, {"h": h, "l": low}).z_offset_m == 3.0


def test_a_climb_raised_again_mid_climb_starts_from_where_the_uav_is() -> None:
    """The gap closed (docs/campaign.md): with offset 3 m in force but none of it climbed yet,
    a raise to 6 m reaches each height later than a climb from 3 m would. B, passing at the
    6 m layer only while that late climb is still under way, blocks it; the old assumption
    (the climb starts at 3 m) saw the UAV already there and climbed through B."""
    from uavmpc.avoidance.encounters import Encounters
    from uavmpc.avoidance.strategy import _climbed

    prm = AvoidanceParams()
    times = np.r_[0.01, 0.01 + 0.2 * np.arange(1, 40)]
    up = _climbed(np.maximum(times - prm.climb_lag_s, 0.0), prm)  # slow edge, from rest
    t_from_3 = times[np.argmax(3.0 + up >= 6.0)]  # there, starting at the offset in force
    t_from_0 = times[np.argmax(up >= 6.0)]  # there, starting where it is
    assert t_from_0 > t_from_3 + 0.5
    b_near = (times > t_from_3 + 0.05) & (times < t_from_0 - 0.05)
    # A is met once even the slow edge from 0 has reached 3 m (t_from_3, the same curve), so
    # the climb under way to the offset in force is not in A's way (see the next test).
    a_near = times >= t_from_3
    known = Encounters(
        ids=("a", "b"), priority=np.array([1, 9]), avoiding=np.array([True, True]),
        silent_row=np.array([False, False]),
        near_xy=np.vstack([a_near, b_near]),
        dz_m=np.vstack([np.full_like(times, -3.0),   # A in the 3 m layer: we yield, climb
                        np.full_like(times, -6.0)]))  # B in the 6 m layer, passing late
    decisions = {}
    for climbed in (3.0, 0.0):
        s = HeightOffsetStrategy(prm)
        s.z_offset_m = 3.0
        decisions[climbed] = s.decide(100.0, "me", 5, 100.0 + times, known, climbed_m=climbed)
    assert decisions[3.0].z_offset_m == 6.0 and not decisions[3.0].waiting_for
    assert decisions[0.0].z_offset_m == 3.0 and decisions[0.0].waiting_for == ("b",)


def test_a_climb_under_way_stops_where_it_is_when_one_it_yields_to_is_in_its_way() -> None:
    """Found with every fault at once (0.5 h, seed 11, trial 2): a UAV raised far up (to the
    ceiling, nothing being clear) climbed on, yielding now to one hovering above it, straight
    into it. The offset in force is 9 m (for A, in our layer), none of it climbed yet; B, whom
    we yield to too, hovers 7 m up: the way to 9 m passes through it, so the climb stops at
    what it has climbed and says it waits for B. The same UAV with the climb done (9 m
    climbed) escapes B upwards, as before."""
    from uavmpc.avoidance.encounters import Encounters

    prm = AvoidanceParams()
    times = np.r_[0.01, 0.01 + 0.2 * np.arange(1, 40)]
    known = Encounters(
        ids=("a", "b"), priority=np.array([1, 2]), avoiding=np.array([True, True]),
        silent_row=np.array([False, False]),
        near_xy=np.ones((2, times.size), bool),
        dz_m=np.vstack([np.zeros_like(times), np.full_like(times, -7.0)]))
    decisions = {}
    for climbed in (0.0, 9.0):
        s = HeightOffsetStrategy(prm)
        s.z_offset_m = 9.0
        decisions[climbed] = s.decide(100.0, "me", 5, 100.0 + times, known, climbed_m=climbed)
    assert decisions[0.0].z_offset_m == 0.0 and decisions[0.0].waiting_for == ("b",)
    assert decisions[0.0].unresolved == ("a",)  # A is met below: the UAV holds short
    assert decisions[9.0].z_offset_m == 12.0 and not decisions[9.0].waiting_for


def test_a_climb_does_not_close_in_on_a_uav_above_it() -> None:
    """Found in the 24 h campaign with burst loss (trial 12): at +3 m, a UAV we yield to is
    1.5 m above us 1–2 s ahead, still climbing to its layer. Its +6 m layer is not clear at
    the end, +9 m is; the way there passes through it while it is near, so we hold at +3 m
    and say whom we wait for. The same UAV met only 6 s ahead (our climb done by then), or
    below us, does not hold the climb."""
    from uavmpc.avoidance.encounters import Encounters

    prm = AvoidanceParams()
    times = np.r_[0.01, 0.01 + 0.2 * np.arange(1, 40)]

    def decide(near: np.ndarray, dz_plus_offset: float) -> object:
        known = Encounters(
            ids=("a",), priority=np.array([1]), avoiding=np.array([True]),
            silent_row=np.array([False]), near_xy=near[None],
            dz_m=np.full((1, times.size), dz_plus_offset - 3.0))
        s = HeightOffsetStrategy(prm)
        s.z_offset_m = 3.0
        return s.decide(100.0, "me", 5, 100.0 + times, known)

    soon = (times > 1.0) & (times < 2.0)
    held = decide(soon, -1.5)  # a 1.5 m above us, soon
    assert held.yielding_to == ("a",) and held.z_offset_m == 3.0
    assert held.waiting_for == ("a",) and held.unresolved == ("a",)
    later = decide((times > 6.0) & (times < 7.0), -1.5)
    assert later.z_offset_m == 9.0 and not later.waiting_for
    below = decide(soon, 1.5)  # a 1.5 m below us: climbing parts us
    assert below.z_offset_m == 6.0 and not below.waiting_for
    # Level within the collision distance (campaign trial 33: plans 2 cm apart): climbing is
    # the way out, holding would wait level with it.
    level = decide(soon, -0.5)
    assert level.z_offset_m == 9.0 and not level.waiting_for


def test_a_silent_uavs_widening_does_not_hold_a_climb_from_a_known_conflict() -> None:
    """Found in the 24 h campaign with burst loss (trial 18): yielding to a from 8 s ahead,
    the climb waited 7.6 s for s, silent and so possibly anywhere within a radius growing with
    its silence, and started 0.1 s before a passed (1.22 m). The way up is checked along the
    plans as announced; s's announced plan in the way still holds it, and the end layer is
    still chosen clear of the widened plan."""
    from uavmpc.avoidance.encounters import Encounters

    prm = AvoidanceParams()
    times = np.r_[0.01, 0.01 + 0.2 * np.arange(1, 40)]
    a_near = (times > 7.0) & (times < 8.5)  # level with us: we yield and climb
    s_widened = (times > 0.5) & (times < 2.5)  # s 1.5 m above the +3 m layer, on the way

    def decide(s_announced: np.ndarray) -> object:
        known = Encounters(
            ids=("s", "a"), priority=np.array([9, 1]), avoiding=np.array([True, True]),
            silent_row=np.array([True, False]), near_xy=np.vstack([s_widened, a_near]),
            dz_m=np.vstack([np.full(times.size, -4.5), np.zeros(times.size)]),
            silent=("s",), announced_xy=np.vstack([s_announced, a_near]))
        return HeightOffsetStrategy(prm).decide(100.0, "me", 5, 100.0 + times, known)

    free = decide(np.zeros(times.size, dtype=bool))  # s's plan as announced is elsewhere
    assert free.yielding_to == ("a",) and not free.waiting_for
    assert free.z_offset_m == 9.0  # +3 m and +6 m are within 3 m of s's (widened) plan
    held = decide(s_widened)  # s announced right there
    assert held.z_offset_m == 0.0 and held.waiting_for == ("s",)


def test_a_geofence_ceiling_caps_the_offset_and_says_so() -> None:
    a, b = head_on()
    t = NOW + REL
    lo = HeightOffsetStrategy()
    lo.limit_offset(2.0)  # less than one layer (dz 3 m) under the volume's ceiling
    d = lo.update(NOW, "b", 2, t, b, {"a": msg("a", 1, a)})
    assert d.z_offset_m == 0.0 and d.ceiling_hit and d.unresolved == ("a",)
    lo = HeightOffsetStrategy()
    lo.limit_offset(3.0)  # exactly one layer: it fits
    d = lo.update(NOW, "b", 2, t, b, {"a": msg("a", 1, a)})
    assert d.z_offset_m == 3.0 and not d.ceiling_hit
    with pytest.raises(ValueError, match="ceiling_m"):
        lo.limit_offset(float("nan"))


# ---------------------------------------------------------------- the acknowledgement

#: The acknowledgement (on by default, docs/safety.md).
ACK = AvoidanceParams()


def heard_msg(uav_id: str, priority: int, positions: np.ndarray, stamp: float,
              heard: tuple[str, ...]) -> PredictionMessage:
    return PredictionMessage(SCHEMA_VERSION, uav_id, priority, stamp, stamp + REL, positions,
                             True, heard=heard)


def test_a_uav_near_that_does_not_list_us_is_yielded_to_after_the_grace() -> None:
    """The higher priority yields to a lower one whose messages, fresh and near, have not
    listed it for ack_grace_s: it has not heard us and will not climb (a silent radio seen
    from the side that hears)."""
    t0 = NOW
    hi = HeightOffsetStrategy(ACK)
    a, b = head_on()
    decisions = []
    for k in range(6):  # 0, 0.5, ..., 2.5 s: b's messages never list a
        now = t0 + 0.5 * k
        decisions.append(hi.update(now, "a", 1, now + REL, a,
                                   {"b": heard_msg("b", 2, b, now, heard=())}))
    assert all(d.z_offset_m == 0.0 and d.deaf == () for d in decisions[:4])  # < 2 s
    at_grace = decisions[4]
    assert at_grace.deaf == ("b",) and at_grace.yielding_to == ("b",)
    assert at_grace.z_offset_m == P.dz_m and decisions[-1].z_offset_m == P.dz_m


def test_a_waiting_uav_that_lists_us_is_not_taken_for_a_deaf_one() -> None:
    """The case rule 8 got wrong: a lower priority holding its climb (waiting for the way up
    to clear) keeps its plan in conflict with ours, but it lists us: it knows, we hold."""
    hi = HeightOffsetStrategy(ACK)
    a, b = head_on()
    for k in range(8):  # 3.5 s of conflict
        now = NOW + 0.5 * k
        d = hi.update(now, "a", 1, now + REL, a, {"b": heard_msg("b", 2, b, now, ("a",))})
    assert d.conflicts == ("b",) and d.deaf == () and d.z_offset_m == 0.0
    assert not d.unheard


def test_nobody_listing_us_means_nobody_hears_us_and_we_yield_to_everyone_near() -> None:
    """Our radio is silent: no one near lists us. Once one has not for the grace, we yield
    to everyone near, the UAV that came near a moment ago included."""
    me = HeightOffsetStrategy(ACK)
    t = NOW + REL
    own = line(t, (-20.0, 0.0, 10.0), (5.0, 0.0, 0.0))
    ahead = line(t, (20.0, 0.0, 10.0), (-5.0, 0.0, 0.0))  # priority 2: yields to us (1)
    for k in range(5):
        now = NOW + 0.5 * k
        d = me.update(now, "a", 1, now + REL, own, {"c": heard_msg("c", 3, ahead, now, ())})
    assert d.deaf == ("c",) and d.unheard
    assert d.z_offset_m == P.dz_m  # it climbed over c
    # a new one near, in the layer it climbed to, never listed us either: yielded to at
    # once (nobody hears us), though it yields to us by priority
    beside = line(t, (20.0, 1.0, 13.0), (-5.0, 0.0, 0.0))
    now = NOW + 2.5
    d = me.update(now, "a", 1, now + REL, own, {"c": heard_msg("c", 3, ahead, now, ()),
                                                "d": heard_msg("d", 4, beside, now, ())})
    assert d.unheard and d.yielding_to == ("d",) and d.deaf == ("c",)
    assert d.z_offset_m == 2 * P.dz_m
    # one of them lists us again: we are heard, only the deaf one is yielded to
    now = NOW + 3.0
    d = me.update(now, "a", 1, now + REL, own, {"c": heard_msg("c", 3, ahead, now, ()),
                                                "d": heard_msg("d", 4, beside, now, ("a",))})
    assert not d.unheard and d.deaf == ("c",)


def test_the_acknowledgement_is_judged_on_fresh_messages_only_and_can_be_turned_off() -> None:
    a, b = head_on()
    # b's one message stays held while it goes silent: its list is old news, no count starts
    hi = HeightOffsetStrategy(ACK)
    old = heard_msg("b", 2, b, NOW, ())
    for k in range(3, 10):
        now = NOW + 0.5 * k  # 1.5 ... 4.5 s: the message is stale (silent) from 1 s on
        d = hi.update(now, "a", 1, now + REL, a, {"b": old})
    assert d.deaf == () and "b" in d.silent
    off = HeightOffsetStrategy(AvoidanceParams(ack_grace_s=0.0))
    for k in range(8):
        now = NOW + 0.5 * k
        d = off.update(now, "a", 1, now + REL, a, {"b": heard_msg("b", 2, b, now, ())})
    assert d.deaf == () and d.z_offset_m == 0.0
    with pytest.raises(ConfigError, match=r"ack_grace_s: must be 0 \(off\) or ≥ timeout_s"):
        AvoidanceParams(ack_grace_s=0.5)


# ---------------------------------------------------------------- time as well as height


def test_with_no_layer_above_it_goes_down_to_a_clear_one_away_from_a_uav_level_with_it() -> None:
    """docs/safety.md, A6: in the only layer under the ceiling, a higher priority arrives level
    with us (the UAV whose goal our hold point is): nothing is clear above, so down to the
    nearest layer clear of it — the way down escapes it, it is level with us."""
    me = HeightOffsetStrategy()
    me.limit_offset(P.dz_m)  # one layer under the ceiling
    t = NOW + REL
    own = hover((0.0, 0.0, 10.0))
    head_on = line(t, (20.0, 0.0, 10.0), (-5.0, 0.0, 0.0))
    d = me.update(NOW, "b", 2, t, own, {"c": msg("c", 1, head_on)})
    assert d.z_offset_m == P.dz_m  # it climbed over c
    later = NOW + 0.5
    arriving = hover((1.0, 0.0, 10.0 + P.dz_m))  # a, level with us, above our start
    d = me.update(later, "b", 2, later + REL, own, {"a": msg("a", 1, arriving, later)})
    assert d.ceiling_hit and d.z_offset_m == 0.0 and d.unresolved == () and not d.holding


def test_a_hold_goes_on_past_a_uav_it_leaves_behind_but_not_past_one_crossing_its_way() -> None:
    """docs/safety.md, A6. Held short (no layer under the ceiling), 3–4 m from a higher
    priority: parked beside the hold point, going on leaves it behind, so the hold ends; but
    one crossing our way comes closer first, and going on would pass through it (found in the
    lossy 16-UAV antipodal swap: a UAV let go every other round passed one at 1.24 m)."""
    t = NOW + REL
    own = line(t, (0.0, 0.0, 10.0), (2.0, 0.0, 0.0))  # on our way east at 2 m/s
    head_on = msg("c", 1, line(t, (20.0, 0.0, 10.0), (-5.0, 0.0, 0.0)))
    later = NOW + 0.1
    t2 = later + REL
    parked = msg("c", 1, hover((-3.0, 0.0, 10.0)), later)
    crossing = msg("c", 1, line(t2, (3.0, -2.0, 10.0), (0.0, 4.0, 0.0), later), later)
    ends = {}
    for name, other in (("parked", parked), ("crossing", crossing)):
        me = HeightOffsetStrategy()
        me.limit_offset(P.dz_m / 2)  # no layer fits under the ceiling
        d = me.update(NOW, "b", 2, t, own, {"c": head_on})
        assert d.holding and d.unresolved == ("c",)
        ends[name] = not me.update(later, "b", 2, t2, own, {"c": other}).holding
    assert ends == {"parked": True, "crossing": False}


def test_a_uav_standing_in_the_way_of_one_it_yields_to_says_it_cannot_make_way() -> None:
    """Found in the 24 h campaign (trial 42): uav3 waited at its waypoint right under uav5 (one
    layer up, so no way up), and uav1 flew to a waypoint beside it, straight through it. A UAV
    whose plan stands still, with no way up, while one it yields to by priority comes to meet
    it is stuck: it says so (its broadcast flag goes down, and the others yield to it) until
    the conflict is resolved."""
    t = NOW + REL
    here = hover((0.0, 0.0, 10.0))
    h = msg("h", 1, line(t, (-30.0, 0.0, 10.0), (5.0, 0.0, 0.0)))  # reaches us in ~5 s
    above = msg("a", 5, hover((0.5, 0.0, 13.0)))  # lower priority, right above us
    s = HeightOffsetStrategy()
    d = s.update(NOW, "o", 3, t, here, {"h": h, "a": above})
    assert d.yielding_to == ("h",) and d.waiting_for == ("a",) and d.z_offset_m == 0.0
    assert d.stuck and d.unresolved == ("h",)
    # Moving, it can still stop short of h's path: not stuck (it holds short instead).
    moving = line(t, (0.0, -10.0, 10.0), (0.0, 2.0, 0.0))
    d = HeightOffsetStrategy().update(NOW, "o", 3, t, moving,
                                      {"h": h, "a": msg("a", 5, moving + UP3)})
    assert d.unresolved == ("h",) and not d.stuck
    # With a way up (nobody above), it climbs: not stuck.
    d = HeightOffsetStrategy().update(NOW, "o", 3, t, here, {"h": h})
    assert d.z_offset_m == 3.0 and not d.stuck
    # Once h no longer meets it, the flag goes up again.
    gone = msg("h", 1, line(t, (30.0, 20.0, 10.0), (5.0, 0.0, 0.0)))
    d = s.update(NOW + 0.1, "o", 3, t + 0.1, here, {"h": gone, "a": above})
    assert not d.stuck
    # Never stuck for a UAV yielded to for its flag (found with every fault at once: two
    # stuck UAVs lowering their flags for each other), nor for one already in conflict now
    # (both hovering: nobody comes to meet it).
    down = msg("h", 1, line(t, (-30.0, 0.0, 10.0), (5.0, 0.0, 0.0)), avoiding=False)
    d = HeightOffsetStrategy().update(NOW, "o", 3, t, here, {"h": down, "a": above})
    assert d.unresolved == ("h",) and not d.stuck
    beside = msg("h", 1, hover((3.0, 0.0, 10.0)))
    d = HeightOffsetStrategy().update(NOW, "o", 3, t, here, {"h": beside, "a": above})
    assert d.unresolved == ("h",) and not d.stuck


def test_a_stuck_uav_broadcasts_its_flag_down_and_the_others_yield_to_it() -> None:
    """Trial 42 of the 24 h campaign (seed 0), flown to past its collision (52.4 s, uav1 into
    uav3 at 0.40 m): uav3 says it is stuck, uav1 yields and climbs over it."""
    from uavmpc.apps.campaign import RandomWalkSpec, trial_run
    from uavmpc.drivers.world import World
    from uavmpc.scenarios.run import RunSettings

    world = World(trial_run(RandomWalkSpec(run=RunSettings(avoidance=True)), 42))
    flags = []
    world.wire.publish = lambda stacks, data, now, send=world.wire.publish: (
        flags.extend((s.uav_id, s.steering.decision is not None
                      and s.steering.decision.stuck) for s in stacks),
        send(stacks, data, now))
    r = world.run(60.0)
    assert not r.collisions and float(np.min(r.min_distance_m)) > 2.0
    assert ("uav3", True) in flags  # it said so


def test_the_cylinders_kernels_are_its_law_point_by_point() -> None:
    """The compiled cylinder (``conflict_points``) and its summaries for a decision
    (``conflict_rows``: who conflicts, from which point; ``conflict_below``: the way down)
    against the law written with numpy, over random encounters with heights on and near the
    cylinder's edge, widened pairs and several offsets."""
    from uavmpc.avoidance.strategy import conflict_below, conflict_points, conflict_rows

    rng = np.random.default_rng(7)
    half = 2.995
    for _ in range(300):
        k, m = int(rng.integers(0, 5)), int(rng.integers(1, 13))
        near = rng.random((k, m)) < 0.6
        dz = rng.choice([-6.0, -3.0, -2.995, 0.0, 2.995, 3.0, 9.0], size=(k, m))
        dz = dz + rng.normal(size=(k, m)) * rng.choice([0.0, 0.01, 2.0])
        widen = rng.random(k) * rng.choice([0.0, 1.0])
        offsets = rng.choice([0.0, 3.0, 6.0, 0.005], size=3)
        h = half + widen[:, None]
        pts = np.empty((3, k, m), dtype=bool)
        conflict_points(near, dz, widen, half, offsets, pts)
        for c, off in enumerate(offsets):
            law = near & (np.abs(dz + off) <= h)
            assert np.array_equal(pts[c], law)
            hit = np.empty(k, dtype=bool)
            first = conflict_rows(near, dz, widen, half, float(off), hit)
            assert np.array_equal(hit, law.any(axis=1))
            cols = np.flatnonzero(law.any(axis=0))
            assert first == (cols[0] if cols.size else -1)
            way_down = near & (dz >= -h - off) & (dz <= h)
            assert conflict_below(near, dz, widen, half, float(off)) == bool(way_down.any())


def test_a_climb_whose_lift_is_dropped_is_braked_as_hard_as_it_started() -> None:
    """A conflict over, a decision drops the lifted climb while the virtual UAV still climbs
    at 4.5 m/s: it is braked at the lifted 3 m/s² until it is back within the nominal speeds
    (at the nominal 1 m/s² it went on 10 m past its offset: found by the falsifier, a walk on
    single-band GNSS 2.9 m over the ceiling by its truth), then flies the nominal limits and
    comes to rest."""
    from uavmpc.avoidance.strategy import CALM
    from uavmpc.onboard import OnboardStack
    from uavmpc.plant.airframe import Airframe
    from uavmpc.reference import Reference

    stack = OnboardStack(Airframe.named("f550"), position_m=(0.0, 0.0, 20.0), uav_id="a",
                         priority=1, avoidance=HeightOffsetStrategy())
    stack.set_mission(Reference.goto(0.0, 0.0, 20.0))
    steering, tracker = stack.steering, stack.tracker
    nominal = steering.nominal_limits
    steering.apply(AvoidanceDecision(z_offset_m=0.0, avoiding=True, climb_speed_mps=5.0,
                                     climb_accel_mps2=3.0))
    state = tracker.state
    state[2, 1], state[2, 2] = 4.5, 0.0
    tracker.set_state(state)
    steering.apply(CALM)
    assert tracker.limits.descend_accel_mps2 == 3.0
    assert tracker.limits.ascend_speed_mps == nominal.ascend_speed_mps
    top, steps = 20.0, 0
    while tracker.state[2, 1] > 0.0 and steps < 2000:
        tracker.step()
        steering.apply(CALM)  # each round looks again while it brakes
        top, steps = max(top, float(tracker.state[2, 0])), steps + 1
    # 4.5²/(2·3) = 3.4 m to the nominal speed and its stop, not 4.5²/2 = 10 m
    assert top - 20.0 < 4.5**2 / (2 * 3.0) + nominal.ascend_speed_mps**2 / 2.0
    assert tracker.limits == nominal  # back within the nominal speeds: nominal limits
