"""Safe math expressions for scenario files.

Nonlinearities such as ``"x2**2 * cos(x1)"`` are parsed with :mod:`ast`, checked node by node
against a whitelist, and turned into a tree of small numpy closures. User text is never passed to
``eval`` or ``exec``; anything outside the whitelist is rejected with a message that names it.

Allowed: numbers, the declared variables (``x1..xn``, ``q1..qn``), ``pi``, ``+ - * / **``, unary
``-``/``+``, and calls to ``abs sqrt exp log sin cos tan tanh sign min max``.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .errors import QcontrolInputError

MAX_SOURCE_LENGTH = 2000
MAX_CONSTANT_EXPONENT = 64.0
MAX_NODES = 500
MAX_DEPTH = 200  # nesting depth; evaluation recurses once per level, so this bounds the stack it needs
SHOWN_SOURCE = 100  # messages quote at most this many characters of an expression

_UNARY_FUNCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "abs": np.abs,
    "sqrt": np.sqrt,
    "exp": np.exp,
    "log": np.log,
    "sin": np.sin,
    "cos": np.cos,
    "tan": np.tan,
    "tanh": np.tanh,
    "sign": np.sign,
}
_VARIADIC_FUNCTIONS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "min": np.minimum,
    "max": np.maximum,
}
_CONSTANTS = {"pi": math.pi}
_BINARY = {
    ast.Add: np.add,
    ast.Sub: np.subtract,
    ast.Mult: np.multiply,
    ast.Div: np.divide,
    ast.Pow: np.power,
}
_BINARY_SYMBOL = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}

_Node = Callable[[Sequence[np.ndarray]], "np.ndarray | float"]

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
    _fn: _Node

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

    @property
    def is_constant(self) -> bool:
        return not self.used


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
    try:
        tree = ast.parse(text.strip(), mode="eval")
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
    nodes, depth = _size(tree.body)
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
    compiler = _Compiler(text, variables, where)
    try:
        fn, _ = compiler.visit(tree.body)
    except RecursionError:
        raise QcontrolInputError(
            f"{where}: expression {_show(text)} is too deeply nested; simplify it"
        ) from None
    return Expression(text, variables, frozenset(compiler.used), fn)


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


class _Compiler:
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
        names = list(self.variables) + list(_CONSTANTS) + list(_UNARY_FUNCTIONS) + list(
            _VARIADIC_FUNCTIONS
        )
        return ", ".join(names)

    def visit(self, node: ast.AST) -> tuple[_Node, float | None]:
        """Return (closure, constant value or None)."""
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise self.fail("too many terms", f"keep expressions under {MAX_NODES} nodes")
        if isinstance(node, ast.Constant):
            value = node.value
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise self.fail(f"literal {_cut(repr(value))} is not a real number", "use plain numbers")
            try:
                as_float = float(value)
            except OverflowError:
                raise self.fail(f"number {_cut(str(value))} is too large", "use a finite number") from None
            if not math.isfinite(as_float):
                raise self.fail(f"number {value!r} is not finite", "use a finite number")
            return self._constant(as_float)
        if isinstance(node, ast.Name):
            return self._name(node.id)
        if isinstance(node, ast.UnaryOp):
            if not isinstance(node.op, (ast.USub, ast.UAdd)):
                raise self.fail(
                    f"operator {type(node.op).__name__} is not allowed", "use only unary + or -"
                )
            inner, value = self.visit(node.operand)
            if isinstance(node.op, ast.UAdd):
                return inner, value
            if value is not None:
                return self._constant(-value)
            return (lambda cols: np.negative(inner(cols))), None
        if isinstance(node, ast.BinOp):
            return self._binop(node)
        if isinstance(node, ast.Call):
            return self._call(node)
        description = _FORBIDDEN_DESCRIPTIONS.get(type(node), f"'{type(node).__name__}' syntax")
        raise self.fail(
            f"{description} is not allowed",
            "use numbers, variables, + - * / ** and the allowed functions",
        )

    def _constant(self, value: float) -> tuple[_Node, float]:
        return (lambda cols: value), value

    def _name(self, name: str) -> tuple[_Node, float | None]:
        if name in self.index:
            i = self.index[name]
            self.used.add(name)
            return (lambda cols: cols[i]), None
        if name in _CONSTANTS:
            return self._constant(_CONSTANTS[name])
        if name in _UNARY_FUNCTIONS or name in _VARIADIC_FUNCTIONS:
            raise self.fail(f"function {_show(name)} used without a call", f"write {name}(...)")
        raise self.fail(f"unknown name {_show(name)}", f"allowed names are {self.allowed_names()}")

    def _binop(self, node: ast.BinOp) -> tuple[_Node, float | None]:
        op_type = type(node.op)
        if op_type not in _BINARY:
            raise self.fail(
                f"operator {type(node.op).__name__} is not allowed", "use only + - * / **"
            )
        left, lval = self.visit(node.left)
        right, rval = self.visit(node.right)
        symbol = _BINARY_SYMBOL[op_type]
        if op_type is ast.Pow and rval is not None and abs(rval) > MAX_CONSTANT_EXPONENT:
            raise self.fail(
                f"exponent {rval:g} is too large",
                f"keep constant exponents within +-{MAX_CONSTANT_EXPONENT:g}",
            )
        if op_type is ast.Div and rval == 0.0:
            raise self.fail("division by zero", "divide by a non-zero number")
        fn = _BINARY[op_type]
        if lval is not None and rval is not None:
            with np.errstate(all="raise"):
                try:
                    value = float(fn(np.float64(lval), np.float64(rval)))
                except (FloatingPointError, OverflowError, ZeroDivisionError):
                    raise self.fail(
                        f"constant part {lval:g} {symbol} {rval:g} is not a finite real number",
                        "fix the constant",
                    ) from None
            if not math.isfinite(value):
                raise self.fail(
                    f"constant part {lval:g} {symbol} {rval:g} is not finite", "fix the constant"
                )
            return self._constant(value)
        if op_type is ast.Pow and rval == 2.0:
            return (lambda cols: np.square(left(cols))), None
        return (lambda cols: fn(left(cols), right(cols))), None

    def _call(self, node: ast.Call) -> tuple[_Node, float | None]:
        if not isinstance(node.func, ast.Name):
            raise self.fail("only calls of plain function names are allowed", "e.g. sin(x1)")
        name = node.func.id
        if node.keywords:
            raise self.fail(f"keyword arguments to {name}() are not allowed", "pass values only")
        if any(isinstance(arg, ast.Starred) for arg in node.args):
            raise self.fail(f"'*' unpacking in {name}() is not allowed", "pass values only")
        if name in _UNARY_FUNCTIONS:
            if len(node.args) != 1:
                raise self.fail(
                    f"{name}() takes exactly 1 argument, got {len(node.args)}", f"write {name}(x1)"
                )
            fn = _UNARY_FUNCTIONS[name]
            inner, value = self.visit(node.args[0])
            if value is not None:
                with np.errstate(all="ignore"):
                    folded = float(fn(np.float64(value)))
                if not math.isfinite(folded):
                    raise self.fail(f"{name}({value:g}) is not finite", "fix the constant")
                return self._constant(folded)
            return (lambda cols: fn(inner(cols))), None
        if name in _VARIADIC_FUNCTIONS:
            if len(node.args) < 2:
                raise self.fail(f"{name}() needs at least 2 arguments", f"write {name}(a, b)")
            fn2 = _VARIADIC_FUNCTIONS[name]
            parts = [self.visit(arg)[0] for arg in node.args]

            def reduce(cols: Sequence[np.ndarray]) -> np.ndarray:
                result = parts[0](cols)
                for part in parts[1:]:
                    result = fn2(result, part(cols))
                return result

            return reduce, None
        if name in self.index or name in _CONSTANTS:
            raise self.fail(f"{_show(name)} is not a function", f"allowed names are {self.allowed_names()}")
        raise self.fail(f"unknown function {_show(name)}", f"allowed names are {self.allowed_names()}")
