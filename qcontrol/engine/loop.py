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
from collections.abc import Sequence
from contextlib import nullcontext
from typing import Any

import numpy as np

from .. import compiled as compiled_paths
from ..plants.base import Disturbable, Plant, actuator_of
from ..quantizer import Quantizer
from ..quantizers import SensorQuantizer
from .compiled_batch import Redo
from .compiled_loop import START, Resume, numba_pays
from .compiled_user import compiled_user
from .divergence import Divergence
from .fastpath import compiled_loop, rows_for
from .reference_rows import ReferenceRows
from .results import RunRecord
from .retention import FullRecord, MetricsRecord, RunParts
from .row_buffer import NEVER
from .signals import SignalContext
from .spec import ProgressCallback, RunSpec


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
        if changes and not isinstance(plant, Disturbable):
            raise ValueError(f"{type(plant).__name__} takes no external load (it is not Disturbable)")
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

    def __init__(self, spec: RunSpec, compiled: bool = True) -> None:
        self.spec = spec
        plant, law, grid = spec.plant, spec.law, spec.grid
        n, batch = plant.n, plant.batch
        self.plant, self.law, self.grid, self.x0 = plant, law, grid, spec.x0
        self.divergence = Divergence(batch, grid.rows, grid.dt, spec.state_bound, law.state_name,
                                     spec.terms, getattr(law, "failures", None))  # a user law's, if any
        self.reference = ReferenceRows(spec.reference, n, grid, whole=spec.record == "full")
        actuator, limited = actuator_of(plant)  # without an actuator, u is applied as commanded
        context = SignalContext(law.coordinates, spec.separation, actuator, spec.velocity_source, limited,
                                tuple(law.diagnostics), spec.quantizer, spec.input_quantizer, spec.chain)
        parts = RunParts(grid, law, self.reference, self.divergence, context, spec.metrics, batch, n)
        self.record = (FullRecord(parts, spec.observer, spec.observe_every) if spec.record == "full"
                       else MetricsRecord(parts, spec.observer))
        self.rows = rows_for(self.record.buffer, batch, spec.state_bound)
        if isinstance(spec.quantizer, SensorQuantizer):  # (one with memory starts every run afresh)
            spec.quantizer.reset()
        self.quantize = self.rows.quantizer(spec.quantizer)
        self.differencing = None  # x2 differenced from the encoder (.velocity), or None
        if spec.velocity_source == "difference":
            self.differencing = self.rows.differenced(self.quantize, grid.hold, grid.hold * grid.dt)
            self.quantize = self.differencing.quantize
        self.progress = ProgressReports(spec.progress, grid.rows)
        self.loads = Loads(plant, spec.loads)
        self.input_quantizer = spec.input_quantizer
        # None: the Python loop (see .compiled_loop; a user's law: its code traced and checked,
        # see .compiled_user, which, as a batch, leaves an input quantizer to the Python loop)
        self.compiled = (compiled_user(spec) or compiled_loop(spec)) if compiled else None
        self.handover: int | None = None  # the row the Python loop took over from (None: none)

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

    def run(self) -> list[RunRecord]:
        """The closed loop, row by row: compiled (:mod:`.compiled_loop`) where the run's parts all
        have a compiled form, then (or else) in Python from the row it hands over."""
        plant = self.plant
        adaptive = self.rows.initial_state(self.law)
        self.record.started = time.perf_counter()
        # a single run too short to pay for numba's start runs every part in Python
        pays = numba_pays(self.grid.rows, plant.batch)
        with nullcontext() if pays else compiled_paths.not_needed(), plant, np.errstate(all="ignore"):
            plant.reset(np.broadcast_to(np.asarray(self.x0, dtype=float), (plant.batch, plant.n)))
            try:
                resume = (START._replace(adaptive=adaptive) if self.compiled is None
                          else self.compiled.run(self, plant, adaptive))
            except Redo:  # a compiled batch's copy left a row it keeps undone: the array form, afresh
                resume = Redo
            if resume is not Redo:
                self.handover = None if resume is None else resume.row
                if resume is not None:
                    self.python_rows(resume)
        if resume is Redo:
            redone = ClosedLoop(self.spec, compiled=False)
            runs = redone.run()
            self.handover = redone.handover
            return runs
        return self.record.results(time.perf_counter())

    def python_rows(self, resume: Resume) -> None:
        """The loop in Python from row ``resume.row``: observe -> quantize -> control -> record ->
        step -> advance."""
        plant, grid, rows = self.plant, self.grid, self.rows
        quantize, reference_at, keep = self.quantize, self.reference.at, rows.keep
        control, advance = rows.law(self.law, grid.dt)
        hold, dt = grid.hold, grid.dt
        adaptive, out = resume.adaptive, resume.out
        io = rows.plant_io(plant, dt)
        observe, step = io.observe, io.step
        if self.input_quantizer is not None:  # the plant is stepped with q_u(u)
            step = QuantizedInput(step, self.input_quantizer).step
        if resume.past:  # the positions the compiled loop differenced, oldest first
            self.differencing.past.extend(resume.past)
        if resume.step_first:  # the step from the row before, which the compiled loop left
            step(out.u)
            adaptive = advance(adaptive, out)
        due = self.next_event(resume.row - 1)
        for k in range(resume.row, grid.rows):
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


class QuantizedInput:
    """A plant's step with the input quantized first, ``step(q_u(u))``: u a float (a batch of one
    in the float form) or a ``(batch,)`` column; ``q_u`` takes ``(batch, 1)`` arrays."""

    def __init__(self, step: Any, quantizer: Quantizer) -> None:
        self.inner, self.quantizer = step, quantizer

    def step(self, u: Any) -> None:
        if isinstance(u, np.ndarray):
            self.inner(self.quantizer(u.reshape(-1, 1))[:, 0])
        else:
            self.inner(float(self.quantizer(np.array([[u]], dtype=float))[0, 0]))


def simulate(spec: RunSpec, *legacy: Any, **options: Any) -> list[RunRecord]:
    """Run the closed loop of ``spec`` (a :class:`~.spec.RunSpec`) for every copy of its plant's
    batch: one :class:`~.results.RunRecord` each, a :class:`~.results.Trajectory` (``record="full"``,
    the default) or a :class:`~.results.RunMetrics` (``record="metrics"``).

    A copy whose state turns non-finite or leaves ``|x_i| <= state_bound`` stops there: its
    record ends with the offending row, ``diverged`` is set and the others run on. The parts
    given one by one, as before the specification existed, are refused with the fix.
    """
    if not isinstance(spec, RunSpec) or legacy or options:
        raise TypeError("simulate takes one RunSpec: simulate(RunSpec(plant=..., law=..., quantizer=..., "
                        "reference=..., x0=..., grid=TimeGrid.of(duration, dt, control_period), ...)) "
                        "replaces simulate(plant, law, quantizer, reference, x0, duration, dt, ...)")
    return ClosedLoop(spec).run()
