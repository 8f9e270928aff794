"""Symbolic differentiation of validated trees, the trees built from them, and their evaluation.

:func:`differentiate` turns the tree of an expression into the tree of its partial derivative in
one variable, by the chain rule, one rule per row of :data:`~qcontrol.expr.operations.OPERATIONS`
(:data:`RULES`). The builders (:func:`add`, :func:`mul`, ...) fold constants and drop zeros and
ones, so that derivatives of derivatives (a backstepping design differentiates its own virtual
controls, nested once per order) stay small. Trees built here share their subtrees: a
:class:`Program` evaluates a set of such trees once per distinct node (by identity), in
topological order, on numpy columns or plain floats.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..errors import QcontrolInputError
from .generators import elementwise
from .operations import FLOAT_REFUSED, NAMED, OPERATIONS, OPERATORS, POWER, Operation
from .tree import Apply, Number, Tree, Variable

ADD, SUB, MUL, DIV = (OPERATORS[op] for op in (ast.Add, ast.Sub, ast.Mult, ast.Div))
NEG = OPERATORS[ast.USub]
ZERO, ONE = Number(0.0), Number(1.0)


def number(value: float) -> Number:
    return Number(float(value))


def _value(node: Tree) -> float | None:
    return node.constant


def apply(row: Operation, *operands: Tree) -> Tree:
    """``row`` on ``operands``; folded to a :class:`~.tree.Number` (numpy's value) when every
    operand is constant."""
    values = [_value(o) for o in operands]
    if row.arity != 0 and operands and all(v is not None for v in values):
        with np.errstate(all="ignore"):
            folded = row.on_arrays(*values) if row.arity is not None else _reduce(row, values)
        return number(float(folded))
    return Apply(row, tuple(operands), None)


def _reduce(row: Operation, values: Sequence[Any]) -> Any:
    result = values[0]
    for value in values[1:]:
        result = row.on_arrays(result, value)
    return result


def add(a: Tree, b: Tree) -> Tree:
    if _value(a) == 0.0:
        return b
    if _value(b) == 0.0:
        return a
    return apply(ADD, a, b)


def sub(a: Tree, b: Tree) -> Tree:
    if _value(b) == 0.0:
        return a
    if _value(a) == 0.0:
        return neg(b)
    return apply(SUB, a, b)


def neg(a: Tree) -> Tree:
    if isinstance(a, Apply) and a.operation is NEG:
        return a.operands[0]
    return apply(NEG, a)


def mul(a: Tree, b: Tree) -> Tree:
    if _value(a) == 0.0 or _value(b) == 0.0:
        return ZERO
    if _value(a) == 1.0:
        return b
    if _value(b) == 1.0:
        return a
    if _value(a) == -1.0:
        return neg(b)
    if _value(b) == -1.0:
        return neg(a)
    return apply(MUL, a, b)


def div(a: Tree, b: Tree) -> Tree:
    if _value(a) == 0.0:
        return ZERO
    if _value(b) == 1.0:
        return a
    return apply(DIV, a, b)


def total(terms: Sequence[Tree]) -> Tree:
    """The sum of ``terms`` left to right (0 for none)."""
    result: Tree = ZERO
    for term in terms:
        result = add(result, term)
    return result


def dot(a: Sequence[Tree], b: Sequence[Tree]) -> Tree:
    """``sum a_j b_j``."""
    return total([mul(x, y) for x, y in zip(a, b, strict=True)])


def call(name: str, *operands: Tree) -> Tree:
    return apply(NAMED[name], *operands)


def _power(base: Tree, exponent: float) -> Tree:
    if exponent == 0.0:
        return ONE
    if exponent == 1.0:
        return base
    return apply(POWER, base, number(exponent))


# --------------------------------------------------------------------------------------------
# The chain rule, one rule per operation: (node, its operands, their derivatives) -> derivative

Rule = Callable[[Apply, Sequence[Tree], Sequence[Tree]], Tree]


def _power_rule(node: Apply, ops: Sequence[Tree], d: Sequence[Tree]) -> Tree:
    a, b = ops
    p = _value(b)
    if p is not None:  # p a**(p - 1) a'
        return mul(mul(number(p), _power(a, p - 1.0)), d[0])
    # a**b (b' log a + b a' / a)
    return mul(node, add(mul(d[1], call("log", a)), div(mul(b, d[0]), a)))


def _extreme_rule(sign: float) -> Rule:
    """``min``/``max`` of two or more operands, pairwise from the left: ``min(a, b) = (a + b) / 2
    - |a - b| / 2``, so its derivative is ``(a' + b') / 2 - sign(a - b) (a' - b') / 2`` (``+``
    for ``max``); at a tie, the mean of the two sides."""

    def rule(node: Apply, ops: Sequence[Tree], d: Sequence[Tree]) -> Tree:
        left, dleft = ops[0], d[0]
        for right, dright in zip(ops[1:], d[1:], strict=True):
            half_sum = mul(number(0.5), add(dleft, dright))
            half_gap = mul(mul(number(0.5 * sign), call("sign", sub(left, right))), sub(dleft, dright))
            dleft = add(half_sum, half_gap)
            left = apply(node.operation, left, right)
        return dleft

    return rule


def _spow_rule(node: Apply, ops: Sequence[Tree], d: Sequence[Tree]) -> Tree:
    a, b = ops
    p = _value(b)
    if p is None:
        raise QcontrolInputError("spow(a, p) with a p that is not constant cannot be differentiated; "
                                 "write a constant exponent")
    return mul(mul(number(p), _power(call("abs", a), p - 1.0)), d[0])  # p |a|**(p - 1) a'


RULES: dict[str, Rule] = {
    "+": lambda node, o, d: add(d[0], d[1]) if len(o) == 2 else d[0],
    "-": lambda node, o, d: sub(d[0], d[1]) if len(o) == 2 else neg(d[0]),
    "*": lambda node, o, d: add(mul(d[0], o[1]), mul(o[0], d[1])),
    "/": lambda node, o, d: sub(div(d[0], o[1]), div(mul(o[0], d[1]), mul(o[1], o[1]))),
    "**": _power_rule,
    "pi": lambda node, o, d: ZERO,
    "abs": lambda node, o, d: mul(call("sign", o[0]), d[0]),
    "sqrt": lambda node, o, d: div(d[0], mul(number(2.0), node)),
    "cbrt": lambda node, o, d: div(d[0], mul(number(3.0), mul(node, node))),
    "exp": lambda node, o, d: mul(node, d[0]),
    "log": lambda node, o, d: div(d[0], o[0]),
    "sin": lambda node, o, d: mul(call("cos", o[0]), d[0]),
    "cos": lambda node, o, d: neg(mul(call("sin", o[0]), d[0])),
    "tan": lambda node, o, d: mul(add(ONE, mul(node, node)), d[0]),
    "tanh": lambda node, o, d: mul(sub(ONE, mul(node, node)), d[0]),
    "sign": lambda node, o, d: ZERO,
    "min": _extreme_rule(-1.0),
    "max": _extreme_rule(1.0),
    "spow": _spow_rule,
}
assert set(RULES) == {row.name for row in OPERATIONS}  # a rule for every row of the table


Memo = dict[tuple[int, int], tuple[Tree, Tree]]  # (id(node), variable) -> (node, its derivative)


def differentiate(tree: Tree, index: int, memo: Memo | None = None) -> Tree:
    """The tree of ``d tree / d variable[index]`` (the chain rule, :data:`RULES`). ``memo`` (by
    node identity and variable) lets many derivatives of trees that share subtrees share theirs."""
    memo = {} if memo is None else memo
    key = (id(tree), index)
    found = memo.get(key)
    if found is not None and found[0] is tree:
        return found[1]
    if isinstance(tree, Number) or tree.constant is not None:
        result: Tree = ZERO
    elif isinstance(tree, Variable):
        result = ONE if tree.index == index else ZERO
    else:
        parts = [differentiate(o, index, memo) for o in tree.operands]
        result = RULES[tree.operation.name](tree, tree.operands, parts)
    memo[key] = (tree, result)
    return result


# --------------------------------------------------------------------------------------------
# Text of a tree (for a derivative's Expression), and evaluation of shared trees


def text(tree: Tree, names: Sequence[str]) -> str:
    """Source text of ``tree`` (fully parenthesised), its variables named ``names``."""
    if isinstance(tree, Number):
        return repr(tree.constant) if tree.constant >= 0 else f"({tree.constant!r})"
    if isinstance(tree, Variable):
        return names[tree.index]
    row, parts = tree.operation, [text(o, names) for o in tree.operands]
    if row.arity == 0:
        return row.name
    if row.is_operator:
        return f"(-{parts[0]})" if row.arity == 1 else f"({parts[0]} {row.name} {parts[1]})"
    return f"{row.name}({', '.join(parts)})"


class Program:
    """Trees that share subtrees, evaluated once per distinct node (by identity) in topological
    order: ``program(values) -> [value of each tree]``, ``values[i]`` the value of variable i, numpy
    columns of any shape (numpy's rows) or plain floats (``math``'s rows; where ``math`` refuses,
    the whole evaluation is numpy's, the package's one fallback rule)."""

    def __init__(self, trees: Sequence[Tree]) -> None:
        self.trees = tuple(trees)
        order: list[Tree] = []
        slot: dict[int, int] = {}
        stack: list[tuple[Tree, bool]] = [(t, False) for t in reversed(self.trees)]
        while stack:
            node, ready = stack.pop()
            if id(node) in slot:
                continue
            operands = node.operands if isinstance(node, Apply) and node.constant is None else ()
            if ready or not operands:
                slot[id(node)] = len(order)
                order.append(node)
                continue
            stack.append((node, True))
            stack.extend((o, False) for o in reversed(operands) if id(o) not in slot)
        self.steps = tuple(self._step(node, slot) for node in order)
        self.outputs = tuple(slot[id(t)] for t in self.trees)

    @staticmethod
    def _step(node: Tree, slot: dict[int, int]) -> tuple:
        if isinstance(node, Variable):
            return ("var", node.index)
        if node.constant is not None:
            return ("const", node.constant)
        if node.operation.arity == 0:
            return ("const", float(node.operation.on_arrays()))
        square = node.operation is POWER and node.operands[1].constant == 2.0
        return ("square" if square else "op", node.operation, tuple(slot[id(o)] for o in node.operands))

    def __len__(self) -> int:
        return len(self.steps)

    def __call__(self, values: Sequence[Any]) -> list[Any]:
        if values and isinstance(values[0], float) and not isinstance(values[0], np.floating):
            try:
                return self._run(values, floats=True)
            except FLOAT_REFUSED:
                with np.errstate(all="ignore"):
                    return [float(v) for v in self._run([np.float64(v) for v in values], floats=False)]
        return self._run(values, floats=False)

    def on_copies(self, values: Sequence[Any]) -> list[Any]:
        """Evaluate on ``(batch,)`` columns (numbers shared by every copy beside them), each
        element what the float evaluation gives that copy's values (as
        :meth:`~qcontrol.expr.Expression.on_copies`): the rows that are ``same_on_arrays`` on
        whole columns, every other row's ``on_floats`` element by element. Where ``math``
        refuses some copy's value, every copy is evaluated alone (numpy's answer where it
        refuses)."""
        try:
            return self._run(values, floats=False, copies=True)
        except FLOAT_REFUSED:
            pass
        arrays = [v for v in values if isinstance(v, np.ndarray) and v.ndim]
        if not arrays:
            return self([float(v) for v in values])
        shape = np.broadcast_shapes(*(a.shape for a in arrays))
        each = [np.broadcast_to(v, shape).ravel().tolist() for v in values]
        rows = [self(list(copy)) for copy in zip(*each, strict=True)]
        return [np.array(column, dtype=float).reshape(shape) for column in zip(*rows, strict=True)]

    def _run(self, values: Sequence[Any], floats: bool, copies: bool = False) -> list[Any]:
        out: list[Any] = []
        push = out.append
        for step in self.steps:
            kind = step[0]
            if kind == "var":
                push(values[step[1]])
            elif kind == "const":
                push(step[1])
            elif kind == "square":
                a = out[step[2][0]]
                push(a * a)
            else:
                row, args = step[1], step[2]
                fn = row.on_floats if floats else _ELEMENTWISE[row] if copies else row.on_arrays
                if row.arity is None:
                    result = out[args[0]]
                    for i in args[1:]:
                        result = fn(result, out[i])
                    push(result)
                else:
                    push(fn(*[out[i] for i in args]))
        return [out[i] for i in self.outputs]


# each row as the copies' evaluation applies it (:meth:`Program.on_copies`): numpy's where it is
# the float row's on every element, else the float row element by element
_ELEMENTWISE = {row: row.on_arrays if row.same_on_arrays else elementwise(row.on_floats)
                for row in OPERATIONS}
