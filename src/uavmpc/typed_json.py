"""The one typed decoder of the JSON files uavmpc writes and reads back (a run's
``summary.json``, a node's or a SITL's launch specification and report).

:func:`decode` turns a JSON value into the type its annotation names, dataclasses included,
checking every field on the way, and raises the caller's error class with a message that names
the field (``landing.touchdowns: must be an integer, not 'two'``). Encoding needs no code of
its own: ``dataclasses.asdict`` and :func:`plain` give what ``json.dumps`` writes.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import types
import typing
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, TypeVar, overload

from uavmpc.config import describe

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T")
D = TypeVar("D", bound="DataclassInstance")

#: The words of an error for each scalar type.
_SCALAR_WORDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


@overload
def decode(tp: type[T], value: object, where: str, error: type[Exception]) -> T: ...


# Any other annotation (``X | None``, ``Any``, ...): what it decodes to is known only at run time.
@overload
def decode(tp: object, value: object, where: str, error: type[Exception]) -> Any: ...


def decode(tp: object, value: object, where: str, error: type[Exception]) -> Any:
    """``value`` (as JSON gives it) as the type ``tp``, or ``error`` naming ``where``.

    ``tp`` is an annotation of: ``Any``, ``bool``, ``int``, ``float`` (an integer is a
    number, made a float), ``str``, ``None``, an enum (by value), a dataclass (every field
    checked; unknown fields and missing fields without a default are errors), ``X | None``,
    ``tuple[X, ...]``, ``tuple[X, Y]``, ``list[X]``, ``dict[K, V]`` or ``Mapping[K, V]``. JSON
    lists become tuples where tuples are due."""
    if tp is Any:
        return value
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        rest = [a for a in args if a is not type(None)]
        if len(rest) != 1:
            raise TypeError(f"{where}: unsupported annotation {tp!r}")
        return decode(rest[0], value, where, error)
    if tp is type(None):
        if value is not None:
            raise error(f"{where}: must be null, not {describe(value)}")
        return None
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return decode_dataclass(tp, value, where, error)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        try:
            return tp(value)
        except ValueError:
            names = ", ".join(repr(m.value) for m in tp)
            raise error(f"{where}: must be one of {names}, not {describe(value)}") from None
    if origin in (Mapping, dict):
        if not isinstance(value, dict):
            raise error(f"{where}: must be an object, not {describe(value)}")
        return {decode(args[0], k, f"{where} key", error):
                decode(args[1], v, f"{where}.{k}", error) for k, v in value.items()}
    if origin in (tuple, list):
        if not isinstance(value, list | tuple):
            raise error(f"{where}: must be a list, not {describe(value)}")
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                raise error(f"{where}: must have {len(args)} items, not {len(value)}")
            items = [decode(a, v, f"{where}[{i}]", error)
                     for i, (a, v) in enumerate(zip(args, value, strict=True))]
        else:
            items = [decode(args[0], v, f"{where}[{i}]", error) for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if isinstance(tp, type) and tp in _SCALAR_WORDS:
        if tp is float:
            if not isinstance(value, bool) and isinstance(value, int | float):
                return float(value)
        elif (isinstance(value, bool) if tp is bool else isinstance(value, str) if tp is str
              else not isinstance(value, bool) and isinstance(value, int)):
            return value
        raise error(f"{where}: must be {_SCALAR_WORDS[tp]}, not {describe(value)}")
    raise TypeError(f"{where}: unsupported annotation {tp!r}")


def decode_dataclass(cls: type[D], value: object, where: str, error: type[Exception]) -> D:
    """An instance of the dataclass ``cls`` from the JSON object ``value`` (:func:`decode`)."""
    if not isinstance(value, dict):
        raise error(f"{where}: must be an object, not {describe(value)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(value) - set(fields))
    if unknown:
        raise error(f"{where}: unknown field {unknown[0]!r}")
    missing = [n for n, f in fields.items() if n not in value
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise error(f"{where}: missing field {missing[0]!r}")
    hints = typing.get_type_hints(cls)
    return cls(**{k: decode(hints[k], v, f"{where}.{k}", error) for k, v in value.items()})


def check_fields(obj: DataclassInstance, where: str, error: type[Exception]) -> None:
    """Check every field of the frozen dataclass ``obj`` against its annotation, normalised as
    :func:`decode` gives it (lists to tuples where tuples are due); for a ``__post_init__``."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        value = decode(hints[f.name], getattr(obj, f.name), f"{where}.{f.name}", error)
        object.__setattr__(obj, f.name, value)


def plain(value: object) -> Any:
    """``value`` as JSON gives it back (lists for tuples, floats for numpy numbers, an enum's
    value)."""
    return json.loads(json.dumps(value, default=_json_default))


def _json_default(value: object) -> object:
    if isinstance(value, enum.Enum):
        return value.value
    tolist = getattr(value, "tolist", None)  # numpy arrays and scalars
    if tolist is not None:
        return tolist()
    raise TypeError(f"not JSON: {type(value).__name__}")
