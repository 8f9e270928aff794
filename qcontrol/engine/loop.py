"""The one closed-loop engine: fixed step, zero-order hold, for any plant and any law.

One step of the loop:

    plant state -> sensor reading -> quantizer -> law (u, adaptive terms) -> record -> plant step

The law is evaluated every ``control_period`` (a multiple of ``dt``); ``u`` is held in between and
the adaptive state is advanced every step under that hold. Row k of a run is the instant
``t_k = k dt``: the state there, what the controller read, and the input applied over
``[t_k, t_k + dt)``. Everything but the loop itself (writing rows, testing them for divergence,
progress, streaming to an observer, reducing to metrics) happens at a few scheduled rows, in
:meth:`ClosedLoop.rare_work`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from ..controller.law import BatchLaw
from ..expr import Expression
from ..plants.base import Plant
from ..quantizer import Quantizer
from ..reference import Reference
from ..timegrid import TimeGrid
from .divergence import Divergence
from .reductions import MetricSettings
from .reference_rows import ReferenceRows
from .results import RunMetrics, Trajectory
from .retention import OBSERVE_EVERY, FullRecord, MetricsRecord, Observer, RunParts
from .row_buffer import NEVER, ArrayRows, FloatRows
from .signals import Separation, SignalContext
from .velocity import VELOCITY_SOURCES, differencing

ProgressCallback = Callable[[int, int], None]  # (row reached, last row)
RECORD_MODES = ("full", "metrics")


class ProgressReports:
    """Reports ``(row, last row)`` to ``callback`` about every 1% of the run, and at its end."""

    def __init__(self, callback: ProgressCallback | None, rows: int) -> None:
        self.callback, self.last = callback, rows - 1
        self.every = max(1, rows // 100)

    def next_event(self, k: int) -> int:
        return NEVER if self.callback is None else (k // self.every + 1) * self.every

    def at(self, end: int, finished: bool) -> None:
        if self.callback is not None and (end % self.every == 0 or finished):
            self.callback(end, self.last)


class Loads:
    """The external load of a run (:meth:`~qcontrol.plants.base.Plant.disturb`), applied at the
    rows where it changes: ``changes`` are ``(row, d)`` in row order, ``d`` in u's units."""

    def __init__(self, plant: Plant, changes: Sequence[tuple[int, float]]) -> None:
        self.plant, self.changes, self.applied = plant, list(changes), 0

    def next_event(self, k: int) -> int:
        return self.changes[self.applied][0] if self.applied < len(self.changes) else NEVER

    def at(self, k: int) -> None:
        """Apply every change due at or before row ``k`` (before the step from row ``k``)."""
        while self.applied < len(self.changes) and self.changes[self.applied][0] <= k:
            self.plant.disturb(self.changes[self.applied][1])
            self.applied += 1


class ClosedLoop:
    """The parts of one run (each with one job) and the loop that drives them (:meth:`run`)."""

    def __init__(self, plant: Plant, law: BatchLaw, quantizer: Quantizer, reference: Reference,
                 grid: TimeGrid, state_bound: float, progress: ProgressCallback | None,
                 observer: Observer | None, observe_every: int, record: str, metrics: MetricSettings,
                 separation: Separation | None, loads: Sequence[tuple[int, float]] = (),
                 velocity_source: str = "sensor", terms: Sequence[tuple[str, Expression]] = ()) -> None:
        n, batch = plant.n, plant.batch
        self.plant, self.law, self.grid = plant, law, grid
        self.divergence = Divergence(batch, grid.rows, grid.dt, state_bound, law.state_name, terms)
        self.reference = ReferenceRows(reference, n, grid, whole=record == "full")
        context = SignalContext(law.coordinates, separation, plant.actuator, velocity_source,
                                plant.actuator_limited, tuple(law.diagnostics))
        parts = RunParts(grid, law, self.reference, self.divergence, context, metrics, batch, n)
        self.record = (FullRecord(parts, observer, observe_every) if record == "full"
                       else MetricsRecord(parts, observer))
        self.rows = FloatRows(self.record.buffer) if batch == 1 else ArrayRows(self.record.buffer,
                                                                               state_bound)
        self.quantize = self.rows.quantizer(quantizer)
        if velocity_source == "difference":
            self.quantize = differencing(self.quantize, grid.hold, grid.hold * grid.dt, self.rows.floats)
        self.progress = ProgressReports(progress, grid.rows)
        self.loads = Loads(plant, loads)

    def next_event(self, k: int) -> int:
        """The first row after ``k`` at which the loop has more to do than step."""
        return min(self.grid.rows - 1, self.rows.next_event(k), self.progress.next_event(k),
                   self.record.next_event(k), self.loads.next_event(k))

    def rare_work(self, k: int) -> bool:
        """Everything but the closed loop itself, at row ``k``: apply a changed external load,
        write and test the rows, report progress, stream or reduce. True when the run is over (at
        its end, or every copy stopped: then the run ends where the last copy did)."""
        self.loads.at(k)
        self.rows.flush(k)
        self.divergence.test(*self.rows.untested(k), self.record.buffer)
        stopped = self.divergence.all_stopped
        end = self.divergence.last_row if stopped else k
        finished = stopped or k == self.grid.rows - 1
        self.progress.at(end, finished)
        self.record.at(end, finished, time.perf_counter())
        return finished

    def run(self, x0: np.ndarray) -> list[Trajectory] | list[RunMetrics]:
        """The closed loop, row by row: observe -> quantize -> control -> record -> step -> advance."""
        plant, grid, rows = self.plant, self.grid, self.rows
        quantize, control, reference_at, keep = self.quantize, self.law.control, self.reference.at, rows.keep
        advance = self.law.advancer(grid.dt, rows.floats)
        hold, dt = grid.hold, grid.dt
        adaptive = rows.initial_state(self.law)
        self.record.started = time.perf_counter()
        with plant, np.errstate(all="ignore"):
            plant.reset(np.broadcast_to(np.asarray(x0, dtype=float), (plant.batch, plant.n)))
            observe, step = plant.io(dt)
            due = self.next_event(-1)
            for k in range(grid.rows):
                x, reading = observe()
                quantized = quantize(reading)
                if k % hold == 0:  # a control sample; u is held until the next one
                    out = control(quantized, reference_at(k), adaptive, k * dt)
                if keep(k, x, reading, quantized, out.u, adaptive) or k == due:
                    if self.rare_work(k):
                        break
                    due = self.next_event(k)
                step(out.u)
                adaptive = advance(adaptive, out)
        return self.record.results(time.perf_counter())


def simulate(
    plant: Plant,
    law: BatchLaw,
    quantizer: Quantizer,
    reference: Reference,
    x0: np.ndarray,
    duration: float,
    dt: float,
    control_period: float | None = None,
    state_bound: float = 1e6,
    progress: ProgressCallback | None = None,
    observer: Observer | None = None,
    observe_every: int = OBSERVE_EVERY,
    record: str = "full",
    metrics: MetricSettings | None = None,
    separation: Separation | None = None,
    loads: Sequence[tuple[int, float]] = (),
    velocity_source: str = "sensor",
    terms: Sequence[tuple[str, Expression]] = (),
) -> list[Trajectory] | list[RunMetrics]:
    """Run the closed loop for every copy in ``plant``'s batch; one :class:`Trajectory` each.

    A copy whose state turns non-finite or leaves ``|x_i| <= state_bound`` stops there: its
    trajectory ends with the offending row, ``diverged`` is set and the others run on.
    ``observer`` is called every ``observe_every`` rows (the last call takes up to half as many
    more) and at the end with the rows that became final, so a recorder can stream them to disk
    while the run goes on. ``record="metrics"`` (sweeps, long runs) keeps only
    :class:`RunMetrics`, in memory that does not grow with the run; an observer then receives each
    buffered chunk as short trajectories (``t`` starting at the chunk's first instant).
    ``metrics`` sets the error rate's thresholds and samples (default: the paper's Table 1);
    ``separation`` names the terms of eq. (1) and their bounding functions r to check along the
    run (eqs. (37)-(43); default: not checked). ``loads``: ``(row, d)`` where the external load
    changes (:meth:`Plant.disturb`, u's units; see :mod:`qcontrol.disturbance`).
    ``velocity_source``: ``"sensor"``, or ``"difference"`` for an x2 differenced from the
    quantized position over the control period (:mod:`.velocity`). ``terms``: the plant's
    expressions by name (``("plant.psi", psi)``), evaluated where a copy turned NaN to say which
    term went out of its domain.
    """
    if record not in RECORD_MODES:
        raise ValueError(f"record must be one of {RECORD_MODES}, got {record!r}")
    if velocity_source not in VELOCITY_SOURCES:
        raise ValueError(f"velocity_source must be one of {VELOCITY_SOURCES}, got {velocity_source!r}")
    if law.copies is not None and law.copies != plant.batch:
        raise ValueError(f"the controller has per-copy parameters for {law.copies} copies, "
                         f"the plant {plant.batch}")
    grid = TimeGrid.of(duration, dt, control_period)
    loop = ClosedLoop(plant, law, quantizer, reference, grid, state_bound, progress, observer, observe_every,
                      record, metrics or MetricSettings(), separation, loads, velocity_source, terms)
    return loop.run(x0)
