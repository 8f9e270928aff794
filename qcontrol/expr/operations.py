"""The expression language as one table: a row per operator, function and constant, with its numpy
and its plain-float implementation. The whitelist check, the messages listing what is allowed and
both code generators read it; adding a function is one row."""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

ScalarFn = Callable[[Sequence[float]], float]
ColumnsFn = Callable[[Sequence[np.ndarray]], "np.ndarray | float"]
# What ``math`` raises where numpy returns NaN or Inf (a domain error, a division by zero, an
# overflow): a float evaluation that raises one of these is answered by numpy instead.
FLOAT_REFUSED = (ValueError, ZeroDivisionError, OverflowError)



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
    # ``on_arrays`` gives ``on_floats``' value for every element, on every machine, and never
    # meets a value ``on_floats`` refuses: a correctly rounded IEEE operation (numpy's own
    # functions, e.g. exp, pow, or its min's sign of a zero, may round or pick otherwise)
    same_on_arrays: bool = False

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


def _signed_power_of_arrays(a: Any, p: Any) -> Any:
    """``spow(a, p) = sign(a) |a|**p``: a real power of a negative base (``a**(1/3)`` is NaN for
    a < 0; ``spow(a, 1/3)`` is the real cube root), odd in ``a``."""
    return np.sign(a) * np.power(np.abs(a), p)


def _signed_power_of_floats(a: float, p: float) -> float:
    """:func:`_signed_power_of_arrays` on plain floats, with the same operations."""
    return _sign_of_float(a) * math.pow(abs(a), p)


OPERATIONS: tuple[Operation, ...] = (
    Operation("+", 2, np.add, operator.add, ast.Add, lambda a, b: lambda xs: a(xs) + b(xs),
              same_on_arrays=True),
    Operation("-", 2, np.subtract, operator.sub, ast.Sub, lambda a, b: lambda xs: a(xs) - b(xs),
              same_on_arrays=True),
    Operation("*", 2, np.multiply, operator.mul, ast.Mult, lambda a, b: lambda xs: a(xs) * b(xs),
              same_on_arrays=True),
    Operation("/", 2, np.divide, operator.truediv, ast.Div, lambda a, b: lambda xs: a(xs) / b(xs)),
    Operation("**", 2, np.power, math.pow, ast.Pow),  # x**2 is a product in both generators
    Operation("-", 1, np.negative, operator.neg, ast.USub, lambda a: lambda xs: -a(xs), same_on_arrays=True),
    Operation("pi", 0, lambda: np.pi, lambda: math.pi, same_on_arrays=True),
    Operation("abs", 1, np.abs, abs, same_on_arrays=True),
    Operation("sqrt", 1, np.sqrt, math.sqrt),
    Operation("cbrt", 1, np.cbrt, math.cbrt),  # the real cube root, also of a negative number
    Operation("exp", 1, np.exp, math.exp),
    Operation("log", 1, np.log, math.log),
    Operation("sin", 1, np.sin, math.sin),
    Operation("cos", 1, np.cos, math.cos),
    Operation("tan", 1, np.tan, math.tan),
    Operation("tanh", 1, np.tanh, math.tanh),
    Operation("sign", 1, np.sign, _sign_of_float, same_on_arrays=True),
    Operation("min", None, np.minimum, _nan_or(min)),
    Operation("max", None, np.maximum, _nan_or(max)),
    Operation("spow", 2, _signed_power_of_arrays, _signed_power_of_floats),  # sign(a) |a|**p
)
OPERATORS = {row.syntax: row for row in OPERATIONS if row.is_operator}
NAMED = {row.name: row for row in OPERATIONS if not row.is_operator}  # in the order messages list them
POWER = OPERATORS[ast.Pow]
