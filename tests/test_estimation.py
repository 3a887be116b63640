"""The GNSS error model, the accelerometer model and the observer (uavmpc.estimation).

Statistical tests use fixed seeds, so each is deterministic; their tolerances are what a
correct implementation would meet for almost every seed (stated per test), so a failure means
the law is wrong, not that the seed was unlucky.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.stats import chi2

from uavmpc.config import ConfigError
from uavmpc.estimation import (
    BA,
    BG,
    GNSS_NORMALS,
    IMU_NORMALS,
    N_STATE,
    POS,
    VEL,
    GnssModel,
    ImuModel,
    ObserverParams,
    gnss_step,
    gnss_table,
    imu_step,
    imu_table,
    initial_accel_bias,
    initial_bias,
    observer_correct,
    observer_init,
    observer_noise,
    observer_predict,
)

DT = 0.01  # the control tick [s]
PERFECT_IMU = ImuModel(0.0, 0.0, 300.0)


def perfect(model: GnssModel) -> GnssModel:
    """``model`` with every σ zero (same rate and τ): fixes equal the truth."""
    return GnssModel(0.0, 0.0, 0.0, 0.0, model.bias_tau_s, 0.0, 0.0, model.rate_hz)


# --- the GNSS model's statistics ------------------------------------------------------------


def _autocov(e: np.ndarray, lag: int) -> np.ndarray:
    """Per series (columns of e (T, K)) the mean of e[t] e[t + lag]: the autocovariance at
    ``lag`` (the error's mean is known to be zero, so nothing is subtracted)."""
    t = e.shape[0] - lag
    return np.einsum("tk,tk->k", e[:t], e[lag:]) / t


def _check_mean(samples: np.ndarray, expected: float, what: str, power: float = 0.1) -> None:
    """The mean of independent per-row estimates equals ``expected`` within 4 standard errors
    (a correct model fails this with probability ≈ 6e-5 per check), and the test has power: the
    standard error is below ``power`` × |expected| (or tiny if expected is 0)."""
    mean = samples.mean()
    se = samples.std(ddof=1) / math.sqrt(samples.size)
    scale = abs(expected) if expected != 0.0 else 1.0
    assert se < power * scale, f"{what}: too few samples to test (SE {se:.3g})"
    assert abs(mean - expected) < 4.0 * se, (
        f"{what}: measured {mean:.5g} ± {se:.2g}, model {expected:.5g}")


@pytest.mark.parametrize("preset", ["single", "rtk"])
def test_gnss_error_statistics_match_the_model(preset: str) -> None:
    """200 UAVs × 600 s of fixes: per axis class (east and north pooled, up apart) the error's
    variance, its autocovariance at lags of 1 fix, τ/2 and τ, the half mean square of the
    fix-to-fix change, and the velocity error's variance and lag-1 covariance match the model:

    C(0) = σ_b² + σ_w², C(L > 0) = σ_b² exp(−L Δ/τ), ½ E[(e_{t+1} − e_t)²] = σ_w² + σ_b²
    (1 − exp(−Δ/τ)), var(e_v) = σ_v², C_v(1) = 0.

    Each row's estimate is independent of the others' (rows draw separate normals; biases start
    stationary), so the spread of the 200 (400 pooled) estimates gives the standard error of
    their mean and the tolerance is 4 of those (`_check_mean`): no hand-tuned percentages. A
    600 s run holds only 5–10 bias correlation times per row, hence the many rows."""
    model = GnssModel.preset(preset)
    n, duration = 200, 600.0
    rng = np.random.default_rng(11)
    table = gnss_table(model, n)
    bias = initial_bias(table, rng)
    fixes = round(duration * model.rate_hz)
    truth_p = rng.uniform(-100.0, 100.0, (n, 3))  # the error must not depend on where the UAV is
    truth_v = rng.uniform(-5.0, 5.0, (n, 3))
    zp = np.empty((n, 3))
    zv = np.empty((n, 3))
    ep = np.empty((fixes, n, 3))
    ev = np.empty((fixes, n, 3))
    for f in range(fixes):
        gnss_step(bias, truth_p, truth_v, model.period_s, table,
                  rng.standard_normal((n, GNSS_NORMALS)), zp, zv)
        ep[f] = zp - truth_p
        ev[f] = zv - truth_v
    a = math.exp(-model.period_s / model.bias_tau_s)
    lag_half = round(0.5 * model.bias_tau_s * model.rate_hz)
    lag_tau = round(model.bias_tau_s * model.rate_hz)
    for axes, sb, sw, sv in (
        ([0, 1], model.horizontal_bias_sigma_m, model.horizontal_white_sigma_m,
         model.horizontal_velocity_sigma_mps),
        ([2], model.vertical_bias_sigma_m, model.vertical_white_sigma_m,
         model.vertical_velocity_sigma_mps),
    ):
        e = ep[:, :, axes].reshape(fixes, -1)
        w = ev[:, :, axes].reshape(fixes, -1)
        label = f"{preset} axes {axes}"
        _check_mean(_autocov(e, 0), sb * sb + sw * sw, f"{label} variance")
        _check_mean(_autocov(e, 1), sb * sb * a, f"{label} lag 1")
        _check_mean(_autocov(e, lag_half), sb * sb * a**lag_half, f"{label} lag τ/2", power=0.2)
        _check_mean(_autocov(e, lag_tau), sb * sb * a**lag_tau, f"{label} lag τ", power=0.25)
        jitter = 0.5 * np.mean(np.diff(e, axis=0) ** 2, axis=0)
        _check_mean(jitter, sw * sw + sb * sb * (1.0 - a), f"{label} fix-to-fix", power=0.02)
        _check_mean(_autocov(w, 0), sv * sv, f"{label} velocity variance", power=0.02)
        _check_mean(_autocov(w, 1) / (sv * sv), 0.0, f"{label} velocity lag 1", power=0.01)


def test_accelerometer_statistics_match_the_model() -> None:
    """100 UAVs × 60 s at 100 Hz, at rest: the sample noise has variance N_a²/dt and no lag-1
    correlation (white), the bias has variance σ_b² (tolerances as in `_check_mean`; the bias
    starts stationary, so even a run shorter than τ samples its variance, one draw per row)."""
    model = ImuModel()
    n, ticks = 100, 6_000
    rng = np.random.default_rng(12)
    table = imu_table(model, n)
    bias = initial_accel_bias(table, rng)
    out = np.empty((n, 3))
    meas = np.empty((ticks, n, 3))
    biases = np.empty((ticks, n, 3))
    for k in range(ticks):
        biases[k] = bias
        imu_step(bias, np.zeros((n, 3)), DT, table, rng.standard_normal((n, IMU_NORMALS)), out)
        meas[k] = out
    white = (meas - biases).reshape(ticks, -1)
    var = model.noise_density_mps2_rthz**2 / DT
    _check_mean(_autocov(white, 0), var, "white variance", power=0.01)
    _check_mean(_autocov(white, 1) / var, 0.0, "white lag 1", power=0.01)
    _check_mean(_autocov(biases.reshape(ticks, -1), 0), model.bias_sigma_mps2**2,
                "bias variance", power=0.15)


# --- the observer on a known trajectory -----------------------------------------------------


def true_accel(t: float, phase: np.ndarray) -> np.ndarray:
    """(N, 3) the test trajectory's acceleration [m/s²]: a 5 m sinusoid of period 15.7 s in x
    (±0.8 m/s²), constant y, and a climb in z (0.5 m/s² for 1 s, then 0.5 m/s up)."""
    a = np.zeros((phase.shape[0], 3))
    a[:, 0] = -5.0 * 0.4**2 * np.sin(0.4 * t + phase)
    if t < 1.0:
        a[:, 2] = 0.5
    return a


@dataclass
class Flight:
    """What `fly` measured over the fixes from ``settle_s`` on (per ENU axis unless said):
    RMS of the fix error (raw) and of the estimate error against the truth, position [m] and
    velocity [m/s]; RMS of the change a correction makes to the estimate (``jump``) and of the
    raw fix error's change from one fix to the next (``raw_jitter``); the largest estimate
    errors; per row the time-averaged NEES of (p, v) summed over the three axes (the whole
    flight); the ANEES over rows every 30 s; the final x and P."""

    raw_p: np.ndarray
    est_p: np.ndarray
    raw_v: np.ndarray
    est_v: np.ndarray
    jump_p: np.ndarray
    jump_v: np.ndarray
    raw_jitter: np.ndarray
    max_p: float
    max_v: float
    nees_rows: np.ndarray
    anees: list[float]
    x: np.ndarray
    P: np.ndarray


def fly(gnss: GnssModel, imu: ImuModel, params: ObserverParams, n: int, duration_s: float,
        seed: int, *, settle_s: float = 10.0, start_error: np.ndarray | None = None) -> Flight:
    """N UAVs fly the test trajectory with the simulated sensors ``gnss``, ``imu`` and a filter
    assuming ``params``; the world's tick order: IMU sample, truth advance, predict, then at a
    fix tick the fix and the correction.

    The truth integrates the acceleration held over each tick exactly (as an IMU's Δv
    describes it), the accelerometer measures that same acceleration: the filter's discrete
    model is then exact, and any inconsistency or noiseless error is the filter's fault."""
    rng = np.random.default_rng(seed)
    gt = gnss_table(gnss, n)
    it = imu_table(imu, n)
    noise = observer_noise(params, n)
    phase = rng.uniform(0.0, 2.0 * np.pi, n)
    p = np.zeros((n, 3))
    v = np.zeros((n, 3))
    p[:, 0] = 5.0 * np.sin(phase)
    v[:, 0] = 2.0 * np.cos(phase)
    p[:, 1] = rng.uniform(-50.0, 50.0, n)
    p[:, 2] = 10.0
    gb = initial_bias(gt, rng)
    ab = initial_accel_bias(it, rng)
    zp = np.empty((n, 3))
    zv = np.empty((n, 3))
    am = np.empty((n, 3))
    every = gnss.ticks_per_fix(DT)
    gnss_step(gb, p, v, gnss.period_s, gt, rng.standard_normal((n, GNSS_NORMALS)), zp, zv)
    x = np.empty((n, 3, N_STATE))
    P = np.empty((n, 3, N_STATE, N_STATE))
    observer_init(x, P, zp, zv, noise)
    if start_error is not None:
        x += start_error
    sums = {k: np.zeros(3) for k in ("raw_p", "est_p", "raw_v", "est_v", "jump_p", "jump_v",
                                     "raw_jitter")}
    count = 0
    max_p = max_v = 0.0
    nees_rows = np.zeros(n)
    anees: list[float] = []
    fixes = 0
    last_raw = zp - p
    for k in range(round(duration_s / DT)):
        a = true_accel(k * DT, phase)
        imu_step(ab, a, DT, it, rng.standard_normal((n, IMU_NORMALS)), am)
        p += v * DT + 0.5 * a * DT * DT
        v += a * DT
        observer_predict(x, P, am, DT, noise)
        if (k + 1) % every:
            continue
        gnss_step(gb, p, v, gnss.period_s, gt, rng.standard_normal((n, GNSS_NORMALS)), zp, zv)
        before_p = x[:, :, POS].copy()
        before_v = x[:, :, VEL].copy()
        observer_correct(x, P, zp, zv, noise)
        fixes += 1
        ep = x[:, :, POS] - p
        ev = x[:, :, VEL] - v
        ppp, ppv, pvv = P[:, :, POS, POS], P[:, :, POS, VEL], P[:, :, VEL, VEL]
        nees = ((pvv * ep * ep - 2.0 * ppv * ep * ev + ppp * ev * ev)
                / (ppp * pvv - ppv * ppv)).sum(axis=1)
        nees_rows += nees
        t = (k + 1) * DT
        if fixes % round(30.0 * gnss.rate_hz) == 0:
            anees.append(float(nees.mean()))
        raw = zp - p
        if t >= settle_s:
            count += 1
            for key, val in (("raw_p", raw), ("est_p", ep), ("raw_v", zv - v), ("est_v", ev),
                             ("jump_p", x[:, :, POS] - before_p),
                             ("jump_v", x[:, :, VEL] - before_v),
                             ("raw_jitter", raw - last_raw)):
                sums[key] += np.mean(val * val, axis=0)
            max_p = max(max_p, float(np.abs(ep).max()))
            max_v = max(max_v, float(np.abs(ev).max()))
        last_raw = raw
    rms = {key: np.sqrt(val / count) for key, val in sums.items()}
    return Flight(**rms, max_p=max_p, max_v=max_v, nees_rows=nees_rows / fixes, anees=anees,
                  x=x, P=P)


#: Per preset, bounds on what `fly` measures for 200 UAVs × 300 s with matched sensors and
#: filter. Measured (seed 1, east/north/up): rtk — raw fix error 12.4/12.3/23.6 mm, estimate
#: 11.5/11.4/21.9 mm; velocity 50/50/80 mm/s raw, 18.7/18.7/22.9 mm/s estimate; a correction
#: moves the position by 6.3/6.3/8.5 mm and the velocity by 16 mm/s RMS (the raw fix jitters by
#: 9.9/9.9/17 mm). single — raw 1.59/1.58/2.46 m, estimate 1.28/1.26/1.96 m (the Doppler-
#: integrated track lets the filter see part of the bias's mean reversion); velocity 22.4/22.5/
#: 29.1 mm/s; a correction moves the position by 21/21/35 mm and the velocity by 11 mm/s (the
#: raw fix jitters by 0.43/0.43/0.71 m).
#: Bounds: (est/raw position ratio, horizontal and vertical velocity RMS [m/s], position
#: correction / raw jitter ratio, velocity correction RMS [m/s]).
BOUNDS = {
    "rtk": (0.96, 0.025, 0.03, 0.75, 0.022),
    "single": (0.90, 0.03, 0.04, 0.1, 0.015),
}


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["rtk", "single"])
def test_observer_beats_raw_gnss_and_is_consistent(preset: str) -> None:
    """Matched filter, 200 UAVs × 300 s on the test trajectory.

    Accuracy and smoothness: the position estimate's error is below the raw fixes' (the white
    part is filtered; with Doppler velocity also part of the bias), the velocity estimate is
    within a few cm/s, and a correction moves the estimate by a small fraction of the raw fixes'
    jitter (the controller sees no steps) — bounds and measured numbers in :data:`BOUNDS`.

    Consistency (NEES): the filter estimates the true p (its b_g state takes the receiver's
    bias), and its P[p, p] already contains the part of the bias it cannot tell from a
    displacement (p and b_g are only seen as their sum, and separate only through the bias's
    slow mean reversion). So the (p, v) error against the *truth* — not against truth + bias —
    is what P describes: for a consistent filter ``e_axisᵀ P_pv⁻¹ e_axis`` is χ²(2) per axis,
    χ²(6) per UAV summed over the independent axes, and the sum over N UAVs χ²(6N). Checked
    twice: every 30 s the ANEES over the 200 rows is inside the two-sided 99.9 % χ²(1200)/200
    interval [5.23, 6.84] (10 snapshots: a correct filter fails one with probability ≈ 1 %); and
    the per-row time-averaged NEES (independent rows) has mean 6 within 4 standard errors."""
    gnss = GnssModel.preset(preset)
    imu = ImuModel()
    n = 200
    got = fly(gnss, imu, ObserverParams(gnss, imu), n, 300.0, seed=1)
    # The figures of docs/faults.md (pytest -s shows them).
    print(f"\n{preset}: position RMS raw {np.round(got.raw_p, 4)} m, estimate "
          f"{np.round(got.est_p, 4)} m; velocity RMS estimate {np.round(got.est_v, 4)} m/s; "
          f"time-averaged NEES {np.mean(got.nees_rows):.2f} (6 expected)")
    pos_ratio, vh, vv, jump_ratio, jump_v = BOUNDS[preset]
    assert np.all(got.est_p < pos_ratio * got.raw_p), (got.est_p, got.raw_p)
    assert np.all(got.est_v[:2] < vh) and got.est_v[2] < vv, got.est_v
    assert np.all(got.est_v < 0.5 * got.raw_v), (got.est_v, got.raw_v)
    assert np.all(got.jump_p < jump_ratio * got.raw_jitter), (got.jump_p, got.raw_jitter)
    assert np.all(got.jump_v < jump_v), got.jump_v
    dof = 6 * n
    lo, hi = chi2.ppf(0.0005, dof) / n, chi2.ppf(0.9995, dof) / n
    assert len(got.anees) == 10
    assert all(lo < a < hi for a in got.anees), (lo, hi, got.anees)
    _check_mean(got.nees_rows, 6.0, f"{preset} time-averaged NEES")


def test_nees_exposes_a_filter_that_takes_the_bias_for_white_noise() -> None:
    """The consistency check has teeth: a filter without the bias state, its R inflated to the
    fix's whole error variance σ_b² + σ_w², averages the bias away over a few fixes and claims
    a far smaller P than its real error (measured ANEES 710 and 835 at 30 s and 60 s for
    ``single``, against 6 and a 99.95 % bound of 7.2)."""
    gnss = GnssModel.preset("single")
    white = dataclasses.replace(
        gnss, horizontal_bias_sigma_m=0.0, vertical_bias_sigma_m=0.0,
        horizontal_white_sigma_m=float(np.hypot(gnss.horizontal_bias_sigma_m,
                                                gnss.horizontal_white_sigma_m)),
        vertical_white_sigma_m=float(np.hypot(gnss.vertical_bias_sigma_m,
                                              gnss.vertical_white_sigma_m)))
    n = 100
    got = fly(gnss, ImuModel(), ObserverParams(white, ImuModel()), n, 60.0, seed=2)
    assert got.anees and min(got.anees) > 10.0 * chi2.ppf(0.9995, 6 * n) / n, got.anees


def test_observer_without_velocity_fixes_is_consistent() -> None:
    """Positions only (``use_velocity=False``): slower, still consistent (per-row NEES mean 6
    within 4 standard errors); the velocity comes from the accelerometer and the position track
    (measured RMS ≈ 0.10/0.10/0.13 m/s for ``single``); the position estimate still filters the
    white part (its error is 0.98–0.99 of the raw fixes' over seeds 3–9)."""
    gnss = GnssModel.preset("single")
    imu = ImuModel()
    got = fly(gnss, imu, ObserverParams(gnss, imu, use_velocity=False), 100, 120.0, seed=3)
    _check_mean(got.nees_rows, 6.0, "positions-only NEES")
    assert np.all(got.est_v < 0.2), got.est_v
    assert np.all(got.est_p < 0.995 * got.raw_p), (got.est_p, got.raw_p)


# --- without noise ----------------------------------------------------------------------------


@pytest.mark.parametrize("preset", ["rtk", "single"])
def test_noiseless_sensors_are_tracked_to_round_off(preset: str) -> None:
    """Perfect receiver and accelerometer (every σ 0), the filter tuned for the preset: started
    from the first fix, the estimate stays on the truth to round-off through 120 s of the
    manoeuvre (position ~50 m, speeds ~2 m/s: round-off ≈ 1e-13). A wrong sign or factor in the
    prediction would leave errors of ~1e-4 between fixes."""
    gnss = GnssModel.preset(preset)
    got = fly(perfect(gnss), PERFECT_IMU, ObserverParams(gnss, ImuModel()), 4, 120.0, seed=4,
              settle_s=0.0)
    assert got.max_p < 1e-12 and got.max_v < 1e-12, (got.max_p, got.max_v)
    assert np.all(np.abs(got.x[:, :, BA]) < 1e-12) and np.all(np.abs(got.x[:, :, BG]) < 1e-12)


def test_noiseless_sensors_converge_from_a_wrong_start() -> None:
    """Perfect sensors, the start off by 0.5 m, 0.2 m/s, 0.03 m/s² of accelerometer bias and
    −0.3 m of GNSS bias per axis, filter tuned for ``rtk``: the estimate converges to the truth.

    The slowest part is telling a position error from a GNSS bias error — the fixes see only
    their sum, and the filter separates them by the bias's mean reversion (τ = 60 s): the error
    decays geometrically, ~150× per 300 s (measured position error 2e-3 m at 300 s, 1.4e-5 m at
    600 s, 2.7e-7 m at 900 s, 1.9e-9 m at 1200 s, 1.5e-11 m at 1500 s, velocity 4e-12 m/s),
    on down to the round-off floor of the test above (~1e-14) some 600 s later. For ``single``
    (τ = 120 s, fixes 50× noisier) it is ~2× per 300 s: an honest filter cannot do better, and
    its P says so."""
    gnss = GnssModel.preset("rtk")
    start = np.zeros((1, 3, N_STATE))
    start[..., POS] = 0.5
    start[..., VEL] = 0.2
    start[..., BA] = 0.03
    start[..., BG] = -0.3
    got = fly(perfect(gnss), PERFECT_IMU, ObserverParams(gnss, ImuModel()), 1, 1500.0, seed=5,
              settle_s=1440.0, start_error=start)
    assert got.max_p < 1e-10 and got.max_v < 3e-11, (got.max_p, got.max_v)
    assert np.all(np.abs(got.x[:, :, BA]) < 1e-10) and np.all(np.abs(got.x[:, :, BG]) < 1e-10)


# --- determinism and batching -----------------------------------------------------------------


def test_same_seed_same_bits() -> None:
    gnss = GnssModel.preset("single")
    runs = [fly(gnss, ImuModel(), ObserverParams(gnss, ImuModel()), 8, 20.0, seed=6)
            for _ in range(2)]
    assert runs[0].x.tobytes() == runs[1].x.tobytes()
    assert runs[0].P.tobytes() == runs[1].P.tobytes()
    other = fly(gnss, ImuModel(), ObserverParams(gnss, ImuModel()), 8, 20.0, seed=7)
    assert other.x.tobytes() != runs[0].x.tobytes()


def _rows(table: tuple, i: int) -> tuple:
    """Row i of a per-row record (nested records too) as a record of one row."""
    return type(table)(*(_rows(f, i) if isinstance(f, tuple) else f[i:i + 1] for f in table))


def test_batched_kernels_equal_one_row_calls_bit_for_bit() -> None:
    """N rows in one call, rows of different receivers and filters (alternately ``single`` and
    ``rtk``, one without velocity), some fixes missing (NaN): each row comes out exactly as when
    called alone — no row's result depends on another's."""
    n = 6
    models = [GnssModel.preset("single" if i % 2 else "rtk") for i in range(n)]
    params = [ObserverParams(m, ImuModel(), use_velocity=(i != 3)) for i, m in enumerate(models)]
    gt, it, noise = gnss_table(models, n), imu_table(ImuModel(), n), observer_noise(params, n)
    rng = np.random.default_rng(8)
    truth_p = rng.uniform(-10.0, 10.0, (n, 3))
    truth_v = rng.uniform(-2.0, 2.0, (n, 3))
    gb, ab = initial_bias(gt, rng), initial_accel_bias(it, rng)
    zp, zv = np.empty((n, 3)), np.empty((n, 3))
    gnss_step(gb, truth_p, truth_v, 0.1, gt, rng.standard_normal((n, GNSS_NORMALS)), zp, zv)
    x, P = np.empty((n, 3, N_STATE)), np.empty((n, 3, N_STATE, N_STATE))
    observer_init(x, P, zp, zv, noise)
    one = [(x[i:i + 1].copy(), P[i:i + 1].copy(), gb[i:i + 1].copy(), ab[i:i + 1].copy())
           for i in range(n)]
    for k in range(50):
        acc = rng.uniform(-3.0, 3.0, (n, 3))
        imu_normals = rng.standard_normal((n, IMU_NORMALS))
        gnss_normals = rng.standard_normal((n, GNSS_NORMALS))
        am = np.empty((n, 3))
        imu_step(ab, acc, DT, it, imu_normals, am)
        observer_predict(x, P, am, DT, noise)
        if k % 10 == 9:
            gnss_step(gb, truth_p, truth_v, 0.1, gt, gnss_normals, zp, zv)
            clean = zp.copy(), zv.copy()
            zp[1, 2] = np.nan
            zv[4, 0] = np.nan
            observer_correct(x, P, zp, zv, noise)
        for i, (xi, Pi, gbi, abi) in enumerate(one):
            ami = np.empty((1, 3))
            imu_step(abi, acc[i:i + 1], DT, _rows(it, i), imu_normals[i:i + 1], ami)
            assert ami.tobytes() == am[i:i + 1].tobytes()
            observer_predict(xi, Pi, ami, DT, _rows(noise, i))
            if k % 10 == 9:
                zpi, zvi = np.empty((1, 3)), np.empty((1, 3))
                gnss_step(gbi, truth_p[i:i + 1], truth_v[i:i + 1], 0.1, _rows(gt, i),
                          gnss_normals[i:i + 1], zpi, zvi)
                assert zpi.tobytes() == clean[0][i:i + 1].tobytes()
                assert zvi.tobytes() == clean[1][i:i + 1].tobytes()
                zpi[:] = zp[i:i + 1]  # the same dropouts
                zvi[:] = zv[i:i + 1]
                observer_correct(xi, Pi, zpi, zvi, _rows(noise, i))
    for i, (xi, Pi, gbi, abi) in enumerate(one):
        assert xi.tobytes() == x[i:i + 1].tobytes()
        assert Pi.tobytes() == P[i:i + 1].tobytes()
        assert gbi.tobytes() == gb[i:i + 1].tobytes()
        assert abi.tobytes() == ab[i:i + 1].tobytes()
    assert np.array_equal(P, np.swapaxes(P, 2, 3))  # kept exactly symmetric


def test_missing_fix_leaves_the_axis_uncorrected() -> None:
    """A NaN component of a fix skips that axis's update (a dropout); a row without velocity
    ignores the velocity fix."""
    gnss = GnssModel.preset("single")
    params = [ObserverParams(gnss, ImuModel()), ObserverParams(gnss, ImuModel(), False)]
    noise = observer_noise(params, 2)
    x, P = np.empty((2, 3, N_STATE)), np.empty((2, 3, N_STATE, N_STATE))
    observer_init(x, P, np.zeros((2, 3)), np.zeros((2, 3)), noise)
    observer_predict(x, P, np.ones((2, 3)), DT, noise)
    x0, P0 = x.copy(), P.copy()
    zp = np.full((2, 3), 1.0)
    zp[0, 1] = np.nan
    zv = np.full((2, 3), 1.0)
    zv[0, 1] = np.nan
    observer_correct(x, P, zp, zv, noise)
    assert np.array_equal(x[0, 1], x0[0, 1]) and np.array_equal(P[0, 1], P0[0, 1])
    assert not np.array_equal(x[0, 0], x0[0, 0])
    # Row 1 fuses only positions: its velocity variance shrinks less than row 0's.
    assert P[1, 0, VEL, VEL] > P[0, 0, VEL, VEL]
    assert np.all(np.diagonal(P, axis1=2, axis2=3) >= 0.0)


# --- presets and validation -------------------------------------------------------------------


def test_presets_are_typical_receivers() -> None:
    single, rtk = GnssModel.preset("single"), GnssModel.preset("rtk")
    h, v = single.position_sigma_m()[0], single.position_sigma_m()[2]
    assert 1.0 <= h <= 2.0 and 2.0 <= v <= 3.0 and 1.5 <= v / h <= 2.0
    assert single.horizontal_bias_sigma_m > single.horizontal_white_sigma_m  # mostly bias
    assert single.rate_hz == 10.0
    h, v = rtk.position_sigma_m()[0], rtk.position_sigma_m()[2]
    assert 0.01 <= h <= 0.02 and 0.02 <= v <= 0.03
    assert rtk.rate_hz == 5.0
    assert GnssModel() == single
    assert single.ticks_per_fix(DT) == 10 and rtk.ticks_per_fix(DT) == 20


def test_bad_preset_names_the_choices() -> None:
    with pytest.raises(ValueError, match=r"'L5'.*choices: rtk, single"):
        GnssModel.preset("L5")
    with pytest.raises(ValueError, match=r"'L5'.*choices: rtk, single"):
        ObserverParams.preset("L5")


@pytest.mark.parametrize(("field", "value", "message"), [
    ("horizontal_bias_sigma_m", -1.0, "must be ≥ 0"),
    ("vertical_white_sigma_m", math.nan, "must be finite"),
    ("horizontal_velocity_sigma_mps", math.inf, "must be finite"),
    ("vertical_bias_sigma_m", "2", "must be a number"),
    ("bias_tau_s", 0.0, "must be > 0"),
    ("rate_hz", 0.0, "must be > 0"),
    ("rate_hz", -10.0, "must be > 0"),
    ("horizontal_white_sigma_m", 1e4, "10000.0 exceeds the sane bound"),
])
def test_gnss_model_names_the_bad_field(field: str, value: object, message: str) -> None:
    with pytest.raises(ConfigError, match=rf"gnss\.{field}: {message}"):
        GnssModel(**{field: value})


@pytest.mark.parametrize(("field", "value", "message"), [
    ("noise_density_mps2_rthz", -0.1, "must be ≥ 0"),
    ("bias_sigma_mps2", math.nan, "must be finite"),
    ("bias_tau_s", 0.0, "must be > 0"),
])
def test_imu_model_names_the_bad_field(field: str, value: float, message: str) -> None:
    with pytest.raises(ConfigError, match=rf"imu\.{field}: {message}"):
        ImuModel(**{field: value})


def test_other_errors_name_the_field() -> None:
    with pytest.raises(ConfigError, match=r"gnss\.single\.rate: unknown field"):
        GnssModel.from_table({"rate": 5.0}, "gnss.single")
    with pytest.raises(ConfigError, match=r"gnss\.rate_hz: a fix every 0\.333"):
        GnssModel(rate_hz=3.0).ticks_per_fix(DT)
    assert GnssModel(rate_hz=1 / 0.3).ticks_per_fix(DT) == 30
    # A perfect receiver is a valid simulated sensor but no filter's R.
    with pytest.raises(ConfigError, match=r"observer\.gnss\.horizontal_white_sigma_m: must be > 0"):
        ObserverParams(perfect(GnssModel()))
    with pytest.raises(ConfigError, match=r"observer\.gnss\.vertical_velocity_sigma_mps"):
        ObserverParams(dataclasses.replace(GnssModel(), vertical_velocity_sigma_mps=0.0))
    ObserverParams(dataclasses.replace(GnssModel(), vertical_velocity_sigma_mps=0.0),
                   use_velocity=False)
    with pytest.raises(ConfigError, match=r"gnss: need one GnssModel or 3"):
        gnss_table([GnssModel()] * 2, 3)
