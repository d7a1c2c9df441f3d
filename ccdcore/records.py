"""Typed records stored as JSON: :class:`Record`, the base of every result a calibration
product holds (``calibration.json``), and :class:`Row`, one line of a result as people read it.

A record is a frozen dataclass whose fields are the keys of its JSON object, in order. Its
field types say what each value may be, and :meth:`Record.from_dict` checks a JSON object
against them (a clear :class:`~ccdcore.errors.CcdError` naming the file and the key when it does
not fit), so that code past the file boundary reads typed attributes, never ``.get("…")``.
:meth:`Record.to_dict` gives the JSON object back: ``from_dict(d).to_dict() == d`` for every
``d`` :meth:`to_dict` can give, key order included, which is what keeps a product's
``calibration.json`` byte-identical when it is loaded and saved again.

Types a field may have: ``bool``, ``int``, ``float`` (an ``int`` is kept as it is, so
``1`` stays ``1``), ``str``, ``None``, unions of these (``float | None``), ``tuple[T, ...]``
and fixed ``tuple[A, B]`` (JSON arrays), ``dict[str, T]`` (objects with free keys) and other
records (objects with fixed keys). Field metadata: ``{"key": "…"}`` stores the field under
another JSON key; ``OMIT_NONE`` leaves the key out when the value is ``None`` (and a missing
key reads as ``None``).

This module is the bottom of the result layer: it imports only NumPy, :mod:`ccdcore.errors`
and :mod:`ccdcore.common`.

Public objects
--------------
Record
    Base class: ``to_dict()``, ``from_dict(d, where=None, path='')``, ``items()``.
OMIT_NONE
    Field metadata: the key is absent from the JSON when the value is ``None``.
Row, rows_text(rows)
    One line of a result: label, value, error, unit and what it means in plain words; a
    result's rows on one line.
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Iterable, Iterator, Mapping, TypeVar, Union

import numpy as np

from .common import format_pm
from .errors import CcdError

__all__ = ["Record", "OMIT_NONE", "Row", "rows_text", "positive_problems"]

R = TypeVar("R", bound="Record")

#: the resolved field types of each record class
_HINTS: dict[type, dict[str, Any]] = {}

#: field metadata: leave the key out of the JSON when the value is None
OMIT_NONE: Mapping[str, Any] = types.MappingProxyType({"omit_none": True})


def _key(f: dataclasses.Field) -> str:
    return f.metadata.get("key", f.name)


class Record:
    """Base of a frozen dataclass stored as one JSON object (see the module docstring)."""

    @classmethod
    def _types(cls) -> dict[str, Any]:
        hints = _HINTS.get(cls)
        if hints is None:
            hints = _HINTS[cls] = typing.get_type_hints(cls)
        return hints

    def items(self) -> Iterator[tuple[str, Any]]:
        """``(key, value)`` of every field in order, as :meth:`to_dict` lists them (a field
        with ``OMIT_NONE`` left out when ``None``), the values as they are (records, tuples)."""
        for f in dataclasses.fields(self):   # type: ignore[arg-type]
            value = getattr(self, f.name)
            if not (value is None and f.metadata.get("omit_none")):
                yield _key(f), value

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: fields in order under their keys, records and tuples converted,
        NaN and infinities as ``None`` (strict JSON)."""
        return {key: _to_json(value) for key, value in self.items()}

    def value_problems(self) -> list[tuple[str, str]]:
        """``(key, problem)`` of every value outside what the record can hold (a gain that is
        not positive ...): checked by :meth:`from_dict` after the types. None by default;
        records with such limits override it."""
        return []

    @classmethod
    def from_dict(cls: type[R], d: Any, where: Any = None, path: str = "") -> R:
        """The record of JSON object ``d``, every value checked against its field's type.

        A missing key takes the field's default (an error when it has none); unknown keys are
        ignored. A value of the wrong type raises :class:`CcdError` naming ``where`` (the
        file) and the key's dotted path below ``path`` (e.g. ``'estimates.noise.points.mu'``:
        items of arrays are not numbered)."""
        return _from_json(cls, d, where, path)


def _to_json(value: Any) -> Any:
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, Record):
        return value.to_dict()
    if isinstance(value, (tuple, list)):
        return [_to_json(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _to_json(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _record_of(cls: type[R], d: Any, where: Any, path: str) -> R:
    if not isinstance(d, Mapping):
        raise _bad(where, path, "an object", d)
    hints = cls._types()
    values = {}
    for f in dataclasses.fields(cls):   # type: ignore[arg-type]
        key = _key(f)
        if key not in d:
            if f.metadata.get("omit_none"):
                values[f.name] = None
                continue
            if f.default is not dataclasses.MISSING or \
                    f.default_factory is not dataclasses.MISSING:   # type: ignore[misc]
                continue
            raise CcdError(where, f"{_join(path, key)!r} is missing")
        values[f.name] = _from_json(hints[f.name], d[key], where, _join(path, key))
    record = cls(**values)
    for key, problem in record.value_problems():
        raise CcdError(where, f"{_join(path, key)!r} {problem}")
    return record


def positive_problems(record: Any, keys: tuple[str, ...], errors: tuple[str, ...] = ()
                      ) -> list[tuple[str, str]]:
    """:meth:`Record.value_problems` of values that must be finite and positive (``keys``) and
    of standard errors that must be finite and non-negative when given (``errors``)."""
    out = []
    for key in keys:
        v = getattr(record, key)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            out.append((key, f"is {v!r}: must be a finite positive number"))
    for key in errors:
        v = getattr(record, key)
        if v is not None and not (math.isfinite(v) and v >= 0):
            out.append((key, f"is {v!r}: a standard error must be finite and not negative"))
    return out


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


def _bad(where: Any, path: str, expected: str, v: Any) -> CcdError:
    at = f"'{path}'" if path else "the value"
    return CcdError(where, f"{at} must be {expected}, got {_kind(v)}")


def _from_json(tp: Any, v: Any, where: Any, path: str) -> Any:
    if isinstance(tp, type) and issubclass(tp, Record):
        return _record_of(tp, v, where, path)
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        args = typing.get_args(tp)
        if v is None and type(None) in args:
            return None
        members = [a for a in args if a is not type(None)]
        if len(members) == 1:       # X | None: X's own message, which names the inner key
            return _from_json(members[0], v, where, path)
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _from_json(arg, v, where, path)
            except CcdError:
                continue
        names = " or ".join("null" if a is type(None) else _name(a) for a in args)
        raise _bad(where, path, names, v)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(v, (list, tuple)):
            raise _bad(where, path, "an array", v)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_from_json(args[0], x, where, path) for x in v)
        if len(v) != len(args):  # a fixed tuple
            raise _bad(where, path, f"an array of {len(args)} values", v)
        return tuple(_from_json(a, x, where, path) for a, x in zip(args, v))
    if origin is dict:
        _, value_type = typing.get_args(tp)
        if not isinstance(v, Mapping):
            raise _bad(where, path, "an object", v)
        return {str(k): _from_json(value_type, x, where, _join(path, k)) for k, x in v.items()}
    if tp is Any:
        return v
    if tp is bool:
        if isinstance(v, bool):
            return v
    elif tp is int:
        if isinstance(v, int) and not isinstance(v, bool):
            return v
    elif tp is float:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            return v
    elif tp is str:
        if isinstance(v, str):
            return v
    elif tp is type(None):
        if v is None:
            return None
    else:
        raise TypeError(f"{path}: a record field cannot have the type {tp!r}")
    raise _bad(where, path, _name(tp), v)


def _name(tp: Any) -> str:
    if isinstance(tp, type) and issubclass(tp, Record):
        return "an object"
    origin = typing.get_origin(tp)
    if origin is tuple:
        return "an array"
    if origin is dict:
        return "an object"
    return {bool: "true/false", int: "an integer", float: "a number", str: "a string"}.get(
        tp, str(tp))


def _kind(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return f"{str(v).lower()}"
    if isinstance(v, (int, float)):
        return f"the number {v!r}"
    if isinstance(v, str):
        return f"the string {v[:40]!r}"
    if isinstance(v, Mapping):
        return "an object"
    if isinstance(v, (list, tuple)):
        return "an array"
    return type(v).__name__


@dataclasses.dataclass(frozen=True)
class Row:
    """One line of a result as people read it: ``label`` (e.g. ``"read noise"``), ``value``
    and ``error`` (``None``: not measured), ``unit`` (``""`` for a pure number), ``meaning``
    (what the figure says, in plain words) and ``text`` (the value as shown when it is not a
    number, e.g. a verdict)."""

    label: str
    value: float | int | None = None
    error: float | None = None
    unit: str = ""
    meaning: str = ""
    text: str | None = None

    @property
    def shown(self) -> str:
        """The value as people read it: ``text`` when given, else ``"value ± error unit"``
        (:func:`ccdcore.common.format_pm`; ``"n/a"`` when not measured)."""
        if self.text is not None:
            return self.text
        return format_pm(self.value, self.error, unit=self.unit)

    def __str__(self) -> str:
        return f"{self.label} {self.shown}"


def rows_text(rows: Iterable[Row]) -> str:
    """A result's rows on one line, as the CLI's ``calibrate`` summary and the app's product
    panel show them: ``label = value ± error unit`` (or its text), ``; `` between them."""
    return "; ".join(f"{r.label} = {r.shown}" for r in rows)
