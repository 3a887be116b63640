"""Loading validated parameters from TOML data files (SPEC: parameters are data).

Every loader names the offending field in its error, e.g. ``limits.horizontal_speed_mps: must be
> 0, got -1.0``, so a typo in a file is found before flight, not inside numpy.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


class ConfigError(ValueError):
    """A parameter file or value that cannot be used (the message names the field)."""


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning syntax errors into a :class:`ConfigError` naming the file."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: invalid TOML: {exc}") from None


def read_packaged_toml(name: str) -> dict[str, Any]:
    """Read one of the TOML files shipped in ``uavmpc/data``."""
    with resources.files("uavmpc.data").joinpath(name).open("rb") as fh:
        return tomllib.load(fh)


def positive(value: Any, field: str, *, upper: float = math.inf, allow_zero: bool = False) -> float:
    """``value`` as a finite float in (0, upper] (or [0, upper] with ``allow_zero``)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{field}: must be a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise ConfigError(f"{field}: must be finite, got {out}")
    if out < 0.0 or (out == 0.0 and not allow_zero):
        raise ConfigError(f"{field}: must be {'≥' if allow_zero else '>'} 0, got {out}")
    if out > upper:
        raise ConfigError(f"{field}: {out} exceeds the sane bound {upper}")
    return out


def take(table: dict[str, Any], key: str, prefix: str) -> Any:
    """``table[key]`` or a :class:`ConfigError` naming ``prefix.key`` as missing."""
    if not isinstance(table, dict):
        raise ConfigError(f"{prefix}: must be a table")
    if key not in table:
        raise ConfigError(f"{prefix}.{key}: missing")
    return table[key]


def reject_unknown(table: dict[str, Any], known: set[str], prefix: str) -> None:
    """Typos in parameter files must not be silently ignored."""
    unknown = sorted(set(table) - known)
    if unknown:
        names = ", ".join(sorted(known))
        raise ConfigError(f"{prefix}.{unknown[0]}: unknown field (known: {names})")


def from_table(cls: type[T], table: Any, prefix: str) -> T:
    """The dataclass ``cls`` from a TOML table: missing fields take their defaults, unknown
    ones are errors naming ``prefix.field``; the dataclass validates the values."""
    if not isinstance(table, dict):
        raise ConfigError(f"{prefix}: must be a table")
    reject_unknown(table, {f.name for f in dataclasses.fields(cls)}, prefix)  # type: ignore[arg-type]
    return cls(**table)
