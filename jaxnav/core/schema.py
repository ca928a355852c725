"""One validator for the TOML files: a schema per section, errors naming key, value and rule.

A schema maps each key of a ``[section]`` to a ``Rule``: a callable that returns the value
converted (numbers to float, lists to tuples) or raises ``Invalid`` with what is allowed. The
study definition (``study/config.py``), the scenario factory's ``[scenario]`` table
(``study/factory.py``) and the car configuration of ``jaxnav lc`` (``apps/car_config.py``) are
all checked by ``check_section`` before any work starts; every message reads
``section.key = value: expected ...`` (``section.key[i]`` for a list item), and unknown keys are
listed with the allowed ones.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any


class SchemaError(ValueError):
    """An invalid configuration value; the message names the key, the value and the rule."""


class Invalid(Exception):
    """Raised by a rule: ``expected`` says what is allowed; ``index`` the offending list item."""

    def __init__(self, expected: str, index: int | None = None, value: Any = None):
        super().__init__(expected)
        self.expected, self.index, self.value = expected, index, value


Rule = Callable[[Any], Any]


def _is_real(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def number(lo: float | None = None, *, strict: bool = False, unit: str = "",
           specials: Mapping[str, Any] | None = None, hi: float | None = None,
           why: str = "") -> Rule:
    """A finite number (``>= lo``, or ``> lo`` when ``strict``; ``<= hi``, ``why`` says where
    that bound comes from), returned as float; ``specials`` maps accepted strings (e.g.
    ``"inf"``) to their values."""
    what = "a number" + (f" of {unit}" if unit else "")
    if lo is not None:
        what += f" {'>' if strict else '>='} {lo:g}"
    if hi is not None:
        what += f"{' and' if lo is not None else ''} <= {hi:g}" + (f" ({why})" if why else "")
    if specials:
        what += " (or " + " or ".join(f'"{s}"' for s in specials) + ")"

    def rule(v):
        if specials and isinstance(v, str) and v in specials:
            return specials[v]
        if not _is_real(v) or (lo is not None and (v <= lo if strict else v < lo)) or (
                hi is not None and v > hi):
            raise Invalid(what)
        return float(v)

    rule.expected = what
    return rule


def whole(lo: int = 0, hi: int | None = None, why: str = "") -> Rule:
    """A whole number >= ``lo`` (and <= ``hi``; ``why`` says where the bound comes from);
    booleans and floats such as 2.5 or 3.0 are refused."""
    what = f"a whole number >= {lo}" + (f" and <= {hi:,}" if hi is not None else "")
    what += f" ({why})" if why else ""

    def rule(v):
        if not isinstance(v, int) or isinstance(v, bool) or v < lo or (hi is not None and v > hi):
            raise Invalid(what)
        return v

    rule.expected = what
    return rule


def boolean() -> Rule:
    """true or false."""

    def rule(v):
        if not isinstance(v, bool):
            raise Invalid("true or false")
        return v

    rule.expected = "true or false"
    return rule


def text() -> Rule:
    """A non-empty string."""

    def rule(v):
        if not isinstance(v, str) or not v:
            raise Invalid("a non-empty string")
        return v

    rule.expected = "a non-empty string"
    return rule


def choice(options: Iterable[str], what: str = "") -> Rule:
    """One of ``options`` (a declared table's names, never an attribute lookup)."""
    options = tuple(options)
    expected = f"one of {', '.join(map(repr, options))}" + (f" ({what})" if what else "")

    def rule(v):
        if not isinstance(v, str) or v not in options:
            raise Invalid(expected)
        return v

    rule.expected = expected
    return rule


def either(*rules: Rule) -> Rule:
    """The first rule that accepts the value."""
    expected = " or ".join(r.expected for r in rules)

    def rule(v):
        for r in rules:
            try:
                return r(v)
            except Invalid:
                pass
        raise Invalid(expected)

    rule.expected = expected
    return rule


def literal(value: str) -> Rule:
    """Exactly the string ``value``."""

    def rule(v):
        if v != value:
            raise Invalid(f'"{value}"')
        return v

    rule.expected = f'"{value}"'
    return rule


def items(item: Rule, *, length: int | None = None, unique: bool = True,
          nonempty: bool = True) -> Rule:
    """A list of values each accepted by ``item`` (returned as a tuple): ``length`` items if
    given, else at least one (``nonempty``), distinct when ``unique``. A bad item is reported
    with its index."""
    shape = f"a list of {length}" if length is not None else (
        "a non-empty list" if nonempty else "a list")
    expected = f"{shape} ({item.expected})"

    def rule(v):
        if not isinstance(v, list | tuple) or (length is not None and len(v) != length) or (
                nonempty and len(v) == 0):
            raise Invalid(expected)
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item(x))
            except Invalid as e:
                raise Invalid(e.expected, i, x) from None
            if unique and out[-1] in out[:-1]:
                raise Invalid("distinct values (duplicate)", i, x)
        return tuple(out)

    rule.expected = expected
    return rule


def fail(key: str, value, expected: str, error: type[SchemaError] = SchemaError):
    """Raise ``error`` with the one-line message ``key = value: expected ...``."""
    raise error(f"{key} = {value!r}: expected {expected}")


def check_section(section: str, table, schema: Mapping[str, Rule], *,
                  required: Iterable[str] = (), error: type[SchemaError] = SchemaError,
                  note: str = "") -> dict[str, Any]:
    """Validate one ``[section]`` table against its schema; returns the converted values of the
    keys present. Unknown and missing keys are errors (``note`` is added to the missing-key
    message, e.g. why there is no default)."""
    if not isinstance(table, Mapping):
        fail(section, table, f"a [{section}] table", error)
    for k in table:
        if k not in schema:
            raise error(f"unknown key {section}.{k} (value {table[k]!r}); allowed keys in "
                        f"[{section}]: {', '.join(schema)}")
    for k in required:
        if k not in table:
            raise error(f"missing key {section}.{k}" + (f" ({note})" if note else ""))
    out = {}
    for k, v in table.items():
        try:
            out[k] = schema[k](v)
        except Invalid as e:
            key, value = (f"{section}.{k}", v) if e.index is None else (
                f"{section}.{k}[{e.index}]", e.value)
            fail(key, value, e.expected, error)
    return out


def check_sections(data, sections: Iterable[str], error: type[SchemaError] = SchemaError):
    """The file's top level: a table of the known ``[section]`` tables."""
    sections = tuple(sections)
    if not isinstance(data, Mapping):
        raise error(f"expected a table of sections, got {type(data).__name__}")
    for k in data:
        if k not in sections:
            raise error(f"unknown section or key [{k}]; allowed sections: "
                        f"{', '.join(sections)}")
        if not isinstance(data[k], Mapping):
            fail(k, data[k], f"a [{k}] table", error)
