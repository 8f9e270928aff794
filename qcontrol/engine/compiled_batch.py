"""The compiled batch: N copies of the ODE closed loop in one generated numba function, each copy
with its own parameters, derived from the same single definitions as the compiled loop of one
run (:mod:`.compiled_loop`).

A sweep, a region map or a study runs a batch of copies that differ in their parameters (kappa,
gamma, sigma, r_scale, theta) and share their structure. The array form runs them as ``(batch,)``
numpy columns, a few dozen numpy calls a step; here the same formulas run once on
``TracedForm(batch)`` (:mod:`qcontrol.compiled.traced`), in which a parameter given per copy
takes a slot of the constants with a value per copy, so one text serves every copy: the
quantizer's :meth:`~qcontrol.quantizer.UniformQuantizer.apply`, the law's ``control`` and advance
(:func:`.compiled_loop.traced_parts`), and the ODE's RK4 (:class:`~qcontrol.plants.ode.ChainNativeForm`).
The generated function loops over the copies and, for each, over the rows between two of the
engine's scheduled rows: the single run's loop body (:func:`.compiled_loop.loop_body`) writing
column ``b`` of the run's buffer. So every copy's numbers are its run alone, to the last bit, and
the record (metrics, divergence, reductions) is the array form's, at the same rows. A batch of
MuJoCo copies runs the same way, each copy's own ``MjData`` stepped by the plant's copy step
(:class:`~qcontrol.plants.mujoco.native_step.MujocoNativeForm`, a row of pointers per copy).

Divergence: the loop marks each row at which some copy's state or adaptive estimate fails the
array form's quick test (non-finite, or ``|x_i|`` beyond the bound), and only those rows are
tested (:class:`~.divergence.Divergence`), as in the array form. A copy keeps being computed after
it stopped, as in the array form. Where a copy's float code cannot give numpy's answer (``math``
refusing an evaluation), that copy stops being computed; the rows it leaves undone are marked,
and when they are rows the copy keeps (it had not stopped before), the whole run is done again
in the array form (:class:`Redo`).

Functions: the compiled code's ``math.exp``, ``expm1``, ``log``, ``tanh``, ... are libm's, as
Python's ``math`` that a run alone and a batch's Python loop evaluate per copy: a batch whose law
holds exactly (expm1) or whose terms take exponentials is compiled, each copy its run alone to the
last bit. ``math.pow`` too: its exponent reaches it through ``opaque``
(:func:`qcontrol.expr.source.float_source`), else LLVM would rewrite ``pow(x, 0.5)`` with a
constant exponent as ``sqrt(x)``, which libm's pow does not always equal (1745 of 2 million values
of ``x ** 0.5`` differ in the last bit). A batch whose code calls a function outside
:data:`SAME_AS_MATH` keeps the Python loop.

Same fallback rules as the single compiled loop (:func:`compiled_batch`): the built-in laws only,
the uniform quantizer only, no input quantizer, input gain b = 1, no terms in t, the sensors'
velocity, batches of at least :data:`~.compiled_loop.MIN_ROWS` copy-rows (as a user's law's), no
observer; the rest runs the array form, and so do the batches of a structure not compiled
before until their cost reaches :data:`~.compiled_loop.COLD_MIN_ROWS` rows of a single run's
Python loop (:func:`array_rows`, :func:`~.compiled_loop.compile_pays`). The text is cached on
disk (:mod:`qcontrol.compiled.cache`).
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from .. import compiled as compiled_paths
from ..compiled import CALLED, JIT
from ..compiled.traced import TracedForm
from ..plants.base import NativeStepper, NativeStepping
from ..plants.ode import ChainPlant
from ..quantizer import UniformQuantizer
from . import compiled_loop
from .compiled_folds import NO_VALUES, Folds, helpers
from .compiled_loop import (
    CONTROL_REFUSED,
    START,
    Resume,
    Schedule,
    TracedParts,
    _indented,
    compilable,
    loop_body,
    module_source,
    traced_parts,
)
from .retention import MetricsRecord
from .spec import RunSpec

# the functions whose compiled form gives Python's math numbers (numba 0.68, SVML off: 1.6 million
# values each, special ones included, equal to the last bit; pow with its exponent opaque to LLVM)
SAME_AS_MATH = frozenset({"math.sin", "math.cos", "math.tan", "math.sqrt", "math.exp", "math.expm1",
                          "math.log", "math.tanh", "math.fabs", "math.isfinite", "math.isinf", "math.nan",
                          "math.pow", "np.floor", "np.cbrt"})
_CALLS = re.compile(r"\b(?:math|np)\.\w+")


def same_as_math(*texts: str) -> bool:
    """Whether generated code calls only functions of :data:`SAME_AS_MATH`."""
    return all(call in SAME_AS_MATH for text in texts for call in _CALLS.findall(text))


def unfolded(batch: int) -> tuple:
    """The folds' arguments of a loop that folds nothing (a full record keeps every row)."""
    return (np.zeros((batch, 0)), np.zeros((batch, 0)), np.zeros(batch, dtype=np.bool_), np.zeros(1),
            NO_VALUES, np.zeros(1, dtype=np.intp), np.zeros((1, 2)))


def array_rows(plant: Any, rows: int) -> int:
    """What ``rows`` rows of ``plant``'s batch cost in the array form, counted in rows of a single
    run's Python loop (about 20 us each; :func:`~.compiled_loop.compile_pays`): on the ODE about
    0.1 ms a row and 1 us a copy-row (5 rows, and a row per 20 copies), on MuJoCo about 20 us a
    copy-row (a row per copy)."""
    copies = plant.batch
    return rows * (5 + copies // 20) if isinstance(plant, ChainPlant) else rows * copies


class Redo(Exception):
    """A copy's compiled code could not give a row it keeps: the run is done again in the array
    form."""


def batch_source(parts: TracedParts, plant: NativeStepper, n: int, m: int, fold: list[str] = (),
                 enter: list[str] = (), leave: list[str] = ()) -> str:
    """The module text: ``copy_rows`` (one copy's rows, the single run's loop body on column b,
    with the quick divergence test and the reductions' folds, ``enter`` before the rows and
    ``leave`` before every return) and ``rows`` (every copy in turn)."""
    finite = ([f"abs(x{i}) <= bound" for i in range(1, n + 1)]
              + [f"math.isfinite(adaptive[{i}])" for i in range(m)])
    test = [f"if not ({' and '.join(finite)}):", "    suspect[k - start] = True"]
    body = [*enter]
    for line in loop_body(parts, plant, n, m, "b, j", test, fold):  # (buffers stored copy after copy)
        if line.lstrip().startswith("return "):
            body += [line[: len(line) - len(line.lstrip())] + text for text in leave]
        body.append(line)
    arguments = "start, stop, step_first, hold, base, bound, yd, xb, mb, qb, ub, ab"
    folds = "odd, e_instants, e_values, e_done, e_last"
    return module_source(plant, [
        helpers(), "",
        CALLED,
        f"def copy_rows(b, {arguments}, adaptive, held, lp, pf, pi, xs, suspect, fp, lf, {folds}):",
        *_indented(body, 1),
        "",
        JIT,
        f"def rows({arguments}, adaptives, helds, lps, pfs, pi, xss, suspect, status, at, fps, lfs,"
        f" {folds}):",
        "    for b in range(xss.shape[0]):",
        "        if status[b] != 0:  # stopped computing: every row marked",
        "            suspect[:] = True",
        "            continue",
        f"        s, k = copy_rows(b, {arguments}, adaptives[b], helds[b], lps[b], pfs[b], pi, xss[b],"
        f" suspect, fps[b], lfs[b], {folds})",
        "        if s != 0:",
        "            status[b], at[b] = s, k",
        "            suspect[max(k + 1 - start, 0):] = True",
        "",
    ])


class CompiledBatch:
    """The compiled form of a batch's law and quantizer; :meth:`run` adds the ODE's step."""

    def __init__(self, parts: TracedParts, form: TracedForm, n: int, m: int, law: Any = None) -> None:
        self.parts, self.form, self.n, self.m, self.law = parts, form, n, m, law
        self.held_width = 1 + m + n  # u, the targets, zbar (a user law's: u and its sample)

    def source(self, plant: NativeStepper, folds: Folds | None = None) -> str:
        """The text of the generated batch loop for this law and plant, with ``folds``."""
        fold, enter, leave = ([], [], []) if folds is None else (folds.lines(), folds.enter, folds.leave)
        return batch_source(self.parts, plant, self.n, self.m, fold, enter, leave)

    def function(self, plant: NativeStepper, folds: Folds | None = None):  # noqa: ANN201 (a numba dispatcher)
        from ..compiled.cache import generated_module

        return generated_module("batch", self.source(plant, folds)).rows

    def folds(self, loop: Schedule) -> Folds | None:
        """The record's reductions folded in the loop (:mod:`.compiled_folds`): a metrics record's."""
        record = loop.record
        if not isinstance(record, MetricsRecord):
            return None
        return Folds(record.reductions, record.context, self.law, self.form, self.n, self.m, self.parts.q,
                     loop.grid.dt)

    def run(self, loop: Schedule, plant: Any, adaptive: tuple) -> Resume | None:
        """The run from row 0 in compiled chunks, the engine's rare work between them; None when
        the run is over, :data:`START` when the plant has no compiled form for it (the array
        form runs it all); raises :class:`Redo` (see the module docstring)."""
        stepper = plant.native_stepper(loop.grid.dt, form=self.form)
        parts, folds = self.parts, self.folds(loop)
        fold = [] if folds is None else folds.lines()
        if stepper is None or not same_as_math(stepper.helpers, *parts.quantize, *parts.control,
                                               *parts.advance, *fold):
            return START._replace(adaptive=adaptive)
        source = self.source(stepper, folds)
        if not compiled_loop.compile_pays("batch", source, array_rows(plant, loop.grid.rows)):
            return START._replace(adaptive=adaptive)  # (the array form: cheaper than a compile)
        try:
            rows = self.function(stepper, folds)
        except Exception as exc:  # numba refusing a construct: the array form, said once
            compiled_paths.fallback("the batch of copies", f"{type(exc).__name__}: {exc}")
            return START._replace(adaptive=adaptive)
        batch, record = plant.batch, loop.record
        state = np.empty((batch, self.m))
        for i, column in enumerate(adaptive):
            state[:, i] = column
        held = np.zeros((batch, self.held_width))
        arrays = record.buffer.by_copy()  # (rows stored copy after copy: see RowBuffer)
        buffers = (arrays["x"], arrays["x_meas"], arrays["x_q"], arrays["u"], arrays["adaptive"])
        status, at = np.zeros(batch, dtype=np.int64), np.zeros(batch, dtype=np.int64)
        bound, lps = float(loop.rows.state_bound), np.ascontiguousarray(self.parts.constants)
        start, step_first = 0, False
        record.folds = folds
        try:
            while True:
                stop = loop.next_event(start - 1)
                yd = np.ascontiguousarray(loop.reference.block(start, stop + 1))
                suspect = np.zeros(stop - start + 1, dtype=np.bool_)
                stepper.sync_in()
                rows(start, stop, step_first, loop.grid.hold, record.buffer.base, bound, yd, *buffers, state,
                     held, lps, stepper.floats, stepper.ints, stepper.state, suspect, status, at,
                     *(unfolded(batch) if folds is None else folds.arguments()))
                self.test(loop, start, suspect)
                self.check(loop.divergence.kept, status, at)
                if loop.rare_work(stop):
                    return None
                start, step_first = stop + 1, True
        except Redo:
            record.folds = None
            raise
        finally:
            stepper.sync_out()

    @staticmethod
    def test(loop: Schedule, start: int, suspect: np.ndarray) -> None:
        """Test the marked rows for divergence, each run of consecutive rows at once (the same
        as one by one: each row is tested after the one before it)."""
        marked = np.flatnonzero(suspect)
        if not len(marked):
            return
        breaks = np.flatnonzero(np.diff(marked) != 1)
        for first, last in zip(np.r_[marked[0], marked[breaks + 1]], np.r_[marked[breaks], marked[-1]],
                               strict=True):
            loop.divergence.test(start + int(first), start + int(last) + 1, loop.record.buffer)

    @staticmethod
    def check(kept: np.ndarray, status: np.ndarray, at: np.ndarray) -> None:
        """Raise :class:`Redo` if a copy stopped being computed before a row it keeps: its control
        at row k (rows before k kept only) or its step from row k (rows up to k kept only)."""
        for b in np.flatnonzero(status):
            last = at[b] - 1 if status[b] == CONTROL_REFUSED else at[b]
            if kept[b] - 1 > last:
                raise Redo(f"copy {b} at row {at[b]}")


def compiled_batch(spec: RunSpec) -> CompiledBatch | None:
    """The compiled form of ``spec``'s batch of copies, or None where it keeps the array form (the
    module docstring says when)."""
    plant, batch = spec.plant, spec.plant.batch
    if batch == 1 or not isinstance(plant, NativeStepping) or spec.velocity_source != "sensor":
        return None
    if spec.grid.rows * batch < compiled_loop.MIN_ROWS or spec.observer is not None:  # (copy-rows)
        return None
    if spec.input_quantizer is not None:
        return None
    if type(spec.quantizer) is not UniformQuantizer or not compiled_paths.enabled():
        return None
    if not compilable(spec.law, batch):
        return None
    form = TracedForm(batch)
    try:
        parts = traced_parts(spec.quantizer, spec.law, plant.n, spec.grid.dt, form)
    except (TypeError, ValueError):  # a formula that cannot be traced: the array form
        return None
    return CompiledBatch(parts, form, plant.n, spec.law.state_size, spec.law)
