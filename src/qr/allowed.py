"""Allowed values of settings, declared once beside each dataclass field and checked in one place.

``setting(0.7, gt=0, lt=1)`` is a dataclass field whose metadata says what it may be;
:func:`check_fields` holds an instance to it, so a wrong value is one :class:`QrInputError`
line naming the key, the value (as the user wrote it) and the allowed range.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import MISSING, dataclass, field, fields
from typing import Callable

import numpy as np

from .errors import QrInputError


def is_number(x) -> bool:
    """A real number, and not a bool (YAML's ``true`` is a Python int: ``mass: true`` is not 1 kg)."""
    return isinstance(x, numbers.Real) and not isinstance(x, (bool, np.bool_))


@dataclass(frozen=True)
class Allowed:
    """What a setting may be: a number or an integer in a range, a list of names from a set, one name
    from a set, or true/false."""

    kind: str  # "number" | "integer" | "names" | "one" | "boolean"
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    names: Callable[[], list[str]] | None = None  # kind "names": the allowed names
    null: str | None = None  # kind "names": what null means (None: null is not allowed)
    nonempty: bool = False
    reasons: Callable[[], dict[str, str]] | None = None  # kind "names": why some known names are refused

    def describe(self) -> str:
        if self.kind == "one":
            return f"one of {', '.join(self.names())}"
        if self.kind == "boolean":
            return "true or false"
        if self.kind == "names":
            what = f"a{' non-empty' if self.nonempty else ''} list of distinct names from {', '.join(self.names())}"
            return what + (f", or null ({self.null})" if self.null else "")
        what = "an integer" if self.kind == "integer" else "a number"
        if math.isfinite(self.lo) and math.isfinite(self.hi):
            return f"{what} in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"
        if math.isfinite(self.lo):
            return f"{what} {'>' if self.lo_open else '>='} {self.lo:g}"
        if math.isfinite(self.hi):
            return f"{what} {'<' if self.hi_open else '<='} {self.hi:g}"
        return f"a finite {what[2:]}" if what == "a number" else what

    def check(self, key: str, value, default, source: str = ""):
        """``value`` as the setting's type; a :class:`QrInputError` naming ``key`` if it is not allowed.

        The fix shows ``key=default`` (``source``: where the default is written).
        """
        fix = f"give {key} {self.describe()}, e.g. {key}={show(default)} (the default{', ' + source if source else ''})"
        if self.kind == "names":
            return self._names(key, value, fix)
        if self.kind == "one":
            if not isinstance(value, str) or value not in self.names():
                raise QrInputError(key, f"{show(value)} is not allowed", fix)
            return value
        if self.kind == "boolean":
            if not isinstance(value, (bool, np.bool_)):
                raise QrInputError(key, f"{show(value)} is not true or false", fix)
            return bool(value)
        if not is_number(value):
            raise QrInputError(key, f"{show(value)} is not {'an integer' if self.kind == 'integer' else 'a number'}",
                               fix)
        if self.kind == "integer":
            if not (isinstance(value, numbers.Integral) or (math.isfinite(value) and float(value).is_integer())):
                raise QrInputError(key, f"{show(value)} is not an integer", fix)
            value = int(value)
        else:
            value = float(value)
        inside = math.isfinite(value) and (value > self.lo if self.lo_open else value >= self.lo) \
            and (value < self.hi if self.hi_open else value <= self.hi)
        if not inside:
            raise QrInputError(key, f"{show(value)} is out of range: it must be {self.describe()}", fix)
        return value

    def _names(self, key, value, fix):
        if value is None:
            if self.null:
                return None
            raise QrInputError(key, "null is not allowed", fix)
        if isinstance(value, str) or not isinstance(value, (list, tuple)):
            example = f" (write [{value}])" if isinstance(value, str) else ""
            raise QrInputError(key, f"{show(value)} is not a list{example}", fix)
        known = self.names()
        bad = [v for v in value if not isinstance(v, str) or v not in known]
        if bad:
            import difflib

            reasons = self.reasons() if self.reasons else {}
            if bad[0] in reasons:
                raise QrInputError(key, f"'{bad[0]}' is not allowed: {reasons[bad[0]]}", fix)
            close = difflib.get_close_matches(str(bad[0]), known, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise QrInputError(key, f"unknown name(s) {', '.join(show(b) for b in bad)}{hint}", fix)
        if len(set(value)) != len(value):
            raise QrInputError(key, f"{show(value)} repeats a name", fix)
        if self.nonempty and not value:
            raise QrInputError(key, "the list is empty", fix)
        return list(value)


def show(x) -> str:
    """A value as the user wrote it on the command line (YAML, not Python)."""
    if isinstance(x, bool):
        return "true" if x else "false"
    if x is None:
        return "null"
    if isinstance(x, (list, tuple)):
        return "[" + ",".join(v if isinstance(v, str) else show(v) for v in x) + "]"
    if isinstance(x, str):
        return f"'{x}'"
    return f"{x:g}" if isinstance(x, float) else str(x)


def allowed(kind="number", *, gt=None, ge=None, lt=None, le=None, names=None, null=None, nonempty=False,
            reasons=None) -> Allowed:
    """``Allowed`` from bounds: ``gt``/``lt`` exclusive, ``ge``/``le`` inclusive."""
    lo, lo_open = (gt, True) if gt is not None else (ge if ge is not None else -math.inf, False)
    hi, hi_open = (lt, True) if lt is not None else (le if le is not None else math.inf, False)
    return Allowed(kind, lo, hi, lo_open, hi_open, names, null, nonempty, reasons)


def setting(default=None, kind="number", *, default_factory=None, **bounds):
    """A dataclass field with its :class:`Allowed` values (:func:`allowed`) in ``metadata['allowed']``."""
    meta = {"allowed": allowed(kind, **bounds)}
    if default_factory is not None:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


def check_fields(obj, key: Callable[[str], str], source: str = "") -> None:
    """Hold every field of a dataclass instance with :func:`setting` metadata to it (values normalised in place).

    ``key(name)``: how the user names the field (``diagnose.block_s``, ``--dropout``).
    """
    for f in fields(obj):
        allowed = f.metadata.get("allowed")
        if allowed is not None:
            default = f.default if f.default_factory is MISSING else f.default_factory()
            setattr(obj, f.name, allowed.check(key(f.name), getattr(obj, f.name), default, source))


def check_known(key: str, given, cls, source: str = "") -> None:
    """Refuse a key of ``given`` that is not a field of the settings dataclass ``cls`` (``key.name``)."""
    from dataclasses import fields as _fields

    names = [f.name for f in _fields(cls)]
    extra = sorted(str(k) for k in given if k not in names)
    if extra:
        raise QrInputError(f"{key}.{extra[0]}", "unknown setting",
                           f"use one of {', '.join(names)}{f' ({source})' if source else ''}")
