"""The metrics of a compiled batch folded inside its loop, the same numbers as the array form's.

A metrics-only run (:class:`~.retention.MetricsRecord`) folds each signal of the signal table
into its reductions (:mod:`.reductions`) a block of rows at a time, in numpy. In the compiled
batch (:mod:`.compiled_batch`) each row of each copy is folded where it is made: the signal's
value is *traced* (:mod:`qcontrol.compiled.traced`) from its own derivation and the reduction's
own ``values`` on one row of symbols (:class:`~qcontrol.compiled.traced.Row`), and the law's
diagnostics from the law's own ``evaluate``; each reduction's compiled fold
(:meth:`~.reductions.Reduction.fold_lines`) folds it into per-copy partials, which
:meth:`~.reductions.Reduction.merge` adds as the array form's ``add`` would. The error rate's
interpolation is :func:`qcontrol.error_rate.follow_row`, its one formula
:func:`qcontrol.error_rate.interpolated`, the array form's too.

The folds count a copy's rows as the array form does only where every row counts (the copy runs
through the block). So a block of rows is merged only when every copy either counts all of its
rows or had stopped before it; a block in which some copy stops (or in which a traced value met
a refusal, where the array form takes numpy's answer) is reduced by the array form, as before,
for every copy (the compiled partials are dropped). A reduction whose values cannot be traced
(a derivation with numpy calls: an actuator's clipping; ...) is always reduced by the array form.
Each signal is derived once per row (:func:`~.signals.derive`, in the traced form:
:class:`~.signals.SignalContext`'s ``form``), its lines before the first fold that reads it, so
the separation's bounding functions and bound ratios (37)-(43) and Lemma 2's errors are the
array form's own derivations, traced. The traced evaluation (``math``) of the separation gives
numpy's numbers to the last bit on sums, products, quotients, squares, abs, sqrt, sin and cos; a
cube, an exponential keep the array form (:func:`~.signals.same_functions`). Lemma 2's errors of a
traced row come from the recursion (31)-(34) itself, where the array form multiplies by the
matrices derived from it (which BLAS rounds otherwise): their fold (:class:`~.lemma2.Lemma2Largest`)
notes the rows that may hold a copy's largest, which the merge recomputes as the copy's run alone
does. A law's diagnostics are traced from the law's own ``evaluate`` in the traced form.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
from collections import Counter
from functools import partial
from operator import attrgetter
from typing import Any

import numpy as np

from .. import error_rate
from ..compiled import JIT
from ..compiled.traced import Row, Symbol, Trace, TracedForm, recording
from .reductions import DiagnosticValues, ErrorRate, Reduction
from .signals import SignalContext, derive, needed

# the error rate's values where nothing is folded: of the layout of ErrorRateStream.values (stored
# run after run), so that the generated loop is compiled for one type of arrays
NO_VALUES = np.zeros((2, 2), order="F")


def helpers() -> str:
    """The error rate's row fold and its formula, as the generated module compiles them: their
    own source (so the generated text, and its cache key, change with them)."""
    inlined = JIT[:-1] + ', inline="always")'  # (into the loop: calls measured slower)
    return "\n\n".join(f"{inlined}\n{inspect.getsource(f)}"
                       for f in (error_rate.interpolated, error_rate.follow_row))


def row_block(n: int, m: int, q: list[str]) -> dict[str, Any]:
    """One row of one copy of the recorded signals, as the compiled loop's locals."""
    return {"x": Row(Symbol(f"x{i}") for i in range(1, n + 1)),
            "x_meas": Row(Symbol(f"m{i}") for i in range(1, n + 1)),
            "x_q": Row(Symbol(text) for text in q), "u": Symbol("u"),
            "adaptive": Row(Symbol(f"adaptive[{i}]") for i in range(m)),
            "yd": Row(Symbol(f"yd[r, {j}]") for j in range(n + 1))}


# The trace's locals (Trace("lf", "f"): f12, its expressions' temporaries fe12_0 and fp12_0), each
# assigned once, by a line of its own, from an expression that has no effect but its value
_LOCAL = re.compile(r"\bf(?:[ep]\d+_)?\d+\b")
_DEFINITION = re.compile(r"(f(?:[ep]\d+_)?\d+) = (.+)")
_ASSIGNED = re.compile(r" *(?!(?:if|elif|else|for|while|return)\b)([^=(]+?) [-+*/]?= ")
_NAME = re.compile(r"\b[A-Za-z_]\w*\b")
_ATOM = re.compile(r"[A-Za-z_]\w*(?:\[[\w, ]+\])?|\(-?[\d.]+(?:e[-+]?\d+)?\)|float\('-?(?:inf|nan)'\)")


def _renamed(aliases: dict[str, str], match: re.Match) -> str:
    return aliases.get(match.group(0), match.group(0))


def compact(every: list[str], samples: list[str]) -> tuple[list[str], list[str]]:
    """The fold's lines of every row and of the control samples (which run after them), with
    each local that copies a value (a local, a number, an input of the row) replaced by that
    value, each one that recomputes an expression of an earlier one by the earlier one, and each
    that nothing reads left out: the same operations on the values that are used, in fewer
    statements (each costs numba's compile of every batch module)."""
    lines = [(False, line) for line in every] + [(True, line) for line in samples]
    assigned = {name for _, line in lines if not _DEFINITION.fullmatch(line.lstrip())
                for target in _ASSIGNED.findall(line) for name in _NAME.findall(target)}
    aliases: dict[str, str] = {}
    earlier: dict[str, str] = {}  # an expression -> the local holding it
    kept: list[tuple[bool, str]] = []
    for section, line in lines:
        line = _LOCAL.sub(partial(_renamed, aliases), line)
        definition = _DEFINITION.fullmatch(line.lstrip())
        if definition and not assigned.intersection(_NAME.findall(definition.group(2))):
            name, value = definition.groups()
            if _ATOM.fullmatch(value) or value in earlier:
                aliases[name] = earlier.get(value, value)
                continue
            earlier[value] = name
        kept.append((section, line))
    return _live(kept)


def _live(lines: list[tuple[bool, str]]) -> tuple[list[str], list[str]]:
    """The lines but the definitions of locals that nothing reads, split by section."""
    defined: dict[str, int] = {}
    reads: Counter = Counter()
    for i, (_, line) in enumerate(lines):
        definition = _DEFINITION.fullmatch(line.lstrip())
        if definition:
            defined[definition.group(1)] = i
        reads.update(_LOCAL.findall(definition.group(2) if definition else line))
    unread = [name for name, i in defined.items() if not reads[name]]
    dropped = set()
    while unread:
        i = defined[unread.pop()]
        dropped.add(i)
        for name in _LOCAL.findall(_DEFINITION.fullmatch(lines[i][1].lstrip()).group(2)):
            reads[name] -= 1
            if not reads[name] and name in defined:
                unread.append(name)
    kept = [(section, line) for i, (section, line) in enumerate(lines) if i not in dropped]
    return [line for section, line in kept if not section], [line for section, line in kept if section]


class Folds:
    """The reductions of a metrics record that the compiled batch folds, their lines, partials
    and per-copy constants, and the merge at each block of rows (module docstring)."""

    def __init__(self, reductions: list[Reduction], context: SignalContext, law: Any, form: TracedForm,
                 n: int, m: int, q: list[str], dt: float) -> None:
        batch = form.batch
        trace = Trace("lf", "f")
        self.every: list[str] = []  # lines of every row
        self.samples: list[str] = []  # lines of the control samples
        self.folded: list[tuple[Reduction, slice]] = []
        self.enter: list[str] = []  # lines before a copy's rows, and before the loop returns
        self.leave: list[str] = []
        start: list[float] = []
        row = row_block(n, m, q)  # the row's signals, each derived once (its lines before their first use)
        context = dataclasses.replace(context, form=form)
        with recording(trace), trace.refusing("odd[b] = True"):
            t = trace.assign(f"k * {trace.constant(dt)}").text  # the row's instant, as TimeGrid's
            self.every += trace.taken()
            # (the control samples' folds last: the lines of every row come first, which they may read)
            for fold in sorted(reductions, key=attrgetter("at_samples")):
                partials = fold.partials
                if partials is None:
                    continue
                try:
                    values, derived = self.traced(fold, row, context)
                    texts = [trace.text(v) for v in values]
                except (TypeError, ValueError):  # not traceable: the array form reduces it
                    trace.taken()
                    continue
                row = derived
                slot = len(start)
                lines = [*trace.taken(), *fold.fold_lines(texts, slot, t, trace.constant)]
                (self.samples if fold.at_samples else self.every).extend(lines)
                self.enter += fold.enter
                self.leave += fold.leave
                start += partials
                self.folded.append((fold, slice(slot, slot + len(partials))))
        self.every, self.samples = compact(self.every, self.samples)
        self.start = np.array(start, dtype=float)
        self.partials = np.empty((batch, len(start)))
        self.constants = trace.table(batch)
        self.odd = np.zeros(batch, dtype=np.bool_)
        self.rate = next((f for f, _ in self.folded if isinstance(f, ErrorRate)), None)
        self.all = reductions
        self.others = [f for f in reductions if all(f is not g for g, _ in self.folded)]
        self.reset()

    @staticmethod
    def traced(fold: Reduction, row: dict[str, Any], context: SignalContext
               ) -> tuple[list[Any], dict[str, Any]]:
        """The values ``fold`` folds at a traced row, from their own definitions: the signals it
        reads derived (:func:`~.signals.derive`, those not derived yet), then its ``values``; and
        the row with those signals."""
        row = dict(row)
        if isinstance(fold, DiagnosticValues):
            columns = (tuple(row["x_q"]), tuple(row["yd"]), tuple(row["adaptive"]))
            values = [d.evaluate(*columns, form=context.form) for d in context.diagnostics]
            if any(d.width != 1 for d in context.diagnostics):
                raise TypeError("a diagnostic of several columns")
            return fold.row_values(values), row
        derive(row, context, tuple(name for name in needed(fold.needs()) if name not in row))
        values = fold.row_values(fold.values(row))
        if not all(isinstance(v, Symbol | float) for v in values):
            raise TypeError("a folded value that is not one number per row")
        return values, row

    def lines(self) -> list[str]:
        """The fold of row k of copy b, after the row is written (``fp``: its partials)."""
        if not self.folded:
            return []
        return [*self.every, "if phase == 0:", *["    " + line for line in self.samples or ["pass"]]]

    def arguments(self) -> tuple:
        """The arrays the generated loop reads and writes: partials, constants, the flag of
        copies whose traced values met a refusal, the error rate's arrays."""
        rate = self.working if self.rate is not None else (np.zeros(1), NO_VALUES,
                                                            np.zeros(1, dtype=np.intp), np.zeros((1, 2)))
        return (self.partials, self.constants, self.odd, *rate)

    def reset(self) -> None:
        self.partials[:] = self.start
        for fold, slots in self.folded:
            fold.restart(self.partials[:, slots])
        self.odd[:] = False
        if self.rate is not None:
            self.working = self.rate.working()

    def merge(self, base: int, stop: int, kept: np.ndarray, diverged: np.ndarray) -> list[Reduction]:
        """Merge the partials of rows ``[base, stop)`` where the array form would have folded the
        same rows (module docstring); return the reductions the array form still folds there
        (then :meth:`reset`, before the loop goes on)."""
        counted = ~self.odd & ((kept > stop) | ~diverged)  # every row counts
        merged = bool(np.all(counted | (kept <= base)))
        if merged:
            for fold, slots in self.folded:
                fold.merge(counted, self.partials[:, slots])
        if self.rate is not None:
            self.rate.undo(~counted if merged else np.ones_like(counted))
        return self.others if merged else self.all
