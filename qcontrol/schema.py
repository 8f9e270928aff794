"""Scenario keys declared as data, and the validator that reads them.

Every key a scenario file may hold is declared once, as a :class:`Key`: its name, its type (a
:class:`ValueType`, which both checks a value and describes itself for the documentation), its
default, its unit and its meaning. A :class:`Section` groups the keys of one TOML table; a table
with a ``kind`` key (the controller, the reference) takes the keys of the chosen kind as well,
which each kind declares in its own module (:class:`KindKeys`).

:class:`Table` is the message-producing reader of one table: every problem becomes one
:class:`~qcontrol.errors.QcontrolInputError` line that names the file, the key, what is wrong and
the fix, e.g. ``example2.toml: controller.c[1]: must be > 0, got -3; use a positive number``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .errors import KeyNotForKind, QcontrolInputError

REQUIRED: Any = object()  # the default of a key that must be given
OPTIONAL: Any = object()  # the default of a key that may be left out and then has no value
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+(\[[0-9]+\])*")


def show_key(key: str) -> str:
    """A key as it may appear in a one-line message: bare if it is a plain name (or an indexed
    one such as ``c[1]``), otherwise quoted like a TOML quoted key (newlines escaped)."""
    return key if _BARE_KEY.fullmatch(key) else json.dumps(key)


def type_name(value: Any) -> str:
    """How a message names the TOML type of ``value``."""
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            list: "a list", dict: "a table"}.get(type(value), type(value).__name__)


class Table:
    """Typed, message-producing access to one TOML table (``name`` is its dotted path)."""

    def __init__(self, data: Any, source: str, name: str, allowed: Sequence[str] | None = None) -> None:
        self.source = source
        self.name = name
        if not isinstance(data, dict):
            raise self.error_at(name or "(top level)", f"must be a table, got {type_name(data)}",
                                _table_hint(name))
        if allowed is not None:
            unknown = sorted(set(data) - set(allowed))
            if unknown:
                where = "" if not name else f"in {name} " if "[" in name else f"in [{name}] "
                raise self.error(unknown[0], "unknown key", f"allowed keys {where}are {', '.join(allowed)}")
        self.data = data

    def error_at(self, key: str, problem: str, fix: str) -> QcontrolInputError:
        return QcontrolInputError(f"{self.source}: {key}: {problem}; {fix}")

    def error(self, key: str, problem: str, fix: str) -> QcontrolInputError:
        return self.error_at(self.path(key), problem, fix)

    def path(self, key: str) -> str:
        key = show_key(key)
        return f"{self.name}.{key}" if self.name else key

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, default: Any = REQUIRED) -> Any:
        """The raw value of ``key``, or ``default``; a missing required key is an error."""
        if key in self.data:
            return self.data[key]
        if default is REQUIRED:
            raise self.error(key, "missing", "add it to the scenario")
        return default

    def number(self, key: str, default: Any = REQUIRED, *, positive: bool = False,
               nonnegative: bool = False, maximum: float | None = None) -> float:
        value = self.get(key, default)
        if value is None:
            return value
        value = self.check_number(key, value, positive, nonnegative)
        if maximum is not None and value > maximum:
            raise self.error(key, f"must be at most {maximum:g}, got {value:g}",
                             f"use a value <= {maximum:g}")
        return value

    def check_number(self, key: str, value: Any, positive: bool = False, nonnegative: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"must be a number, got {type_name(value)} {value!r}", "write e.g. 1.5")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {value}", "use a finite number")
        if positive and value <= 0:
            raise self.error(key, f"must be > 0, got {value:g}", "use a positive number")
        if nonnegative and value < 0:
            raise self.error(key, f"must be >= 0, got {value:g}", "use a number >= 0")
        return value

    def numbers(self, key: str, length: int | None = None, *, positive: bool = False,
                default: Any = REQUIRED) -> tuple[float, ...]:
        value = self.get(key, default)
        if not isinstance(value, list):
            raise self.error(key, f"must be a list of numbers, got {type_name(value)}",
                             "write e.g. [1.0, 2.0]")
        if length is not None and len(value) != length:
            raise self.error(key, f"has {len(value)} entries, expected {length}",
                             f"give exactly {length} number(s)")
        return tuple(self.check_number(f"{key}[{i}]", v, positive) for i, v in enumerate(value))

    def integer(self, key: str, default: Any = REQUIRED, minimum: int | None = None,
                maximum: int | None = None) -> int:
        value = self.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be a whole number, got {type_name(value)} {value!r}", "write e.g. 2")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum}, got {value}", f"use a value >= {minimum}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"must be at most {maximum}, got {value}", f"use a value <= {maximum}")
        return value

    def string(self, key: str, default: Any = REQUIRED, choices: Sequence[str] | None = None,
               more: str = "") -> str:
        """A string, one of ``choices`` if given (``more``: how else a choice can be made, appended to
        the refusal's fix)."""
        value = self.get(key, default)
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {type_name(value)}", 'write e.g. "text"')
        if choices is not None and value not in choices:
            raise self.error(key, f"{value!r} is not allowed", f"use one of {', '.join(choices)}{more}")
        return value

    def strings(self, key: str, default: Any = REQUIRED) -> tuple[str, ...]:
        value = self.get(key, default)
        if isinstance(value, str) or not isinstance(value, list):
            raise self.error(key, f"must be a list of expression strings, got {type_name(value)}",
                             'write e.g. ["x2", "sin(x1)"]')
        for i, v in enumerate(value):
            if not isinstance(v, str):
                raise self.error(f"{key}[{i}]", f"must be an expression string, got {type_name(v)}",
                                 'quote it, e.g. "1 + q2**2"')
        return tuple(value)

    def table(self, key: str, allowed: Sequence[str] | None = None, default: Any = REQUIRED) -> Table:
        return Table(self.get(key, default), self.source, self.path(key), allowed)


def _table_hint(name: str) -> str:
    """How to write the table ``name`` in TOML: ``[a.b]``, or for an entry of a list of tables
    (``a.b[0]``) the header ``[[a.b]]`` of each entry."""
    bare = re.sub(r"\[[0-9]+\]$", "", name)
    if bare != name and "[" not in bare:
        return f"write each entry as a table, under a [[{bare}]] header"
    return f"write [{name}]" if name else "write key = value pairs under [table] headers"


# --------------------------------------------------------------------------------------------
# Value types: each reads a key of a Table and says in words what it accepts.

Reader = Callable[[Table, str, Any, Mapping[str, int]], Any]


@dataclass(frozen=True)
class ValueType:
    """How one key is read and checked (``read(table, key, default, sizes)``) and how the
    documentation names what it accepts (``text``; ``{n}`` and friends name a size)."""

    text: str
    read: Reader
    path: bool = False  # a file path, relative to the scenario file's folder


def number(*, positive: bool = False, nonnegative: bool = False, maximum: float | None = None) -> ValueType:
    text = "number > 0" if positive else "number >= 0" if nonnegative else "number"
    text += f", at most {maximum:g}" if maximum is not None else ""
    return ValueType(text, lambda t, k, d, s: t.number(k, d, positive=positive, nonnegative=nonnegative,
                                                       maximum=maximum))


def integer(minimum: int | None = None, maximum: int | None = None) -> ValueType:
    text = "whole number" + (f" >= {minimum}" if minimum is not None else "")
    text += f", at most {maximum}" if maximum is not None else ""
    return ValueType(text, lambda t, k, d, s: t.integer(k, d, minimum, maximum))


def string(choices: Sequence[str] | None = None, more: str = "") -> ValueType:
    """A string, one of ``choices`` if given; ``more`` completes the refusal of another value (e.g.
    how to register a controller kind)."""
    text = "string" if choices is None else "one of " + ", ".join(f'"{c}"' for c in choices)
    return ValueType(text, lambda t, k, d, s: t.string(k, d, choices, more))


def numbers(size: str | None = None, *, positive: bool = False) -> ValueType:
    """A list of numbers; ``size`` names its length among the sizes (``"n"``: the plant order)."""
    what = "numbers > 0" if positive else "numbers"
    text = f"list of {size} {what}" if size else f"list of {what}"
    return ValueType(text, lambda t, k, d, s: t.numbers(k, s[size] if size else None, positive=positive,
                                                         default=d))


def expressions(variables: str) -> ValueType:
    """A list of expression strings over ``variables`` (e.g. ``"x1..xn"``)."""
    return ValueType(f"list of expressions over {variables}", lambda t, k, d, s: t.strings(k, d))


def expression(variables: str) -> ValueType:
    return ValueType(f"expression over {variables}", lambda t, k, d, s: t.string(k, d))


def custom(text: str, read: Reader, path: bool = False) -> ValueType:
    """A type read by its own function (tables, lists of tables, numbers or pairs ...); ``path``:
    its value is a file path relative to the scenario file's folder."""
    return ValueType(text, read, path)


@dataclass(frozen=True)
class Key:
    """One scenario key: how it is read, its default (:data:`REQUIRED` if it must be given),
    its unit, what it means, and an ``example`` value as TOML text (docs/scenarios.md shows it;
    a required key needs one). ``default_text`` states a default that is computed when the file
    is read (e.g. the file's name) for the documentation."""

    name: str
    type: ValueType
    default: Any = REQUIRED
    unit: str = ""
    meaning: str = ""
    example: str = ""
    default_text: str = ""

    @property
    def optional(self) -> bool:
        """Whether the key may be left out with no value (e.g. ``kappa`` beside ``kappa_margin``)."""
        return self.default is OPTIONAL


def read_keys(table: Table, keys: Sequence[Key], sizes: Mapping[str, int]) -> dict[str, Any]:
    """Every key of ``keys`` read from ``table`` (absent optional keys: None)."""
    values = {}
    for key in keys:
        if key.optional:
            values[key.name] = key.type.read(table, key.name, None, sizes) if table.has(key.name) else None
        else:
            values[key.name] = key.type.read(table, key.name, key.default, sizes)
    return values


@dataclass(frozen=True)
class KindKeys:
    """The keys one kind of a kinded table takes (e.g. the proposed law's kappa, gamma, ...).

    ``alternatives`` groups keys that give one setting in two ways (``kappa`` or
    ``kappa_margin``): a key of a group given directly in the table replaces the whole group of
    the kind's sub-table.
    """

    kind: str
    keys: tuple[Key, ...]
    meaning: str = ""
    alternatives: tuple[tuple[str, ...], ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k.name for k in self.keys)


@dataclass(frozen=True)
class Section:
    """The keys of one table: ``keys`` always apply; with ``kinds``, the key ``kind`` chooses one
    of them and that kind's keys apply too (see :func:`kind_table`; a kind whose keys are None is
    a law registered from Python, whose own factory checks them). ``array``: the file holds a list
    of such tables, ``[[name]]``, each with its kind's keys directly in it (no sub-tables).
    ``stand_in``: a key of another table that stands in for this whole table when it is left out
    (``controller.delta`` for ``[quantizer]``)."""

    name: str
    keys: tuple[Key, ...]
    meaning: str = ""
    kinds: Mapping[str, KindKeys | None] = field(default_factory=dict)
    array: bool = False
    stand_in: str = ""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k.name for k in self.keys)

    @property
    def optional(self) -> bool:
        """Whether the whole table may be left out: another key stands in for it, or every key it
        takes has a default and, in a kinded table, so has every key of the kind chosen by default."""
        if self.stand_in:
            return True
        if any(k.default is REQUIRED for k in self.keys):
            return False
        if not self.kinds:
            return True
        chosen = self.kinds.get(next((k.default for k in self.keys if k.name == "kind"), None))
        return chosen is not None and all(k.default is not REQUIRED for k in chosen.keys)


def kind_table(table: Table, common: Sequence[str], kinds: Mapping[str, KindKeys | None],
               kind: str) -> Table:
    """The table of the chosen ``kind``: its own keys, from the sub-table ``[name.<kind>]`` with
    the keys given directly in ``[name]`` on top.

    Settings of a kind that is not chosen may sit in its own sub-table (so that switching the kind
    from the command line works); a key given directly in the table must belong to the chosen kind
    (or to ``common``), otherwise it is refused with the keys that do apply. ``kinds[k]`` is None
    for a kind that declares no keys of its own (a law registered from Python): its keys are not
    checked here. Returns a :class:`Table` of the merged keys; each value remembers the path it
    came from, so messages name the sub-table or the direct key as written.
    """
    chosen = kinds[kind]
    merged: dict[str, Any] = {}
    origin: dict[str, str] = {}
    sub = table.data.get(kind)
    if isinstance(sub, dict):
        names = None if chosen is None else chosen.names
        inner = Table(sub, table.source, table.path(kind), names)
        for key, value in inner.data.items():
            merged[key], origin[key] = value, inner.path(key)
    elif sub is not None:
        raise table.error(kind, f"must be a table of the settings of kind {kind!r}, got {type_name(sub)}",
                          f"write [{table.path(kind)}]")
    for other, keys in kinds.items():  # sub-tables of kinds not chosen: names checked only
        if other != kind and isinstance(table.data.get(other), dict) and keys is not None:
            Table(table.data[other], table.source, table.path(other), keys.names)
    for key, value in table.data.items():
        if key in common or key in kinds:
            continue
        if chosen is not None and key not in chosen.names:
            problem = table.error(key, _not_for_kind(key, kind, kinds),
                                  _keys_that_apply(table, common, kind, chosen, kinds, key))
            raise KeyNotForKind(str(problem), table.path(key))
        group = _group(chosen, key)
        for alternative in group:  # a direct key replaces its whole group of the sub-table
            merged.pop(alternative, None)
            origin.pop(alternative, None)
        merged[key], origin[key] = value, table.path(key)
    return _MergedTable(merged, table.source, table.name, origin)


def _group(keys: KindKeys | None, key: str) -> tuple[str, ...]:
    if keys is not None:
        for group in keys.alternatives:
            if key in group:
                return group
    return (key,)


def _owners(key: str, kinds: Mapping[str, KindKeys | None]) -> list[str]:
    return [k for k, keys in kinds.items() if keys is not None and key in keys.names]


def _not_for_kind(key: str, kind: str, kinds: Mapping[str, KindKeys | None]) -> str:
    owners = _owners(key, kinds)
    if owners:
        return f"does not apply to kind {kind!r} (it is a setting of kind {owners[0]!r})"
    return f"unknown key for kind {kind!r}"


def _keys_that_apply(table: Table, common: Sequence[str], kind: str, chosen: KindKeys,
                     kinds: Mapping[str, KindKeys | None], key: str) -> str:
    names = ", ".join([*common, *chosen.names])
    owners = _owners(key, kinds) or [k for k in kinds if k != kind]
    if not owners:
        return f"keys of [{table.name}] with kind = {kind!r} are {names}"
    return (f"keys of [{table.name}] with kind = {kind!r} are {names}; settings of other kinds go in their "
            f"own sub-table, e.g. [{table.name}.{owners[0]}]")


class _MergedTable(Table):
    """A :class:`Table` whose keys came from several places; messages name each key's origin."""

    def __init__(self, data: dict, source: str, name: str, origin: Mapping[str, str]) -> None:
        super().__init__(data, source, name)
        self.origin = dict(origin)

    def path(self, key: str) -> str:
        bare, index = re.fullmatch(r"(.*?)((?:\[[0-9]+\])*)", key).groups()
        if bare in self.origin:
            return self.origin[bare] + index
        return super().path(key)
