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
