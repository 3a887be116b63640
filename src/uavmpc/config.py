"""Loading validated parameters from TOML data files (SPEC: parameters are data).

Every loader names the offending field in its error, e.g. ``limits.horizontal_speed_mps: must be
> 0, got -1.0``, so a typo in a file is found before flight, not inside numpy.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import sys
import tomllib
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")  # a dataclass type

_FLOAT_MAX = sys.float_info.max


class ConfigError(ValueError):
    """A parameter file or value that cannot be used (the message names the field)."""


def describe(value: object, limit: int = 40) -> str:
    """A short description of ``value`` for an error message: never the repr of a container
    (a deeply nested one would recurse, a large one flood the log) nor of a huge number."""
    if isinstance(value, list | tuple):
        return f"an array of {len(value)}"
    if isinstance(value, dict):
        return f"a table of {len(value)}"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**limit:
        # repr() of an integer of more than 4300 digits raises; its size is what matters.
        return f"an integer of about {int(math.log10(abs(value))) + 1} digits"
    if isinstance(value, str) and len(value) > limit:  # (cut before repr(): quotes stay)
        return f"{value[:limit - 10]!r}... ({len(value)} characters)"
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit - 3]}..."


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; every way it can fail (missing, unreadable, not UTF-8, not TOML)
    becomes a :class:`ConfigError` naming the file."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found") from None
    except OSError as exc:  # a directory, no permission, a name too long, ...
        raise ConfigError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except ValueError as exc:  # a NUL byte in the path
        raise ConfigError(f"{p}: cannot read: {exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:  # TOML is UTF-8 by definition
        raise ConfigError(f"{p}: not UTF-8 text (byte {raw[exc.start]:#04x} at offset "
                          f"{exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: invalid TOML: {exc}") from None
    except RecursionError:  # arrays nested thousands deep exhaust tomllib's recursion
        raise ConfigError(f"{p}: invalid TOML: nested too deeply") from None
    except ValueError as exc:  # tomllib lets int()'s limit of 4300 digits through
        raise ConfigError(f"{p}: invalid TOML: {exc}") from None


def read_packaged_toml(name: str) -> dict[str, Any]:
    """Read one of the TOML files shipped in ``uavmpc/data``."""
    with resources.files("uavmpc.data").joinpath(name).open("rb") as fh:
        return tomllib.load(fh)


def positive(value: object, field: str, *, upper: float = math.inf,
             allow_zero: bool = False) -> float:
    """``value`` as a finite float in (0, upper] (or [0, upper] with ``allow_zero``)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{field}: must be a number, got {describe(value)}")
    try:
        out = float(value)
    except OverflowError:  # a TOML integer beyond the float range (≈ 1.8e308)
        raise ConfigError(f"{field}: {describe(value)} is too large (beyond the float "
                          "range)") from None
    if not math.isfinite(out):
        raise ConfigError(f"{field}: must be finite, got {out}")
    if out < 0.0 or (out == 0.0 and not allow_zero):
        raise ConfigError(f"{field}: must be {'≥' if allow_zero else '>'} 0, got {out}")
    if out > upper:
        raise ConfigError(f"{field}: {out} exceeds the sane bound {upper}")
    return out


def finite(value: object, field: str, bound: float = math.inf) -> float:
    """``value`` as a float, a number with |value| ≤ ``bound`` (finite in any case)."""
    limit = "" if bound >= _FLOAT_MAX else f" within ±{bound:g}"
    # Compared before float(): an integer beyond the float range compares exactly (float()
    # would raise OverflowError), and NaN fails every comparison.
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not -min(bound, _FLOAT_MAX) <= value <= min(bound, _FLOAT_MAX):
        raise ConfigError(f"{field}: must be a finite number{limit}, got {describe(value)}")
    return float(value)


def take(table: dict[str, Any], key: str, prefix: str) -> Any:
    """``table[key]`` or a :class:`ConfigError` naming ``prefix.key`` as missing."""
    if not isinstance(table, dict):
        raise ConfigError(f"{prefix}: must be a table")
    if key not in table:
        raise ConfigError(f"{prefix}.{key}: missing")
    return table[key]


def reject_unknown(table: dict[str, Any], known: set[str], prefix: str) -> None:
    """Typos in parameter files must not be silently ignored; and what should be a table but
    is not (``link = 5``, ``[[uavs]]`` entries that are numbers) is named as such, before
    anything iterates over it."""
    if not isinstance(table, dict):
        raise ConfigError(f"{prefix}: must be a table, got {describe(table)}")
    unknown = sorted(set(table) - known)
    if unknown:
        names = ", ".join(sorted(known))
        close = difflib.get_close_matches(str(unknown[0]), sorted(known), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise ConfigError(f"{prefix}.{unknown[0]}: unknown field ({hint}known: {names})")


def from_table(cls: type[T], table: object, prefix: str) -> T:
    """The dataclass ``cls`` from a TOML table: missing fields take their defaults, unknown
    ones are errors naming ``prefix.field``; the dataclass validates the values."""
    if not isinstance(table, dict):
        raise ConfigError(f"{prefix}: must be a table")
    reject_unknown(table, {f.name for f in dataclasses.fields(cls)}, prefix)
    return cls(**table)


def exit_code_of(run: Callable[[], int]) -> int:
    """``run()``'s exit code; a configuration error, or an optional extra not installed, is one
    line on stderr and exit code 2 instead of a traceback (the CLI's rule, and this module's)."""
    try:
        return int(run())
    except ConfigError as exc:
        print(f"uavmpc: {exc}", file=sys.stderr)
        return 2
    except ImportError as exc:
        if "pip install" not in str(exc):
            raise
        print(f"uavmpc: {exc}", file=sys.stderr)  # an optional extra is missing
        return 2
