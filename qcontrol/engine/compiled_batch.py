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
the record (metrics, divergence, reductions) is the array form's, at the same rows. A large
batch's ODE copies (:func:`paired`) run two at a time, in lockstep (:func:`pair_lines`): a copy's
row depends on its row before, a chain of dependent operations the processor cannot overlap, but
two copies' chains it can (Example 2, 1000 copies: 10-15 % less time per copy-step); each copy's
operations are still its own loop's, in its order. A smaller batch compiles the one-copy function
only (the pair's costs more to compile). A batch of MuJoCo copies runs one copy at a time, each
copy's own ``MjData``
stepped by the plant's copy step (:class:`~qcontrol.plants.mujoco.native_step.MujocoNativeForm`,
a row of pointers per copy).

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
from functools import lru_cache
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
    LoopParts,
    Resume,
    Schedule,
    TracedParts,
    _indented,
    compilable,
    loop_body,
    loop_parts,
    module_source,
    traced_parts,
)
from .retention import MetricsRecord
from .spec import RunSpec

# the functions whose compiled form gives Python's math numbers (numba 0.68, SVML off: 1.6 million
# values each, special ones included, equal to the last bit; pow with its exponent opaque to LLVM;
# np.maximum: exact, NaN where either side is, as numpy's)
SAME_AS_MATH = frozenset({"math.sin", "math.cos", "math.tan", "math.sqrt", "math.exp", "math.expm1",
                          "math.log", "math.tanh", "math.fabs", "math.isfinite", "math.isinf", "math.nan",
                          "math.pow", "np.floor", "np.cbrt", "np.maximum"})
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


# ODE copies run two at a time from PAIRS_MIN_ROWS copy-rows (docs/performance.md, 'The compiled
# batch: copies two at a time'): a pair's function costs about 3.5 s more CPU to compile (once per
# structure, then cached, and loaded as fast), and saves about 13-15 ns of a copy-step of Example 2
# (10-15 %) at any batch size; from 2 million copy-rows (200 copies of a 10 s run) that is about
# 30 ms a run, the compile paid back in about a hundred runs: the large batches (a sweep's full
# chunks, 1000 copies), not a test's or a small batch's, which compile the one-copy function only.
PAIRS_MIN_ROWS = 2_000_000
_ASSIGNED = re.compile(r"^\s*(\w+(?:\s*,\s*\w+)*)\s*=[^=]")
_RETURN = re.compile(r"^(\s*)return (.+)$")
# the second copy's own arguments (its locals are named in the lines), renamed in a pair's lines
COPY_ARGUMENTS = ("b", "adaptive", "held", "lp", "pf", "xs", "fp", "lf")


def copy_names(lines: list[str]) -> set[str]:
    """A copy's own names in its loop's ``lines``: the locals they assign and
    :data:`COPY_ARGUMENTS` (not the row's ``k``, ``r``, ``j``, ``phase``, shared by a pair)."""
    names = set(COPY_ARGUMENTS)
    for line in lines:
        match = _ASSIGNED.match(line)
        if match:
            names.update(name.strip() for name in match.group(1).split(","))
    return names - {"k", "r", "j", "phase"}


def second_copy(lines: list[str], names: set[str]) -> list[str]:
    """``lines`` of one copy as the second copy of a pair's: each of ``names`` (:func:`copy_names`)
    renamed ``name_c`` (comments dropped); the shared arrays and the row's indices are the pair's."""
    pattern = re.compile(r"(?<![\w.])(" + "|".join(sorted(names, key=len, reverse=True)) + r")\b")
    return [pattern.sub(r"\1_c", line.split("  #")[0]) for line in lines]


def _returning(lines: list[str], leave: list[str], who: int, resume: str, first: str) -> list[str]:
    """``lines`` with each ``return status, k`` of copy ``who`` (0 or 1) of a pair as the pair's
    return (``who, status, k``, and where the other copy resumes: its first row and step_first),
    both copies' ``leave`` before it."""
    out = []
    for line in lines:
        match = _RETURN.match(line)
        if match:
            indent = match.group(1)
            out += [indent + text for text in leave]
            line = f"{indent}return {who}, {match.group(2)}, {resume}, {first}"
        out.append(line)
    return out


def pair_lines(pieces: LoopParts, enter: list[str], leave: list[str]) -> list[str]:
    """The body of ``pair_rows``: the rows of two copies (the second's names :func:`second_copy`'s)
    in lockstep, each copy's operations those of its own loop (``copy_rows``) in the same order,
    so each copy's numbers are its own, to the last bit: two independent chains of dependent
    operations, which the processor overlaps (a copy's row waits on its row before). Where a copy
    stops (a refusal), both copies' state is written back and the pair returns which one stopped,
    its status and row, and where the other resumes alone: at row k if it has only read (and
    controlled) row k, which it does again with the same numbers, at k + 1 with its step first
    if it has written row k."""
    names = copy_names([*enter, *(line for part in pieces for line in part)])
    both = [*leave, *second_copy(leave, names)]
    second = LoopParts(*(second_copy(part, names) for part in pieces))
    row = _returning(pieces.row, both, 0, "k", "False") + _returning(second.row, both, 1, "k", "False")
    step = (_returning(pieces.step, both, 0, "k + 1", "True")
            + _returning(second.step, both, 1, "k + 1", "False"))
    return [
        *enter, *second_copy(enter, names),
        *_returning(pieces.entry, both, 0, "start", "step_first"),
        *_returning(second.entry, both, 1, "start", "False"),
        "phase = start % hold",
        "for k in range(start, stop + 1):",
        "    r = k - origin",
        *_indented(row, 1),
        "    j = k - base",
        *_indented(pieces.keep + second.keep, 1),
        "    if k == stop:",
        *_indented(both, 2),
        "        return -1, 0, k, 0, False",
        *_indented(step, 1),
        "    phase = 0 if phase + 1 == hold else phase + 1",
        *both,
        "return -1, 0, stop, 0, False",
    ]


@lru_cache(maxsize=32)
def _paired(pieces: tuple[tuple[str, ...], ...], enter: tuple[str, ...], leave: tuple[str, ...]
            ) -> tuple[str, ...]:
    """:func:`pair_lines` of the same lines made once (each run and chunk asks again)."""
    return tuple(pair_lines(LoopParts(*(list(part) for part in pieces)), list(enter), list(leave)))


ARGUMENTS = "hold, base, bound, yd, xb, mb, qb, ub, ab"  # (the generated functions' shared arguments)
FOLDS = "odd, e_instants, e_values, e_done, e_last"


def rows_lines(pairs: bool) -> list[str]:
    """``rows``: every copy not stopped in turn, by ``copy_rows``; with ``pairs``, by ``pair_rows``,
    two at a time where both run, and a copy alone (the last of an odd batch; where one copy of a
    pair stopped, the other from where it was) paired with a scratch twin of itself: the same
    numbers written twice to its rows, its own state kept (two calls: neither copied into
    ``rows``, compiled once)."""
    alone = ("c, c, start, first, stop, step, {0}, adaptives[c], {1}, helds[c], {2}, lps[c], lps[c], pfs[c],"
             " pfs[c], xss[c], {3}, suspect, fps[c], {4}, lfs[c], lfs[c], pi, {5}")
    twin = [f"{name}[c].copy()" for name in ("adaptives", "helds", "xss", "fps")]
    each = ", ".join(f"{name}[b], {name}[b + 1]" for name in ("adaptives", "helds", "lps", "pfs", "xss"))
    return [
        JIT,
        f"def rows(start, stop, step_first, {ARGUMENTS}, adaptives, helds, lps, pfs, pi, xss, suspect,"
        f" status, at, fps, lfs, {FOLDS}):",
        "    count, paired = xss.shape[0], -1",
        "    for b in range(count):",
        "        if b == paired:  # (run with the copy before it)",
        "            continue",
        "        if status[b] != 0:  # stopped computing: every row marked",
        "            suspect[:] = True",
        "            continue",
        *_indented([
            "if b + 1 < count and status[b + 1] == 0:",
            f"    w, s, k, first, step = pair_rows(b, b + 1, start, start, stop, step_first, {ARGUMENTS},"
            f" {each}, suspect, fps[b], fps[b + 1], lfs[b], lfs[b + 1], pi, {FOLDS})",
            "    paired = b + 1",
            "    if w < 0:",
            "        continue",
            "    status[b + w], at[b + w] = s, k  # one copy stopped: the other runs on alone",
            "    suspect[max(k + 1 - start, 0):] = True",
            "    c = b + 1 - w",
            "else:",
            "    c, first, step = b, start, step_first",
            f"_, s, k, _, _ = pair_rows({alone.format(ARGUMENTS, *twin, FOLDS)})",
        ] if pairs else [
            "c, first, step = b, start, step_first",
            f"s, k = copy_rows(c, start, first, stop, step, {ARGUMENTS}, adaptives[c], helds[c], lps[c],"
            f" pfs[c], pi, xss[c], suspect, fps[c], lfs[c], {FOLDS})",
        ], 2),
        "        if s != 0:",
        "            status[c], at[c] = s, k",
        "            suspect[max(k + 1 - start, 0):] = True",
    ]


def batch_source(parts: TracedParts, plant: NativeStepper, n: int, m: int, fold: list[str] = (),
                 enter: list[str] = (), leave: list[str] = (), pairs: bool = False) -> str:
    """The module text: ``copy_rows`` (one copy's rows from ``start``, the single run's loop body
    on column b, with the quick divergence test and the reductions' folds, ``enter`` before the
    rows and ``leave`` before every return; ``yd``'s first line is row ``origin``'s), or with
    ``pairs`` ``pair_rows`` (two copies in lockstep: :func:`pair_lines`, the ODE's step written
    out in the loop by :func:`written_step`, where numba's inlining of the step's helper ran its
    passes again at each call; the entry's step, once a call, calls the shared helper), and
    ``rows``."""
    # (every test evaluated, joined by &: no branch per test, fewer blocks for numba to compile)
    finite = ([f"(abs(x{i}) <= bound)" for i in range(1, n + 1)]
              + [f"math.isfinite(adaptive[{i}])" for i in range(m)])
    test = [f"if not ({' & '.join(finite)}):", "    suspect[k - origin] = True"]
    pieces = loop_parts(parts, plant, n, m, "b, j", test, fold)  # (buffers stored copy after copy)
    # (pairs where the plant's step is written out in the loop and the row keeps no return of its own)
    step = written_step(plant) if pairs else None
    pairs = step is not None and not any(_RETURN.match(line) for line in pieces.keep)
    if pairs:
        pieces = pieces._replace(step=[*step, *pieces.step[len(plant.step):]])
        function = [f"def pair_rows(b, b_c, origin, start, stop, step_first, {ARGUMENTS}, adaptive,"
                    " adaptive_c, held, held_c, lp, lp_c, pf, pf_c, xs, xs_c, suspect, fp, fp_c, lf, lf_c,"
                    f" pi, {FOLDS}):",
                    *_indented(_paired(tuple(map(tuple, pieces)), tuple(enter), tuple(leave)), 1)]
    else:
        body = [*enter]
        for line in loop_body(parts, plant, n, m, "b, j", test, fold, "origin"):
            if line.lstrip().startswith("return "):
                body += [line[: len(line) - len(line.lstrip())] + text for text in leave]
            body.append(line)
        function = [f"def copy_rows(b, origin, start, stop, step_first, {ARGUMENTS}, adaptive, held, lp, pf,"
                    f" pi, xs, suspect, fp, lf, {FOLDS}):", *_indented(body, 1)]
    return module_source(plant, [helpers(), "", CALLED, *function, "", *rows_lines(pairs), ""])


_ODE_STEP = ("if plant_step(u, xs, pf):", "    return 2, k")  # the ODE's step in the loop (ChainNativeForm)


def written_step(plant: NativeStepper) -> list[str] | None:
    """The ODE's step as lines of the loop: the body of its one helper ``plant_step(u, xs, pf)``
    (the same statements, so the same operations in the same order), its ``return True`` (refused)
    the loop's ``return 2, k`` and its final ``return False`` dropped; None for another plant's."""
    header, helpers = "def plant_step(u, xs, pf):", plant.helpers.rstrip("\n").split("\n")
    if tuple(plant.step) != _ODE_STEP or helpers.count(header) != 1 or plant.helpers.count("\ndef ") != 1:
        return None
    body = helpers[helpers.index(header) + 1:]
    if not body or body[-1] != "    return False" or not all(line.startswith("    ") for line in body):
        return None
    lines = []
    for line in (line[4:] for line in body[:-1]):
        statement = line.lstrip()
        if statement.startswith("return") or "plant_step" in statement:
            if statement != "return True":
                return None
            line = line[: len(line) - len(statement)] + "return 2, k"
        lines.append(line)
    return lines


class CompiledBatch:
    """The compiled form of a batch's law and quantizer; :meth:`run` adds the ODE's step."""

    pairs = True  # a large batch's copies two at a time (:func:`paired`)
    gated = True  # compiled once its array form's cost reaches a compile's (compile_pays, array_rows)

    def __init__(self, parts: TracedParts, form: TracedForm, n: int, m: int, law: Any = None) -> None:
        self.parts, self.form, self.n, self.m, self.law = parts, form, n, m, law
        self.held_width = 1 + m + n  # u, the targets, zbar (a user law's: u and its sample)

    def source(self, plant: NativeStepper, folds: Folds | None = None, pairs: bool = False) -> str:
        """The text of the generated batch loop for this law and plant, with ``folds``, its copies
        two at a time with ``pairs``."""
        fold, enter, leave = ([], [], []) if folds is None else (folds.lines(), folds.enter, folds.leave)
        return batch_source(self.parts, plant, self.n, self.m, fold, enter, leave, pairs)

    def function(self, source: str):  # noqa: ANN201 (a numba dispatcher)
        """The generated batch loop of ``source`` (:meth:`source`), compiled or loaded from the cache."""
        from ..compiled.cache import generated_module

        return generated_module("batch", source).rows

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
        pairs = self.pairs and paired(plant, loop.grid.rows)
        source = self.source(stepper, folds, pairs)
        if self.gated and not compiled_loop.compile_pays("batch", source, array_rows(plant, loop.grid.rows)):
            return START._replace(adaptive=adaptive)  # (the array form: cheaper than a compile)
        try:
            rows = self.function(source)  # (the text the gate counted: one module named)
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


def paired(plant: Any, rows: int) -> bool:
    """Whether a batch of ``plant``'s copies of ``rows`` rows runs its copies two at a time: ODE
    copies of at least :data:`PAIRS_MIN_ROWS` copy-rows."""
    return isinstance(plant, ChainPlant) and plant.batch * rows >= PAIRS_MIN_ROWS


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
