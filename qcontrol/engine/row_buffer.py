"""Where the loop puts each row it records: the buffer of recorded signals and its two writers.

A batch of one runs on plain floats (:class:`FloatRows`): a numpy call on a one-element array
costs about a microsecond, float arithmetic tens of nanoseconds, so its rows are kept as tuples and
written to the arrays in blocks. A larger batch writes each row into the arrays directly
(:class:`ArrayRows`). Both offer the loop the same four things: the initial adaptive state and the
quantizer in their form, ``keep`` (one row), ``flush`` and ``untested`` (at the loop's rare rows).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from ..controller.law import BatchLaw
from ..quantizer import QuantizedReading, Quantizer, float_quantizer, quantize
from .signals import RECORDED

FLUSH_ROWS = 1000  # a batch of one: rows kept as Python tuples before they are written to arrays
NEVER = 1 << 62  # a row no run reaches


class RowBuffer:
    """Arrays of the recorded signals for ``capacity`` rows of ``batch`` copies:
    ``arrays[name]`` has shape ``(capacity, batch, width)`` (``(capacity, batch)`` for a scalar);
    buffer row ``j`` holds run row ``base + j`` (a metrics-only run reuses the buffer chunk after
    chunk)."""

    def __init__(self, capacity: int, batch: int, n: int, m: int) -> None:
        self.base = 0
        self.arrays = {
            s.name: np.full((capacity, batch) if s.width == "1" else (capacity, batch, s.size(n, m)), np.nan)
            for s in RECORDED
        }

    def rows(self, first: int, stop: int) -> dict[str, np.ndarray]:
        """Views of run rows ``[first, stop)`` of every recorded signal."""
        held = slice(first - self.base, stop - self.base)
        return {name: array[held] for name, array in self.arrays.items()}


class FloatRows:
    """A batch of one on plain floats: each row is one tuple (x, x_meas, x_q, u, adaptive, in the
    order of the signal table), written to the buffer at :meth:`flush`, at least every
    :data:`FLUSH_ROWS` rows, and tested for divergence there (a per-step test cost about 1 us of
    a 25 us MuJoCo step). The run may go on for up to that many rows after it diverged; those
    rows do not count."""

    floats = True

    def __init__(self, buffer: RowBuffer) -> None:
        self.buffer = buffer
        self._pending: list[tuple] = []
        self._append = self._pending.append
        self._tested = 0  # rows [0, tested) are tested for divergence
        self._columns = []  # (name, first column, stop column) of each signal in a row's tuple
        start = 0
        for signal in RECORDED:
            width = 1 if signal.width == "1" else buffer.arrays[signal.name].shape[2]
            self._columns.append((signal.name, start, start + width, signal.width == "1"))
            start += width

    def initial_state(self, law: BatchLaw) -> tuple[float, ...]:
        return tuple(law.initial_state(1)[0].tolist())

    def quantizer(self, quantizer: Quantizer) -> Callable[[Sequence[float]], QuantizedReading]:
        return float_quantizer(quantizer)

    def keep(self, k: int, x: list[float], meas: list[float], reading: QuantizedReading, u: float,
             adaptive: tuple) -> None:
        """Row ``k``; returns None: it is tested at the next :meth:`flush`."""
        self._append((*x, *meas, *reading.columns, u, *adaptive))

    def flush(self, k: int) -> None:
        """Write the pending rows, which end at run row ``k``, to the buffer."""
        if not self._pending:
            return
        block = np.array(self._pending, dtype=float)
        stop = k - self.buffer.base + 1
        rows = slice(stop - len(self._pending), stop)
        for name, first, last, scalar in self._columns:
            self.buffer.arrays[name][rows, 0] = block[:, first] if scalar else block[:, first:last]
        self._pending.clear()

    def untested(self, k: int) -> tuple[int, int]:
        """The rows to test for divergence now: every row since the last test, up to ``k``."""
        first, self._tested = self._tested, k + 1
        return first, k + 1

    def next_event(self, k: int) -> int:
        """The next row at which the pending rows must be flushed."""
        return ((k + 1) // FLUSH_ROWS + 1) * FLUSH_ROWS - 1


class ArrayRows:
    """A batch: each row written into the buffer's arrays as it comes, and tested at once (cheap
    while the row is in the cache); only a row that fails the test is examined copy by copy."""

    floats = False

    def __init__(self, buffer: RowBuffer, state_bound: float) -> None:
        self.buffer = buffer
        self.state_bound = state_bound
        self._x, self._x_meas, self._x_q, self._u, self._adaptive = (buffer.arrays[s.name] for s in RECORDED)
        self._suspect = -1  # the last row that failed the quick test

    def initial_state(self, law: BatchLaw) -> tuple[np.ndarray, ...]:
        return tuple(np.ascontiguousarray(law.initial_state(self._u.shape[1]).T))

    def quantizer(self, quantizer: Quantizer) -> Callable[[np.ndarray], QuantizedReading]:
        return lambda readings: quantize(quantizer, readings)

    def keep(self, k: int, x: np.ndarray, meas: np.ndarray, reading: QuantizedReading, u: np.ndarray,
             adaptive: tuple) -> bool:
        """Row ``k``; True when some copy may have diverged there (NaN fails either test)."""
        j = k - self.buffer.base
        self._x[j], self._x_meas[j], self._x_q[j], self._u[j] = x, meas, reading.values, u
        for i, a in enumerate(adaptive):
            self._adaptive[j, :, i] = a
        if np.abs(self._x[j]).max() <= self.state_bound and math.isfinite(self._adaptive[j].sum()):
            return False
        self._suspect = k
        return True

    def flush(self, k: int) -> None:
        """Nothing to do: rows are written as they come."""

    def untested(self, k: int) -> tuple[int, int]:
        """Row ``k`` if it failed the quick test, else nothing."""
        return (k, k + 1) if self._suspect == k else (k, k)

    def next_event(self, k: int) -> int:
        """Never: a batch needs no scheduled rows of its own."""
        return NEVER
