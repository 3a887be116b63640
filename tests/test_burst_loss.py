"""Burst loss on the simulated link: the two-state Gilbert channel per directed pair."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from uavmpc import scenarios
from uavmpc.comms.link import SimulatedLink
from uavmpc.config import ConfigError
from uavmpc.scenarios import LinkSettings
from uavmpc.scenarios.run import RunSpec

P, L = 0.3, 4.0


def lost_copies(link: SimulatedLink, senders: list[str], receivers: list[str],
                n: int) -> dict[tuple[str, str], np.ndarray]:
    """Publish ``n`` rounds (every sender once per round, no delay); the loss indicator of
    every (sender, receiver) pair, per round."""
    for k in range(n):
        for s in senders:
            link.publish(b"%s %d" % (s.encode(), k), s, 0.01 * k)
    out = {}
    for r in receivers:
        got = np.zeros((len(senders), n), dtype=bool)
        for data in link.receive(r, 1e9):
            s, k = data.split()
            got[senders.index(s.decode()), int(k)] = True
        for i, s in enumerate(senders):
            if s != r:
                out[(s, r)] = ~got[i]
    return out


def runs_of_losses(lost: np.ndarray) -> np.ndarray:
    """Lengths of the maximal runs of consecutive losses."""
    edges = np.diff(np.concatenate(([0], lost.astype(np.int8), [0])))
    return np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)


def trace(seed: int, **kwargs: float) -> list[tuple[str, float, bytes]]:
    where = {"a": np.zeros(3), "b": np.array([60.0, 0, 0]), "c": np.array([0, 150.0, 0])}
    link = SimulatedLink(["a", "b", "c"], latency_s=0.02, jitter_s=0.2, loss=0.4,
                         range_m=100.0, position_of=where.get, seed=seed, **kwargs)
    out = []
    for k in range(300):
        t = 0.05 * k
        where["c"] = np.array([0, 150.0 - k, 0])  # flies into range half-way
        if k == 100:
            link.join("d")  # no position: out of range
        link.publish(b"a%d" % k, "a", t)
        link.publish(b"c%d" % k, "c", t)
        for r in ("a", "b", "c", "d"):
            out += [(r, t, d) for d in link.receive(r, t)]
    return out


def test_burst_len_zero_is_todays_independent_loss() -> None:
    assert trace(3, burst_len=0.0) == trace(3)
    # Pinned from the link before the burst model existed: the i.i.d. stream is unchanged.
    link = SimulatedLink(["a", "b"], loss=0.3, seed=3, burst_len=0.0)
    lost = lost_copies(link, ["a"], ["b"], 40)[("a", "b")]
    assert np.flatnonzero(lost).tolist() == [0, 2, 8, 10, 11, 14, 17, 18, 30, 37, 38, 39]


def test_bursts_keep_the_loss_rate_and_lengthen_the_runs() -> None:
    n = 20_000
    bursty = lost_copies(SimulatedLink(["a", "b"], loss=P, burst_len=L, seed=1),
                         ["a", "b"], ["a", "b"], n)
    iid = lost_copies(SimulatedLink(["a", "b"], loss=P, seed=1), ["a", "b"], ["a", "b"], n)
    # Loss indicators of a Gilbert chain are correlated, rho_k = lam^k with
    # lam = 1 - p - r = 0.643: var(mean) = P (1 - P) / n * (1 + lam) / (1 - lam), a standard
    # error of 0.007 per pair (0.005 over both): ±0.02 is about 3 of them per pair.
    for pair in (("a", "b"), ("b", "a")):
        assert bursty[pair].mean() == pytest.approx(P, abs=0.02)
        assert iid[pair].mean() == pytest.approx(P, abs=0.02)
    # Runs are geometric: mean L = 4, sd sqrt(1 - r) / r = 3.5, about n P / L = 1500 runs a
    # pair, a standard error of 0.06 over both pairs; i.i.d. runs have mean 1 / (1 - P) = 1.43,
    # standard error 0.009.
    bursty_runs = np.concatenate([runs_of_losses(v) for v in bursty.values()])
    iid_runs = np.concatenate([runs_of_losses(v) for v in iid.values()])
    assert bursty_runs.mean() == pytest.approx(L, abs=0.3)
    assert iid_runs.mean() == pytest.approx(1.0 / (1.0 - P), abs=0.05)
    link = SimulatedLink(["a", "b"], loss=P, burst_len=L, seed=2)
    lost = lost_copies(link, ["a"], ["b"], 5000)[("a", "b")]
    assert link.stats.dropped == int(lost.sum())  # a burst loss is counted as a loss
    assert link.stats.in_flight == 0


def test_pairs_lose_independently() -> None:
    n = 20_000
    link = SimulatedLink(["a", "b", "c"], loss=P, burst_len=L, seed=4)
    lost = lost_copies(link, ["a", "b"], ["a", "b", "c"], n)
    # Two autocorrelated indicator series, independent: the sample correlation has variance
    # (1 + lam^2) / (1 - lam^2) / n, a standard error of 0.011. A shared chain would give 1.
    for one, two in ((("a", "b"), ("a", "c")),  # two receivers of one sender
                     (("a", "b"), ("b", "a")),  # the two directions of a pair
                     (("a", "c"), ("b", "c"))):  # two senders to one receiver
        assert abs(np.corrcoef(lost[one], lost[two])[0, 1]) < 0.05
        assert np.mean(lost[one] & lost[two]) == pytest.approx(P * P, abs=0.02)


def test_out_of_range_copies_do_not_step_the_chain() -> None:
    # loss 0.5 with bursts of 1: p = r = 1, a pair's copies alternate lost / delivered exactly,
    # so a gap that stepped the chain (or storage that forgot it) would show up as two equal
    # outcomes in a row.
    where = {"a": np.zeros(3), "b": np.array([10.0, 0, 0]), "c": np.array([20.0, 0, 0])}
    link = SimulatedLink(["a", "b", "c"], loss=0.5, burst_len=1.0, range_m=100.0,
                         position_of=where.get, seed=6)
    gap = range(20, 23)  # b is away: 3 copies of each of its 4 pairs are not sent
    joins = {10: 1, 30: 3, 45: 6}  # late members without a position: the storage grows 3 times
    for k in range(60):
        where["b"] = np.array([500.0 if k in gap else 10.0, 0, 0])
        for _ in range(joins.get(k, 0)):
            link.join(f"late{len(link.members)}")
        for s in "abc":
            link.publish(b"%s %d" % (s.encode(), k), s, 0.01 * k)
    got = {r: link.receive(r, 1e9) for r in "abc"}
    for s in "abc":
        for r in "abc":
            if s == r:
                continue
            sent = [k for k in range(60) if not ("b" in (s, r) and k in gap)]
            outcome = np.array([b"%s %d" % (s.encode(), k) in got[r] for k in sent], np.int8)
            assert np.all(np.diff(outcome) != 0), (s, r)
    late_copies = 3 * (1 * 20 + 4 * 15 + 10 * 15)
    assert link.stats.dropped_range == 4 * len(gap) + late_copies


def test_first_copies_are_lost_at_the_stationary_rate() -> None:
    # 200 members, one broadcast each: 39 800 pairs, each at its first copy. A chain started
    # in Good would lose p = 0.107 of them, not P (standard error 0.0023).
    link = SimulatedLink([f"u{i}" for i in range(200)], loss=P, burst_len=L, seed=8)
    for uav in link.members:
        link.publish(b"x", uav, 0.0)
    assert link.stats.dropped / link.stats.sent == pytest.approx(P, abs=0.01)


def test_bursty_link_is_deterministic_per_seed() -> None:
    assert trace(1, burst_len=L) == trace(1, burst_len=L)
    assert trace(1, burst_len=L) != trace(2, burst_len=L)
    assert trace(1, burst_len=L) != trace(1)


@pytest.mark.parametrize("burst_len", [0.5, -1.0, float("nan"), float("inf")])
def test_link_rejects_a_bad_burst_len(burst_len: float) -> None:
    with pytest.raises(ValueError, match="burst_len"):
        SimulatedLink(["a", "b"], loss=0.3, burst_len=burst_len)


def test_link_rejects_bursts_too_short_for_the_loss() -> None:
    with pytest.raises(ValueError, match=r"burst_len=1.5 with loss=0.9 needs P\(good→bad\) = 6 "
                                         r"> 1"):
        SimulatedLink(["a", "b"], loss=0.9, burst_len=1.5)
    with pytest.raises(ValueError, match="burst_len"):
        SimulatedLink(["a", "b"], loss=1.0, burst_len=2.0)
    SimulatedLink(["a", "b"], loss=0.5, burst_len=1.0)  # p = 1 exactly: allowed
    SimulatedLink(["a", "b"], loss=0.9, burst_len=9.0)


@pytest.mark.parametrize("table", [{"burst_len": 0.5}, {"burst_len": -1}, {"burst_len": "4"},
                                   {"burst_len": float("nan")},
                                   {"loss": 0.9, "burst_len": 1.5}])
def test_link_settings_reject_a_bad_burst_len(table: dict[str, object]) -> None:
    with pytest.raises(ConfigError, match=r"link\.burst_len"):
        LinkSettings.from_dict(table)


def test_scenario_burst_len_reaches_the_world_link(tmp_path: Path) -> None:
    from uavmpc.drivers.world import World

    text = resources.files("uavmpc.scenarios").joinpath("converge_center.toml").read_text()
    path = tmp_path / "bursty.toml"
    path.write_text(text.replace("loss = 0.0", "loss = 0.3\nburst_len = 4.0"))
    sc = scenarios.load(path)
    assert sc.link == LinkSettings(latency_s=0.05, jitter_s=0.02, loss=0.3, burst_len=4.0)
    assert LinkSettings.from_dict({}).burst_len == 0.0
    assert World(RunSpec(sc)).link.burst_len == 4.0
