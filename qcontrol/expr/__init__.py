"""Safe math expressions for scenario files.

Nonlinearities such as ``"x2**2 * cos(x1)"`` are parsed with :mod:`ast` once, checked node by node
against a whitelist and turned into a small validated tree (numbers, variables, operations); user
text is never passed to ``eval`` or ``exec``, and anything outside the whitelist is rejected with a
message that names it. Generators turn that tree into closures: numpy calls on columns
(:meth:`Expression.__call__`, :meth:`Expression.on_columns`), ``math`` calls on plain floats
(:func:`scalar_function`, :meth:`Expression.on_floats`), and the plain-float values on columns
(:meth:`Expression.on_copies`: each copy of a batch computes what its run alone computes). All
read one table, :data:`OPERATIONS`: a row per operator, function and constant, with its numpy and
its plain-float implementation.

Allowed: numbers, the declared variables (``x1..xn``, ``q1..qn``), ``pi``, ``+ - * / **``, unary
``-``/``+``, and calls to ``abs sqrt cbrt exp log sin cos tan tanh sign min max`` and
``spow(a, p) = sign(a) |a|**p`` (a power of a negative base: ``x3**(1/3)`` is NaN for x3 < 0,
``cbrt(x3)`` and ``spow(x3, 1/3)`` are the real cube root).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..errors import QcontrolInputError
from .calculus import differentiate, text
from .generators import columns_closure, copies_closure, float_closure
from .operations import FLOAT_REFUSED, NAMED, OPERATIONS, ColumnsFn, Operation, ScalarFn
from .tree import (
    MAX_CONSTANT_EXPONENT,
    MAX_DEPTH,
    MAX_NODES,
    MAX_SOURCE_LENGTH,
    SHOWN_SOURCE,
    Apply,
    Tree,
    Validator,
    Variable,
    parse,
    show,
)

__all__ = [
    "MAX_CONSTANT_EXPONENT",
    "MAX_DEPTH",
    "MAX_NODES",
    "MAX_SOURCE_LENGTH",
    "OPERATIONS",
    "SHOWN_SOURCE",
    "Expression",
    "FLOAT_REFUSED",
    "FloatCombination",
    "FloatTerms",
    "Operation",
    "ScalarFn",
    "combine",
    "compile_expression",
    "derivative",
    "expression",
    "scalar_function",
]


@runtime_checkable
class SelfRecording(Protocol):
    """A value that records what is computed from it (the compiled loop's traced columns,
    :mod:`qcontrol.compiled.traced`): an expression evaluated on it is recorded by it."""

    def evaluated(self, expression: Expression, columns: Sequence[Any]) -> Any: ...


@dataclass(frozen=True)
class Expression:
    """A compiled expression: call it with an array ``values[..., len(variables)]``."""

    source: str
    variables: tuple[str, ...]
    used: frozenset[str]
    _fn: ColumnsFn
    _tree: Tree = field(repr=False)

    def __call__(self, values: np.ndarray) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        columns = values.T if values.ndim <= 2 else np.moveaxis(values, -1, 0)
        result = self._fn(columns)
        if np.ndim(result) == 0:
            return np.full(values.shape[:-1], float(result))
        return np.asarray(result, dtype=float)

    def __deepcopy__(self, memo: dict) -> Expression:
        """Itself: an expression does not change, and its tree's operations are compared by
        identity (a copy of a law holding one computes what the law computes)."""
        return self

    def on_columns(self, columns: Sequence[np.ndarray]) -> np.ndarray | float:
        """Evaluate on ``columns[i]`` = values of ``variables[i]`` (no reshaping; a constant
        expression returns a float). The fast path for hot loops."""
        return self._fn(columns)

    def on_floats(self, values: Sequence[float]) -> float:
        """Evaluate on plain floats, ``values[i]`` = ``variables[i]``: the same expression through
        ``math`` (:func:`scalar_function`). Where ``math`` refuses (a domain error, an overflow:
        :data:`FLOAT_REFUSED`), numpy's value (NaN, Inf) is returned, the one fallback rule, so
        both evaluations agree up to the last bit, except that ``(-inf)**0.5`` is inf here (C's
        ``pow``) and NaN through numpy (a square root)."""
        try:
            return self._scalar_fn(values)
        except FLOAT_REFUSED:
            with np.errstate(all="ignore"):
                return float(self._fn(values))
        except TypeError:  # a traced value (a user's law traced for the compiled loop) records itself
            for value in values:
                if isinstance(value, SelfRecording):
                    return value.evaluated(self, values)
            raise

    @cached_property
    def _scalar_fn(self) -> ScalarFn:
        return scalar_function(self)

    def on_copies(self, columns: Sequence[np.ndarray | float]) -> np.ndarray | float:
        """Evaluate on ``(batch,)`` columns (numbers shared by every copy beside them), each
        element exactly :meth:`on_floats` of that copy's values: what the copy's run alone
        computes (:func:`~.generators.copies_closure`; numpy's own exp, pow, ... may differ from
        ``math``'s in the last bit, and :meth:`on_columns` keeps numpy's). Where ``math`` refuses
        some copy's value, every copy is evaluated by :meth:`on_floats`, numpy's answer where it
        refuses."""
        try:
            return self._copies_fn(columns)
        except FLOAT_REFUSED:
            pass
        arrays = [c for c in columns if isinstance(c, np.ndarray) and c.ndim]
        if not arrays:
            return self.on_floats([float(c) for c in columns])
        shape = np.broadcast_shapes(*(a.shape for a in arrays))
        each = [np.broadcast_to(c, shape).ravel().tolist() for c in columns]
        values = [self.on_floats(copy) for copy in zip(*each, strict=True)]
        return np.array(values, dtype=float).reshape(shape)

    @cached_property
    def _copies_fn(self) -> ColumnsFn:
        return copies_closure(self._tree)


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
    known = _COMPILED.get((text, variables))
    if known is not None:  # (an Expression is immutable: one compiled text serves every variant)
        return known
    if len(text) > MAX_SOURCE_LENGTH:
        raise QcontrolInputError(
            f"{where}: expression is {len(text)} characters long; the limit is {MAX_SOURCE_LENGTH}"
        )
    if not text.strip():
        raise QcontrolInputError(f"{where}: empty expression; write a formula such as \"0\" or \"x2\"")
    body = parse(text, variables, where)
    validator = Validator(text, variables, where)
    try:
        tree = validator.visit(body)
        on_columns = columns_closure(tree)
    except RecursionError:
        raise QcontrolInputError(
            f"{where}: expression {show(text)} is too deeply nested; simplify it"
        ) from None
    compiled = Expression(text, variables, frozenset(validator.used), on_columns, tree)
    if len(_COMPILED) >= COMPILED_KEPT:
        _COMPILED.clear()
    _COMPILED[(text, variables)] = compiled
    return compiled


COMPILED_KEPT = 4096  # expressions kept compiled (a sweep's variants repeat the same few texts)
_COMPILED: dict[tuple[str, tuple[str, ...]], Expression] = {}


def scalar_function(expression: Expression) -> ScalarFn:
    """A plain-float version of a (validated) :class:`Expression`: ``f((x1, x2)) -> float``.

    For the hot loops of one copy (:mod:`qcontrol.engine.fastpath` says why). Where ``math``
    refuses it raises one of :data:`FLOAT_REFUSED`, and the one rule is then numpy's answer
    (:meth:`Expression.on_floats`). ``sin``, ``exp``, ... may differ from numpy's in the last bit.
    """
    return float_closure(expression._tree)


class FloatTerms:
    """Expressions evaluated on plain floats through ``math`` (:func:`scalar_function`), in order;
    where ``math`` refuses one (:data:`FLOAT_REFUSED`), each is evaluated by
    :meth:`Expression.on_floats`, which gives numpy's answer there and ``math``'s elsewhere: the
    one fallback rule, for the engine's float form and MuJoCo's passive callback alike."""

    def __init__(self, expressions: Sequence[Expression]) -> None:
        self.expressions = tuple(expressions)
        self.fast = tuple(scalar_function(e) for e in self.expressions)

    def __call__(self, values: Sequence[float]) -> list[float]:
        try:
            return [f(values) for f in self.fast]
        except FLOAT_REFUSED:
            return [e.on_floats(values) for e in self.expressions]


def combine(pairs: Sequence[tuple[object, Callable]], values: Sequence) -> object:
    """``sum of c * f(values)`` over ``(c, f)`` pairs, left to right (``c`` None: ``f(values)`` as
    it is; no terms: 0.0): a linear combination of evaluated expressions, for any kind of values."""
    total = None
    for c, f in pairs:
        value = f(values) if c is None else c * f(values)
        total = value if total is None else total + value
    return 0.0 if total is None else total


class FloatCombination:
    """:func:`combine` of expressions on plain floats through ``math``, with :class:`FloatTerms`'
    fallback rule: where ``math`` refuses a term, every term by :meth:`Expression.on_floats`."""

    def __init__(self, expressions: Sequence[Expression], coefficients: Sequence[float | None]) -> None:
        self.fast = tuple(zip(coefficients, (scalar_function(e) for e in expressions), strict=True))
        self.safe = tuple(zip(coefficients, (e.on_floats for e in expressions), strict=True))

    def __call__(self, values: Sequence[float]) -> float:
        try:  # combine(self.fast, values), written out: a MuJoCo step calls this four times
            total = None
            for c, f in self.fast:
                value = f(values) if c is None else c * f(values)
                total = value if total is None else total + value
        except FLOAT_REFUSED:
            return combine(self.safe, values)
        return 0.0 if total is None else total


def derivative(expression: Expression, variable: str) -> Expression:
    """The partial derivative of ``expression`` in ``variable`` (one of its variables), as an
    :class:`Expression` over the same variables: its tree by the chain rule
    (:func:`~.calculus.differentiate`), its source the tree written out. Where the expression
    is not differentiable (``abs`` at 0, ``min``/``max`` at a tie, ``sign`` at 0), the value is
    the rule's (``sign(0) = 0``, the mean of the two sides)."""
    if variable not in expression.variables:
        raise QcontrolInputError(f"derivative: {variable!r} is not a variable of {show(expression.source)} "
                                 f"(its variables are {', '.join(expression.variables)})")
    tree = differentiate(expression._tree, expression.variables.index(variable))
    used = frozenset(v for v in expression.variables if v in _used(tree, expression.variables))
    names = expression.variables
    return Expression(text(tree, names), names, used, columns_closure(tree), tree)


def _used(tree: Tree, names: Sequence[str]) -> set[str]:
    """The names of the variables a (calculus-built) tree reads."""
    found, stack, seen = set(), [tree], set()
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, Variable):
            found.add(names[node.index])
        elif isinstance(node, Apply):
            stack.extend(node.operands)
    return found


def expression(source: str, variables: Sequence[str] = ("x1", "x2")) -> Expression:
    """The compiler scenarios use, public: ``qcontrol.expression("1 + q2**2", variables=("q1",
    "q2"))`` parses and whitelist-checks ``source`` (the same language and safety as a scenario's
    ``psi``, ``phi`` and ``r``: see the module docstring; ``cbrt`` and ``spow(a, p) = sign(a)
    |a|**p`` give real powers of negative bases) and returns an :class:`Expression`: ``f(values)``
    on an array ``values[..., len(variables)]`` (a row per state), ``f.on_floats([q1, q2])`` on
    plain floats. Refusals are one :class:`QcontrolInputError` line."""
    if isinstance(variables, str) or not isinstance(variables, Sequence) or not all(
            isinstance(v, str) and v.isidentifier() for v in variables):
        raise QcontrolInputError(f"expression: variables must be a list of names such as (\"q1\", \"q2\"), "
                                 f"got {variables!r}")
    if len(set(variables)) != len(variables) or any(v in NAMED for v in variables):
        raise QcontrolInputError(f"expression: variables {list(variables)} must be distinct and not the name "
                                 "of a function or constant")
    return compile_expression(source, variables, "expression")
