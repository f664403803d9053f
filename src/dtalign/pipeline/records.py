"""The results' JSON form, generated from their fields.

:func:`to_json` writes a result record (a dataclass: a
:class:`~dtalign.pipeline.PolylineFit`'s parts) as JSON-ready values, field
by field; :func:`from_json` reads one back from its fields' annotations.
JSON has no infinity and no NaN: a value that is not finite is written as
``None``, and read back as None where the field's type admits None, else
as the record's ``NONFINITE`` (a float, or a dict of them by field name;
``inf`` where it says nothing).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import types
import typing
from typing import Any

import numpy as np

__all__ = ["from_json", "to_json"]


def to_json(value: Any) -> Any:
    """``value`` as JSON-ready Python: records as dicts of their fields, tuples
    and arrays as lists, a float that is not finite as None."""
    if isinstance(value, enum.Enum):
        return value.value
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_json(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): to_json(v) for k, v in value.items()}
    if isinstance(value, np.ndarray | tuple | list):
        return [to_json(x) for x in value]
    raise TypeError(f"no JSON form for {type(value).__name__}")


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _read(tp: Any, x: Any, nonfinite: float) -> Any:
    """``x`` read as the type ``tp``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (types.UnionType, typing.Union):
        if x is None and type(None) in args:
            return None
        (tp,) = (a for a in args if a is not type(None))
        return _read(tp, x, nonfinite)
    if tp is float:
        return nonfinite if x is None else float(x)
    if tp in (int, bool, str):
        return tp(x)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_read(args[0], v, nonfinite) for v in x)
        return tuple(_read(a, v, nonfinite) for a, v in zip(args, x, strict=True))
    if origin is dict:
        return {_read(args[0], k, nonfinite): _read(args[1], v, nonfinite) for k, v in x.items()}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return from_json(tp, x)
    raise TypeError(f"cannot read {tp!r}")


def from_json(cls: type, d: dict[str, Any], **given: Any) -> Any:
    """The ``cls`` record :func:`to_json` wrote as ``d``; ``given`` fields are
    taken as they are. A field absent from ``d`` (a dict written before the
    field existed) takes its default.

    Raises
    ------
    KeyError
        If ``d`` lacks a field that has no default.
    """
    hints = _hints(cls)
    nonfinite = getattr(cls, "NONFINITE", math.inf)
    values = dict(given)
    for f in dataclasses.fields(cls):
        if f.name in values or (f.name not in d and (
                f.default is not dataclasses.MISSING
                or f.default_factory is not dataclasses.MISSING)):
            continue
        fill = nonfinite.get(f.name, math.inf) if isinstance(nonfinite, dict) else nonfinite
        values[f.name] = _read(hints[f.name], d[f.name], fill)
    return cls(**values)
