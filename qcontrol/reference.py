"""Reference signals y_d with analytic derivatives (Assumption 3: y_d^(0..n) known, bounded)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


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
