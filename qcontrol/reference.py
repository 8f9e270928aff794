"""Reference signals y_d with analytic derivatives (Assumption 3: y_d^(0..n) known, bounded), and
the keys of each kind of ``[reference]`` in a scenario (:data:`REFERENCE_KINDS`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .schema import Key, KindKeys, Table, custom, number, read_keys


class Reference(Protocol):
    """A reference trajectory y_d(t).

    ``derivatives(t, order)`` returns ``[y_d, y_d', ..., y_d^(order)]`` in the last axis: shape
    ``(order + 1,)`` for a scalar ``t``, ``t.shape + (order + 1,)`` for an array of instants.
    """

    def derivatives(self, t: float | np.ndarray, order: int) -> np.ndarray: ...


@dataclass(frozen=True)
class Sine:
    """``y_d = offset + amplitude * sin(frequency * t + phase)`` (frequency in rad/s)."""

    amplitude: float = 1.0
    frequency: float = 1.0
    phase: float = 0.0
    offset: float = 0.0

    def derivatives(self, t: float | np.ndarray, order: int) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        out = np.empty(t.shape + (order + 1,))
        arg = self.frequency * t + self.phase
        s, c = np.sin(arg), np.cos(arg)
        # d^j/dt^j sin(w t + p) = w^j * [sin, cos, -sin, -cos][j mod 4]
        cycle = (s, c, -s, -c)
        for j in range(order + 1):
            out[..., j] = self.amplitude * self.frequency**j * cycle[j % 4]
        out[..., 0] += self.offset
        return out


@dataclass(frozen=True)
class Constant:
    """``y_d = value``; every derivative is zero."""

    value: float = 0.0

    def derivatives(self, t: float | np.ndarray, order: int) -> np.ndarray:
        out = np.zeros(np.shape(t) + (order + 1,))
        out[..., 0] = self.value
        return out


@dataclass(frozen=True)
class SumOfSines:
    """A constant offset plus a sum of sines; each term is a :class:`Sine` (its offset ignored)."""

    terms: tuple[Sine, ...]
    offset: float = 0.0

    def derivatives(self, t: float | np.ndarray, order: int) -> np.ndarray:
        out = np.zeros(np.shape(t) + (order + 1,))
        for term in self.terms:
            out += term.derivatives(t, order)
            out[..., 0] -= term.offset
        out[..., 0] += self.offset
        return out


# --------------------------------------------------------------------------------------------
# Scenario keys: [reference], one kind each


def _check_derivatives(table: Table, key: str, amplitude: float, frequency: float, order: int) -> None:
    """The controller uses y_d^(k) = amplitude frequency^k (...) for k <= n: all must be finite."""
    try:
        biggest = max(abs(amplitude) * abs(frequency) ** k for k in range(order + 1))
    except OverflowError:
        biggest = math.inf
    if not math.isfinite(biggest):
        raise table.error(key, f"amplitude {amplitude:g} at frequency {frequency:g} rad/s gives a non-finite "
                          f"derivative y_d^(k), k <= {order}", "use a smaller amplitude or frequency")


SINE_KEYS = (
    Key("amplitude", number(), 1.0, "y units", "amplitude of the sine", example="1.0"),
    Key("frequency", number(), 1.0, "rad/s", "angular frequency", example="1.5"),
    Key("phase", number(), 0.0, "rad", "phase at t = 0"),
)
OFFSET = Key("offset", number(), 0.0, "y units", "constant added to y_d")
CONSTANT_KEYS = (Key("value", number(), 0.0, "y units", "the constant y_d", example="0.2"),)


def _read_terms(table: Table, key: str, default: object, sizes: object) -> tuple[Sine, ...]:
    """``terms``: a non-empty list of tables, each read with the keys of a sine."""
    raw = table.get(key, default)
    if not isinstance(raw, list) or not raw:
        raise table.error(key, "must be a non-empty list of tables",
                          "write terms = [{amplitude = 1.0, frequency = 2.0}]")
    names = [k.name for k in SINE_KEYS]
    return tuple(Sine(**read_keys(Table(term, table.source, f"{table.path(key)}[{i}]", names), SINE_KEYS, {}))
                 for i, term in enumerate(raw))


SUM_KEYS = (
    Key("terms", custom("list of tables {amplitude, frequency, phase}", _read_terms),
        meaning="the sines summed: amplitude (y units), frequency (rad/s), phase (rad), as for kind sine",
        example="[{amplitude = 1.0, frequency = 1.5}, {amplitude = 0.2, frequency = 4.0, phase = 0.5}]"),
    OFFSET,
)


def _sine(table: Table, order: int) -> Sine:
    v = read_keys(table, (*SINE_KEYS, OFFSET), {})
    _check_derivatives(table, "frequency", v["amplitude"], v["frequency"], order)
    return Sine(**v)


def _constant(table: Table, order: int) -> Constant:
    return Constant(**read_keys(table, CONSTANT_KEYS, {}))


def _sum_of_sines(table: Table, order: int) -> SumOfSines:
    v = read_keys(table, SUM_KEYS, {})
    for i, term in enumerate(v["terms"]):
        where = Table({}, table.source, f"{table.path('terms')}[{i}]")
        _check_derivatives(where, "frequency", term.amplitude, term.frequency, order)
    return SumOfSines(v["terms"], v["offset"])


@dataclass(frozen=True)
class ReferenceKind:
    """One kind of reference: its keys and how a reference is made from them (``parse(table, n)``)."""

    keys: KindKeys
    parse: Callable[[Table, int], Reference]


REFERENCE_KINDS: dict[str, ReferenceKind] = {
    "sine": ReferenceKind(
        KindKeys("sine", (*SINE_KEYS, OFFSET), "y_d = offset + amplitude sin(frequency t + phase)"), _sine),
    "constant": ReferenceKind(KindKeys("constant", CONSTANT_KEYS, "a set point: y_d = value"), _constant),
    "sum_of_sines": ReferenceKind(KindKeys("sum_of_sines", SUM_KEYS, "y_d = offset + a sum of sines"),
                                  _sum_of_sines),
}
