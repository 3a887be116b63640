"""The tracker's QP stage section by section (docs/scale.md), as prepare_sections.py does for
the prepare stage.

``python benchmarks/qp_sections.py [UAVS] [SECONDS]`` (default 20 12) flies a random walk with
avoidance for SECONDS, takes its tracker rows as they are at each of the 50 ticks that follow,
and times, in a compiled loop (one thread, best of 3 per tick), each row's prepare stage
followed by its QP stage (:func:`~uavmpc.tracker.kernels.solve_row`) with the solver cut
short before each section of :func:`~uavmpc.solvers.batchqp.solve_one` (its own source with
a ``return`` inserted; the anchors below must be found, or the script stops), and the
prepare stage alone: the difference between two cuts is what that section costs. The
solver's warm-start caches are restored before every pass, so every pass solves the same
problems from the same warm sets. Prints ns per QP solve and section, the solves per
UAV-tick and the iterations per solve; the last line is JSON.

A cut lets the compiler drop everything after it, so the code before it may compile
differently: a section of a few hundred ns is within that effect (the data checks, two
short branch-free loops, read about 0.6 µs here). The whole and the large sections are what
to trust.
"""

from __future__ import annotations

import json
import sys
from typing import Any

from cuts import best, compiled, copied, cut, flown, source_of
from numba import njit

import uavmpc.solvers.batchqp as B
import uavmpc.tracker.kernels as K

#: (label, the source line the section starts with, the return inserted before it).
#: The label names the code from the previous anchor (or the start of the QP stage: the row's
#: start copied, the caches' age) to this one.
SECTIONS = [
    ("start: the row's start copied, the calls", "    # Non-finite data (NaN in a bound",
     "    return OPTIMAL, 0, 0\n"),
    ("data checked", "    # The iteration works with these shifted bounds",
     "    return OPTIMAL, 0, 0\n"),
    ("bounds shifted", "    # Warm start. The factor depends on W only",
     "    return OPTIMAL, 0, 0\n"),
    ("warm start (reuse, or refactorise)", "    iterations = 0\n    status = 0\n",
     "    return OPTIMAL, 0, nw\n"),
    ("multipliers of W (two triangular solves)",
     "        # Blocking row on the way from λ to λ*", "        return OPTIMAL, iterations, nw\n"),
    ("blocking rows", "        # Primal point of W: rows of G(U − U_free)",
     "        return OPTIMAL, iterations, nw\n"),
    ("primal point of every row (Gram product)",
     "        # Rows violated beyond the tolerance compete",
     "        return OPTIMAL, iterations, nw\n"),
    ("worst violation, further iterations", "    if status != OPTIMAL:\n",
     "    return OPTIMAL, iterations, nw\n"),
    ("U from the multipliers", "    _refine(f, lower, upper,",
     "    return OPTIMAL, iterations, nw\n"),
    ("one KKT refinement", "    # Never trust the iteration alone",
     "    return OPTIMAL, iterations, nw\n"),
]


def _cut_solvers() -> list[Any]:
    """solve_row compiled on solve_one cut before each section (and whole, last)."""
    one, warm, row = source_of(B.solve_one), source_of(B.solve_warm), source_of(K.solve_row)
    out = []
    for n in range(len(SECTIONS) + 1):
        code = one
        if n < len(SECTIONS):
            _, anchor, ret = SECTIONS[n]
            code = cut(one, anchor, ret, "qp_sections")
        space = dict(vars(B))
        compiled(code, space, "solve_one", B.FASTMATH)
        row_space = dict(vars(K))
        row_space["solve_warm"] = compiled(warm, space, "solve_warm", B.FASTMATH)
        out.append(compiled(row, row_space, "solve_row", K.FASTMATH))
    return out


@njit
def _restore(rows: Any, rows0: Any) -> None:
    """What the QP stage writes, back as it was (the warm sets and factors)."""
    rows.ws[:] = rows0.ws
    rows.lf[:] = rows0.lf
    rows.widx[:] = rows0.widx
    rows.wside[:] = rows0.wside
    rows.nw[:] = rows0.nw
    rows.age[:] = rows0.age


def _timer(solve: Any) -> Any:
    @njit
    def loop(reps: int, n: int, rows: Any, rows0: Any, refs: Any, c: Any, sc: Any) -> None:
        for _ in range(reps):
            _restore(rows, rows0)
            for i in range(n):
                K.prepare_row(i, rows, refs, c, sc)
                if solve is not None:
                    solve(i, rows, c, sc)
    return loop


def main(uavs: int = 20, seconds: float = 12.0, ticks: int = 50) -> None:
    w = flown(uavs, seconds)
    tb = w.onboard.tracker
    c = tb.consts
    m = c.horizon_s.shape[0]
    # The rows at ``ticks`` consecutive ticks: a factor is refreshed every 50 solves of its
    # axis, and the UAVs' axes, started together, tend to refresh at the same tick.
    moments = []
    for _ in range(ticks):
        moments.append((copied(tb.rows), tb.table()))
        w.run(w.period_s)

    # The problems: solves per row, iterations per solve (whole solver, once).
    solves = iterations = 0
    for rows0, refs in moments:
        probe = copied(rows0)
        sc = K.make_scratch(m)
        for i in range(uavs):
            K.prepare_row(i, probe, refs, c, sc)
            solves += int(probe.need[i].sum())
            K.solve_row(i, probe, c, sc)
            iterations += int(probe.iterations[i])
    if solves == 0:
        sys.exit("qp_sections: no axis needed the QP in these ticks; fly longer")

    reps = 20
    per_pass = []
    for solve in [None, *_cut_solvers()]:
        loop = _timer(solve)
        total = 0.0
        for rows0, refs in moments:
            rows = copied(rows0)
            sc = K.make_scratch(m)
            loop(1, uavs, rows, rows0, refs, c, sc)  # compile (first), warm the caches
            total += best(loop, reps, uavs, rows, rows0, refs, c, sc, repeat=3) / reps
        per_pass.append(total)
    base = per_pass[0]
    whole = (per_pass[-1] - base) / solves
    print(f"{uavs} UAVs, {ticks} ticks from {seconds:g} s: {solves} QP solves "
          f"({solves / (uavs * ticks):.2f} per UAV-tick), {iterations / solves:.2f} iterations "
          f"per solve; {whole * 1e9:.0f} ns per solve")
    print(f"{'section':44s} {'ns per solve':>12s} {'share':>6s}")
    sections = []
    before = base
    for (label, _, _), t in zip([*SECTIONS, ("final bound check", "", "")], per_pass[1:],
                                strict=True):
        ns = (t - before) / solves * 1e9
        before = t
        print(f"{label:44s} {ns:12.0f} {ns / (whole * 1e9):6.0%}")
        sections.append({"section": label, "ns_per_solve": ns})
    print(json.dumps({"uavs": uavs, "seconds": seconds, "ticks": ticks, "solves": solves,
                      "iterations_per_solve": iterations / solves,
                      "ns_per_solve": whole * 1e9, "sections": sections}))


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]) if args else 20, float(args[1]) if len(args) > 1 else 12.0)
