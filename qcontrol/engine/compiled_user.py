"""A user's law in the compiled loop and the compiled batch, where its code has a compiled form.

A :class:`~qcontrol.Law` whose code, traced and checked (:mod:`.user_trace`), is arithmetic on its
inputs runs as a built-in law does (:mod:`.compiled_loop`, :mod:`.compiled_batch`): the same loop
body, with its lines in place of the built-in law's and the sample its update holds (u, ``x_q``,
``yd``, ``t``) in the loop's ``held`` array; a batch of them with each copy's numbers in its row
of the constants. A column-form law of the user's (a class outside the package written over
columns) is traced as the built-in laws are, on a copy of it, and its lines checked against its
float form (a single run's); a batch of it, one law object for every copy, runs those lines for
each copy, the one trace's constants in every copy's row, as a batch of equal ``Law`` copies
does. The runs that take this path follow the compiled loop's and the compiled batch's rules
(:func:`compiled_user`), a batch from 5000 copy-rows (a ``Law``'s Python costs a call per copy).
The compiled run hands over to the Python loop where a traced expression refuses (as a built-in
law does); a run of a ``Law`` whose first input or first state update is not finite is done again
in Python, which checks them (:class:`~.compiled_batch.Redo`).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np

from .. import compiled as compiled_paths
from ..compiled.traced import TRACED, Symbol, Trace, TracedForm, recording
from ..controller.law import AnyColumnForm
from ..controller.user import UserLaw, sample
from ..plants.ode import ChainPlant
from ..quantizer import UniformQuantizer
from .compiled_batch import CompiledBatch, Redo
from .compiled_loop import MIN_ROWS, CompiledLoop, TracedParts, numba_pays, traced_parts
from .fastpath import single_copy, single_copy_quantizer
from .spec import RunSpec
from .user_numpy import compiled_fma, same_bits
from .user_trace import (
    CHECKS,
    COMPILED,
    Held,
    QuietMath,
    check_points,
    python_calls,
    quietly,
    trace_law,
    unchanged,
    why_not,
)


def user_parts(quantizer: UniformQuantizer, law: UserLaw, n: int, dt: float,
               form: TracedForm = TRACED) -> TracedParts | None:
    """The compiled loop's parts for a user law: the quantizer's lines (its own formula on
    symbols, as for a built-in law) and each copy's traced law; None where the law has none."""
    trace = Trace()
    with recording(trace):
        q = [quantizer.apply(Symbol(f"m{i}"), TRACED.floor) for i in range(1, n + 1)]
        q_text = [trace.text(qi) for qi in q]
        quantize = trace.taken()
    traces, why = trace_law(law, n, dt, trace.constants)
    law.compiled_form = why or COMPILED
    if traces is None:
        return None
    first = traces[0]
    if form.batch == 1:  # the Python loop's calls too, where it runs (a short run, a hand-over)
        law.fast = python_calls(first, n, law.state_size)
    start = [*[f"sq{i} = {q}" for i, q in enumerate(q_text)], f"st = k * {dt!r}"]
    constants = (np.array(first.constants, dtype=float) if form.batch == 1
                 else per_copy([tr.constants for tr in traces], form.batch))
    return TracedParts(quantize, q_text, start + first.control, first.advance, constants, 0.0)


def per_copy(rows: Sequence[Sequence[float]], batch: int) -> np.ndarray:
    """The constants of a batch, ``(batch, slots)``: each copy's trace's row, or the one trace's
    in every row where the copies share one (a batch of equal laws, or a column-form law's one
    object for every copy)."""
    rows = list(rows) * (batch if len(rows) == 1 else 1)
    return np.array(rows, dtype=float).reshape(batch, len(rows[0]))


def column_checked(parts: TracedParts, law: Any, quantizer: UniformQuantizer, n: int,
                   dt: float) -> str | None:
    """Why the traced lines of a column-form law (with the quantizer's) do not give what a single
    run's Python loop computes (:func:`~.fastpath.single_copy`: u and the state one step on, bit
    for bit) at :data:`CHECKS` samples; None: they do."""
    m = law.state_size
    source = "\n".join(["def control(m, yd, adaptive, k, lp, held):", "    r = 0",
                        *[f"    m{i + 1} = m[{i}]" for i in range(n)],
                        *[f"    {line}" for line in parts.quantize + parts.control], "    return 0, 0", "",
                        "def advance(adaptive, lp, held):", *[f"    {line}" for line in parts.advance],
                        "    return None"])
    functions: dict[str, Any] = {"math": QuietMath(), "np": np}
    exec(compile(source, "<traced law>", "exec"), functions)  # noqa: S102 (text made by the tracer alone)
    quantize, (control, advance) = single_copy_quantizer(quantizer), single_copy(law, dt)
    state0 = np.asarray(law.initial_state(1), dtype=float).reshape(m)
    compared = 0
    for t, readings, yd, state in check_points(n, m, state0, seed=n * 1000 + m):
        k = round(t / dt)
        held, adaptive = np.zeros(1 + m + n), state.copy()
        status, _ = functions["control"](readings.tolist(), yd.reshape(1, -1), adaptive, k, parts.constants,
                                         held)
        if status:
            continue
        out = control(quantize(readings.tolist()), yd.tolist(), tuple(state.tolist()), k * dt)
        stepped = [float(v) for v in advance(tuple(state.tolist()), out)]
        functions["advance"](adaptive, parts.constants, held)
        pairs = zip([float(out.u), *stepped], [held[0], *adaptive.tolist()], strict=True)
        if not all(same_bits(a, b) for a, b in pairs):
            return f"its traced lines differ from its float form at readings {readings.tolist()}"
        compared += 1
    return None if compared >= CHECKS // 2 else "too few samples where it gives a number to check it"


def column_parts(quantizer: UniformQuantizer, law: Any, n: int, dt: float) -> TracedParts | str:
    """A column-form law that is not a built-in class (a subclass of ``qcontrol.BacksteppingLaw``
    or of a built-in law with code of its own): the compiled loop's parts from its own formulas
    traced as the built-in laws' are (:func:`~.compiled_loop.traced_parts`), on a copy of it,
    twice (it must stay as the first trace left it and record the same lines), then checked
    against its float form; or why not."""
    try:
        with quietly():
            traced = copy.deepcopy(law)
            parts = traced_parts(quantizer, traced, n, dt)
            before = copy.deepcopy(traced)
            again = traced_parts(quantizer, traced, n, dt)
            if not unchanged(vars(before), vars(traced)):
                return "it changes its own attributes (a state kept outside its declared state)"
            lines = (parts.quantize, parts.control, parts.advance, parts.constants.tobytes())
            if (again.quantize, again.control, again.advance, again.constants.tobytes()) != lines:
                return "it computes differently at each call (random numbers, a clock, a global?)"
            why = column_checked(parts, law, quantizer, n, dt)
    except Exception as exc:  # any failure of the law's code on symbols: the Python loop
        return why_not(exc)
    return parts if why is None else why


class CompiledUserLoop(CompiledLoop):
    """A single run of a traced user law: the built-in's compiled loop with the sample held."""

    def __init__(self, parts: TracedParts, law: UserLaw, n: int) -> None:
        super().__init__(parts, n, law.state_size)
        self.law, self.held_width = law, Held(n).width

    def function(self, source: str) -> Any:
        return with_fma(super().function(source))

    def held_output(self, held: np.ndarray) -> Any:
        """``held`` (u, x_q, yd, t) as the sample the Python loop continues with."""
        n, values = self.n, held.tolist()
        x_q, yd = np.array(values[1:1 + n]), np.array(values[1 + n:2 * n + 2])
        return sample((values[0], values[2 * n + 2], [x_q], yd))

    def run(self, loop: Any, plant: Any, adaptive: tuple) -> Any:
        first = FirstChecked(loop, self.m)
        resume = super().run(first, plant, adaptive)
        if resume is not None and resume.row > 0:  # the Python loop goes on: the law's first calls were
            first.check(resume.row - 1)  # compiled, and are checked as its Python would check them
            self.law._checked.update(first.done)
        return resume


class CompiledUserBatch(CompiledBatch):
    """A batch of traced user laws: the built-in's compiled batch with each copy's sample held."""

    pairs = False  # one copy at a time at any size: the pair's renaming is checked on built-in laws
    # compiled at once: without it a batch runs each copy's law through Python floats, about 300x
    # the built-in's batch (a 2 s batch of 50: 5.6 s a run, where the compile costs about 4 s once)
    gated = False

    def __init__(self, parts: TracedParts, form: TracedForm, n: int, m: int) -> None:
        super().__init__(parts, form, n, m)
        self.held_width = Held(n).width

    def function(self, source: str) -> Any:
        return with_fma(super().function(source))

    def run(self, loop: Any, plant: Any, adaptive: tuple) -> Any:
        return super().run(FirstChecked(loop, self.m), plant, adaptive)


def with_fma(rows: Any) -> Any:
    """The generated loop ``rows`` with ``fma`` among its globals (a traced law's products of
    vectors, :mod:`.user_numpy`), before numba compiles it."""
    rows.py_func.__globals__.setdefault("fma", compiled_fma())
    return rows


class FirstChecked:
    """The engine's loop as the compiled run sees it, checking at its first rare rows (before any
    rare work) that every copy's first input and first state update are finite; else
    :class:`Redo`: the Python loop, which checks them at a law's first call, runs the run again.
    :attr:`done` names the methods whose first output was checked so."""

    def __init__(self, loop: Any, m: int) -> None:
        self.loop, self.m, self.done = loop, m, set()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.loop, name)

    def check(self, last: int) -> None:
        """Check what rows ``0 .. last`` hold of the first outputs (u at row 0, the state at row 1)."""
        buffer = self.loop.record.buffer
        if buffer.base != 0 or len(self.done) == 3:
            return
        first = {"control()": buffer.arrays["u"][0]} if last >= 0 else {}
        if last >= 1 or not self.m:
            first |= {"advance()": buffer.arrays["adaptive"][min(1, last)], "state_rate()": None}
        if not all(np.all(np.isfinite(a)) for a in first.values() if a is not None):
            raise Redo("a user law's first output is not finite")
        self.done |= set(first)

    def rare_work(self, k: int) -> bool:
        self.check(k)
        return self.loop.rare_work(k)


def own_column_law(law: Any) -> bool:
    """A column-form law of the user's: a class defined outside the package, written over columns,
    that is not a subclass of a built-in law with a compiled form (``compiled_class``: whose
    subclasses with code of their own run their own Python, docs/laws.md section 5)."""
    return type(law).__module__.partition(".")[0] != "qcontrol" and isinstance(law, AnyColumnForm) \
        and not isinstance(law, UserLaw) and getattr(type(law), "compiled_class", None) is None \
        and law.copies in (None, 1)


def compiled_user(spec: RunSpec) -> CompiledLoop | CompiledBatch | None:
    """The compiled form of a run or batch of a user's law, or None (for any other law, and where
    the law keeps the Python loop). The runs it takes are the compiled loop's and the compiled
    batch's (uniform quantizer, the sensors' velocity, no input quantizer; a batch of ODE copies
    without an observer), from :data:`~.compiled_loop.MIN_ROWS` rows, for a batch from as many
    copy-rows."""
    law, plant, rows = spec.law, spec.plant, spec.grid.rows
    batch, user = plant.batch, isinstance(spec.law, UserLaw)
    if user:
        law.fast = None  # traced afresh for this run's step (a law object may serve several runs)
    if not (user or own_column_law(law)) or spec.velocity_source != "sensor" \
            or type(spec.quantizer) is not UniformQuantizer or spec.input_quantizer is not None:
        return None
    if batch == 1 and (rows < MIN_ROWS or not numba_pays(rows, 1)):
        if user and compiled_paths.requested():  # the Python loop, with the law's traced calls
            user_parts(spec.quantizer, law, plant.n, spec.grid.dt)
        return None
    if batch != 1 and (rows * batch < MIN_ROWS or not isinstance(plant, ChainPlant)
                       or spec.observer is not None):
        return None
    if not compiled_paths.enabled():
        return None
    n, dt = plant.n, spec.grid.dt
    if not user:
        parts = column_parts(spec.quantizer, law, n, dt)
        if isinstance(parts, str):
            return None
        if batch == 1:
            return CompiledLoop(parts, n, law.state_size)
        # one law object steps every copy (a class kind's batch shares its settings): its one trace,
        # checked, in every copy's row of the constants, so each copy runs its run alone's lines
        shared = parts._replace(constants=per_copy([parts.constants.tolist()], batch))
        return CompiledBatch(shared, TracedForm(batch), n, law.state_size, law)
    form = TRACED if batch == 1 else TracedForm(batch)
    parts = user_parts(spec.quantizer, law, n, dt, form)
    if parts is None:
        return None
    if batch == 1:
        return CompiledUserLoop(parts, law, n)
    return CompiledUserBatch(parts, form, n, law.state_size)
