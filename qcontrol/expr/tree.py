"""Parsing and the whitelist check: source text -> a small validated tree (numbers, variables,
operations of :data:`~qcontrol.expr.operations.OPERATIONS`), built once and kept in the
:class:`~qcontrol.expr.Expression`. Anything outside the whitelist is refused with a message that
names it; user text is never passed to ``eval`` or ``exec``."""

from __future__ import annotations

import ast
import math
from dataclasses import dataclass

import numpy as np

from ..errors import QcontrolInputError
from .operations import NAMED, OPERATORS, POWER, Operation

MAX_SOURCE_LENGTH = 2000
MAX_CONSTANT_EXPONENT = 64.0
MAX_NODES = 500
MAX_DEPTH = 200  # nesting depth; evaluation recurses once per level, so this bounds the stack it needs
SHOWN_SOURCE = 100  # messages quote at most this many characters of an expression

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
class Number:
    """A literal number."""

    constant: float


@dataclass(frozen=True)
class Variable:
    """A declared variable: ``index`` is its position in ``Expression.variables``."""

    index: int
    constant: None = None


@dataclass(frozen=True)
class Apply:
    """An operator, a function call or a named constant (no operands), with its table row."""

    operation: Operation
    operands: tuple[Tree, ...]
    constant: float | None  # when every operand is constant (never for min and max), else None


Tree = Number | Variable | Apply


def cut(text: str) -> str:
    """``text`` cut to :data:`SHOWN_SOURCE` characters, for a message."""
    if len(text) > SHOWN_SOURCE:
        return text[:SHOWN_SOURCE] + f"... ({len(text)} characters)"
    return text


def show(text: str) -> str:
    """``repr`` of ``text`` for a one-line message: newlines escaped, long text cut."""
    return cut(repr(text))


def parse(text: str, variables: tuple[str, ...], where: str) -> ast.expr:
    """The syntax tree of ``text``, within :data:`MAX_NODES` nodes and :data:`MAX_DEPTH` levels."""
    try:
        body = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as exc:
        raise QcontrolInputError(
            f"{where}: cannot parse {show(text)} ({exc.msg}); use numbers, {', '.join(variables)}, "
            "+ - * / ** and the allowed functions"
        ) from None
    except ValueError as exc:  # e.g. null bytes (Python < 3.12)
        raise QcontrolInputError(f"{where}: cannot parse {show(text)} ({exc}); use plain text") from None
    except (RecursionError, MemoryError):
        raise QcontrolInputError(
            f"{where}: expression {show(text)} is too deeply nested; simplify it"
        ) from None
    nodes, depth = _size(body)
    if nodes > MAX_NODES:
        raise QcontrolInputError(
            f"{where}: too many terms ({nodes} syntax nodes) in {show(text)}; keep expressions under "
            f"{MAX_NODES} nodes"
        )
    if depth > MAX_DEPTH:
        raise QcontrolInputError(
            f"{where}: expression {show(text)} is nested {depth} levels deep; keep it under {MAX_DEPTH} "
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


class Validator:
    """Turns a syntax tree into a validated tree, or raises with a message that names the problem."""

    def __init__(self, source: str, variables: tuple[str, ...], where: str) -> None:
        self.source = source
        self.variables = variables
        self.index = {name: i for i, name in enumerate(variables)}
        self.where = where
        self.used: set[str] = set()
        self.nodes = 0

    def fail(self, problem: str, fix: str) -> QcontrolInputError:
        return QcontrolInputError(f"{self.where}: {problem} in {show(self.source)}; {fix}")

    def allowed_names(self) -> str:
        return ", ".join([*self.variables, *NAMED])

    def visit(self, node: ast.AST) -> Tree:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise self.fail("too many terms", f"keep expressions under {MAX_NODES} nodes")
        if isinstance(node, ast.Constant):
            return Number(self._number(node.value))
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
            raise self.fail(f"literal {cut(repr(value))} is not a real number", "use plain numbers")
        try:
            as_float = float(value)
        except OverflowError:
            raise self.fail(f"number {cut(str(value))} is too large", "use a finite number") from None
        if not math.isfinite(as_float):
            raise self.fail(f"number {value!r} is not finite", "use a finite number")
        return as_float

    def _name(self, name: str) -> Tree:
        if name in self.index:
            self.used.add(name)
            return Variable(self.index[name])
        row = NAMED.get(name)
        if row is not None and row.arity == 0:
            return self._apply(row, [])
        if row is not None:
            raise self.fail(f"function {show(name)} used without a call", f"write {name}(...)")
        if name == "t":  # time: the plant's terms take it (x1..xn, t), nothing else does
            raise self.fail("t (time) is not allowed here", "only plant.psi and plant.phi may depend on t; "
                            "a bounding function r is a function of the readings q1..qn alone (a bounded "
                            "forcing is covered by a constant entry of r)")
        raise self.fail(f"unknown name {show(name)}", f"allowed names are {self.allowed_names()}")

    def _unary(self, node: ast.UnaryOp) -> Tree:
        if isinstance(node.op, ast.UAdd):
            return self.visit(node.operand)
        row = OPERATORS.get(type(node.op))
        if row is None:
            raise self.fail(f"operator {type(node.op).__name__} is not allowed", "use only unary + or -")
        return self._apply(row, [self.visit(node.operand)])

    def _binary(self, node: ast.BinOp) -> Tree:
        row = OPERATORS.get(type(node.op))
        if row is None:
            raise self.fail(f"operator {type(node.op).__name__} is not allowed", "use only + - * / **")
        left, right = self.visit(node.left), self.visit(node.right)
        exponent = right.constant
        if row is POWER and exponent is not None and abs(exponent) > MAX_CONSTANT_EXPONENT:
            raise self.fail(
                f"exponent {exponent:g} is too large",
                f"keep constant exponents within +-{MAX_CONSTANT_EXPONENT:g}",
            )
        if row.syntax is ast.Div and right.constant == 0.0:
            raise self.fail("division by zero", "divide by a non-zero number")
        return self._apply(row, [left, right])

    def _call(self, node: ast.Call) -> Tree:
        if not isinstance(node.func, ast.Name):
            raise self.fail("only calls of plain function names are allowed", "e.g. sin(x1)")
        name = node.func.id
        if node.keywords:
            raise self.fail(f"keyword arguments to {name}() are not allowed", "pass values only")
        if any(isinstance(arg, ast.Starred) for arg in node.args):
            raise self.fail(f"'*' unpacking in {name}() is not allowed", "pass values only")
        row = NAMED.get(name)
        if row is None or row.arity == 0:
            known = row is not None or name in self.index  # a constant or a variable
            problem = f"{show(name)} is not a function" if known else f"unknown function {show(name)}"
            raise self.fail(problem, f"allowed names are {self.allowed_names()}")
        if row.arity == 1 and len(node.args) != 1:
            raise self.fail(f"{name}() takes exactly 1 argument, got {len(node.args)}", f"write {name}(x1)")
        if row.arity == 2 and len(node.args) != 2:
            raise self.fail(f"{name}() takes exactly 2 arguments, got {len(node.args)}",
                            f"write {name}(x1, 0.5)")
        if row.arity is None and len(node.args) < 2:
            raise self.fail(f"{name}() needs at least 2 arguments", f"write {name}(a, b)")
        return self._apply(row, [self.visit(arg) for arg in node.args])

    def _apply(self, row: Operation, operands: list[Tree]) -> Apply:
        """``row`` on ``operands``, folded with numpy when they are all constant (not min/max)."""
        values = [operand.constant for operand in operands]
        if row.arity is None or any(value is None for value in values):
            return Apply(row, tuple(operands), None)
        if row.arity == 0:
            return Apply(row, (), float(row.on_arrays()))
        if row.arity == 1:
            return Apply(row, tuple(operands), self._fold_unary(row, *values))
        return Apply(row, tuple(operands), self._fold_binary(row, *values))

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
