"""State quantizers, the paper's eqs. (3)-(4).

The controller only ever sees ``q(x)``; the engine applies a :class:`Quantizer` to every sensor
reading before the controller is called.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from .columns import ARRAYS, Column, ColumnForm
from .errors import QcontrolInputError


class Quantizer(Protocol):
    """Anything that maps readings to quantized readings, elementwise, with a known bound.

    ``max_error`` is the bound of property (4): ``|q(x) - x| <= max_error`` for every real x.
    Lemma 2's bounds are computed from it, so a plugged-in quantizer must state it honestly.
    """

    max_error: float

    def __call__(self, x: np.ndarray) -> np.ndarray: ...


def uniform(x: Any, delta: Any, floor: Callable[[Any], Any] = np.floor) -> Any:
    """``q(x) = delta floor(x / delta + 1/2)``, eq. (3): the one definition of the uniform
    quantizer, for a step shared by every channel or one per channel (``delta`` broadcast against
    ``x``), on a column of any form with that form's ``floor``."""
    return delta * floor(x / delta + 0.5)


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
        return self.apply(np.asarray(x, dtype=float), np.floor)

    def apply(self, x: Any, floor: Callable[[Any], Any]) -> Any:
        """:func:`uniform` with this quantizer's step, on a column of any form
        (:mod:`qcontrol.columns`: an array, a float, a traced symbol) with that form's ``floor``."""
        return uniform(x, self.delta, floor)

    def __repr__(self) -> str:
        return f"UniformQuantizer(delta={self.delta!r})"


class QuantizedReading:
    """Sensor readings after quantization: the only state a controller accepts (Assumption 2).

    Controllers refuse plain arrays, so the true state cannot be handed to them by accident.
    ``max_error`` carries the quantizer's bound so the controller can check that its Lemma 2
    bounds were computed for this quantizer.

    Two views of the same numbers: ``values`` with shape ``(batch, n)``, and ``columns``, one
    column per state ``q_1 .. q_n`` in the reading's :attr:`form` (:mod:`qcontrol.columns`; a
    ``(batch,)`` array each in the array form). The controller's formulas work on columns and take
    what else they need from ``form``; ``values`` of a reading made from columns is made when
    first asked for.
    """

    __slots__ = ("_values", "columns", "max_error", "form", "batch")

    def __init__(self, values: np.ndarray | None, max_error: float, *,
                 columns: Sequence[Column] | None = None, form: ColumnForm = ARRAYS,
                 batch: int | None = None) -> None:
        """``QuantizedReading(values, max_error)`` for a ``(batch, n)`` array, or
        ``QuantizedReading(None, max_error, columns=..., form=..., batch=...)`` for the columns of
        ``batch`` copies in that form."""
        self.max_error = max_error
        self._values = values
        self.form = form
        if columns is None:
            self.columns: tuple = tuple(np.asarray(values).T)
            self.batch = len(values)
        elif batch is None:
            raise ValueError("a QuantizedReading made from columns needs batch=, the copies they hold")
        else:
            self.columns, self.batch = tuple(columns), batch

    @property
    def values(self) -> np.ndarray:
        if self._values is None:
            self._values = self.form.array(self.columns, self.batch)
        return self._values


def quantize(quantizer: Quantizer, readings: np.ndarray) -> QuantizedReading:
    """Apply ``quantizer`` to sensor ``readings`` (shape ``(batch, n)``)."""
    return QuantizedReading(quantizer(readings), quantizer.max_error)
