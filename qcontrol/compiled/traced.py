"""The traced column form: the formulas' own Python code run once on symbols, recorded as source.

The laws' formulas, the quantizer and the ODE plant's RK4 are written once over *columns*
(:mod:`qcontrol.columns`) with elementwise arithmetic. Run on columns of this form, each column
a :class:`Symbol` (the name of a local variable of the generated code), every ``+ - * /`` a
formula makes is recorded, in the order the formula makes it, as one line of Python source
``t7 = t3 * lp[12]``; every number that meets a symbol (a gain, a coefficient, the step ``h``)
is put in the array ``lp`` (:meth:`Trace.constant`), so one generated text serves every value
of the constants. Arithmetic between plain numbers (a law's constants, ``h / 6``) runs in
Python as it does in the float form. For a batch of copies (:class:`TracedForm` with ``batch``
> 1) a parameter given per copy is a ``(batch,)`` array: it takes a slot like a number, whose
value differs per copy (:meth:`Trace.table`), so the one text serves every copy. The text is
therefore the float form's computation, the
same IEEE operations in the same order, which numba compiles (numpy's error model, no
fast-math contraction) for the engine's compiled loop: the compiled form is *derived* from the
one definition, never restated.

Where the float form would raise instead of giving a number (``math`` refusing an evaluation,
a division by zero), the recorded code cannot: it runs :attr:`Trace.refusal` instead (the
compiled loop's ``return status, k``), and the Python form runs from there.

A symbol has no truth value (a formula that branches on a column's value cannot be traced and
keeps the Python loop), unless the trace is told which branch holds (``Symbol(text, truth)``:
a load known to be nonzero in the branch being traced).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from functools import partial
from typing import Any

import numpy as np

from ..expr import Expression, combine
from ..expr.calculus import Program
from ..expr.source import FLAG, Statements, float_source, operation_source

Value = Any  # a Symbol, or a plain number


class Trace:
    """The source lines and constants of one generated function, being recorded."""

    def __init__(self, array: str = "lp", prefix: str = "t") -> None:
        """Constants go to the array named ``array``, locals are named ``{prefix}{i}``."""
        self.array, self.prefix = array, prefix
        self.lines: list[str] = []
        self.constants: list[float | np.ndarray] = []  # a number, or a (batch,) column per copy
        self.refusal: str | None = None  # the statement where Python would raise; None: untraceable
        self.deferred = False  # refusals gathered into REFUSED, tested at the end (:meth:`deferring`)
        self._deferred = 0  # the refusals gathered into REFUSED so far
        self._count = 0

    def name(self, prefix: str = "") -> str:
        self._count += 1
        return f"{self.prefix}{prefix}{self._count}"

    def constant(self, value: float | np.ndarray) -> str:
        """``value`` (a number, or a ``(batch,)`` column of per-copy numbers) as a slot of the
        constants' array (a new slot each time: the text depends on no value)."""
        self.constants.append(value.astype(float) if isinstance(value, np.ndarray) else float(value))
        return f"{self.array}[{len(self.constants) - 1}]"

    def table(self, batch: int | None = None) -> np.ndarray:
        """The constants' array: ``(slots,)`` for one copy, ``(batch, slots)`` (row b copy b's)
        for a batch."""
        if batch is None:
            return np.array(self.constants, dtype=float)
        table = np.empty((batch, len(self.constants)))
        for slot, value in enumerate(self.constants):
            table[:, slot] = value
        return table

    def taken(self) -> list[str]:
        """The lines recorded so far, handed over and forgotten."""
        lines, self.lines = self.lines, []
        return lines

    def text(self, value: Value) -> str:
        """The source of a column: a symbol's name, or a number's slot of ``lp``."""
        if isinstance(value, Symbol):
            return value.text
        if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind == "f":
            return self.constant(value)  # a per-copy parameter of a batch
        if isinstance(value, bool | np.bool_) or not isinstance(value, int | float | np.number):
            raise TypeError(f"a traced formula met {type(value).__name__} {value!r}, not a column")
        return self.constant(value)

    def assign(self, expression: str) -> Symbol:
        """A new local holding ``expression``."""
        name = self.name()
        self.lines.append(f"{name} = {expression}")
        return Symbol(name)

    def refuse_if(self, condition: str) -> None:
        """Where ``condition`` holds the float form raises: the code runs :attr:`refusal` (none
        set: the formula cannot be traced here)."""
        if self.refusal is None:
            raise TypeError("a traced formula may raise where no hand-over to Python is possible")
        if self.deferred:
            self._deferred += 1
            self.lines.append(f"{REFUSED} = {REFUSED} | ({condition})")
        else:
            self.lines += [f"if {condition}:", f"    {self.refusal}"]

    @contextmanager
    def refusing(self, statement: str | None):  # noqa: ANN201 (a context manager)
        """Record with ``statement`` as the refusal (the compiled loop's ``return 2, k``)."""
        before, self.refusal, self.deferred = (self.refusal, self.deferred), statement, False
        try:
            yield self
        finally:
            self.refusal, self.deferred = before

    @contextmanager
    def deferring(self, statement: str):  # noqa: ANN201 (a context manager)
        """As :meth:`refusing`, but the refusals' conditions are gathered into one flag and
        ``statement`` runs once, after the block, if any held. Only for a block with no effect
        before its end (straight-line float arithmetic into locals: a step whose state is written
        after it, a control whose output is), where stopping at the first refusal or at the end
        is the same: what runs after a refusal only makes NaN or Inf (numpy's error model), and
        one test replaces a branch per refusal, which kept the compiler from interleaving the
        step's arithmetic."""
        before, self.refusal, self.deferred = (self.refusal, self.deferred), statement, True
        lines, first, gathered = self.lines, len(self.lines), self._deferred
        self.lines.append(f"{REFUSED} = False")
        try:
            yield self
        finally:
            self.refusal, self.deferred = before
        if self._deferred > gathered or self.lines is not lines:
            self.lines += [f"if {REFUSED}:", f"    {statement}"]
        else:  # nothing refuses: neither the flag nor its test (a branch never taken, compiled all the same)
            del lines[first]


REFUSED = "refused"  # the flag of :meth:`Trace.deferring` (a bool local of the generated code)
_CURRENT: list[Trace] = []  # the trace being recorded (a stack: recordings do not nest in practice)


def current() -> Trace:
    if not _CURRENT:
        raise RuntimeError("a traced column used outside qcontrol.compiled.traced.recording()")
    return _CURRENT[-1]


@contextmanager
def recording(trace: Trace):  # noqa: ANN201 (a context manager)
    """Symbols' arithmetic inside the block is recorded in ``trace``."""
    _CURRENT.append(trace)
    try:
        yield trace
    finally:
        _CURRENT.pop()


def _binary(symbol: str, left: Value, right: Value) -> Symbol:
    trace = current()
    a, b = trace.text(left), trace.text(right)
    if symbol == "/" and isinstance(right, Symbol):
        trace.refuse_if(f"{b} == 0.0")  # a float division by zero raises
    return trace.assign(f"{a} {symbol} {b}")


class Symbol:
    """A column of the traced form: the name of a float local of the generated code. Its
    arithmetic is recorded in the current :class:`Trace` (module docstring)."""

    __slots__ = ("text", "truth")
    __array_ufunc__ = None  # an array meeting a symbol (a per-copy parameter) defers to the symbol

    def __init__(self, text: str, truth: bool | None = None) -> None:
        self.text, self.truth = text, truth

    def __add__(self, other: Value) -> Symbol:
        return _binary("+", self, other)

    def __radd__(self, other: Value) -> Symbol:
        return _binary("+", other, self)

    def __sub__(self, other: Value) -> Symbol:
        return _binary("-", self, other)

    def __rsub__(self, other: Value) -> Symbol:
        return _binary("-", other, self)

    def __mul__(self, other: Value) -> Symbol:
        return _binary("*", self, other)

    def __rmul__(self, other: Value) -> Symbol:
        return _binary("*", other, self)

    def __truediv__(self, other: Value) -> Symbol:
        return _binary("/", self, other)

    def __rtruediv__(self, other: Value) -> Symbol:
        return _binary("/", other, self)

    def __neg__(self) -> Symbol:
        return current().assign(f"-{self.text}")

    def __abs__(self) -> Symbol:
        return current().assign(f"abs({self.text})")

    def __lt__(self, other: Value) -> Symbol:
        """A comparison, as a bool local (False where either side is NaN, as numpy's): only for
        the form's ``where``; it has no truth value of its own."""
        return _binary("<", self, other)

    def evaluated(self, expression: Expression, columns: Sequence[Value]) -> Symbol:
        """``expression`` on traced ``columns`` (this one among them), recorded: how an expression's
        ``on_floats`` meets a symbol (:func:`evaluate`)."""
        return evaluate(expression, columns)

    def __bool__(self) -> bool:
        if self.truth is None:
            raise TypeError("a traced formula branches on a column's value: it keeps the Python loop")
        return self.truth

    def __repr__(self) -> str:
        return f"Symbol({self.text!r})"


class Row(tuple):
    """One row of one copy of a recorded signal, ``(..., width)`` in the array form, as symbols:
    indexed on its last axis as the array form's blocks are (``row[..., 0]`` a symbol,
    ``row[..., :1]`` a row), with elementwise arithmetic, so that a derivation written on blocks
    (``x[..., :1] - yd[..., :1]``) runs on it and is recorded."""

    def __getitem__(self, index: Any) -> Any:
        if isinstance(index, tuple) and len(index) == 2 and index[0] is Ellipsis:
            index = index[1]
        picked = tuple.__getitem__(self, index)
        return Row(picked) if isinstance(index, slice) else picked

    def _each(self, other: Any, operation: Callable[[Value, Value], Value]) -> Row:
        others = other if isinstance(other, Row) else (other,) * len(self)
        return Row(operation(a, b) for a, b in zip(self, others, strict=True))

    def __add__(self, other: Any) -> Row:
        return self._each(other, lambda a, b: a + b)

    def __sub__(self, other: Any) -> Row:
        return self._each(other, lambda a, b: a - b)

    def __mul__(self, other: Any) -> Row:
        return self._each(other, lambda a, b: a * b)

    def __abs__(self) -> Row:
        return Row(abs(a) for a in self)


class TracedTerms:
    """Expressions evaluated on symbols: their trees as source (:func:`float_source`), refusing
    where the float form's ``math`` would refuse (the float form then takes numpy's answer)."""

    def __init__(self, expressions: Sequence[Expression]) -> None:
        self.expressions = tuple(expressions)

    def __call__(self, columns: Sequence[Value]) -> list[Value]:
        return [evaluate(e, columns) for e in self.expressions]


def evaluate(expression: Expression, columns: Sequence[Value]) -> Symbol:
    """One expression on traced columns, recorded (``columns[i]`` its ``variables[i]``)."""
    trace = current()
    names = [trace.text(c) for c in columns]
    body = Statements(trace.name("e") + "_")
    value = float_source(expression._tree, names, body)
    if any(FLAG in line for line in body.lines):  # math may refuse: the flag and its test
        trace.lines += [f"{FLAG} = False", *body.lines]
        trace.refuse_if(FLAG)
    else:
        trace.lines += body.lines
    if _NAME_OR_LITERAL.fullmatch(value):  # a local or a literal: itself, not a copy (one variable less)
        return Symbol(value)
    return trace.assign(value)


# a local's name, or a finite float literal as float_source writes one: (1.0), (-2.5e-07)
_NAME_OR_LITERAL = re.compile(r"[A-Za-z_]\w*|\(-?[0-9][0-9.]*(?:e[-+]?[0-9]+)?\)")


def evaluate_program(program: Program, values: Sequence[Value]) -> list[Value]:
    """A :class:`~qcontrol.expr.calculus.Program` (trees sharing subtrees) on traced ``values``,
    recorded step by step in its order (each shared node once), every step the float
    evaluation's operation (:func:`~qcontrol.expr.source.operation_source`); where ``math`` would
    refuse some step (the float evaluation then takes numpy's answer for the whole program), the
    refusal."""
    trace = current()
    body = Statements(trace.name("p") + "_")
    texts: list[str] = []
    for step in program.steps:
        kind = step[0]
        if kind == "var":
            texts.append(trace.text(values[step[1]]))
        elif kind == "const":
            texts.append(trace.constant(step[1]))
        elif kind == "square":
            a = texts[step[2][0]]
            texts.append(body.temporary(f"{a} * {a}"))
        else:
            texts.append(operation_source(step[1], [texts[i] for i in step[2]], body))
    if any(FLAG in line for line in body.lines):  # math may refuse: the flag and its test
        trace.lines += [f"{FLAG} = False", *body.lines]
        trace.refuse_if(FLAG)
    else:
        trace.lines += body.lines
    return [Symbol(texts[i]) for i in program.outputs]


def _expm1(x: Value) -> Value:
    """``exp(x) - 1``; where ``math.expm1`` raises (an infinite result of a finite argument), the
    refusal."""
    if not isinstance(x, Symbol):
        return math.expm1(x)
    trace = current()
    result = trace.assign(f"math.expm1({x.text})")
    trace.refuse_if(f"math.isinf({result.text}) & math.isfinite({x.text})")
    return result


def _floor(x: Value) -> Value:
    """numpy's floor (the float form's ``math.floor`` where it answers, numpy's value where it
    refuses: the same number)."""
    if not isinstance(x, Symbol):
        return float(np.floor(x))
    return current().assign(f"np.floor({x.text})")


def _where(condition: Value, a: Value, b: Value) -> Value:
    """numpy's ``where(condition, a, b)`` on a traced condition (:meth:`Symbol.__lt__`) or plain
    values."""
    if not isinstance(condition, Symbol):
        return a if condition else b
    trace = current()
    return trace.assign(f"{trace.text(a)} if {condition.text} else {trace.text(b)}")


def _minimum(a: Value, b: Value) -> Value:
    """numpy's ``minimum(a, b)`` (NaN if either is NaN), on symbols or numbers."""
    return _numpy_of_two("minimum", a, b)


def _maximum(a: Value, b: Value) -> Value:
    """numpy's ``maximum(a, b)`` (NaN if either is NaN), on symbols or numbers."""
    return _numpy_of_two("maximum", a, b)


def _numpy_of_two(name: str, a: Value, b: Value) -> Value:
    """numpy's function ``name`` of two values: its number where neither is a symbol, else its
    call written in the trace."""
    if not isinstance(a, Symbol) and not isinstance(b, Symbol):
        return float(getattr(np, name)(a, b))
    trace = current()
    return trace.assign(f"np.{name}({trace.text(a)}, {trace.text(b)})")


class TracedForm:
    """The :class:`~qcontrol.columns.ColumnForm` whose columns are :class:`Symbol`\\ s; a
    parameter is a plain number, as in the float form (a batch of one), or for a batch of
    ``batch`` copies a ``(batch,)`` array where it differs per copy (a slot of its own per copy)."""

    expm1: Callable[[Value], Value] = staticmethod(_expm1)
    floor: Callable[[Value], Value] = staticmethod(_floor)
    minimum: Callable[[Value, Value], Value] = staticmethod(_minimum)
    maximum: Callable[[Value, Value], Value] = staticmethod(_maximum)
    where: Callable[[Value, Value, Value], Value] = staticmethod(_where)

    def __init__(self, batch: int = 1) -> None:
        self.batch = batch

    def __deepcopy__(self, memo: dict) -> TracedForm:
        """Itself (a form holds no state; a law's copy keyed by it finds it)."""
        return self

    def column(self, values: Any) -> float | np.ndarray:
        array = np.asarray(values, dtype=float)
        if array.size == 1:
            return float(array.reshape(1)[0])
        if array.shape != (self.batch,) or self.batch == 1:
            raise ValueError(f"{array.size} per-copy values for a batch of {self.batch}")
        return array.copy()

    def terms(self, expressions: Sequence[Expression]) -> TracedTerms:
        return TracedTerms(expressions)

    def program(self, program: Program) -> Callable[[Sequence[Value]], list[Value]]:
        return partial(evaluate_program, program)

    def combination(self, expressions: Sequence[Expression], coefficients: Sequence[Any]
                    ) -> Callable[[Sequence[Value]], Value]:
        pairs = tuple(zip([None if c is None else self.column(c) for c in coefficients],
                          [partial(evaluate, e) for e in expressions], strict=True))
        return partial(combine, pairs)  # the array form's sum, left to right

    def columns(self, rows: Any) -> list[Value]:
        raise TypeError("the traced form's columns are symbols: made by the compiled loop, not from arrays")

    def array(self, columns: Sequence[Value], batch: int) -> Any:
        raise TypeError("the traced form's columns are symbols: they have no array")

    def __repr__(self) -> str:
        return "TRACED" if self.batch == 1 else f"TracedForm(batch={self.batch})"


TRACED = TracedForm()
