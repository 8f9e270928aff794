"""The code generators: a validated tree -> numpy calls on columns, -> ``math`` calls on plain
floats (the hot loops of a batch of one and MuJoCo's passive callback), and -> the float
generator's values on columns (a batch of copies, each its run alone's). All read the rows of
:data:`~qcontrol.expr.operations.OPERATIONS`."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from itertools import repeat
from typing import NamedTuple

import numpy as np

from .operations import FLOAT_REFUSED, POWER, ColumnsFn, Operation, ScalarFn
from .tree import Number, Tree, Variable

# --------------------------------------------------------------------------------------------
# numpy generator: validated tree -> closure over columns


def columns_closure(node: Tree) -> ColumnsFn:
    """``f(columns)`` of numpy calls; a constant part returns numpy's folded value (a float)."""
    if node.constant is not None:
        value = node.constant
        return lambda cols: value
    if isinstance(node, Variable):
        i = node.index
        return lambda cols: cols[i]
    row, parts = node.operation, [columns_closure(operand) for operand in node.operands]
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
    if row is POWER and node.operands[1].constant == 2.0:
        return lambda cols: np.square(left(cols))
    return lambda cols: fn(left(cols), right(cols))


# --------------------------------------------------------------------------------------------
# Float generator: validated tree -> closure over plain floats (hot loops of a batch of one,
# MuJoCo's passive callback)


def float_closure(tree: Tree) -> ScalarFn:
    """The plain-float closure of a validated tree (see :func:`qcontrol.expr.scalar_function`)."""
    return float_part(tree).fn


class _FloatPart(NamedTuple):
    """A subtree on plain floats: its closure, and what lets the operation above read it directly."""

    fn: ScalarFn
    value: float | None = None  # a constant: operators on constants are folded on floats
    index: int | None = None  # a variable: ``xs[index]``


def _float_constant(value: float) -> _FloatPart:
    return _FloatPart(lambda xs: value, value=value)


def float_part(node: Tree) -> _FloatPart:
    """The float closure of ``node``. Operators on constants are folded (with the float
    implementation); functions are not, a function of a constant is evaluated at each call."""
    if isinstance(node, Number):
        return _float_constant(node.constant)
    if isinstance(node, Variable):
        i = node.index
        return _FloatPart(lambda xs: xs[i], index=i)
    row, parts = node.operation, [float_part(operand) for operand in node.operands]
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
    if row is POWER and right.value == 2.0:
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


# --------------------------------------------------------------------------------------------
# Copies generator: validated tree -> closure over columns whose every element is the float
# closure's value on that copy's floats (a batch of copies in the engine's loop)


def copies_closure(node: Tree) -> ColumnsFn:
    """``f(columns)`` on ``(batch,)`` columns (or plain floats), each element what
    :func:`float_closure` gives on that copy's floats, to the last bit: the rows that are
    ``same_on_arrays`` (``+ - *``, ``abs``, ...) and ``x**2`` (a product in both) run as numpy
    calls on whole columns, every other row applies its ``on_floats`` element by element (numpy's
    exp, pow, ... round differently from ``math``'s), and constant parts take the float
    generator's values. Where ``on_floats`` refuses an element (:data:`FLOAT_REFUSED`), that
    error is raised, as the float closure raises it (:meth:`qcontrol.expr.Expression.on_copies`
    then evaluates copy by copy)."""
    if node.constant is not None:
        return _copies_constant(float_part(node))
    if isinstance(node, Variable):
        i = node.index
        return lambda cols: cols[i]
    row, parts = node.operation, [copies_closure(operand) for operand in node.operands]
    if row is POWER and node.operands[1].constant == 2.0:
        base = parts[0]

        def square(cols: Sequence[np.ndarray]) -> np.ndarray:
            a = base(cols)
            return a * a

        return square
    fn = row.on_arrays if row.same_on_arrays else elementwise(row.on_floats)
    if len(parts) == 1:
        inner = parts[0]
        return lambda cols: fn(inner(cols))
    if len(parts) == 2 and row.arity is not None:
        left, right = parts
        return lambda cols: fn(left(cols), right(cols))
    return lambda cols: fn(*[part(cols) for part in parts])


def _copies_constant(part: _FloatPart) -> ColumnsFn:
    """A constant part as the float closure computes it: folded, or a function of constants
    (evaluated once here; where ``math`` refuses it, every evaluation raises the refusal)."""
    if part.value is not None:
        value = part.value
        return lambda cols: value
    try:
        value = part.fn(())
    except FLOAT_REFUSED as exc:
        refusal = exc

        def refused(cols: Sequence[np.ndarray]) -> float:
            raise refusal

        return refused
    return lambda cols: value


def elementwise(f: Callable[..., float]) -> Callable[..., np.ndarray | float]:
    """``f`` of plain floats applied to each element of its operands (arrays broadcast against
    each other and against plain numbers): a float for plain operands, else an array."""

    def each(*operands: np.ndarray | float) -> np.ndarray | float:
        shapes = {a.shape for a in operands if isinstance(a, np.ndarray) and a.ndim}
        if not shapes:
            return f(*[float(a) for a in operands])
        if len(shapes) > 1:
            operands = tuple(np.broadcast_arrays(*operands))
            shapes = {operands[0].shape}
        (shape,) = shapes
        lists = [a.ravel().tolist() if isinstance(a, np.ndarray) and a.ndim else repeat(float(a))
                 for a in operands]
        return np.fromiter(map(f, *lists), float, math.prod(shape)).reshape(shape)

    return each
