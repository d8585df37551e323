"""Names and units of the states and inputs of a problem (docs/problem-format.md, "Engineering forms").

Names and units are data read from a file, shown in terminal tables, HTML reports and plot labels,
so they are restricted to a safe character set (no markup, no control characters, no TeX), checked
here for the JSON file and for the Python constructors alike:

* a name: a letter, then letters, digits or ``_``, at most :data:`NAME_MAX` characters; the names of
  the states (and those of the inputs) are distinct; ``min`` and ``max`` are reserved (the array form
  of ``bounds``);
* a unit: at most :data:`UNIT_MAX` characters among letters, digits, space and ``/ * ^ . ( ) % - _ °``
  (``m/s``, ``rad/s^2``, ``N*m``, ``deg``, ``°C``); empty for a dimensionless quantity.

Without names, the states are ``x1 … xn`` and the inputs ``u1 … um`` (the names ``bounds`` accepts).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from amcp_drake.model.errors import ProblemError

NAME_MAX = 24
UNIT_MAX = 16
NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]{0,23}$"
UNIT_PATTERN = r"^[A-Za-z0-9 /*^.()%_°-]{0,16}$"
RESERVED_NAMES = frozenset({"min", "max"})
_NAME = re.compile(NAME_PATTERN)
_UNIT = re.compile(UNIT_PATTERN)


@dataclass(frozen=True)
class Signal:
    """A named state or input with its unit (``unit`` empty: dimensionless or not given)."""

    name: str
    unit: str = ""

    @property
    def label(self) -> str:
        """``name [unit]``, or ``name`` without a unit (the text of tables and plot axes)."""
        return f"{self.name} [{self.unit}]" if self.unit else self.name


def default_names(prefix: str, count: int) -> tuple[str, ...]:
    """``x1 … xn`` (prefix ``x``) or ``u1 … um`` (prefix ``u``): the names of unnamed signals."""
    return tuple(f"{prefix}{i + 1}" for i in range(count))


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def as_signal(field: str, value: Any) -> Signal:
    """One :class:`Signal` from a Signal, a name, a ``(name, unit)`` pair or ``{"name": ..., "unit": ...}``."""
    if isinstance(value, Signal):
        name, unit = value.name, value.unit
    elif isinstance(value, str):
        name, unit = value, ""
    elif isinstance(value, tuple) and len(value) == 2:
        name, unit = value
    elif isinstance(value, dict):
        unknown = sorted(set(value) - {"name", "unit"})
        if unknown:
            raise ProblemError(f"{field}.{unknown[0]}", "one of the keys ['name', 'unit']", f"unknown key {unknown[0]!r}")
        if "name" not in value:
            raise ProblemError(f"{field}.name", "a value", "nothing (key missing)")
        name, unit = value["name"], value.get("unit", "")
    else:
        raise ProblemError(field, 'a name or {"name": ..., "unit": ...}', _shown(value))
    if not isinstance(name, str) or not _NAME.match(name):
        raise ProblemError(f"{field}.name", f"a name of 1 to {NAME_MAX} characters: a letter, then letters, digits "
                           "or '_'", _shown(name))
    if name in RESERVED_NAMES:
        raise ProblemError(f"{field}.name", "a name other than 'min' and 'max' (reserved for the array form of "
                           "bounds)", _shown(name))
    if not isinstance(unit, str) or not _UNIT.match(unit):
        raise ProblemError(f"{field}.unit", f"a unit of at most {UNIT_MAX} characters among letters, digits, space "
                           "and / * ^ . ( ) % - _ °", _shown(unit))
    return Signal(name, unit)


def as_signals(field: str, value: Any, count: int) -> tuple[Signal, ...]:
    """The ``count`` signals of ``value`` (None or empty: none given, ``()``); distinct names."""
    if value is None or (isinstance(value, (list, tuple)) and len(value) == 0):
        return ()
    if not isinstance(value, (list, tuple)):
        raise ProblemError(field, f"a list of {count} names or {{\"name\", \"unit\"}} objects", _shown(value))
    if len(value) != count:
        raise ProblemError(field, f"{count} entries (one per {'state' if field.endswith('states') else 'input'})",
                           f"{len(value)} entries")
    out = tuple(as_signal(f"{field}[{i}]", v) for i, v in enumerate(value))
    seen: dict[str, int] = {}
    for i, s in enumerate(out):
        if s.name in seen:
            raise ProblemError(f"{field}[{i}].name", f"a name not used before (it is that of {field}[{seen[s.name]}])",
                               repr(s.name))
        seen[s.name] = i
    return out


def signals_to_json(signals: tuple[Signal, ...]) -> list[dict]:
    """The JSON form of ``signals`` (``unit`` omitted when empty)."""
    return [{"name": s.name, "unit": s.unit} if s.unit else {"name": s.name} for s in signals]


__all__ = ["Signal", "as_signal", "as_signals", "default_names", "signals_to_json"]
