"""What a run keeps of its signals when only its metrics are wanted, folded in as rows arrive.

Each :class:`Reduction` folds one signal of a batch of runs, chunk by chunk (:class:`Chunk`), into
the figure the summary reports; a full record is reduced the same way, as one chunk, so both give
the same numbers. Rows at or after the row that stopped a copy do not count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

from ..error_rate import ErrorRateStream


@dataclass(frozen=True)
class Chunk:
    """Rows ``first .. first + len(t) - 1`` of a batch: their instants ``t`` and, per copy, how
    many rows it keeps (``kept``; a diverged copy keeps the rows up to the one that stopped it) and
    whether it diverged."""

    first: int
    t: np.ndarray
    kept: np.ndarray
    diverged: np.ndarray
    hold: int = 1  # rows per control period: the control samples are the rows k with k % hold == 0

    @cached_property
    def everyone(self) -> bool:
        """Every row counts for every copy (no copy stopped in or before the chunk)."""
        return bool(self.kept.min() > self.first + len(self.t))

    @cached_property
    def valid(self) -> np.ndarray:
        """``(rows, batch)``: the row counts for the copy."""
        return (self.first + np.arange(len(self.t)))[:, None] < self.kept[None, :]


class Reduction:
    """Folds one signal, ``(rows, batch[, width])`` per chunk, into a value per copy."""

    name: ClassVar[str]  # its key in RunMetrics and in the summary

    def __init__(self, batch: int, width: int, duration: float) -> None:
        self.batch = batch

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        raise NotImplementedError

    def value(self, b: int) -> Any:
        raise NotImplementedError


def _finite_or_nan(value: float) -> float:
    return value if math.isfinite(value) else math.nan


class LargestAbs(Reduction):
    """The largest finite ``|u|`` (NaN when there is none)."""

    name = "max_abs_u"

    def __init__(self, batch: int, width: int, duration: float) -> None:
        super().__init__(batch, width, duration)
        self.largest = np.full(batch, -np.inf)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        size = np.abs(values)
        counted = np.isfinite(size) if chunk.everyone else chunk.valid & np.isfinite(size)
        np.maximum(self.largest, np.where(counted, size, -np.inf).max(axis=0), out=self.largest)

    def value(self, b: int) -> float:
        return _finite_or_nan(float(self.largest[b]))


class LargestAbsApplied(LargestAbs):
    """The largest finite ``|u|`` the actuator applied."""

    name = "max_abs_u_applied"


class SaturatedFraction(Reduction):
    """The fraction of control samples (rows ``k`` with ``k % hold == 0`` and a finite u) at which
    the actuator clipped the command (NaN when there is none)."""

    name = "saturated_fraction"

    def __init__(self, batch: int, width: int, duration: float) -> None:
        super().__init__(batch, width, duration)
        self.clipped = np.zeros(batch)
        self.samples = np.zeros(batch)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        rows = chunk.first + np.arange(len(chunk.t))
        counted = chunk.valid & ((rows % chunk.hold) == 0)[:, None] & np.isfinite(values)
        self.samples += counted.sum(axis=0)
        self.clipped += np.where(counted, values, 0.0).sum(axis=0)

    def value(self, b: int) -> float:
        return float(self.clipped[b] / self.samples[b]) if self.samples[b] else math.nan


class ErrorRate(Reduction):
    """Table 1's error rate E(omega) of ``z_1`` (see :mod:`qcontrol.error_rate`)."""

    name = "error_rate"

    def __init__(self, batch: int, width: int, duration: float) -> None:
        super().__init__(batch, width, duration)
        self.stream = ErrorRateStream(duration, batch=batch)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        z1 = values[..., 0]
        self.stream.add(chunk.t, z1 if chunk.everyone else np.where(chunk.valid, z1, np.nan))

    def value(self, b: int) -> dict[str, float]:
        return self.stream.rates(run=b)


class LastHalfLargestAbs(Reduction):
    """The largest finite ``|z_1|`` over the last half of the run (NaN when there is none)."""

    name = "max_abs_z1_last_half"

    def __init__(self, batch: int, width: int, duration: float) -> None:
        super().__init__(batch, width, duration)
        self.half = duration / 2.0
        self.largest = np.full(batch, -np.inf)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        z1 = values[..., 0]
        late = chunk.valid & (chunk.t >= self.half)[:, None] & np.isfinite(z1)
        np.maximum(self.largest, np.where(late, np.abs(z1), -np.inf).max(axis=0), out=self.largest)

    def value(self, b: int) -> float:
        return _finite_or_nan(float(self.largest[b]))


class Lemma2Largest(Reduction):
    """The largest finite Lemma 2 error ``|e_zi|`` per i, over every row before a divergence (the
    row that stopped a diverged copy holds an out-of-range state, where quantization error is
    meaningless)."""

    name = "e_z_max"

    def __init__(self, batch: int, width: int, duration: float) -> None:
        super().__init__(batch, width, duration)
        self.largest = np.full((batch, width), -np.inf)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        checked = np.isfinite(values)
        if not chunk.everyone:
            last = np.where(chunk.diverged, chunk.kept - 1, chunk.kept)
            rows = chunk.first + np.arange(len(chunk.t))
            checked &= (rows[:, None] < last[None, :])[..., None]
        np.maximum(self.largest, np.where(checked, values, -np.inf).max(axis=0), out=self.largest)

    def value(self, b: int) -> np.ndarray:
        return self.largest[b].copy()


class FinalValue(Reduction):
    """The adaptive state at the last row each copy keeps."""

    name = "final_adaptive"

    def __init__(self, batch: int, width: int, duration: float) -> None:
        super().__init__(batch, width, duration)
        self.final = np.full((batch, width), np.nan)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        last = chunk.kept - 1 - chunk.first
        here = (last >= 0) & (last < len(chunk.t))
        self.final[here] = values[last[here], np.flatnonzero(here)]

    def value(self, b: int) -> np.ndarray:
        return self.final[b].copy()
