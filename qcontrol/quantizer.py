"""State quantizers, SPEC section 2, the paper's eqs. (3)-(4).

The controller only ever sees ``q(x)``; the engine applies a :class:`Quantizer` to every sensor
reading before the controller is called.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from .errors import QcontrolInputError


@runtime_checkable
class Quantizer(Protocol):
    """Anything that maps readings to quantized readings, elementwise, with a known bound.

    ``max_error`` is the bound of property (4): ``|q(x) - x| <= max_error`` for every real x.
    Lemma 2's bounds are computed from it, so a plugged-in quantizer must state it honestly.
    """

    max_error: float

    def __call__(self, x: np.ndarray) -> np.ndarray: ...


class UniformQuantizer:
    """Uniform mid-tread quantizer with step ``delta`` and infinitely many levels, eq. (3).

    ``q(x) = l * delta`` for ``(2l-1) delta/2 <= x < (2l+1) delta/2``, i.e.
    ``q(x) = delta * floor(x / delta + 1/2)``. Property (4): ``|q(x) - x| <= delta / 2``.
    """

    def __init__(self, delta: float) -> None:
        if not (np.isfinite(delta) and delta > 0):
            raise QcontrolInputError(f"quantizer step delta must be a finite number > 0, got {delta!r}")
        self.delta = float(delta)
        self.max_error = self.delta / 2.0

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.delta * np.floor(np.asarray(x, dtype=float) / self.delta + 0.5)

    def on_floats(self, values: Sequence[float]) -> tuple[float, ...]:
        """:meth:`__call__` on plain floats, bit for bit (``floor`` is exact either way)."""
        d = self.delta
        try:
            return tuple([d * math.floor(v / d + 0.5) for v in values])
        except (ValueError, OverflowError):  # NaN or Inf: numpy's answer
            return tuple(self(np.array(values)).tolist())

    def __repr__(self) -> str:
        return f"UniformQuantizer(delta={self.delta!r})"


class QuantizedReading:
    """Sensor readings after quantization: the only state a controller accepts (Assumption 2).

    Controllers refuse plain arrays, so the true state cannot be handed to them by accident.
    ``max_error`` carries the quantizer's bound so the controller can check that its Lemma 2
    bounds were computed for this quantizer.

    Two views of the same numbers: ``values`` with shape ``(batch, n)``, and ``columns``, one
    value per state ``q_1 .. q_n``, each a ``(batch,)`` array, or a plain float for a reading of
    one copy made by :func:`quantize_floats` (``floats`` is then true). The controller's formulas
    work on columns; either view is made from the other when first asked for.
    """

    __slots__ = ("_values", "_columns", "max_error", "floats")

    def __init__(self, values: np.ndarray, max_error: float) -> None:
        self._values: np.ndarray | None = values
        self._columns: tuple | None = None
        self.max_error = max_error
        self.floats = False

    @classmethod
    def of_floats(cls, values: Sequence[float], max_error: float) -> QuantizedReading:
        """A reading of one copy as plain floats ``q_1 .. q_n`` (the batch-of-one fast path)."""
        reading = cls.__new__(cls)
        reading._values, reading._columns = None, tuple(values)
        reading.max_error, reading.floats = max_error, True
        return reading

    @property
    def values(self) -> np.ndarray:
        if self._values is None:
            self._values = np.array([self._columns], dtype=float)
        return self._values

    @property
    def columns(self) -> tuple:
        if self._columns is None:
            self._columns = tuple(self._values.T)
        return self._columns


def quantize(quantizer: Quantizer, readings: np.ndarray) -> QuantizedReading:
    """Apply ``quantizer`` to sensor ``readings`` (shape ``(batch, n)``)."""
    return QuantizedReading(quantizer(readings), quantizer.max_error)


def quantize_floats(quantizer: Quantizer, readings: Sequence[float]) -> QuantizedReading:
    """Apply ``quantizer`` to the readings of one copy, plain floats ``x_1 .. x_n``. A quantizer
    with an ``on_floats`` method (:class:`UniformQuantizer`) does it without numpy."""
    on_floats = getattr(quantizer, "on_floats", None)
    values = on_floats(readings) if on_floats is not None else quantizer(np.array([readings]))[0].tolist()
    return QuantizedReading.of_floats(values, quantizer.max_error)
