"""The compiled loop: a batch of one with a built-in law, run in numba between the engine's
scheduled rows, generated from the parts' own Python code.

The engine's float path (:mod:`.fastpath`) chooses it for a run whose parts all have a compiled
form: the uniform quantizer (one step, or a step and a range per channel:
:class:`~qcontrol.quantizers.ChannelQuantizer`), a built-in law, the plant's
:class:`~qcontrol.plants.base.NativeStepper` (the ODE's RK4 on its terms, or MuJoCo's copy step
calling ``mj_step`` from compiled code), the velocity sensor's or the differenced velocity
(:mod:`.velocity`). The quantizer's formula (:meth:`~qcontrol.quantizer.UniformQuantizer.apply`),
the differenced velocity's (:func:`~.velocity.differenced`) and the law's ``control`` and advance are
not restated here: they run once on the traced column form (:mod:`qcontrol.compiled.traced`),
whose symbols record every operation they make, in order, as source lines
(:func:`traced_parts`). The generated function runs the loop body of
:meth:`~.loop.ClosedLoop.run` for rows ``[start, stop]`` (observe, quantize, control every
``hold`` rows, the row written into the run's buffer, step, advance) with the same operations
in the same order (numpy's error model, no fast-math contraction), so every row is the Python
loop's to the last bit. Between calls the engine does its rare work
(:meth:`~.loop.ClosedLoop.rare_work`) at the rows it schedules, as ever.

Where the compiled code cannot give the Python loop's numbers (``math`` refusing an evaluation
the Python form answers with numpy), it stops before the row (or the step) and the Python loop
runs on from there (:class:`Resume`). Everything else runs in Python from the start: user laws
and subclasses that change a built-in law, other
quantizers, batches, runs shorter than :data:`MIN_ROWS` rows, single runs of fewer than
:data:`COLD_MIN_ROWS` in a process that has not started numba (:func:`numba_pays`), runs of
a structure not compiled before until its runs reach :data:`COLD_MIN_ROWS` rows
(:func:`compile_pays`), and every run when ``QCONTROL_COMPILE=0`` or numba is missing.

The generated text is kept in the user's cache folder (:mod:`qcontrol.compiled.cache`), keyed by
the text and the versions; the numbers (gains, theta, the step, addresses) are arguments, so one
compiled function serves every run of the same structure.
"""

from __future__ import annotations

import sys
from typing import Any, NamedTuple, Protocol

import numpy as np

from .. import compiled as compiled_paths
from ..compiled import JIT
from ..compiled.traced import TRACED, Symbol, Trace, TracedForm, recording
from ..controller.backstepping import BacksteppingLaw, ControlOutput, output
from ..controller.law import BatchLaw
from ..plants.base import NativeStepper, NativeStepping, Plant
from ..quantizer import QuantizedReading, UniformQuantizer
from ..quantizers import ChannelQuantizer, HysteresisQuantizer
from . import velocity
from .reference_rows import ReferenceRows
from .spec import RunSpec

# Runs shorter than MIN_ROWS stay in Python: the Python loop takes 15-30 us a row, the compiled
# one about 1 us on the ODE (MuJoCo's own step, about 12 us, stays), but numba costs about 0.5 s
# to start in a process and 1.5 s of CPU to compile a new structure (once, then cached), so a
# short run (a test, a quick check) would spend more on the compiler than it saves. In a process
# that has not started numba yet (a run from the command line) only a single run of
# COLD_MIN_ROWS rows pays for the start: there MuJoCo's passive callback stays in Python too.
# A structure not compiled before compiles once its runs reach COLD_MIN_ROWS rows (a batch's
# array form counted in such rows), where Python has cost about what the compile does.
MIN_ROWS = 5000
COLD_MIN_ROWS = 50_000
DONE, CONTROL_REFUSED, STEP_REFUSED = 0, 1, 2  # what a call returns, with the row it stopped at


class Resume(NamedTuple):
    """Where the Python loop takes over: at ``row``, with the adaptive state there and, when
    ``step_first``, the step and advance of the row before still to do with the held ``out``;
    ``past``: a differenced velocity's positions of the rows before, oldest first."""

    row: int
    step_first: bool
    adaptive: tuple
    out: ControlOutput | None
    past: tuple = ()


START = Resume(0, False, (), None)


class Schedule(Protocol):
    """What the compiled loop uses of the engine's :class:`~.loop.ClosedLoop`: its grid, record
    and reference rows, and its rare rows (:meth:`next_event`, :meth:`rare_work`)."""

    grid: Any
    record: Any
    reference: ReferenceRows

    def next_event(self, k: int) -> int: ...

    def rare_work(self, k: int) -> bool: ...


def _indented(lines: list[str], depth: int) -> list[str]:
    return ["    " * depth + line for line in lines]


class TracedParts(NamedTuple):
    """The run's quantizer and law as lines of the loop, recorded from their own Python code run
    on symbols (:mod:`qcontrol.compiled.traced`): ``quantize`` (``m1 .. mn`` -> ``q``, the names
    or constants of ``q_1 .. q_n``), ``control`` (at a sample: fills ``held`` with u, the targets
    and zbar), ``advance`` (every step), the constants ``lp`` they read, and the output's rate;
    ``keep``: lines after the row's control (a differenced velocity keeping the position);
    ``memory``: the hysteresis quantizer whose level per channel the loop keeps in ``lv`` (NaN
    before the first reading), else None; ``applied``: with an input quantizer, the lines that set
    the plant's input ``u`` to q_u of the held ``held[0]`` (the record keeps ``held[0]``)."""

    quantize: list[str]
    q: list[str]
    control: list[str]
    advance: list[str]
    constants: np.ndarray
    rate: Any  # a number, or per copy a (batch,) array
    keep: tuple[str, ...] = ()
    memory: Any = None  # a quantizer whose levels the loop keeps in ``lv`` (hysteresis), or None
    applied: tuple[str, ...] = ()  # lines setting the plant's input u from held[0] (an input quantizer)


def _quantized(quantizer: Any, n: int, trace: Trace) -> list:
    """The traced readings q_1 .. q_n of ``quantizer`` (each channel's own formula); a hysteresis
    quantizer's levels read from and kept in ``lv``."""
    if isinstance(quantizer, UniformQuantizer):
        return [quantizer.apply(Symbol(f"m{i}"), TRACED.floor) for i in range(1, n + 1)]
    if isinstance(quantizer, HysteresisQuantizer):
        q = [quantizer.apply_channel(i, Symbol(f"m{i + 1}"), Symbol(f"lv[{i}]"), TRACED) for i in range(n)]
        trace.lines += [f"lv[{i}] = {trace.text(qi)}" for i, qi in enumerate(q)]
        return q
    return [quantizer.apply_channel(i - 1, Symbol(f"m{i}"), TRACED) for i in range(1, n + 1)]


def traced_parts(quantizer: UniformQuantizer, law: BatchLaw, n: int, dt: float,
                 form: TracedForm = TRACED, period: float | None = None,
                 input_quantizer: UniformQuantizer | None = None) -> TracedParts:
    """:meth:`UniformQuantizer.apply`, ``law.control`` and ``law.advancer_in`` run on the traced
    form (``form``: :data:`TRACED`, or ``TracedForm(batch)`` for a batch of copies, whose
    constants then have a row per copy); raises TypeError where a formula cannot be traced (the
    run keeps the Python loop). ``period``: x2 differenced from the position over this many
    seconds (the control period, ``hold`` rows; :func:`differenced_velocity`); ``input_quantizer``:
    the plant is stepped with q_u(u) (:meth:`UniformQuantizer.apply` on the held u)."""
    m, trace = law.state_size, Trace()
    with recording(trace):
        q = _quantized(quantizer, n, trace)
        keep: list[str] = []
        if period is not None:
            q, keep = differenced_velocity(trace, q, period)
        q_text = [trace.text(qi) for qi in q]
        quantize = trace.taken()
        with trace.deferring(f"return {CONTROL_REFUSED}, k"):  # (held written after it)
            reading = QuantizedReading(None, quantizer.max_error, columns=q, form=form, batch=1)
            yd = [Symbol(f"yd[r, {j}]") for j in range(n + 1)]
            state = tuple(Symbol(f"adaptive[{i}]") for i in range(m))
            t = trace.assign(f"k * {trace.constant(dt)}")
            out = law.control(reading, yd, state, t)
            held = [out.u, *out.target, *out.zbar]
            texts = [trace.text(v) for v in held]
        trace.lines += [f"held[{i}] = {text}" for i, text in enumerate(texts)]
        control = trace.taken()
        if isinstance(out.rate, Symbol) or len(out.target) != m or len(out.zbar) != n:
            raise TypeError("a law output the compiled loop cannot hold")
        symbols = [Symbol(f"held[{i}]") for i in range(len(held))]
        kept = output((symbols[0], tuple(symbols[1 + m:]), tuple(symbols[1:1 + m]), out.rate))
        advanced = law.advancer_in(form, dt)(state, kept)  # (no refusal: it follows the step)
        texts = [trace.text(v) for v in advanced]
        trace.lines += [f"adaptive[{i}] = {text}" for i, text in enumerate(texts)]
        advance = trace.taken()
        applied: tuple[str, ...] = ()
        if input_quantizer is not None:
            text = trace.text(input_quantizer.apply(Symbol("held[0]"), TRACED.floor))
            applied = (*trace.taken(), f"u = {text}")
    rate = out.rate if isinstance(out.rate, np.ndarray) else float(out.rate)
    constants = trace.table(None if form.batch == 1 else form.batch)
    memory = quantizer if isinstance(quantizer, HysteresisQuantizer) else None
    return TracedParts(quantize, q_text, control, advance, constants, rate, tuple(keep), memory, applied)


def differenced_velocity(trace: Trace, q: list, period: float) -> tuple[list, list[str]]:
    """``q`` with x2 replaced by the velocity differenced from the quantized position
    (:func:`~.velocity.differenced`, traced), as the float form's
    :class:`~.fastpath.FloatDifferencing` does: the positions of the last ``hold`` rows are
    kept in ``vb`` (row k's at ``k % hold``, the loop's ``phase``), all the first row's before
    the run. Returns the readings and the line that keeps the row's position, run after the
    row's control (so a control that hands over to Python leaves the positions as they were
    before the row)."""
    position = trace.text(q[0])
    trace.lines += ["if k == 0:", f"    vb[:] = {position}"]
    rate = velocity.differenced(q[0], Symbol("vb[phase]"), period)
    return [q[0], rate, *q[2:]], [f"vb[phase] = {position}"]


class LoopParts(NamedTuple):
    """The pieces of one copy's loop (:func:`loop_body`): ``entry`` before the rows (the plant's
    setup, the held u, the step and advance from the row before when ``step_first``), ``row``
    (row k read, quantized, tested, controlled at a sample), ``keep`` (the row written into the
    buffers, then folded) and ``step`` (the step and advance to row k + 1). ``entry`` and
    ``step`` may ``return 2, k``, ``row`` ``return 1, k``."""

    entry: list[str]
    row: list[str]
    keep: list[str]
    step: list[str]


def loop_parts(parts: TracedParts, plant: NativeStepper, n: int, m: int, at: str = "j, 0",
               test: list[str] = (), fold: list[str] = ()) -> LoopParts:
    """The pieces of :func:`loop_body` (its arguments)."""
    record = ([f"xb[{at}, {i - 1}] = x{i}" for i in range(1, n + 1)]
              + [f"mb[{at}, {i - 1}] = m{i}" for i in range(1, n + 1)]
              + [f"qb[{at}, {i}] = {q}" for i, q in enumerate(parts.q)]
              + [f"ub[{at}] = {'held[0]' if parts.applied else 'u'}"]
              + [f"ab[{at}, {i}] = adaptive[{i}]" for i in range(m)]
              + list(parts.keep))
    take = list(parts.applied) or ["u = held[0]"]  # the plant's input: the held u, or q_u of it
    entry = [*plant.setup, *take, "if step_first:", "    k = start - 1",
             *_indented(plant.step + parts.advance, 1)]
    row = [*plant.observe, *parts.quantize, *test, "if phase == 0:", *_indented(parts.control, 1),
           *_indented(take, 1)]
    return LoopParts(entry, row, [*record, *fold], [*plant.step, *parts.advance])


def loop_body(parts: TracedParts, plant: NativeStepper, n: int, m: int, at: str = "j, 0",
              test: list[str] = (), fold: list[str] = (), origin: str = "start") -> list[str]:
    """The lines of the loop over rows ``[start, stop]`` of one copy, returning ``(status, row)``;
    ``at`` indexes the row (``j``) of the copy in the buffers (``"j, 0"``: buffers stored row
    after row; a batch's, stored copy after copy: ``"b, j"``); ``test`` runs after the row is read
    (a batch's quick divergence test), ``fold`` after it is written (a batch's reductions);
    ``origin`` names the row of ``yd``'s first line (``r = k - origin``).
    ``phase`` is ``k % hold`` (a control sample at 0), counted rather than divided (no integer
    division a row)."""
    pieces = loop_parts(parts, plant, n, m, at, test, fold)
    return [
        *pieces.entry,
        "phase = start % hold",
        "for k in range(start, stop + 1):",
        f"    r = k - {origin}",
        *_indented(pieces.row, 1),
        "    j = k - base",
        *_indented(pieces.keep, 1),
        "    if k == stop:",
        "        return 0, k",
        *_indented(pieces.step, 1),
        "    phase = 0 if phase + 1 == hold else phase + 1",
        "return 0, stop",
    ]


def module_source(plant: NativeStepper, functions: list[str]) -> str:
    """A generated module: its imports, the plant's helpers (from a module of their own, compiled
    once for every loop and batch of the plant: :func:`~qcontrol.compiled.cache.shared`), then
    ``functions``' lines."""
    from ..compiled.cache import shared

    return "\n".join([
        '"""qcontrol\'s compiled loop (generated): see KEY."""',  # (user text only as a repr literal)
        "import math", "", "import numba", "import numpy as np", "",
        f"KEY = {plant.key!r}", "",
        "from qcontrol.compiled.pointers import as_pointer, carray, opaque", "",
        shared("step", plant.helpers), "", *functions, "",
    ])


def loop_source(parts: TracedParts, plant: NativeStepper, n: int, m: int) -> str:
    """The module text of the loop function ``rows(...) -> (status, row)``."""
    return module_source(plant, [
        JIT,
        "def rows(start, stop, step_first, hold, base, yd, xb, mb, qb, ub, ab, adaptive, held, lp, pf, pi,"
        f" xs{', vb' if parts.keep else ''}{', lv' if parts.memory is not None else ''}):",
        *_indented(loop_body(parts, plant, n, m), 1),
    ])


class CompiledLoop:
    """The compiled form of one run's law and quantizer; :meth:`run` adds the plant's."""

    def __init__(self, parts: TracedParts, n: int, m: int) -> None:
        self.parts, self.n, self.m = parts, n, m
        self.held_width = 1 + m + n  # u, the targets, zbar (a user law's: u and its sample)

    def source(self, plant: NativeStepper) -> str:
        """The text of the generated loop for this law and plant."""
        return loop_source(self.parts, plant, self.n, self.m)

    def function(self, source: str):  # noqa: ANN201 (a numba dispatcher)
        """The generated loop of ``source`` (:meth:`source`), compiled or loaded from the disk cache."""
        from ..compiled.cache import generated_module

        return generated_module("loop", source).rows

    def held_output(self, held: np.ndarray) -> ControlOutput:
        """``held`` (u, targets, zbar) as the output the Python loop continues with."""
        values, m = held.tolist(), self.m
        return output((values[0], tuple(values[1 + m:]), tuple(values[1:1 + m]), self.parts.rate))

    def run(self, loop: Schedule, plant: Plant, adaptive: tuple) -> Resume | None:
        """The run from row 0 in compiled chunks, the engine's rare work between them; None when
        the run is over, else where the Python loop takes over (all of the run when the plant has
        no compiled form for it)."""
        stepping = isinstance(plant, NativeStepping)
        stepper = plant.native_stepper(loop.grid.dt, loop.grid.rows) if stepping else None
        source = None if stepper is None else self.source(stepper)
        if source is None or not compile_pays("loop", source, loop.grid.rows):
            return START._replace(adaptive=adaptive)
        try:
            rows = self.function(source)  # (the text the gate counted: one module named)
        except Exception as exc:  # numba refusing a construct: the Python loop, said once
            compiled_paths.fallback("the closed loop", f"{type(exc).__name__}: {exc}")
            return START._replace(adaptive=adaptive)
        state, held = np.array(adaptive, dtype=float), np.zeros(self.held_width)
        hold = loop.grid.hold
        positions = (np.zeros(hold),) if self.parts.keep else ()  # a differenced velocity's
        memory = self.parts.memory  # a hysteresis quantizer: its levels, NaN before the first reading
        levels = (np.full(self.n, np.nan),) if memory is not None else ()
        arrays = loop.record.buffer.arrays
        buffers = (arrays["x"], arrays["x_meas"], arrays["x_q"], arrays["u"], arrays["adaptive"])
        start, step_first = 0, False
        while True:
            stop = loop.next_event(start - 1)
            yd = np.ascontiguousarray(loop.reference.block(start, stop + 1))
            stepper.sync_in()
            status, row = rows(start, stop, step_first, hold, loop.record.buffer.base, yd, *buffers, state,
                               held, self.parts.constants, stepper.floats, stepper.ints, stepper.state,
                               *positions, *levels)
            stepper.sync_out()
            if status in (CONTROL_REFUSED, STEP_REFUSED):
                after = status == STEP_REFUSED  # the row's step and advance still to do
                resume = row + after
                if memory is not None and resume:  # (a row read again: the same level, held_level)
                    memory.level = levels[0].reshape(1, self.n).copy()
                past = tuple(np.roll(positions[0], -resume).tolist()) if positions and resume else ()
                return Resume(resume, after, tuple(state.tolist()), self.held_output(held) if after else None,
                              past)
            if loop.rare_work(stop):
                return None
            start, step_first = stop + 1, True


def compilable(law: BatchLaw, copies: int = 1) -> bool:
    """Whether the law's own code may be traced for the compiled loop of ``copies`` copies (1: a
    run; more: :mod:`.compiled_batch`): an object of a built-in law class with a compiled form
    whose ``has_compiled_equivalent`` (the base class's definition: a subclass's own property is
    itself a change) says it runs its class's code, with its parameters shared or one per copy.
    Anything else (a user law, a subclass with code of its own that may keep state or draw
    numbers) keeps the Python loop."""
    return isinstance(law, BacksteppingLaw) and BacksteppingLaw.has_compiled_equivalent.fget(law) \
        and law.copies in (None, copies)


def numba_pays(rows: int, batch: int) -> bool:
    """Whether a run may use numba at all (the compiled loop, MuJoCo's native callback): a batch
    (sweeps, studies: long, and ``mujoco.batch`` needs the native callback), a run in a process
    that has started numba already, or a single run of at least :data:`COLD_MIN_ROWS` rows, which
    pays for numba's start. A shorter single run in a fresh process (a 10 s run from the command
    line) is faster in Python, cold cache or warm (docs/architecture.md, 'The compiled loop')."""
    return batch != 1 or "numba" in sys.modules or rows >= COLD_MIN_ROWS


def compile_pays(kind: str, source: str, rows: int) -> bool:
    """Whether a run of ``rows`` rows (a batch's cost in rows of a single run's Python loop:
    :func:`~.compiled_batch.array_rows`) takes the generated module ``source`` of ``kind``
    (:mod:`qcontrol.compiled.cache`): where it was compiled before (loaded in a fraction of a
    second), or where the rows run without it so far, this run's included, reach
    :data:`COLD_MIN_ROWS`, about as much Python (or array form) as a compile costs. Else the run
    keeps Python, which costs less than the compile, and its rows are counted in the cache
    folder: whatever the runs to come, a structure costs at most about twice what
    the best choice in hindsight would (docs/architecture.md, 'The compiled loop')."""
    from ..compiled import cache

    ran = cache.uncompiled_rows(kind, source)
    if ran is None or ran + rows >= COLD_MIN_ROWS:
        return True
    try:
        cache.count_uncompiled(kind, source, ran + rows)
    except OSError:  # a cache folder that cannot be written: compiling says why, once
        return True
    return False


def compiled_loop(spec: RunSpec) -> CompiledLoop | None:
    """The compiled form of ``spec``'s law and quantizer for a batch of one, or None where the
    run keeps the Python loop (see the module docstring)."""
    rows = spec.grid.rows
    if spec.plant.batch != 1 or rows < MIN_ROWS:
        return None
    period = None  # x2 from the velocity sensor, else differenced over the control period
    if spec.velocity_source == "difference":
        if spec.plant.n < 2:
            return None
        period = spec.grid.hold * spec.grid.dt
    if not numba_pays(rows, 1):  # (before enabled(), which imports it)
        return None
    if type(spec.quantizer) not in (UniformQuantizer, ChannelQuantizer, HysteresisQuantizer):
        return None  # (a subclass: its own way)
    if spec.input_quantizer is not None and type(spec.input_quantizer) is not UniformQuantizer:
        return None
    if not compiled_paths.enabled():
        return None
    if not compilable(spec.law):
        return None
    try:
        parts = traced_parts(spec.quantizer, spec.law, spec.plant.n, spec.grid.dt, period=period,
                             input_quantizer=spec.input_quantizer)
    except TypeError:  # a formula that cannot be traced: the Python loop
        return None
    return CompiledLoop(parts, spec.plant.n, spec.law.state_size)
