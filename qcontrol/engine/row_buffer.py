"""Where the loop puts each row it records: the buffer of recorded signals, and its writer for a
batch in array form (:class:`ArrayRows`; :mod:`.fastpath` chooses the rows of a run). The rows
of every form offer the loop the same things: the initial adaptive state,
the quantizer, the differenced velocity and the plant's observe and step in their form, ``keep``
(one row), and ``flush``, ``untested`` and ``next_event`` (at the loop's rare rows).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from ..controller.backstepping import Advance
from ..controller.law import BatchLaw
from ..plants.base import Plant
from ..quantizer import QuantizedReading, Quantizer, quantize
from .signals import RECORDED
from .velocity import ArrayDifferencing

NEVER = 1 << 62  # a row no run reaches


class RowBuffer:
    """Arrays of the recorded signals for ``capacity`` rows of ``batch`` copies:
    ``arrays[name]`` has shape ``(capacity, batch, width)`` (``(capacity, batch)`` for a scalar);
    buffer row ``j`` holds run row ``base + j`` (a metrics-only run reuses the buffer chunk after
    chunk).

    Stored row after row (a row of every copy together: the array form writes a row at a time), or,
    after :meth:`by_copy`, copy after copy (``arrays`` are then views of ``copies``, the arrays
    ``(batch, capacity[, width])``): the compiled batch writes every row of one copy in turn, and
    rows of a copy stored together stay on a few memory pages instead of one page per row (with
    1000 copies a row of ``x`` is 16 kB: the pages' translations, not the stores, cost most)."""

    def __init__(self, capacity: int, batch: int, n: int, m: int) -> None:
        self.base = 0
        self.shapes = {s.name: (capacity, batch) if s.width == "1" else (capacity, batch, s.size(n, m))
                       for s in RECORDED}
        self._arrays: dict[str, np.ndarray] | None = None  # made when first asked for (or by by_copy)
        self.copies: dict[str, np.ndarray] | None = None

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        if self._arrays is None:
            self._arrays = {name: np.full(shape, np.nan) for name, shape in self.shapes.items()}
        return self._arrays

    def by_copy(self) -> dict[str, np.ndarray]:
        """Store the rows copy after copy from now on (rows written before are kept); returns
        ``copies``. The same values are read through ``arrays``, whatever the storage."""
        if self.copies is None:
            if self._arrays is None:
                self.copies = {name: np.full((shape[1], shape[0], *shape[2:]), np.nan)
                               for name, shape in self.shapes.items()}
            else:
                self.copies = {name: np.ascontiguousarray(np.swapaxes(a, 0, 1))
                               for name, a in self._arrays.items()}
            self._arrays = {name: np.swapaxes(a, 0, 1) for name, a in self.copies.items()}
        return self.copies

    def rows(self, first: int, stop: int) -> dict[str, np.ndarray]:
        """Views of run rows ``[first, stop)`` of every recorded signal."""
        held = slice(first - self.base, stop - self.base)
        return {name: array[held] for name, array in self.arrays.items()}


class ArrayRows:
    """A batch: each row written into the buffer's arrays as it comes, and tested at once (cheap
    while the row is in the cache); only a row that fails the test is examined copy by copy."""

    def __init__(self, buffer: RowBuffer, state_bound: float) -> None:
        self.buffer, self.batch = buffer, buffer.shapes["u"][1]
        self.state_bound = state_bound
        self._suspect = -1  # the last row that failed the quick test

    def initial_state(self, law: BatchLaw) -> tuple[np.ndarray, ...]:
        return tuple(np.ascontiguousarray(law.initial_state(self.batch).T))

    def quantizer(self, quantizer: Quantizer) -> Callable[[np.ndarray], QuantizedReading]:
        return partial(quantize, quantizer)

    def differenced(self, quantize: Callable[[np.ndarray], QuantizedReading], hold: int, period: float
                    ) -> ArrayDifferencing:
        return ArrayDifferencing(quantize, hold, period)

    def plant_io(self, plant: Plant, h: float) -> ArrayIO:
        return ArrayIO(plant, h)

    def law(self, law: BatchLaw, h: float) -> tuple[Callable[..., Any], Advance]:
        """``(control, advance)`` of the batch: the law's array form."""
        return law.control, law.advancer(h)

    def keep(self, k: int, x: np.ndarray, meas: np.ndarray, reading: QuantizedReading, u: np.ndarray,
             adaptive: tuple) -> bool:
        """Row ``k``; True when some copy may have diverged there (NaN fails either test)."""
        j, arrays = k - self.buffer.base, self.buffer.arrays  # (its storage may change: RowBuffer.by_copy)
        arrays["x"][j], arrays["x_meas"][j], arrays["x_q"][j], arrays["u"][j] = x, meas, reading.values, u
        for i, a in enumerate(adaptive):
            arrays["adaptive"][j, :, i] = a
        if np.abs(arrays["x"][j]).max() <= self.state_bound and math.isfinite(arrays["adaptive"][j].sum()):
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


class ArrayIO:
    """The plant's own observe, and its step with the run's step length ``h``."""

    def __init__(self, plant: Plant, h: float) -> None:
        self.plant, self.h = plant, h
        self.observe = plant.observe

    def step(self, u: np.ndarray) -> None:
        self.plant.step(u, self.h)
