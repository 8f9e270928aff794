"""What a run keeps of its signals when only its metrics are wanted, folded in as rows arrive.

Each :class:`Reduction` folds one signal of a batch of runs, chunk by chunk (:class:`Chunk`), into
the figure the summary reports; a full record is reduced the same way, as one chunk, so both give
the same numbers. Rows at or after the row that stopped a copy do not count.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

from ..error_rate import TABLE1_OMEGAS, TABLE1_SAMPLES, ErrorRateStream

Constant = Callable[[float], str]  # a number as a slot of the compiled fold's constants


@dataclass(frozen=True)
class MetricSettings:
    """The error rate's thresholds omega and samples M (default: the paper's Table 1)."""

    omegas: tuple[float, ...] = TABLE1_OMEGAS
    samples: int = TABLE1_SAMPLES


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

    @cached_property
    def before_divergence(self) -> np.ndarray:
        """``(rows, batch)``: the row counts for the copy and is not the one that stopped it (whose
        state left the range where the theory's checks mean anything)."""
        last = np.where(self.diverged, self.kept - 1, self.kept)
        return (self.first + np.arange(len(self.t)))[:, None] < last[None, :]


class Reduction:
    """Folds one signal, ``(rows, batch[, width])`` per chunk, into a value per copy.

    ``reads`` names the signals :meth:`values` needs from a block of rows (by default the reduced
    signal itself); a metrics-only run derives only the signals its reductions read."""

    name: ClassVar[str]  # its key in RunMetrics and in the summary
    signal: ClassVar[str]  # the signal it reduces
    reads: ClassVar[tuple[str, ...]] = ()
    # Its compiled form, for the compiled batch (qcontrol.engine.compiled_batch): None where only
    # this array form folds it; else the start values of the per-copy partials that
    # :meth:`fold_lines` folds the rows of one copy into (rows that all count and are finite),
    # and :meth:`merge` adds to the reduction as :meth:`add` would. ``at_samples``: it folds
    # the control samples only.
    partials: ClassVar[tuple[float, ...] | None] = None
    at_samples: ClassVar[bool] = False
    # lines run before a copy's rows and after them (before the loop returns): state of the fold
    # held in the loop's locals
    enter: ClassVar[tuple[str, ...]] = ()
    leave: ClassVar[tuple[str, ...]] = ()

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        self.batch = batch

    @classmethod
    def needs(cls) -> tuple[str, ...]:
        return cls.reads or (cls.signal,)

    def values(self, block: Mapping[str, np.ndarray]) -> np.ndarray:
        """The reduced signal's values in a block of rows."""
        return block[self.signal]

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        raise NotImplementedError

    def value(self, b: int) -> Any:
        """Copy ``b``'s value: a reduction defines this or :meth:`every_value` (where making every
        copy's at once costs less), and the other follows from it."""
        if type(self).every_value is Reduction.every_value:
            raise NotImplementedError
        return self.every_value()[b]

    def every_value(self) -> list[Any]:
        """:meth:`value` of every copy in turn."""
        return [self.value(b) for b in range(self.batch)]

    def row_values(self, values: Any) -> list[Any]:
        """The values one row of one copy folds, from :meth:`values` of a traced row."""
        return [values]

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        """The compiled fold of one row of one copy, a row that counts: ``values`` (their names)
        into the partials ``fp[slot ..]``, taking only finite values where :meth:`add` does
        (``v - v == 0.0``: v is finite); ``t`` names the row's instant."""
        raise NotImplementedError

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        """Add the partials ``(batch, slots)`` of the copies ``copies`` (a mask), whose rows all
        counted, as :meth:`add` would have added those rows."""
        raise NotImplementedError

    def restart(self, partials: np.ndarray) -> None:
        """Per-copy start values of the partials ``(batch, slots)``, after the common ones (none)."""


def _finite_or_nan(value: float) -> float:
    return value if math.isfinite(value) else math.nan


def _each_finite_or_nan(values: np.ndarray) -> list[float]:
    """:func:`_finite_or_nan` of each value (NaN as ``math.nan`` itself, as there)."""
    return [_finite_or_nan(v) for v in values.tolist()]


class LargestAbs(Reduction):
    """The largest finite ``|u|`` (NaN when there is none)."""

    name, signal = "max_abs_u", "u"

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.largest = np.full(batch, -np.inf)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        size = np.abs(values)
        if chunk.everyone:  # the usual chunk: every value counts and is finite (then no mask is needed)
            top = size.max(axis=0)
            if np.isfinite(top).all():
                np.maximum(self.largest, top, out=self.largest)
                return
        counted = np.isfinite(size) if chunk.everyone else chunk.valid & np.isfinite(size)
        np.maximum(self.largest, np.where(counted, size, -np.inf).max(axis=0), out=self.largest)

    def every_value(self) -> list[float]:
        return _each_finite_or_nan(self.largest)

    partials = (-math.inf,)

    def row_values(self, values: Any) -> list[Any]:
        return [abs(values)]

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        size = values[0]
        return [f"if {size} > fp[{slot}] and {size} - {size} == 0.0:", f"    fp[{slot}] = {size}"]

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        self.largest[copies] = np.maximum(self.largest[copies], partials[copies, 0])


def tracking_error(block: Mapping[str, np.ndarray]) -> np.ndarray:
    """``z_1 = x_1 - y_d`` (eq. (7)), shape ``(rows, batch, 1)``: the same floats as ``z[..., :1]``,
    without deriving the other errors."""
    return block["x"][..., :1] - block["yd"][..., :1]


class LargestAbsApplied(LargestAbs):
    """The largest finite ``|u|`` the actuator applied."""

    name, signal = "max_abs_u_applied", "u_applied"


class SaturatedFraction(Reduction):
    """The fraction of control samples (rows ``k`` with ``k % hold == 0`` and a finite u) at which
    the actuator clipped the command (NaN when there is none)."""

    name, signal = "saturated_fraction", "saturated"

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.clipped = np.zeros(batch)
        self.samples = np.zeros(batch)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        samples = slice((-chunk.first) % chunk.hold, None, chunk.hold)  # the control samples' rows
        at = values[samples]
        counted = np.isfinite(at)
        if not chunk.everyone:
            counted &= chunk.valid[samples]
        self.samples += counted.sum(axis=0)
        self.clipped += np.where(counted, at, 0.0).sum(axis=0)

    def every_value(self) -> list[float]:
        with np.errstate(all="ignore"):
            fractions = (self.clipped / self.samples).tolist()
        return [f if n else math.nan for f, n in zip(fractions, self.samples.tolist(), strict=True)]

    # (its values are 0 or 1: their sums are whole numbers, the same in any order)
    partials, at_samples = (0.0, 0.0), True

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        value = values[0]
        return [f"if {value} - {value} == 0.0:", f"    fp[{slot}] += 1.0", f"    fp[{slot + 1}] += {value}"]

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        self.samples[copies] += partials[copies, 0]
        self.clipped[copies] += partials[copies, 1]


class ReadingSaturatedFraction(SaturatedFraction):
    """The fraction of rows (readings with a finite value) at which a reading saturated at the end
    of its channel's range (NaN when there is none)."""

    name, signal = "reading_saturated_fraction", "reading_saturated"
    at_samples = False

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        counted = np.isfinite(values)
        if not chunk.everyone:
            counted &= chunk.valid
        self.samples += counted.sum(axis=0)
        self.clipped += np.where(counted, values, 0.0).sum(axis=0)


class LargestInputQuantizationError(LargestAbs):
    """The largest finite ``|q_u(u) - u|``: what the input's quantizer changed."""

    name, signal = "max_abs_input_quantization_error", "input_quantization_error"


class InputQuantizedFraction(SaturatedFraction):
    """The fraction of control samples at which the applied input ``q_u(u)`` differed from u."""

    name, signal = "input_quantized_fraction", "input_quantized"


class ErrorRate(Reduction):
    """Table 1's error rate E(omega) of ``z_1`` (see :mod:`qcontrol.error_rate`)."""

    name, signal, reads = "error_rate", "z", ("x", "yd")
    values = staticmethod(tracking_error)

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.stream = ErrorRateStream(duration, settings.samples, batch)
        self.omegas = settings.omegas
        self.counted: list[dict[str, float]] | None = None  # every copy's rates, once asked

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        z1 = values[..., 0]
        self.stream.add(chunk.t, z1 if chunk.everyone else np.where(chunk.valid, z1, np.nan))
        self.counted = None

    def value(self, b: int) -> dict[str, float]:
        if self.counted is None:  # every copy's at once (the summary asks each)
            self.counted = self.stream.every_rate(self.omegas)
        return self.counted[b]

    # folded into the stream's own arrays by error_rate.follow_row (no partials of its own): the
    # compiled batch works on copies of the stream's progress (:meth:`working`)
    partials = ()

    def row_values(self, values: Any) -> list[Any]:
        return [abs(values[..., 0])]

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        return [f"e_ta, e_za, e_i = follow_row({t}, {values[0]}, e_instants, e_values, b, e_ta, e_za, e_i)"]

    # the run's progress in the loop's locals: read when a copy's rows start, written back whenever
    # they stop (the compiled batch: qcontrol.engine.compiled_folds)
    enter = ("e_ta, e_za, e_i = e_last[b, 0], e_last[b, 1], e_done[b]",)
    leave = ("e_done[b] = e_i", "e_last[b, 0], e_last[b, 1] = e_ta, e_za")

    def working(self) -> tuple[np.ndarray, ...]:
        """The arrays the compiled fold reads and writes: the instants, the values at them, and
        copies of each run's progress (``done``, ``(last_t, last_z)``)."""
        stream = self.stream
        self.started = stream.done.copy()
        self.done = stream.done.copy()
        self.last = np.column_stack([stream.last_t, stream.last_z])
        return stream.instants, stream.values, self.done, self.last

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        stream, self.counted = self.stream, None
        stream.done[copies] = self.done[copies]
        stream.last_t[copies], stream.last_z[copies] = self.last[copies, 0], self.last[copies, 1]

    def undo(self, copies: np.ndarray) -> None:
        """Forget what the compiled fold wrote for ``copies`` (a mask): not reached yet."""
        self.counted = None
        for b in np.flatnonzero(copies & (self.done != self.started)):
            self.stream.values[self.started[b]:self.done[b], b] = np.inf


class LastHalfLargestAbs(Reduction):
    """The largest finite ``|z_1|`` over the last half of the run (NaN when there is none)."""

    name, signal, reads = "max_abs_z1_last_half", "z", ("x", "yd")
    values = staticmethod(tracking_error)

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.half = duration / 2.0
        self.largest = np.full(batch, -np.inf)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        z1 = values[..., 0]
        late = chunk.valid & (chunk.t >= self.half)[:, None] & np.isfinite(z1)
        np.maximum(self.largest, np.where(late, np.abs(z1), -np.inf).max(axis=0), out=self.largest)

    def every_value(self) -> list[float]:
        return _each_finite_or_nan(self.largest)

    partials = (-math.inf,)

    def row_values(self, values: Any) -> list[Any]:
        return [abs(values[..., 0])]

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        size = values[0]
        return [f"if {t} >= {constant(self.half)} and {size} > fp[{slot}] and {size} - {size} == 0.0:",
                f"    fp[{slot}] = {size}"]

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        self.largest[copies] = np.maximum(self.largest[copies], partials[copies, 0])


class FinalValue(Reduction):
    """The adaptive state at the last row each copy keeps."""

    name, signal = "final_adaptive", "adaptive"

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.final = np.full((batch, width), np.nan)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        last = chunk.kept - 1 - chunk.first
        here = (last >= 0) & (last < len(chunk.t))
        self.final[here] = values[last[here], np.flatnonzero(here)]

    def value(self, b: int) -> np.ndarray:
        return self.final[b].copy()


class BoundConstants(Reduction):
    """The empirical constants of the separation (37)-(43): the largest ``|term_i| / r_i(x_q)`` per
    term over every row before a divergence; Inf where the ratio was ever infinite or undefined
    (the term is not bounded by its r on the run)."""

    name, signal = "bound_constants", "bound_ratio"

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.largest = np.full((batch, width), -np.inf)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        values = np.where(np.isfinite(values), values, np.inf)
        if not chunk.everyone:
            values = np.where(chunk.before_divergence[..., None], values, -np.inf)
        np.maximum(self.largest, values.max(axis=0, initial=-np.inf), out=self.largest)

    def value(self, b: int) -> np.ndarray:
        return self.largest[b].copy()

    # per term its largest ratio (a value not finite counts as Inf); the values are the ratios
    # traced from their own derivation (qcontrol.engine.signals.bound_ratios)
    @property
    def partials(self) -> tuple[float, ...]:  # type: ignore[override]
        return (-math.inf,) * self.largest.shape[1]

    def row_values(self, values: Any) -> list[Any]:
        return list(values)

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        lines = []
        for i, value in enumerate(values):
            lines += [f"if not {value} - {value} == 0.0:", f"    fp[{slot + i}] = {constant(math.inf)}",
                      f"elif {value} > fp[{slot + i}]:", f"    fp[{slot + i}] = {value}"]
        return lines

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        self.largest[copies] = np.maximum(self.largest[copies], partials[copies])


class DiagnosticValues(Reduction):
    """A law's diagnostics over its control samples before a divergence: per column the largest
    finite value (``"max"``) and the value at the last sample kept (``"last"``); the summary
    reports the one each diagnostic declares (NaN where there is none)."""

    name, signal = "diagnostics", "diagnostics"

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.largest = np.full((batch, width), -np.inf)
        self.last = np.full((batch, width), np.nan)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        if values.shape[-1] == 0:
            return
        samples = slice((-chunk.first) % chunk.hold, None, chunk.hold)  # the control samples' rows
        at = values[samples]
        counted = np.isfinite(at)
        if not chunk.everyone:
            counted &= chunk.before_divergence[samples][..., None]
        top = np.where(counted, at, -np.inf).max(axis=0, initial=-np.inf)
        np.maximum(self.largest, top, out=self.largest)
        seen = counted.any(axis=0)
        latest = at.shape[0] - 1 - np.argmax(counted[::-1], axis=0)
        picked = np.take_along_axis(at, latest[None], axis=0)[0]
        self.last = np.where(seen, picked, self.last)

    def every_value(self) -> list[dict[str, np.ndarray]]:
        largest, last = np.where(np.isfinite(self.largest), self.largest, np.nan), self.last.copy()
        return [{"max": largest[b], "last": last[b]} for b in range(self.batch)]

    # per column: the largest value and the last (NaN: no sample yet); its values are the law's
    # diagnostics traced on the row (the compiled batch: qcontrol.engine.compiled_batch)
    at_samples = True

    @property
    def partials(self) -> tuple[float, ...]:  # type: ignore[override]
        return (-math.inf, math.nan) * self.largest.shape[1]

    def row_values(self, values: Any) -> list[Any]:
        return list(values)

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        lines = []
        for i, value in enumerate(values):
            top, last = slot + 2 * i, slot + 2 * i + 1
            lines += [f"if {value} - {value} == 0.0:", f"    fp[{last}] = {value}",
                      f"    if {value} > fp[{top}]:", f"        fp[{top}] = {value}"]
        return lines

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        top, last = partials[:, 0::2], partials[:, 1::2]
        self.largest[copies] = np.maximum(self.largest[copies], top[copies])
        seen = copies[:, None] & ~np.isnan(last)
        self.last = np.where(seen, last, self.last)


class SmallestBound(Reduction):
    """The smallest value of each bounding function ``r_i(x_q)`` over every row before a
    divergence: eqs. (37)-(43) need ``r_i >= 1`` wherever the run goes, which the scenario's load
    checks only on sampled states (Inf where no row was seen; NaN rows are skipped)."""

    name, signal = "smallest_r", "r"

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.smallest = np.full((batch, width), np.inf)

    def add(self, chunk: Chunk, values: np.ndarray) -> None:
        values = np.where(np.isnan(values), np.inf, values)
        if not chunk.everyone:
            values = np.where(chunk.before_divergence[..., None], values, np.inf)
        np.minimum(self.smallest, values.min(axis=0, initial=np.inf), out=self.smallest)

    def value(self, b: int) -> np.ndarray:
        return self.smallest[b].copy()

    # per term its smallest value (NaN skipped: never smaller); the values are the bounding
    # functions traced from their own derivation (qcontrol.engine.signals.bounds)
    @property
    def partials(self) -> tuple[float, ...]:  # type: ignore[override]
        return (math.inf,) * self.smallest.shape[1]

    def row_values(self, values: Any) -> list[Any]:
        return list(values)

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        lines = []
        for i, value in enumerate(values):
            lines += [f"if {value} < fp[{slot + i}]:", f"    fp[{slot + i}] = {value}"]
        return lines

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        self.smallest[copies] = np.minimum(self.smallest[copies], partials[copies])
