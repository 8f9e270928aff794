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
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

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

    def on_floats(self, values: Sequence[float]) -> float:
        """Evaluate on plain floats, ``values[i]`` = ``variables[i]``: the same expression through
        ``math`` (:func:`scalar_function`), a few tens of nanoseconds per operation instead of a
        microsecond. Where ``math`` refuses (a domain error, an overflow), numpy's value (NaN,
        Inf) is returned, so both evaluations agree everywhere up to the last bit."""
        try:
            return self._scalar_fn(values)
        except (ValueError, ZeroDivisionError, OverflowError):
            with np.errstate(all="ignore"):
                return float(self._fn(values))

    @cached_property
    def _scalar_fn(self) -> ScalarFn:
        return scalar_function(self)

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


# --------------------------------------------------------------------------------------------
# The same expressions on plain floats (hot loops of a batch of one, MuJoCo's passive callback)

_SCALAR_FUNCTIONS: dict[str, Callable[[float], float]] = {
    "abs": abs, "sqrt": math.sqrt, "exp": math.exp, "log": math.log, "sin": math.sin,
    "cos": math.cos, "tan": math.tan, "tanh": math.tanh,
    "sign": lambda a: a if a != a else (1.0 if a > 0 else -1.0 if a < 0 else 0.0),  # NaN stays NaN
}
ScalarFn = Callable[[Sequence[float]], float]


def scalar_function(expression: Expression) -> ScalarFn:
    """A plain-float version of a (validated) :class:`Expression`: ``f((x1, x2)) -> float``.

    A numpy call on a scalar costs about a microsecond, the same operation on floats a few tens of
    nanoseconds, so hot loops on one copy (MuJoCo's passive callback, a batch of one) use ``math``
    instead. Domain errors raise (the caller decides; :meth:`Expression.on_floats` falls back to
    numpy's answer). ``sin``, ``exp``, ... may differ from numpy's in the last bit.
    """
    index = {name: i for i, name in enumerate(expression.variables)}
    fn, _ = _scalar(ast.parse(expression.source.strip(), mode="eval").body, index)
    return fn


def _scalar(node: ast.AST, index: dict[str, int]) -> tuple[ScalarFn, float | None]:
    if isinstance(node, ast.Constant):
        value = float(node.value)
        return (lambda xs: value), value
    if isinstance(node, ast.Name):
        if node.id in index:
            i = index[node.id]
            return (lambda xs: xs[i]), None
        value = math.pi  # the only constant the expression language knows
        return (lambda xs: value), value
    if isinstance(node, ast.UnaryOp):
        inner, value = _scalar(node.operand, index)
        if isinstance(node.op, ast.UAdd):
            return inner, value
        if value is not None:
            return (lambda xs: -value), -value
        return (lambda xs: -inner(xs)), None
    if isinstance(node, ast.BinOp):
        left, lv = _scalar(node.left, index)
        right, rv = _scalar(node.right, index)
        op = type(node.op)
        li, ri = _variable(node.left, index), _variable(node.right, index)
        if (op in _ARITHMETIC and (lv is None) != (rv is None)) or (li is not None and ri is not None):
            # a constant or a variable on either side: read it directly (one call per node)
            return _leaf_arithmetic(_ARITHMETIC[op] if op in _ARITHMETIC else None, node, left, lv, li,
                                    right, rv, ri), None
        if op is ast.Pow and rv == 2.0 and li is not None:
            return (lambda xs: xs[li] * xs[li]), None  # like np.square, exactly
        if op is ast.Add:
            fn: ScalarFn = lambda xs: left(xs) + right(xs)  # noqa: E731
        elif op is ast.Sub:
            fn = lambda xs: left(xs) - right(xs)  # noqa: E731
        elif op is ast.Mult:
            fn = lambda xs: left(xs) * right(xs)  # noqa: E731
        elif op is ast.Div:
            fn = lambda xs: left(xs) / right(xs)  # noqa: E731
        elif rv == 2.0:
            def fn(xs: Sequence[float]) -> float:
                a = left(xs)
                return a * a  # like np.square, exactly
        else:
            fn = lambda xs: math.pow(left(xs), right(xs))  # noqa: E731
        if lv is not None and rv is not None:
            value = fn(())
            return (lambda xs: value), value
        return fn, None
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        parts = [_scalar(arg, index)[0] for arg in node.args]
        name = node.func.id
        if name in ("min", "max"):
            pick = min if name == "min" else max

            def reduce(xs: Sequence[float]) -> float:
                values = [p(xs) for p in parts]
                return math.nan if any(v != v for v in values) else pick(values)

            return reduce, None
        f, arg = _SCALAR_FUNCTIONS[name], parts[0]
        i = _variable(node.args[0], index)
        if i is not None:
            return (lambda xs: f(xs[i])), None
        return (lambda xs: f(arg(xs))), None
    raise ValueError(f"unexpected syntax in a validated expression: {ast.dump(node)}")


_ARITHMETIC = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
}


def _variable(node: ast.AST, index: dict[str, int]) -> int | None:
    """The position of a variable node in ``xs``, or None."""
    return index.get(node.id) if isinstance(node, ast.Name) else None


def _leaf_arithmetic(op: Callable[[float, float], float] | None, node: ast.BinOp, left: ScalarFn,
                     lv: float | None, li: int | None, right: ScalarFn, rv: float | None,
                     ri: int | None) -> ScalarFn:
    """``left op right`` where one side is a constant or both are variables, without a call per
    leaf. ``op`` is None for ``**`` (then both sides are variables: ``math.pow``)."""
    if op is None:
        return lambda xs: math.pow(xs[li], xs[ri])
    if lv is not None:
        return (lambda xs: op(lv, xs[ri])) if ri is not None else (lambda xs: op(lv, right(xs)))
    if rv is not None:
        return (lambda xs: op(xs[li], rv)) if li is not None else (lambda xs: op(left(xs), rv))
    return lambda xs: op(xs[li], xs[ri])
