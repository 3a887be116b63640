"""A published campaign result that a random-walk campaign's report is set beside.

The reference design's Table II ships as ``uavmpc/data/table2.toml``, with its source; a table
in the same format can be given as a file. :func:`comparison_rows` puts our percentiles, each
with its bootstrap interval (:func:`uavmpc.scenarios.stats.bootstrap_interval`), beside the
published ones and says whether each published number lies inside our interval.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from uavmpc.config import ConfigError, read_packaged_toml, read_toml, reject_unknown

#: The tables that ship with uavmpc (name → file in ``uavmpc/data``).
BUILT_IN = {"table2": "table2.toml"}
#: How our side of the comparison is computed (said in report.md and report.html).
DEFINITION = ("Our percentiles are those of the empirical CDF (a percentile is a trial's "
              "value, numpy's inverted_cdf; a trial without collision counts as later than "
              "its length); the published table does not state its definition. Our intervals "
              "are 95 % percentile-bootstrap intervals (4 000 resamples of the trials, "
              "seeded).")
#: The percentiles a table may give (those a campaign reports).
PERCENTILE_KEYS = ("p50", "p75", "p95", "p99")


@dataclass(frozen=True)
class PublishedResult:
    """One published random_walk campaign: without avoidance, its number of trials and
    percentiles of the time to first collision [s]; with avoidance, its hours, collisions and
    closest approach [m] (None where it publishes nothing)."""

    name: str
    source: str
    setup: str
    #: When its times start (e.g. "take-off").
    time_origin: str
    trials: int | None = None
    time_to_first_collision_s: tuple[tuple[str, float], ...] = ()
    hours: float | None = None
    collisions: int | None = None
    min_distance_m: float | None = None

    @classmethod
    def load(cls, which: str | Path) -> PublishedResult:
        """A built-in table by name (``table2``) or a TOML file in its format."""
        if str(which) in BUILT_IN:
            return cls.from_dict(read_packaged_toml(BUILT_IN[str(which)]), str(which))
        path = Path(which)
        if path.suffix != ".toml" and not path.exists():
            raise ConfigError(f"reference: {str(which)!r} is neither a built-in table "
                              f"({', '.join(BUILT_IN)}) nor a TOML file")
        return cls.from_dict(read_toml(path), str(path))

    @classmethod
    def from_dict(cls, t: dict[str, Any], where: str) -> PublishedResult:
        reject_unknown(t, {"name", "source", "setup", "time_origin", "without_avoidance",
                           "with_avoidance"}, where)
        for key in ("name", "source", "setup", "time_origin"):
            if not isinstance(t.get(key), str) or not t[key].strip():
                raise ConfigError(f"{where}.{key}: must be a non-empty string")
        off = t.get("without_avoidance", {})
        on = t.get("with_avoidance", {})
        reject_unknown(off, {"trials", "time_to_first_collision_s"},
                       f"{where}.without_avoidance")
        reject_unknown(on, {"hours", "collisions", "min_distance_m"}, f"{where}.with_avoidance")
        ttc = off.get("time_to_first_collision_s", {})
        reject_unknown(ttc, set(PERCENTILE_KEYS),
                       f"{where}.without_avoidance.time_to_first_collision_s")
        for k, v in ttc.items():
            _number(v, f"{where}.without_avoidance.time_to_first_collision_s.{k}")
        return cls(
            name=t["name"], source=" ".join(t["source"].split()),
            setup=" ".join(t["setup"].split()), time_origin=t["time_origin"],
            trials=_count(off.get("trials"), f"{where}.without_avoidance.trials"),
            time_to_first_collision_s=tuple((k, float(ttc[k])) for k in PERCENTILE_KEYS
                                            if k in ttc),
            hours=_number(on.get("hours"), f"{where}.with_avoidance.hours"),
            collisions=_count(on.get("collisions"), f"{where}.with_avoidance.collisions"),
            min_distance_m=_number(on.get("min_distance_m"),
                                   f"{where}.with_avoidance.min_distance_m"))

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["time_to_first_collision_s"] = dict(self.time_to_first_collision_s)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PublishedResult:
        return cls(**{**d, "time_to_first_collision_s":
                      tuple(d["time_to_first_collision_s"].items())})


def _number(v: object, field: str) -> float | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
        raise ConfigError(f"{field}: must be a number ≥ 0, got {v!r}")
    return float(v)


def _count(v: object, field: str) -> int | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise ConfigError(f"{field}: must be an integer ≥ 0, got {v!r}")
    return v


def _s(v: float | None, censored_at: float) -> str:
    return f"> {censored_at:g} s" if v is None else f"{v:.1f} s"


def inside(value: float, interval: tuple[float | None, float | None]) -> str:
    """Whether ``value`` lies in ``interval`` (a None upper end: beyond the trials' length),
    as the report says it: "yes", or "no: below" / "no: above"."""
    lo, hi = interval
    if lo is not None and value < lo:
        return "no: below"
    if hi is not None and value > hi:
        return "no: above"
    return "yes"


def comparison_rows(report: dict[str, Any]) -> list[tuple[str, str, str, str, str]]:
    """(quantity, ours, our 95 % interval, published, published inside our interval?) for a
    campaign report that carries a ``reference`` (empty if it has none)."""
    if not report.get("reference"):
        return []
    ref = PublishedResult.from_json(report["reference"])
    cap = report["censored_at_s"]
    rows: list[tuple[str, str, str, str, str]] = []
    if not report["avoidance"]:
        ours = report["time_to_first_collision_s"]
        ci = report.get("time_to_first_collision_ci95_s") or {}
        for k, v in ref.time_to_first_collision_s:
            lo, hi = ci.get(k, (None, None))
            rows.append((f"time to first collision, {k[1:]} %", _s(ours.get(k), cap),
                         f"[{_s(lo, cap)}, {_s(hi, cap)}]", f"{v:g} s",
                         inside(v, (lo, hi)) if k in ci else "–"))
        rows.append(("trials", str(report["trials"]), "",
                     "–" if ref.trials is None else str(ref.trials), ""))
    else:
        rows.append(("simulated hours", f"{report['simulated_hours']:.2f}", "",
                     "–" if ref.hours is None else f"{ref.hours:g}", ""))
        rows.append(("collisions", str(report["collisions"]), "",
                     "–" if ref.collisions is None else str(ref.collisions), ""))
        rows.append(("closest approach over all trials", f"{report['min_distance_m']:.2f} m", "",
                     "–" if ref.min_distance_m is None else f"{ref.min_distance_m:g} m", ""))
    origin = ("t = 0 on the ground (the take-off)" if report.get("ground_start")
              else "t = 0, in the air at the walk's start")
    rows.append(("times count from", origin, "", ref.time_origin, ""))
    return rows


def comparison_markdown(report: dict[str, Any]) -> str:
    """:func:`comparison_rows` as a Markdown section ('' without a reference)."""
    rows = comparison_rows(report)
    if not rows:
        return ""
    ref = report["reference"]
    lines = [f"\n## Beside the {ref['name']}\n",
             f"Source: {ref['source']}. Its set-up: {ref['setup']}.\n",
             f"{DEFINITION}\n",
             "| random_walk | ours | our 95 % interval | published | published inside ours? |",
             "|---|---|---|---|---|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"
