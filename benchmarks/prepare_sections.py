"""The tracker's prepare stage section by section, against its arithmetic (docs/scale.md).

``python benchmarks/prepare_sections.py [UAVS] [SECONDS]`` (default 20 12) flies a random walk
with avoidance for SECONDS, takes its tracker rows as they are then, and times
:func:`~uavmpc.tracker.kernels.prepare_row` on them in a compiled loop (one thread, best of 7),
whole and cut short after each of its sections: the difference between two cuts is what that
section costs. The cut versions are the kernel's own source with a ``return`` inserted before
a section (the anchors below must be found, or the script stops), compiled here, not cached.

Next to each section it prints its arithmetic: the multiply-adds its matrix products need
(each matrix's nonzeros times the rows' moving axes) and, as the reference measured in the
same run, what a plain compiled loop takes for that many multiply-adds on data in cache. The
last line is JSON.
"""

from __future__ import annotations

import json
import sys
from typing import Any

import numpy as np
from cuts import best, compiled, copied, cut, flown, source_of
from numba import njit

import uavmpc.tracker.kernels as K

#: (label, the source line the section starts with).
SECTIONS = [
    ("horizon times, reference sampled", "    t_now = rows.t_s[i]\n"),
    ("heading the short way round", "    # Heading: the short way round"),
    ("bounds laid out, relative positions", "    # Positions relative to the current one"),
    ("braking envelope", "    braking = limit_excess("),
    ("constraint rows' free response", "    vref, rows_free = sc.vref, sc.rows_free\n"),
    ("resting axes found", "    n_act = 0\n"),
    ("f: state terms", "    for ax in range(4):\n        r1, r2, up = "),
    ("f: reference product", "    _axpy_axes(r_rel, c.f_ref_t"),
    ("f: reference velocity products", "    if c.use_vref:"),
    ("unconstrained optima product", "    u[:] = 0.0"),
    ("bounds checked (C u product)", "    # Bound check of the unconstrained optima."),
]
#: The matrices (fields of the tracker's constants) each product section multiplies with.
PRODUCTS = {"f: reference product": ("f_ref_t",),
            "f: reference velocity products": ("vref_of_ref", "f_vref_t"),
            "unconstrained optima product": ("neg_hinv",),
            "bounds checked (C u product)": ("c_t",)}


def _cut_versions() -> list[Any]:
    """prepare_row cut before each section (and whole, last), compiled."""
    src = source_of(K.prepare_row)
    out = []
    for n in range(len(SECTIONS) + 1):
        code = src
        if n < len(SECTIONS):
            code = cut(src, SECTIONS[n][1], "    return\n", "prepare_sections")
        out.append(compiled(code, dict(vars(K)), "prepare_row", K.FASTMATH))
    return out


def _timer(prep: Any) -> Any:
    @njit
    def loop(reps: int, n: int, rows: Any, refs: Any, c: Any, sc: Any) -> None:
        for _ in range(reps):
            for i in range(n):
                prep(i, rows, refs, c, sc)
    return loop


@njit(fastmath=True)
def _macs(reps: int, a: np.ndarray, x: np.ndarray, y: np.ndarray) -> float:
    """reps × a (2, K) times x (K, W) into y (2, W): the plain loop, dense, in cache."""
    for _ in range(reps):
        for k in range(x.shape[0]):
            a0, a1 = a[0, k], a[1, k]
            for j in range(x.shape[1]):
                y[0, j] += a0 * x[k, j]
                y[1, j] += a1 * x[k, j]
    return y[0, 0]


def main(uavs: int = 20, seconds: float = 12.0) -> None:
    w = flown(uavs, seconds)
    tb = w.onboard.tracker
    rows0, refs, c = tb.rows, tb.table(), tb.consts
    m = c.horizon_s.shape[0]

    reps = 500
    per_row = []
    for prep in _cut_versions():
        loop = _timer(prep)
        sc = K.make_scratch(m)
        loop(1, uavs, copied(rows0), refs, c, sc)  # compile
        # The rows' state is not advanced between calls: every call prepares the same tick.
        per_row.append(best(loop, reps, uavs, copied(rows0), refs, c, sc) / (reps * uavs))
    whole = per_row[-1]
    ra = copied(rows0)
    sc = K.make_scratch(m)
    for i in range(uavs):
        K.prepare_row(i, ra, refs, c, sc)
    # An axis at rest (prepare_row's own test) keeps its linear term at zero.
    moving = int(sum(ra.f[i, ax].any() for i in range(uavs) for ax in range(4)))
    axes_per_row = moving / uavs
    # The plain multiply-add rate, dense 2 × m by m × (2m + 1), in cache.
    a = np.random.default_rng(0).standard_normal((2, m))
    x = np.random.default_rng(1).standard_normal((m, 2 * m + 1))
    y = np.zeros((2, 2 * m + 1))
    _macs(1, a, x, y)
    r = 20000
    ns_per_mac = best(_macs, r, a, x, y) / (r * 2 * m * (2 * m + 1)) * 1e9

    print(f"{uavs} UAVs after {seconds:g} s: prepare_row {whole * 1e9:.0f} ns per row, "
          f"{axes_per_row:.2f} of 4 axes moving; a plain compiled multiply-add in cache "
          f"{ns_per_mac:.3f} ns")
    print(f"{'section':40s} {'ns':>6s} {'share':>6s} {'mult.-adds':>10s} "
          f"{'at the plain rate':>18s}")
    sections = []
    before = 0.0
    for (label, _), t in zip(SECTIONS, per_row[1:], strict=True):
        ns = (t - before) * 1e9
        before = t
        macs = 0.0
        for name in PRODUCTS.get(label, ()):  # the products need the nonzeros only
            macs += np.count_nonzero(getattr(c, name)) * axes_per_row
        floor = macs * ns_per_mac
        print(f"{label:40s} {ns:6.0f} {ns / (whole * 1e9):6.0%} {macs:10.0f} "
              f"{(f'{floor:.0f} ns' if macs else ''):>18s}")
        sections.append({"section": label, "ns": ns, "multiply_adds": macs,
                         "plain_rate_ns": floor})
    print(json.dumps({"uavs": uavs, "seconds": seconds, "ns_per_row": whole * 1e9,
                      "moving_axes_per_row": axes_per_row, "plain_ns_per_mac": ns_per_mac,
                      "sections": sections}))


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]) if args else 20, float(args[1]) if len(args) > 1 else 12.0)
