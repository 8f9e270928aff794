"""Safe math expressions for scenario files.

Nonlinearities such as ``"x2**2 * cos(x1)"`` are parsed with :mod:`ast` once, checked node by node
against a whitelist and turned into a small validated tree (numbers, variables, operations); user
text is never passed to ``eval`` or ``exec``, and anything outside the whitelist is rejected with a
message that names it. Two generators turn that tree into closures: numpy calls on columns
(:meth:`Expression.__call__`, :meth:`Expression.on_columns`) and ``math`` calls on plain floats
(:func:`scalar_function`, :meth:`Expression.on_floats`). Both read one table, :data:`OPERATIONS`:
a row per operator, function and constant, with its numpy and its plain-float implementation.

Allowed: numbers, the declared variables (``x1..xn``, ``q1..qn``), ``pi``, ``+ - * / **``, unary
``-``/``+``, and calls to ``abs sqrt exp log sin cos tan tanh sign min max``.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np

from .errors import QcontrolInputError

MAX_SOURCE_LENGTH = 2000
MAX_CONSTANT_EXPONENT = 64.0
MAX_NODES = 500
MAX_DEPTH = 200  # nesting depth; evaluation recurses once per level, so this bounds the stack it needs
SHOWN_SOURCE = 100  # messages quote at most this many characters of an expression

ScalarFn = Callable[[Sequence[float]], float]
_ColumnsFn = Callable[[Sequence[np.ndarray]], "np.ndarray | float"]


# --------------------------------------------------------------------------------------------
# The language: one row per operator, function and constant, for both generators


@dataclass(frozen=True)
class Operation:
    """One row of :data:`OPERATIONS`: what the user writes and what each generator computes."""

    name: str  # the operator's symbol ("**") or the function's or constant's name ("sin", "pi")
    arity: int | None  # operands; None: two or more (``on_arrays`` then takes two, left to right)
    on_arrays: Callable[..., Any]  # numpy, on columns; also folds constant parts at compile time
    on_floats: Callable[..., Any]  # plain floats: ``math``, :mod:`operator`, builtins
    syntax: type[ast.AST] | None = None  # an operator's ast class; None for a function or a constant
    # Python's own operator written out on the operands' closures, which saves the call of
    # ``on_floats`` per evaluation (only where no operand can be read directly)
    inline: Callable[..., ScalarFn] | None = None

    @property
    def is_operator(self) -> bool:
        return self.syntax is not None


def _sign_of_float(a: float) -> float:
    """numpy's ``sign`` on a plain float: -1.0, 0.0 or 1.0, and NaN stays NaN."""
    return a if a != a else (1.0 if a > 0 else -1.0 if a < 0 else 0.0)


def _nan_or(pick: Callable[[tuple[float, ...]], float]) -> Callable[..., float]:
    """``pick`` (``min`` or ``max``) of plain floats, but NaN if any is NaN, as numpy's."""

    def pick_or_nan(*values: float) -> float:
        for value in values:
            if value != value:
                return math.nan
        return pick(values)

    return pick_or_nan


OPERATIONS: tuple[Operation, ...] = (
    Operation("+", 2, np.add, operator.add, ast.Add, lambda a, b: lambda xs: a(xs) + b(xs)),
    Operation("-", 2, np.subtract, operator.sub, ast.Sub, lambda a, b: lambda xs: a(xs) - b(xs)),
    Operation("*", 2, np.multiply, operator.mul, ast.Mult, lambda a, b: lambda xs: a(xs) * b(xs)),
    Operation("/", 2, np.divide, operator.truediv, ast.Div, lambda a, b: lambda xs: a(xs) / b(xs)),
    Operation("**", 2, np.power, math.pow, ast.Pow),  # x**2 is a product in both generators
    Operation("-", 1, np.negative, operator.neg, ast.USub, lambda a: lambda xs: -a(xs)),
    Operation("pi", 0, lambda: np.pi, lambda: math.pi),
    Operation("abs", 1, np.abs, abs),
    Operation("sqrt", 1, np.sqrt, math.sqrt),
    Operation("exp", 1, np.exp, math.exp),
    Operation("log", 1, np.log, math.log),
    Operation("sin", 1, np.sin, math.sin),
    Operation("cos", 1, np.cos, math.cos),
    Operation("tan", 1, np.tan, math.tan),
    Operation("tanh", 1, np.tanh, math.tanh),
    Operation("sign", 1, np.sign, _sign_of_float),
    Operation("min", None, np.minimum, _nan_or(min)),
    Operation("max", None, np.maximum, _nan_or(max)),
)
_OPERATORS = {row.syntax: row for row in OPERATIONS if row.is_operator}
_NAMED = {row.name: row for row in OPERATIONS if not row.is_operator}  # in the order messages list them
_POWER = _OPERATORS[ast.Pow]

_FORBIDDEN_DESCRIPTIONS = {
    ast.Attribute: "attribute access ('.')",
    ast.Subscript: "indexing ('[...]')",
    ast.Lambda: "lambda",
    ast.ListComp: "comprehension",
    ast.SetComp: "comprehension",
    ast.DictComp: "comprehension",
    ast.GeneratorExp: "generator expression",
    ast.Compare: "comparison",
    ast.BoolOp: "'and'/'or'",
    ast.IfExp: "conditional expression",
    ast.NamedExpr: "assignment (':=')",
    ast.Starred: "'*' unpacking",
    ast.List: "list literal",
    ast.Tuple: "tuple literal",
    ast.Dict: "dict literal",
    ast.Set: "set literal",
    ast.JoinedStr: "f-string",
    ast.Await: "await",
    ast.Yield: "yield",
    ast.YieldFrom: "yield",
}


# --------------------------------------------------------------------------------------------
# The validated tree: built once by the whitelist check, kept in the Expression, read by both
# generators. ``constant`` is numpy's value of a constant part (folded at compile time).


@dataclass(frozen=True)
class _Number:
    """A literal number."""

    constant: float


@dataclass(frozen=True)
class _Variable:
    """A declared variable: ``index`` is its position in ``Expression.variables``."""

    index: int
    constant: None = None


@dataclass(frozen=True)
class _Apply:
    """An operator, a function call or a named constant (no operands), with its table row."""

    operation: Operation
    operands: tuple[_Tree, ...]
    constant: float | None  # when every operand is constant (never for min and max), else None


_Tree = _Number | _Variable | _Apply


def _cut(text: str) -> str:
    """``text`` cut to :data:`SHOWN_SOURCE` characters, for a message."""
    if len(text) > SHOWN_SOURCE:
        return text[:SHOWN_SOURCE] + f"... ({len(text)} characters)"
    return text


def _show(text: str) -> str:
    """``repr`` of ``text`` for a one-line message: newlines escaped, long text cut."""
    return _cut(repr(text))


@dataclass(frozen=True)
class Expression:
    """A compiled expression: call it with an array ``values[..., len(variables)]``."""

    source: str
    variables: tuple[str, ...]
    used: frozenset[str]
    _fn: _ColumnsFn
    _tree: _Tree = field(repr=False)

    def __call__(self, values: np.ndarray) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        columns = values.T if values.ndim <= 2 else np.moveaxis(values, -1, 0)
        result = self._fn(columns)
        if np.ndim(result) == 0:
            return np.full(values.shape[:-1], float(result))
        return np.asarray(result, dtype=float)

    def on_columns(self, columns: Sequence[np.ndarray]) -> np.ndarray | float:
        """Evaluate on ``columns[i]`` = values of ``variables[i]`` (no reshaping; a constant
        expression returns a float). The fast path for hot loops."""
        return self._fn(columns)

    def on_floats(self, values: Sequence[float]) -> float:
        """Evaluate on plain floats, ``values[i]`` = ``variables[i]``: the same expression through
        ``math`` (:func:`scalar_function`), a few tens of nanoseconds per operation instead of a
        microsecond. Where ``math`` refuses (a domain error, an overflow), numpy's value (NaN,
        Inf) is returned, so both evaluations agree up to the last bit, except that
        ``(-inf)**0.5`` is inf here (C's ``pow``) and NaN through numpy (a square root)."""
        try:
            return self._scalar_fn(values)
        except (ValueError, ZeroDivisionError, OverflowError):
            with np.errstate(all="ignore"):
                return float(self._fn(values))

    @cached_property
    def _scalar_fn(self) -> ScalarFn:
        return scalar_function(self)


def compile_expression(source: object, variables: Sequence[str], where: str = "expression") -> Expression:
    """Parse, whitelist-check and compile ``source`` into an :class:`Expression`.

    ``where`` prefixes every error message (e.g. ``"example2.toml: plant.phi[1]"``).
    Raises :class:`QcontrolInputError` for anything not allowed.
    """
    variables = tuple(variables)
    if isinstance(source, bool) or not isinstance(source, (str, int, float)):
        raise QcontrolInputError(
            f"{where}: expected a math expression string such as \"x2**2 * cos(x1)\", "
            f"got {type(source).__name__}"
        )
    text = str(source)
    if len(text) > MAX_SOURCE_LENGTH:
        raise QcontrolInputError(
            f"{where}: expression is {len(text)} characters long; the limit is {MAX_SOURCE_LENGTH}"
        )
    if not text.strip():
        raise QcontrolInputError(f"{where}: empty expression; write a formula such as \"0\" or \"x2\"")
    body = _parse(text, variables, where)
    validator = _Validator(text, variables, where)
    try:
        tree = validator.visit(body)
        on_columns = _columns_closure(tree)
    except RecursionError:
        raise QcontrolInputError(
            f"{where}: expression {_show(text)} is too deeply nested; simplify it"
        ) from None
    return Expression(text, variables, frozenset(validator.used), on_columns, tree)


def _parse(text: str, variables: tuple[str, ...], where: str) -> ast.expr:
    """The syntax tree of ``text``, within :data:`MAX_NODES` nodes and :data:`MAX_DEPTH` levels."""
    try:
        body = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as exc:
        raise QcontrolInputError(
            f"{where}: cannot parse {_show(text)} ({exc.msg}); use numbers, {', '.join(variables)}, "
            "+ - * / ** and the allowed functions"
        ) from None
    except ValueError as exc:  # e.g. null bytes (Python < 3.12)
        raise QcontrolInputError(f"{where}: cannot parse {_show(text)} ({exc}); use plain text") from None
    except (RecursionError, MemoryError):
        raise QcontrolInputError(
            f"{where}: expression {_show(text)} is too deeply nested; simplify it"
        ) from None
    nodes, depth = _size(body)
    if nodes > MAX_NODES:
        raise QcontrolInputError(
            f"{where}: too many terms ({nodes} syntax nodes) in {_show(text)}; keep expressions under "
            f"{MAX_NODES} nodes"
        )
    if depth > MAX_DEPTH:
        raise QcontrolInputError(
            f"{where}: expression {_show(text)} is nested {depth} levels deep; keep it under {MAX_DEPTH} "
            "levels (e.g. factor repeated terms)"
        )
    return body


def _size(root: ast.AST) -> tuple[int, int]:
    """Number of nodes and nesting depth of an AST, without recursion."""
    nodes, deepest = 0, 0
    stack = [(root, 1)]
    while stack:
        node, depth = stack.pop()
        nodes += 1
        deepest = max(deepest, depth)
        stack.extend((child, depth + 1) for child in ast.iter_child_nodes(node))
    return nodes, deepest


# --------------------------------------------------------------------------------------------
# Whitelist check: syntax tree -> validated tree, constant parts folded with numpy


class _Validator:
    """Turns a syntax tree into a validated tree, or raises with a message that names the problem."""

    def __init__(self, source: str, variables: tuple[str, ...], where: str) -> None:
        self.source = source
        self.variables = variables
        self.index = {name: i for i, name in enumerate(variables)}
        self.where = where
        self.used: set[str] = set()
        self.nodes = 0

    def fail(self, problem: str, fix: str) -> QcontrolInputError:
        return QcontrolInputError(f"{self.where}: {problem} in {_show(self.source)}; {fix}")

    def allowed_names(self) -> str:
        return ", ".join([*self.variables, *_NAMED])

    def visit(self, node: ast.AST) -> _Tree:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise self.fail("too many terms", f"keep expressions under {MAX_NODES} nodes")
        if isinstance(node, ast.Constant):
            return _Number(self._number(node.value))
        if isinstance(node, ast.Name):
            return self._name(node.id)
        if isinstance(node, ast.UnaryOp):
            return self._unary(node)
        if isinstance(node, ast.BinOp):
            return self._binary(node)
        if isinstance(node, ast.Call):
            return self._call(node)
        description = _FORBIDDEN_DESCRIPTIONS.get(type(node), f"'{type(node).__name__}' syntax")
        raise self.fail(
            f"{description} is not allowed",
            "use numbers, variables, + - * / ** and the allowed functions",
        )

    def _number(self, value: object) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(f"literal {_cut(repr(value))} is not a real number", "use plain numbers")
        try:
            as_float = float(value)
        except OverflowError:
            raise self.fail(f"number {_cut(str(value))} is too large", "use a finite number") from None
        if not math.isfinite(as_float):
            raise self.fail(f"number {value!r} is not finite", "use a finite number")
        return as_float

    def _name(self, name: str) -> _Tree:
        if name in self.index:
            self.used.add(name)
            return _Variable(self.index[name])
        row = _NAMED.get(name)
        if row is not None and row.arity == 0:
            return self._apply(row, [])
        if row is not None:
            raise self.fail(f"function {_show(name)} used without a call", f"write {name}(...)")
        raise self.fail(f"unknown name {_show(name)}", f"allowed names are {self.allowed_names()}")

    def _unary(self, node: ast.UnaryOp) -> _Tree:
        if isinstance(node.op, ast.UAdd):
            return self.visit(node.operand)
        row = _OPERATORS.get(type(node.op))
        if row is None:
            raise self.fail(f"operator {type(node.op).__name__} is not allowed", "use only unary + or -")
        return self._apply(row, [self.visit(node.operand)])

    def _binary(self, node: ast.BinOp) -> _Tree:
        row = _OPERATORS.get(type(node.op))
        if row is None:
            raise self.fail(f"operator {type(node.op).__name__} is not allowed", "use only + - * / **")
        left, right = self.visit(node.left), self.visit(node.right)
        exponent = right.constant
        if row is _POWER and exponent is not None and abs(exponent) > MAX_CONSTANT_EXPONENT:
            raise self.fail(
                f"exponent {exponent:g} is too large",
                f"keep constant exponents within +-{MAX_CONSTANT_EXPONENT:g}",
            )
        if row.syntax is ast.Div and right.constant == 0.0:
            raise self.fail("division by zero", "divide by a non-zero number")
        return self._apply(row, [left, right])

    def _call(self, node: ast.Call) -> _Tree:
        if not isinstance(node.func, ast.Name):
            raise self.fail("only calls of plain function names are allowed", "e.g. sin(x1)")
        name = node.func.id
        if node.keywords:
            raise self.fail(f"keyword arguments to {name}() are not allowed", "pass values only")
        if any(isinstance(arg, ast.Starred) for arg in node.args):
            raise self.fail(f"'*' unpacking in {name}() is not allowed", "pass values only")
        row = _NAMED.get(name)
        if row is None or row.arity == 0:
            known = row is not None or name in self.index  # a constant or a variable
            problem = f"{_show(name)} is not a function" if known else f"unknown function {_show(name)}"
            raise self.fail(problem, f"allowed names are {self.allowed_names()}")
        if row.arity == 1 and len(node.args) != 1:
            raise self.fail(f"{name}() takes exactly 1 argument, got {len(node.args)}", f"write {name}(x1)")
        if row.arity is None and len(node.args) < 2:
            raise self.fail(f"{name}() needs at least 2 arguments", f"write {name}(a, b)")
        return self._apply(row, [self.visit(arg) for arg in node.args])

    def _apply(self, row: Operation, operands: list[_Tree]) -> _Apply:
        """``row`` on ``operands``, folded with numpy when they are all constant (not min/max)."""
        values = [operand.constant for operand in operands]
        if row.arity is None or any(value is None for value in values):
            return _Apply(row, tuple(operands), None)
        if row.arity == 0:
            return _Apply(row, (), float(row.on_arrays()))
        if row.arity == 1:
            return _Apply(row, tuple(operands), self._fold_unary(row, *values))
        return _Apply(row, tuple(operands), self._fold_binary(row, *values))

    def _fold_unary(self, row: Operation, value: float) -> float:
        with np.errstate(all="ignore"):
            folded = float(row.on_arrays(np.float64(value)))
        if not math.isfinite(folded):
            raise self.fail(f"{row.name}({value:g}) is not finite", "fix the constant")
        return folded

    def _fold_binary(self, row: Operation, left: float, right: float) -> float:
        constant_part = f"constant part {left:g} {row.name} {right:g}"
        with np.errstate(all="raise"):
            try:
                value = float(row.on_arrays(np.float64(left), np.float64(right)))
            except (FloatingPointError, OverflowError, ZeroDivisionError):
                raise self.fail(f"{constant_part} is not a finite real number", "fix the constant") from None
        if not math.isfinite(value):
            raise self.fail(f"{constant_part} is not finite", "fix the constant")
        return value


# --------------------------------------------------------------------------------------------
# numpy generator: validated tree -> closure over columns


def _columns_closure(node: _Tree) -> _ColumnsFn:
    """``f(columns)`` of numpy calls; a constant part returns numpy's folded value (a float)."""
    if node.constant is not None:
        value = node.constant
        return lambda cols: value
    if isinstance(node, _Variable):
        i = node.index
        return lambda cols: cols[i]
    row, parts = node.operation, [_columns_closure(operand) for operand in node.operands]
    fn = row.on_arrays
    if row.arity is None:

        def reduce(cols: Sequence[np.ndarray]) -> np.ndarray:
            result = parts[0](cols)
            for part in parts[1:]:
                result = fn(result, part(cols))
            return result

        return reduce
    if row.arity == 1:
        inner = parts[0]
        return lambda cols: fn(inner(cols))
    left, right = parts
    if row is _POWER and node.operands[1].constant == 2.0:
        return lambda cols: np.square(left(cols))
    return lambda cols: fn(left(cols), right(cols))


# --------------------------------------------------------------------------------------------
# Float generator: validated tree -> closure over plain floats (hot loops of a batch of one,
# MuJoCo's passive callback)


def scalar_function(expression: Expression) -> ScalarFn:
    """A plain-float version of a (validated) :class:`Expression`: ``f((x1, x2)) -> float``.

    A numpy call on a scalar costs about a microsecond, the same operation on floats a few tens of
    nanoseconds, so hot loops on one copy (MuJoCo's passive callback, a batch of one) use ``math``
    instead. Domain errors raise (the caller decides; :meth:`Expression.on_floats` falls back to
    numpy's answer). ``sin``, ``exp``, ... may differ from numpy's in the last bit.
    """
    return _float_part(expression._tree).fn


class _FloatPart(NamedTuple):
    """A subtree on plain floats: its closure, and what lets the operation above read it directly."""

    fn: ScalarFn
    value: float | None = None  # a constant: operators on constants are folded on floats
    index: int | None = None  # a variable: ``xs[index]``


def _float_constant(value: float) -> _FloatPart:
    return _FloatPart(lambda xs: value, value=value)


def _float_part(node: _Tree) -> _FloatPart:
    """The float closure of ``node``. Operators on constants are folded (with the float
    implementation); functions are not, a function of a constant is evaluated at each call."""
    if isinstance(node, _Number):
        return _float_constant(node.constant)
    if isinstance(node, _Variable):
        i = node.index
        return _FloatPart(lambda xs: xs[i], index=i)
    row, parts = node.operation, [_float_part(operand) for operand in node.operands]
    if row.arity == 0:
        return _float_constant(row.on_floats())
    if row.arity == 1:
        return _float_unary(row, parts[0])
    if row.arity == 2:
        return _float_binary(row, *parts)
    return _FloatPart(_float_variadic(row.on_floats, [part.fn for part in parts]))


def _float_unary(row: Operation, operand: _FloatPart) -> _FloatPart:
    f = row.on_floats
    inner, value, i = operand
    if value is not None:
        if row.is_operator:
            return _float_constant(f(value))
        return _FloatPart(lambda xs: f(value))
    if i is not None:
        return _FloatPart(lambda xs: f(xs[i]))
    if row.inline is not None:
        return _FloatPart(row.inline(inner))
    return _FloatPart(lambda xs: f(inner(xs)))


def _float_binary(row: Operation, left: _FloatPart, right: _FloatPart) -> _FloatPart:
    if row is _POWER and right.value == 2.0:
        return _float_square(left)
    f = row.on_floats
    if left.value is not None and right.value is not None:
        return _float_constant(f(left.value, right.value))
    direct = _read_directly(f, left, right)
    if direct is not None:
        return _FloatPart(direct)
    if row.inline is not None:
        return _FloatPart(row.inline(left.fn, right.fn))
    lf, rf = left.fn, right.fn
    return _FloatPart(lambda xs: f(lf(xs), rf(xs)))


def _float_square(base: _FloatPart) -> _FloatPart:
    """``base**2`` as a product, like ``np.square`` (exactly, and inf rather than OverflowError)."""
    inner, value, i = base
    if value is not None:
        return _float_constant(value * value)
    if i is not None:
        return _FloatPart(lambda xs: xs[i] * xs[i])

    def square(xs: Sequence[float]) -> float:
        a = inner(xs)
        return a * a

    return _FloatPart(square)


def _read_directly(
    f: Callable[[float, float], float], left: _FloatPart, right: _FloatPart
) -> ScalarFn | None:
    """``f(left, right)`` reading a constant on either side, or variables on both sides, directly:
    no call per leaf. None otherwise: then both operands' closures are called (with Python's own
    operator written out where the row has one)."""
    lv, li, lf = left.value, left.index, left.fn
    rv, ri, rf = right.value, right.index, right.fn
    if lv is not None:
        return (lambda xs: f(lv, xs[ri])) if ri is not None else (lambda xs: f(lv, rf(xs)))
    if rv is not None:
        return (lambda xs: f(xs[li], rv)) if li is not None else (lambda xs: f(lf(xs), rv))
    if li is not None and ri is not None:
        return lambda xs: f(xs[li], xs[ri])
    return None


def _float_variadic(f: Callable[..., float], parts: list[ScalarFn]) -> ScalarFn:
    if len(parts) == 2:
        first, second = parts
        return lambda xs: f(first(xs), second(xs))
    return lambda xs: f(*[part(xs) for part in parts])
