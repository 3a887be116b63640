"""The one percentile definition of every figure a flight or a campaign reports.

A percentile is a sample value: that of the empirical distribution function
(``numpy.percentile(..., method="inverted_cdf")``: the smallest sample x such that at least
q % of the samples are ≤ x). It needs no interpolation, so it is defined for right-censored
samples too (an infinite value stands for "later than the trial's length"): a percentile that
falls on one is reported as None.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Final

import numpy as np

METHOD: Final = "inverted_cdf"


def percentile(values: Iterable[float], q: float) -> float | None:
    """The ``q`` % percentile of ``values`` (None for none, or when it falls on an infinite
    value: a censored sample)."""
    x = np.asarray(list(values), dtype=float)
    if not x.size:
        return None
    if not (isinstance(q, int | float) and 0.0 <= q <= 100.0):
        raise ValueError(f"percentile: q must be in [0, 100], got {q!r}")
    if np.isnan(x).any():
        raise ValueError("percentile: NaN among the values")
    v = float(np.percentile(x, q, method=METHOD))
    return v if math.isfinite(v) else None


def bootstrap_interval(values: Iterable[float], q: float, *, level: float = 0.95,
                       resamples: int = 4000, seed: int = 0
                       ) -> tuple[float | None, float | None]:
    """The percentile-bootstrap ``level`` interval of the ``q`` % percentile of ``values``.

    ``resamples`` samples of the same size are drawn with replacement (seeded by ``seed``, so a
    report is reproducible), the percentile (:func:`percentile`'s definition) taken of each,
    and the interval is the central ``level`` share of those: its ends are again sample values
    (``inverted_cdf``). A bound on a censored (infinite) value is None, "later than the trials
    lasted"; (None, None) for no values."""
    x = np.asarray(list(values), dtype=float)
    if not x.size:
        return None, None
    if not (0.0 < level < 1.0):
        raise ValueError(f"bootstrap_interval: level must be in (0, 1), got {level!r}")
    if np.isnan(x).any():
        raise ValueError("bootstrap_interval: NaN among the values")
    rng = np.random.default_rng(seed)
    draws = x[rng.integers(0, x.size, size=(int(resamples), x.size))]
    stats = np.percentile(draws, q, axis=1, method=METHOD)
    tail = 50.0 * (1.0 - level)
    lo, hi = (float(np.percentile(stats, p, method=METHOD)) for p in (tail, 100.0 - tail))
    return (lo if math.isfinite(lo) else None), (hi if math.isfinite(hi) else None)
