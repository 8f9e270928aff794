"""The third generator: a validated tree -> Python source text on plain floats, for numba.

The text computes exactly what :func:`~qcontrol.expr.generators.float_closure` computes, with
the same folding of constants and the same operations in the same order (``x**2`` a product,
``**`` ``math.pow``, ``sign``/``min``/``max``/``spow`` as their plain-float rows, ``cbrt`` as
numpy's, which is libm's as ``math.cbrt`` is: numba has no ``math.cbrt``). Where the closure
would raise (``math``'s domain and overflow errors, a division by zero), the generated code
cannot; it sets a flag instead, :data:`FLAG`, which the caller turns into the closure's caller's
answer (NaN for MuJoCo's passive force). CPython's rule for the ``math`` functions: an error
when the result is NaN from a non-NaN argument or infinite from a finite one; for ``math.pow``
when the result is not finite from finite arguments.
"""

from __future__ import annotations

import ast
import math

from .operations import NAMED, OPERATORS, POWER, Operation
from .tree import Apply, Number, Tree, Variable

FLAG = "bad"  # the generated statements' error flag (a bool the caller initialises to False), set
# with | and & rather than or/and: no branch per test, less for numba to compile
_MATH = {"sqrt", "exp", "log", "sin", "cos", "tan", "tanh"}  # CPython's math_1 functions


class Statements:
    """Source lines computing subexpressions into temporaries ``{prefix}{i}``."""

    def __init__(self, prefix: str) -> None:
        self.prefix, self.lines, self._count = prefix, [], 0

    def temporary(self, value: str) -> str:
        name = f"{self.prefix}{self._count}"
        self._count += 1
        self.lines.append(f"{name} = {value}")
        return name


def float_source(tree: Tree, variables: list[str], out: Statements) -> str:
    """The source of ``tree`` (its variables named ``variables[i]``): a literal, a variable or a
    temporary whose lines are appended to ``out``."""
    text, _ = _part(tree, variables, out)
    return text


def operation_source(row: Operation, operands: list[str], out: Statements) -> str:
    """``row`` (not a constant) on operands given as source (names or temporaries, never folded),
    written as :func:`float_source` writes it: the float evaluation's operations, flagged where
    they would raise. A program of shared trees is written step by step with it
    (:func:`qcontrol.compiled.traced.evaluate_program`)."""
    parts = [(text, None) for text in operands]
    if row.arity == 1:
        return _unary(row, parts[0], out)[0]
    if row.arity == 2:
        return _binary(row, parts[0], parts[1], out)[0]
    return _variadic(row, operands, out)


def _literal(value: float) -> tuple[str, float]:
    return (f"({value!r})" if math.isfinite(value) else f"float({str(value)!r})"), value


def _part(node: Tree, names: list[str], out: Statements) -> tuple[str, float | None]:
    """(source, the constant's value or None), as ``float_part`` (values fold where it folds)."""
    if isinstance(node, Number):
        return _literal(node.constant)
    if isinstance(node, Variable):
        return names[node.index], None
    assert isinstance(node, Apply)
    row = node.operation
    if row.arity == 0:
        return _literal(row.on_floats())
    parts = [_part(operand, names, out) for operand in node.operands]
    if row.arity == 1:
        return _unary(row, parts[0], out)
    if row.arity == 2:
        return _binary(row, parts[0], parts[1], out)
    return _variadic(row, [text for text, _ in parts], out), None


def _unary(row: Operation, operand: tuple[str, float | None], out: Statements) -> tuple[str, float | None]:
    text, value = operand
    if row.is_operator:  # unary minus
        return _literal(row.on_floats(value)) if value is not None else (out.temporary(f"-{text}"), None)
    if row.name == "abs":
        return out.temporary(f"abs({text})"), None
    if row.name == "sign":
        return _sign(out.temporary(text), out), None
    if row.name == "cbrt":  # defined everywhere: math.cbrt never raises
        return out.temporary(f"np.cbrt({text})"), None
    assert row.name in _MATH, row.name
    a = out.temporary(text)
    r = out.temporary(f"math.{row.name}({a})")
    out.lines.append(f"{FLAG} = {FLAG} | (({r} != {r}) & ({a} == {a})) "
                     f"| (math.isinf({r}) & math.isfinite({a}))")
    return r, None


def _binary(row: Operation, left: tuple[str, float | None], right: tuple[str, float | None],
            out: Statements) -> tuple[str, float | None]:
    (lt, lv), (rt, rv) = left, right
    if row is POWER and rv == 2.0:
        if lv is not None:
            return _literal(lv * lv)
        a = out.temporary(lt)
        return out.temporary(f"{a} * {a}"), None
    if lv is not None and rv is not None:
        return _literal(row.on_floats(lv, rv))
    if row is POWER:
        return _power(lt, rt, out), None
    if row.name == "spow":  # sign(a) * math.pow(abs(a), p), as its plain-float row
        a = out.temporary(lt)
        return out.temporary(f"{_sign(a, out)} * {_power(f'abs({a})', rt, out)}"), None
    if row.syntax is ast.Div:
        b = out.temporary(rt)
        out.lines.append(f"{FLAG} = {FLAG} | ({b} == 0.0)")
        return out.temporary(f"{lt} / {b}"), None
    symbol = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*"}[row.syntax]
    return out.temporary(f"{lt} {symbol} {rt}"), None


def _sign(a: str, out: Statements) -> str:
    """numpy's sign of the temporary ``a`` on a float: -1.0, 0.0 or 1.0, NaN for NaN."""
    return out.temporary(f"{a} if {a} != {a} else (1.0 if {a} > 0 else (-1.0 if {a} < 0 else 0.0))")


def _power(base: str, exponent: str, out: Statements) -> str:
    """``math.pow``, flagged where CPython's raises (a non-finite result of finite arguments). The
    exponent reaches it through ``opaque`` (:mod:`qcontrol.compiled.pointers`, which generated code
    imports): LLVM would compute a constant power 0.5 as a square root, -1 as a division, which
    libm's pow, that CPython's ``math.pow`` calls, does not always equal to the last bit."""
    b, e = out.temporary(base), out.temporary(exponent)
    r = out.temporary(f"math.pow({b}, opaque({e}))")
    out.lines.append(f"{FLAG} = {FLAG} | (math.isfinite({b}) & math.isfinite({e}) "
                     f"& (not math.isfinite({r})))")
    return r


def _variadic(row: Operation, texts: list[str], out: Statements) -> str:
    """``min``/``max``: NaN if any operand is NaN, else the first extreme value (Python's rule)."""
    values = [out.temporary(text) for text in texts]
    better = "<" if row.name == "min" else ">"
    pick = values[0]
    for value in values[1:]:
        pick = out.temporary(f"{value} if {value} {better} {pick} else {pick}")
    any_nan = " or ".join(f"{v} != {v}" for v in values)
    return out.temporary(f"math.nan if ({any_nan}) else {pick}")


assert {row.name for row in NAMED.values() if row.arity != 0} == _MATH | {"abs", "sign", "min", "max",
                                                                              "cbrt", "spow"}
assert set(OPERATORS) == {ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow, ast.USub}
