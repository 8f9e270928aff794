"""The batch-of-one fast path: the engine's adapter between the array form every part implements
and plain Python floats, the one module that knows the float form.

Why: a numpy call on a one-element array costs about a microsecond, float arithmetic tens of
nanoseconds, and a closed-loop step makes a few dozen of them; so a single run (a batch of one)
steps on floats, a batch of copies on ``(batch,)`` numpy columns. This module is where that
choice is made for a run (:func:`rows_for`) and where everything the float form needs lives:

* :data:`FLOATS`: the float :class:`~qcontrol.columns.ColumnForm`, each column one plain float.
  The laws' formulas and the ODE plant's RK4 are written over columns of any form
  (:mod:`qcontrol.columns`); given this form, the same lines run on floats, with the parameters
  as floats, ``math.expm1``, and expressions evaluated through ``math``
  (:class:`qcontrol.expr.FloatTerms`, generated from the same expression trees as numpy's);
* :class:`FloatRows`: the rows of one copy kept as tuples and written to the arrays in blocks;
* :class:`FloatQuantize`: q(x) of eq. (3) on floats, bit for bit the array quantizer's;
* :class:`FloatDifferencing`: the encoder's differenced velocity (:mod:`.velocity`) on floats;
* :func:`float_io`: a plant that steps in any form
  (:class:`~qcontrol.plants.base.ColumnStepping`) in this one, any other through its array form
  (:class:`ArrayPlantAsFloats`), so a plant that implements only the array form runs at every
  batch size;
* :meth:`FloatRows.law`: a law whose formulas serve any form
  (:class:`~qcontrol.controller.law.AnyColumnForm`) in this one, any other through its array
  form (:class:`ArrayLawAsFloats`), so a law that implements only the array form runs at every
  batch size too.

One step further, :func:`compiled_loop`: a batch of one whose parts all have a compiled form (the
uniform quantizer, a built-in law, a plant with :class:`~qcontrol.plants.base.NativeStepping`)
runs the same loop body as one generated numba function (:mod:`.compiled_loop`) between the
engine's scheduled rows, writing the same rows into the same buffer; everything else runs the
float form below.

The one fallback rule: where ``math`` refuses an evaluation that numpy answers with NaN or Inf
(:data:`qcontrol.expr.FLOAT_REFUSED`), numpy's answer is taken
(:meth:`qcontrol.expr.Expression.on_floats`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any, NamedTuple

import numpy as np

from ..columns import ArrayForm, Column, Combination, Parameter
from ..controller.backstepping import Advance, Columns
from ..controller.law import AnyColumnForm, BatchLaw
from ..expr import FLOAT_REFUSED, Expression, FloatCombination, FloatTerms
from ..expr.calculus import Program
from ..expr.generators import elementwise
from ..plants.base import ColumnIO, ColumnStepping, Plant
from ..quantizer import QuantizedReading, Quantizer, UniformQuantizer
from . import velocity
from .compiled_batch import CompiledBatch, compiled_batch
from .compiled_loop import CompiledLoop
from .compiled_loop import compiled_loop as compiled_loop_of
from .row_buffer import ArrayIO, ArrayRows, RowBuffer
from .signals import RECORDED
from .spec import RunSpec

Quantize = Callable[[Any], QuantizedReading]
FLUSH_ROWS = 1000  # a batch of one: rows kept as Python tuples before they are written to arrays


class FloatForm:
    """The float :class:`~qcontrol.columns.ColumnForm`: a batch of one, each column a plain float."""

    expm1 = staticmethod(math.expm1)

    def column(self, values: Parameter | list[float]) -> float:
        if type(values) is list and len(values) == 1:  # one copy's value, as the user-law adapter gives it
            return float(values[0])
        array = np.asarray(values, dtype=float)
        if array.size != 1:
            raise ValueError(f"{array.size} per-copy values for a batch of one")
        return float(array.reshape(1)[0])

    def terms(self, expressions: Sequence[Expression]) -> FloatTerms:
        return FloatTerms(expressions)

    def program(self, program: Program) -> Callable[[Sequence[Any]], list[float]]:
        return partial(float_program, program)

    def combination(self, expressions: Sequence[Expression], coefficients: Sequence[Parameter | None]
                    ) -> FloatCombination:
        return FloatCombination(expressions, [None if c is None else self.column(c) for c in coefficients])

    def columns(self, rows: np.ndarray) -> list[float]:
        rows = np.asarray(rows, dtype=float)
        if len(rows) != 1:
            raise ValueError(f"{len(rows)} rows for a batch of one")
        return rows[0].tolist()

    def array(self, columns: Sequence[Column], batch: int) -> np.ndarray:
        return np.array([columns], dtype=float)  # (1, 0) for none

    def __repr__(self) -> str:
        return "FLOATS"


FLOATS = FloatForm()


def float_program(program: Program, values: Sequence[Any]) -> list[float]:
    """``program`` on one copy's values as plain floats (``math``; numpy's answer where it
    refuses, :class:`~qcontrol.expr.calculus.Program`)."""
    return program([float(v) for v in values])


class FloatQuantize:
    """``quantize`` for the readings of one copy, plain floats ``x_1 .. x_n``: the uniform
    quantizer's own formula (:meth:`~qcontrol.quantizer.UniformQuantizer.apply`) on floats with
    ``math.floor`` (``floor`` is exact either way, so bit for bit the array form's); another
    quantizer through its array form."""

    def __init__(self, quantizer: Quantizer) -> None:
        self.quantizer, self.max_error = quantizer, quantizer.max_error
        self.apply = quantizer.apply if isinstance(quantizer, UniformQuantizer) else None

    def quantize(self, readings: Sequence[float]) -> QuantizedReading:
        return QuantizedReading(None, self.max_error, columns=self.values(readings), form=FLOATS,
                                 batch=1)

    def values(self, readings: Sequence[float]) -> tuple[float, ...]:
        apply = self.apply
        if apply is not None:
            try:
                return tuple([apply(v, math.floor) for v in readings])
            except FLOAT_REFUSED:  # NaN or Inf: numpy's answer
                pass
        return tuple(self.quantizer(np.array([readings], dtype=float))[0].tolist())


def float_quantizer(quantizer: Quantizer) -> Quantize:
    """``quantize(readings) -> QuantizedReading`` for one copy's plain floats."""
    return FloatQuantize(quantizer).quantize


class FloatDifferencing:
    """x2 of one copy's reading replaced by the quantized position differenced over ``hold`` rows
    (``period`` seconds), on floats (:mod:`.velocity`). Called once per row, in order."""

    def __init__(self, quantize: Quantize, hold: int, period: float) -> None:
        self.inner, self.hold, self.period = quantize, hold, period
        self.past: deque[float] = deque(maxlen=hold)  # q(x1) of the last `hold` rows, oldest first

    def quantize(self, values: Sequence[float]) -> QuantizedReading:
        q = self.inner(values)
        columns = q.columns
        q1 = columns[0]
        past = self.past
        if not past:
            past.extend([q1] * self.hold)
        rate = velocity.differenced(q1, past[0], self.period)
        past.append(q1)
        return QuantizedReading(None, q.max_error, columns=(q1, rate, *columns[2:]),
                                 form=FLOATS, batch=1)


class ArrayPlantAsFloats:
    """A plant with only the array form, as one copy's :class:`~qcontrol.plants.base.ColumnIO` in
    the float form."""

    def __init__(self, plant: Plant, h: float) -> None:
        self.plant, self.h = plant, h

    def observe(self) -> tuple[list[float], list[float]]:
        x, reading = self.plant.observe()
        return np.asarray(x, dtype=float).tolist()[0], np.asarray(reading, dtype=float).tolist()[0]

    def step(self, u: float) -> None:
        self.plant.step(np.array([u]), self.h)


def float_io(plant: Plant, h: float) -> ColumnIO:
    """One copy's observe and step on floats: the plant's columns in :data:`FLOATS`, or its array
    form."""
    return plant.column_io(FLOATS, h) if isinstance(plant, ColumnStepping) else ArrayPlantAsFloats(plant, h)


class FloatOutput(NamedTuple):
    """What :class:`ArrayLawAsFloats` gives the loop: ``u`` as a float, and the law's own output
    (array form), which its advance reads."""

    u: float
    held: Any


class ArrayLawAsFloats:
    """A law with only the array form, driven on one copy's floats: the reading and the adaptive
    state become one-row arrays, ``u`` and the advanced state floats again."""

    def __init__(self, law: BatchLaw, h: float) -> None:
        self.law, self.array_advance = law, law.advancer(h)

    def control(self, reading: QuantizedReading, yd: Sequence[float], state: Columns,
                t: float = 0.0) -> FloatOutput:
        out = self.law.control(QuantizedReading(reading.values, reading.max_error), yd,
                               tuple([np.array([e]) for e in state]), t)
        return FloatOutput(float(np.asarray(out.u).reshape(-1)[0]), out)

    def advance(self, state: Columns, out: FloatOutput) -> Columns:
        advanced = self.array_advance(tuple([np.array([e]) for e in state]), out.held)
        return tuple([float(np.asarray(e).reshape(-1)[0]) for e in advanced])


class FloatRows:
    """A batch of one on plain floats: each row is one tuple (x, x_meas, x_q, u, adaptive, in the
    order of the signal table), written to the buffer at :meth:`flush`, at least every
    :data:`FLUSH_ROWS` rows, and tested for divergence there (a per-step test cost about 1 us of
    a 25 us MuJoCo step). The run may go on for up to that many rows after it diverged; those
    rows do not count. Offers the loop what :class:`~.row_buffer.ArrayRows` offers, in float form."""

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

    def quantizer(self, quantizer: Quantizer) -> Quantize:
        return FloatQuantize(quantizer).quantize

    def differenced(self, quantize: Quantize, hold: int, period: float) -> FloatDifferencing:
        return FloatDifferencing(quantize, hold, period)

    def plant_io(self, plant: Plant, h: float) -> ColumnIO:
        return float_io(plant, h)

    def law(self, law: BatchLaw, h: float) -> tuple[Callable[..., Any], Advance]:
        """``(control, advance)`` of one copy on floats: the law in :data:`FLOATS`, or its array form."""
        return single_copy(law, h)

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


def single_copy(law: BatchLaw, h: float) -> tuple[Callable[..., Any], Advance]:
    """``(control, advance)`` of a single run's law in the form it steps in (:meth:`FloatRows.law`;
    also what a user's law traced for the compiled loop is checked against)."""
    if isinstance(law, AnyColumnForm):
        return law.control, law.advancer_in(FLOATS, h)
    adapter = ArrayLawAsFloats(law, h)
    return adapter.control, adapter.advance


def single_copy_quantizer(quantizer: Quantizer) -> Quantize:
    """A single run's ``quantize(readings) -> QuantizedReading``, in the form it steps in."""
    return FloatQuantize(quantizer).quantize


def compiled_loop(spec: RunSpec) -> CompiledLoop | CompiledBatch | None:
    """The compiled form of a batch of one (:mod:`.compiled_loop`: numba, rows written into the
    same buffer between the same rare rows) or of a batch of copies (:mod:`.compiled_batch`),
    or None where the run keeps the Python loop (the array form for a batch): the other place the
    form of a run is chosen."""
    return compiled_loop_of(spec) if spec.plant.batch == 1 else compiled_batch(spec)


class CopiesForm(ArrayForm):
    """The form a batch of copies steps in: ``(batch,)`` numpy columns, as in the array form, but
    every value a function gives is what the float form gives that copy (expressions by
    :meth:`~qcontrol.expr.Expression.on_copies`, ``math.expm1`` element by element), where numpy's
    own exp, pow, ... may round otherwise: so each copy's numbers are its run alone's. What is
    computed from a record keeps the array form (numpy's functions, for a batch and a single run
    alike)."""

    expm1 = staticmethod(elementwise(math.expm1))

    def terms(self, expressions: Sequence[Expression]) -> CopiesTerms:
        return CopiesTerms(expressions)

    def program(self, program: Program) -> Callable[[Sequence[Column]], list[Column]]:
        return program.on_copies

    def combination(self, expressions: Sequence[Expression], coefficients: Sequence[Parameter | None]
                    ) -> Combination:
        return Combination(tuple(zip(coefficients, (e.on_copies for e in expressions), strict=True)))

    def __repr__(self) -> str:
        return "COPIES"


class CopiesTerms:
    """Expressions evaluated on a batch's columns, each copy's values its run alone's."""

    def __init__(self, expressions: Sequence[Expression]) -> None:
        self.functions = tuple(e.on_copies for e in expressions)

    def __call__(self, columns: Sequence[Column]) -> list[Column]:
        return [f(columns) for f in self.functions]


COPIES = CopiesForm()


class CopyRows(ArrayRows):
    """A batch of copies in :data:`COPIES`: the reading, a law whose formulas serve any form and a
    plant that steps in any form are in it; a law or a plant with only the array form is driven
    in the array form, as a run alone drives it (:class:`ArrayLawAsFloats`,
    :class:`ArrayPlantAsFloats`)."""

    def quantizer(self, quantizer: Quantizer) -> Quantize:
        return partial(copies_reading, quantizer)

    def plant_io(self, plant: Plant, h: float) -> ColumnIO | ArrayIO:
        if isinstance(plant, ColumnStepping):
            return ColumnsAsArrays(plant.column_io(COPIES, h), plant.batch)
        return ArrayIO(plant, h)

    def law(self, law: BatchLaw, h: float) -> tuple[Callable[..., Any], Advance]:
        if isinstance(law, AnyColumnForm):
            return law.control, law.advancer_in(COPIES, h)
        return partial(array_control, law), law.advancer(h)


def copies_reading(quantizer: Quantizer, readings: np.ndarray) -> QuantizedReading:
    """A batch's ``(batch, n)`` readings quantized, the reading in :data:`COPIES`."""
    return QuantizedReading(quantizer(readings), quantizer.max_error, form=COPIES)


def array_control(law: BatchLaw, reading: QuantizedReading, yd: Sequence[float], state: Columns,
                  t: float = 0.0) -> Any:
    """``law.control`` of a law with only the array form, given the reading in the array form."""
    return law.control(QuantizedReading(reading.values, reading.max_error), yd, state, t)


class ColumnsAsArrays:
    """A plant's observe in a form's columns, given as the ``(batch, n)`` arrays the loop records."""

    def __init__(self, io: ColumnIO, batch: int) -> None:
        self.io, self.batch, self.step = io, batch, io.step

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        x, meas = self.io.observe()
        state = COPIES.array(x, self.batch)
        return state, state if meas is x else COPIES.array(meas, self.batch)


def rows_for(buffer: RowBuffer, batch: int, state_bound: float) -> FloatRows | CopyRows:
    """The loop's rows for a run, the one place the form is chosen: floats for a batch of one,
    ``(batch,)`` columns whose values are each copy's float form's otherwise (:data:`COPIES`).
    Each offers the loop the quantizer, the plant's and the law's observe/step/control/advance in
    its form."""
    return FloatRows(buffer) if batch == 1 else CopyRows(buffer, state_bound)
