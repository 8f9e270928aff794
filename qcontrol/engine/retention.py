"""What a run keeps: every row (:class:`FullRecord`) or only its metrics (:class:`MetricsRecord`).

Both receive the loop's rows through a :class:`~qcontrol.engine.row_buffer.RowBuffer`, derive the
signals the loop does not record (z, zbar, e_z: :func:`~qcontrol.engine.signals.derive`) for many
rows at once, hand finished rows to an observer (a recording streams them to disk while the run
goes on), and tell the loop at which rows they need it to stop and call :meth:`at`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..controller.law import BatchLaw
from ..quantizers import ChannelQuantizer, SensorQuantizer
from ..timegrid import TimeGrid
from .divergence import Divergence
from .lemma2 import Lemma2Largest, lemma2_slack
from .reductions import Chunk, MetricSettings
from .reference_rows import ReferenceRows
from .results import RunMetrics, Trajectory
from .row_buffer import NEVER, RowBuffer
from .signals import DERIVED, REDUCTIONS, SIGNALS, SignalContext, derive, needed

# observer(start_row, stop_row, runs): rows [start_row, stop_row) of every run are final and may
# be streamed out (e.g. to a rerun recording); ``runs`` are views truncated at stop_row.
Observer = Callable[[int, int, list[Trajectory]], None]

OBSERVE_EVERY = 5000  # rows per observer call: streamed chunks, few enough to keep recording cheap
METRICS_CHUNK = 1000  # rows buffered per reduction in a metrics-only run (at least; see below)
METRICS_BUFFER_ELEMENTS = 5000  # rows x copies per chunk (so a single run reduces 5000 rows at a time)
# and at most (a large batch: each page of a fresh buffer costs a first touch, about 15 ns per copy-step
# of 1000 copies with 1500-row buffers, 96 MB), down to METRICS_MIN_CHUNK rows
METRICS_BUFFER_LIMIT = 250_000
METRICS_MIN_CHUNK = 250
REDUCE_ELEMENTS = 100_000  # rows x copies per block when deriving z, e_z (cache-sized temporaries)


@dataclass(frozen=True)
class RunParts:
    """The parts of a run a record reads: the grid, the law, the reference rows, the divergence
    bookkeeping, what derivations read, the metrics' settings, the batch size and the order."""

    grid: TimeGrid
    law: BatchLaw
    reference: ReferenceRows
    divergence: Divergence
    context: SignalContext
    metrics: MetricSettings
    batch: int
    n: int


def chunk_end(first: int, size: int, rows: int) -> int:
    """The last row of the chunk of ``size`` rows that starts at row ``first``, or the run's last
    row if fewer than ``size // 2`` rows would be left after it (a 10 s, 1 kHz run streams 5000 +
    5001 rows, not 5000 + 5000 + 1: each chunk costs a recording a send per series)."""
    last = first + size - 1
    return rows - 1 if rows - 1 - last < size // 2 else last


class _Record:
    """What both records share: the run's parts, and how rows become trajectories."""

    def __init__(self, parts: RunParts, capacity: int, observer: Observer | None) -> None:
        self.grid, self.law, self.reference = parts.grid, parts.law, parts.reference
        self.divergence, self.context, self.metrics = parts.divergence, parts.context, parts.metrics
        self.batch, self.observer = parts.batch, observer
        self.buffer = RowBuffer(capacity, parts.batch, parts.n, parts.law.state_size)
        self.widths = {s.name: s.size(parts.n, parts.law.state_size, self.context.terms,
                                     self.context.diagnostic_width) for s in SIGNALS}
        self.started = 0.0  # the run's start (time.perf_counter), set by the loop

    def metas(self, now: float) -> list[dict[str, Any]]:
        """What each copy's record carries besides its signals (:class:`RunRecord`'s fields); what
        the copies share is made once."""
        d, separation = self.divergence, self.context.separation
        sensor = self.context.quantizer if isinstance(self.context.quantizer, SensorQuantizer) else None
        shared = dict(adaptive_name=self.law.state_name, dt=self.grid.dt,
                      duration=self.grid.duration, hold=self.grid.hold,
                      velocity_source=self.context.velocity_source, chain=self.context.chain,
                      actuator_limited=self.context.actuator_limited,
                      wall_time_s=now - self.started, metrics=self.metrics,
                      bound_names=() if separation is None else separation.names,
                      law_diagnostics=self.context.diagnostics,
                      quantizer_sector=sensor.sector if sensor is not None else None,
                      reading_range=isinstance(sensor, ChannelQuantizer) and sensor.range is not None,
                      quantized_input=self.context.input_quantizer is not None)
        L_z = self.law.coordinates.L_z
        return [shared | dict(L_z=L_z.copy(), diverged=d.times[b] is not None, diverged_time=d.times[b],
                              divergence_reason=d.reasons[b],
                              law_failure=d.reasons[b] if d.law_failed[b] else None)
                for b in range(self.batch)]

    def signals(self, first: int, stop: int, derived: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
        """The signals of run rows ``[first, stop)``: views of the buffer, the reference, and the
        derived signals (all, or those named in ``derived``)."""
        block = self.buffer.rows(first, stop)
        block["yd"] = self.reference.block(first, stop)[:, None, :]
        return derive(block, self.context, derived)

    def trajectories(self, first: int, lengths: np.ndarray, signals: dict[str, np.ndarray],
                     now: float) -> list[Trajectory]:
        """Trajectories over run rows ``first + [0, lengths[b])`` of ``signals`` (views)."""
        return [
            Trajectory(t=self.grid.instants(first, first + lengths[b]),
                       signals={s.name: signals[s.name][: lengths[b], 0 if s.shared else b] for s in SIGNALS},
                       **meta)
            for b, meta in enumerate(self.metas(now))
        ]


class FullRecord(_Record):
    """Keeps every row of every copy; derives z, zbar and e_z in cache-sized blocks when they are
    first asked for; calls the observer every ``observe_every`` rows (the last call takes up to
    half as many more) and at the end."""

    def __init__(self, parts: RunParts, observer: Observer | None, observe_every: int) -> None:
        super().__init__(parts, parts.grid.rows, observer)
        self.observe_every = observe_every
        self.observed = 0  # rows [0, observed) went to the observer
        self.derived = 0  # rows [0, derived) have their derived signals
        self.own = {"yd": parts.reference.table[:, None, :]}  # what the buffer does not hold
        for s in DERIVED:
            width = () if s.width == "1" else (self.widths[s.name],)
            self.own[s.name] = np.full((self.grid.rows, self.batch, *width), np.nan)

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """Every signal's rows: the buffer's (however it stores them) and the derived."""
        return self.buffer.arrays | self.own

    def next_event(self, k: int) -> int:
        return NEVER if self.observer is None else chunk_end(self.observed, self.observe_every,
                                                             self.grid.rows)

    def at(self, end: int, finished: bool, now: float) -> None:
        if self.observer is None or not (finished or end == self.next_event(end)):
            return
        self.observer(self.observed, end + 1, self._runs(np.minimum(self.divergence.kept, end + 1), now))
        self.observed = end + 1

    def results(self, now: float) -> list[Trajectory]:
        return self._runs(self.divergence.kept, now)

    def _runs(self, lengths: np.ndarray, now: float) -> list[Trajectory]:
        self._derive(int(lengths.max()))
        return self.trajectories(0, lengths, self.arrays, now)

    def _derive(self, stop: int) -> None:
        """Fill the derived signals of rows ``[derived, stop)``, a cache-sized block at a time."""
        block = max(1, REDUCE_ELEMENTS // self.batch)
        for first in range(self.derived, stop, block):
            last = min(stop, first + block)
            signals = self.signals(first, last)
            for s in DERIVED:
                self.own[s.name][first:last] = signals[s.name]
        self.derived = max(self.derived, stop)


class MetricsRecord(_Record):
    """Keeps only the reductions of the signal table (:class:`RunMetrics`): rows are buffered a
    chunk at a time (``METRICS_CHUNK`` rows, more for small batches, fewer for large ones) and
    folded in, so 1000 copies of a 10 s, 1 kHz run need about 25 MB instead of several GB and
    memory does not grow with the run. An observer receives each chunk as short trajectories
    (rows ``[0, len)`` new)."""

    def __init__(self, parts: RunParts, observer: Observer | None) -> None:
        batch = parts.batch
        self.chunk = max(METRICS_BUFFER_ELEMENTS // batch,
                         min(METRICS_CHUNK, max(METRICS_MIN_CHUNK, METRICS_BUFFER_LIMIT // batch)))
        super().__init__(parts, min(parts.grid.rows, self.chunk + self.chunk // 2), observer)
        self.reductions = [fold(self.batch, self.widths[fold.signal], self.grid.duration, self.metrics)
                           for fold in REDUCTIONS]
        self.derived = needed(tuple(name for fold in REDUCTIONS for name in fold.needs()))
        self.folds: Any = None  # a compiled batch's folds of these reductions (engine/compiled_folds.py)
        if self.batch > 1:  # a batch: Lemma 2's largest errors as its runs alone's
            for fold in self.reductions:
                if isinstance(fold, Lemma2Largest):
                    fold.alone, fold.slack = self.alone, lemma2_slack(self.context.coordinates)

    def alone(self, rows: np.ndarray, copies: np.ndarray) -> np.ndarray:
        """Lemma 2's errors ``(len(rows), n)`` at run rows ``rows`` (held in the buffer) of copies
        ``copies``, each derived as the copy's run alone derives it: from a block of one copy,
        whose products numpy takes row by row (a vector times a matrix), where a batch's block
        is multiplied as a matrix, which BLAS rounds otherwise."""
        arrays, first = self.buffer.arrays, int(rows.min())
        block = {name: arrays[name][rows - self.buffer.base, copies][:, None] for name in ("x_meas", "x_q")}
        block["yd"] = self.reference.block(first, int(rows.max()) + 1)[rows - first][:, None]
        return derive(block, self.context, ("zbar", "e_z"))["e_z"][:, 0]

    def next_event(self, k: int) -> int:
        return chunk_end(self.buffer.base, self.chunk, self.grid.rows)

    def at(self, end: int, finished: bool, now: float) -> None:
        if not (finished or end == self.next_event(end)):
            return
        base, stop = self.buffer.base, end + 1
        if self.observer is not None:
            lengths = np.clip(self.divergence.kept - base, 0, stop - base)
            self.observer(0, stop - base, self.trajectories(base, lengths, self.signals(base, stop), now))
        self._reduce(base, stop)
        self.buffer.base = stop

    def _reduce(self, base: int, stop: int) -> None:
        """Fold rows ``[base, stop)`` into the reductions, a cache-sized block at a time."""
        diverged = self.divergence.kept < self.grid.rows
        reductions, derived = self.reductions, self.derived
        if self.folds is not None:  # those the compiled batch folded are merged, unless a copy stopped
            reductions = self.folds.merge(base, stop, self.divergence.kept, diverged)
            if reductions is not self.reductions:
                derived = needed(tuple(name for fold in reductions for name in fold.needs()))
        rows = max(1, REDUCE_ELEMENTS // self.batch)
        for first in range(base, stop, rows):
            last = min(stop, first + rows)
            chunk = Chunk(first, self.grid.instants(first, last), self.divergence.kept, diverged,
                          self.grid.hold)
            block = self.signals(first, last, derived)
            for fold in reductions:
                fold.add(chunk, fold.values(block))
        if self.folds is not None:
            self.folds.reset()

    def results(self, now: float) -> list[RunMetrics]:
        every = [(fold.name, fold.every_value()) for fold in self.reductions]
        return [
            RunMetrics(steps=int(self.divergence.kept[b]) - 1, values={name: v[b] for name, v in every},
                       **meta)
            for b, meta in enumerate(self.metas(now))
        ]
