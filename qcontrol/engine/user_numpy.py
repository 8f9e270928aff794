"""numpy, ``float()`` and ``math`` on a traced user law's values: what of them a compiled line
restates bit for bit, recorded; the rest refused with its reason.

A traced law (:mod:`.user_trace`) computes on symbols. Where it writes its law with numpy the
way users do (``float(...)`` of a result, ``np.array([...])`` of values, ``np.tanh(x)``,
``state @ r``), the compiled line must give the float that numpy gives, to the last bit:

* ``float(v)`` is ``v`` (a float already, in the law's Python); ``np.array``/``np.asarray`` of a
  list holding traced values is a small traced vector (:class:`~.user_trace.TracedInputs`);
* elementwise ``+ - * /`` on such vectors and on single values is the float operation itself;
* a numpy function of one value (``np.exp``, ``np.tanh``, ...) is recorded as the ``math``
  function the compiled code calls only after :func:`same_as_math` found numpy's float64 results
  (for a single value and for short arrays, which numpy may hand to SIMD code that rounds its own
  way) equal to ``math``'s at every probe; ``math.<f>`` of a traced value is ``math.<f>`` itself;
* a product of two vectors (``a @ b``, ``np.dot``, ``a.dot(b)``) is numpy's own arithmetic
  written out: numpy adds ``0.0`` to BLAS's ``ddot``, which accumulates ``acc = fma(a_i, b_i,
  acc)`` from ``acc = 0.0`` (fused multiply-adds: one rounding each), used only for the lengths at
  which :func:`dot_model_holds` found it equal to numpy's ``@`` at every probe. Matrix products
  (numpy's ``gemv``/``gemm`` kernels) are refused.

The probes decide what is recorded; the check of :mod:`.user_trace` (the recorded lines run in
Python against the law's own Python at sample points, bit for bit) still decides whether the law
is compiled.
"""

from __future__ import annotations

import builtins
import contextlib
import math
import operator
import sys
import types
from collections.abc import Iterator, Sequence
from fractions import Fraction
from functools import cache
from typing import Any

import numpy as np

from ..compiled.traced import Symbol, Trace, current

_SPLIT = 134217729.0  # 2**27 + 1: Veltkamp's split of a double into two halves of 26 bits


def fma(a: float, b: float, c: float) -> float:
    """``a * b + c`` rounded once (IEEE fused multiply-add), in Python: the product's rounding
    error found exactly (Dekker's product), the three terms summed exactly by ``math.fsum``; out of
    that method's range (huge or tiny magnitudes) by exact rationals."""
    a, b, c = float(a), float(b), float(c)
    p = a * b
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c)):
        return p + c  # inf and NaN propagate as in the fused operation
    if p == 0.0 or c == 0.0:
        return p + c if p == 0.0 else p  # exact product 0 (a or b is 0), or nothing to add
    if 1e-280 < abs(p) < 1e280 and abs(a) < 1e290 and abs(b) < 1e290 and abs(c) < 1e300:
        t = _SPLIT * a
        ahi = t - (t - a)
        t = _SPLIT * b
        bhi = t - (t - b)
        alo, blo = a - ahi, b - bhi
        error = ((ahi * bhi - p) + ahi * blo + alo * bhi) + alo * blo  # a * b == p + error exactly
        return math.fsum((p, error, c))
    try:
        return float(Fraction(a) * Fraction(b) + Fraction(c))
    except OverflowError:
        return math.copysign(math.inf, p)


def _fma_codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
    from numba import types as nb

    values = [context.cast(builder, v, t, nb.float64) for v, t in zip(args, sig.args, strict=True)]
    return builder.fma(*values)


def _fma_typing(typingctx: Any, a: Any, b: Any, c: Any) -> tuple:
    from numba import types as nb

    return nb.float64(a, b, c), _fma_codegen


@cache
def compiled_fma() -> Any:
    """``fma(a, b, c)`` for numba: LLVM's fused multiply-add (one rounding, as :func:`fma`)."""
    from numba.extending import intrinsic

    return intrinsic(_fma_typing)


# ---- probes: where numpy's float64 arithmetic is the written-out line's ---------------------------

def _probe_values(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = rng.normal(0.0, 1.0, count) * 10.0 ** rng.uniform(-8, 3, count)
    special = [0.0, -0.0, 1.0, -1.0, 0.5, 2.0, 1e-300, -1e-300, 5e-324, 700.0, -745.0, 20.0, -20.0]
    return np.concatenate([special, values])


def same_bits(a: float, b: float) -> bool:
    """Whether two floats are the same to the bit (the sign of zero included; any NaN is any NaN)."""
    return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))


def dot_model(a: list, b: list) -> Any:
    """numpy's product of two float vectors as it computes it (module docstring)."""
    acc: Any = 0.0
    for x, y in zip(a, b, strict=True):
        acc = traced_fma(x, y, acc)
    return 0.0 + acc


@cache
def dot_model_holds(k: int) -> bool:
    """Whether numpy's ``a @ b`` of contiguous float64 vectors of length ``k`` equals
    :func:`dot_model` at every probe (random vectors, cancelling sums, zeros of both signs)."""
    if not 1 <= k <= 15:
        return False
    rng = np.random.default_rng(k)
    values = _probe_values(600 * k, k)
    for i in range(400):
        a, b = rng.choice(values, k), rng.choice(values, k)
        if i % 4 == 1:  # a sum that cancels: each term's rounding shows
            b = a[::-1] * rng.choice([-1.0, 1.0], k) * (1 + rng.normal(0, 1e-8, k))
        if i % 4 == 2:  # an exact product, then one whose rounding a fused step keeps: 2**-60, not 0
            a, b = np.zeros(k), np.zeros(k)
            a[0], b[0] = -(1.0 + 2.0 ** -29), 1.0
            a[-1], b[-1] = (1.0 + 2.0 ** -30), (1.0 + 2.0 ** -30)
        numpy_product = float(np.ascontiguousarray(a) @ np.ascontiguousarray(b))
        if not same_bits(numpy_product, dot_model(a.tolist(), b.tolist())):
            return False
    return True


# numpy functions of one value recorded as math's, and when math would refuse the value (a Python
# exception; numpy's NaN or Inf in compiled code) the refusal: the Python loop from that sample
_FUNCTIONS = {np.exp: ("exp", "not ({x} < 709.0)"), np.log: ("log", "not ({x} > 0.0)"),
              np.sqrt: ("sqrt", "{x} < 0.0"), np.sin: ("sin", "math.isinf({x})"),
              np.cos: ("cos", "math.isinf({x})"), np.tanh: ("tanh", None), np.arctan: ("atan", None),
              np.sinh: ("sinh", "not (abs({x}) < 709.0)"), np.cosh: ("cosh", "not (abs({x}) < 709.0)"),
              np.expm1: ("expm1", "not ({x} < 709.0)"), np.log1p: ("log1p", "not ({x} > -1.0)")}
_MATH_NAMES = {name: guard for name, guard in _FUNCTIONS.values()} | {"fabs": None}


@cache
def same_as_math(ufunc: np.ufunc) -> bool:
    """Whether numpy's ``ufunc`` on float64 gives ``math``'s result at every probe where ``math``
    answers, called as a law calls it: on a single value (numpy's scalar and Python's float) and
    on contiguous arrays of 1 to 16 values (where numpy may use SIMD code)."""
    name, _ = _FUNCTIONS[ufunc]
    function = getattr(math, name)
    values = _probe_values(4000, 7)
    wanted = []
    for v in values.tolist():
        try:
            wanted.append(function(v))
        except (ValueError, OverflowError):
            wanted.append(None)
    with np.errstate(all="ignore"):
        results = [ufunc(values).tolist(), [ufunc(v) for v in values[:600].tolist()],
                   [float(ufunc(v)) for v in values[600:1200]]]
        results += [ufunc(values[i:i + k]).tolist() for k in range(1, 17) for i in range(0, 4000, 97)]
    lengths = [(0, len(values)), (0, 600), (600, 1200)]
    lengths += [(i, i + k) for k in range(1, 17) for i in range(0, 4000, 97)]
    for (start, stop), got in zip(lengths, results, strict=True):
        for w, g in zip(wanted[start:stop], got, strict=False):
            if w is not None and not same_bits(w, float(g)):
                return False
    return True


# ---- recording ---------------------------------------------------------------------------------

def traced_fma(a: Any, b: Any, c: Any) -> Any:
    """``fma(a, b, c)``: a recorded line where any of them is traced, else the number."""
    if not any(isinstance(v, Symbol) for v in (a, b, c)):
        return fma(a, b, c)
    trace = current()
    return trace.assign(f"fma({trace.text(a)}, {trace.text(b)}, {trace.text(c)})")


def math_call(name: str, x: Any) -> Any:
    """``math.<name>(x)`` recorded, with its refusal where ``math`` would refuse ``x``."""
    trace = current()
    text = trace.text(x)
    guard = _MATH_NAMES[name]
    if guard is not None:
        trace.refuse_if(guard.format(x=text))
    return trace.assign(f"math.{name}({text})")


_ARITHMETIC = {np.add: operator.add, np.subtract: operator.sub, np.multiply: operator.mul,
               np.true_divide: operator.truediv, np.negative: operator.neg, np.positive: operator.pos}


def _one(ufunc: np.ufunc, args: tuple) -> Any:
    """``ufunc`` on single values, some of them traced."""
    if ufunc in _ARITHMETIC:  # numpy's numbers as Python's (the same float), so the symbol's operator runs
        return _ARITHMETIC[ufunc](*[a.item() if isinstance(a, np.generic) else a for a in args])
    if not any(isinstance(a, Symbol) for a in args):
        return ufunc(*args)
    if ufunc is np.absolute:
        return current().assign(f"abs({current().text(args[0])})")
    if ufunc in _FUNCTIONS and same_as_math(ufunc):
        return math_call(_FUNCTIONS[ufunc][0], args[0])
    if ufunc in _FUNCTIONS:
        name = _FUNCTIONS[ufunc][0]
        raise TypeError(f"numpy's {ufunc.__name__} on a value computed from its inputs (numpy's rounds "
                        f"differently from math's {name} here): write math.{name}(...) or an expression")
    raise TypeError(f"numpy's {ufunc.__name__} on a value computed from its inputs")


def ufunc_call(ufunc: np.ufunc, method: str, operands: tuple, kwargs: dict) -> Any:
    """A numpy ufunc meeting traced values (a traced vector or a single traced value)."""
    if method != "__call__" or kwargs:
        raise TypeError(f"numpy's {ufunc.__name__} ({method}) on a value computed from its inputs")
    if ufunc is np.matmul:
        return dot(*operands)
    if not any(isinstance(x, np.ndarray) for x in operands):
        return _one(ufunc, operands)
    arrays = [np.asarray(x) if isinstance(x, np.ndarray) else _boxed(x) for x in operands]
    shape = np.broadcast_shapes(*[a.shape for a in arrays])
    flat = [np.broadcast_to(a, shape).ravel().tolist() for a in arrays]
    values = [_one(ufunc, args) for args in zip(*flat, strict=True)]
    if not shape:
        return values[0]
    if any(isinstance(x, TracedInputs) for x in operands) or any(isinstance(v, Symbol) for v in values):
        return inputs(values).reshape(shape)
    return np.array(values).reshape(shape)


def _boxed(value: Any) -> np.ndarray:
    box = np.empty((), dtype=object)
    box[()] = value
    return box


def dot(a: Any, b: Any) -> Any:
    """``a @ b`` of two vectors as numpy computes it (:func:`dot_model`), where that holds."""
    a, b = np.asarray(a), np.asarray(b)
    if a.ndim != 1 or b.ndim != 1:
        raise TypeError(f"numpy's matrix product of shapes {a.shape} and {b.shape} on values computed "
                        "from its inputs (BLAS rounds it its own way): write the sums out")
    if a.shape != b.shape:
        raise ValueError(f"shapes {a.shape} and {b.shape} not aligned")
    if a.strides[0] != 8 or b.strides[0] != 8 or not dot_model_holds(a.shape[0]):
        raise TypeError(f"numpy's product of two vectors of {a.shape[0]} on values computed from its "
                        "inputs, which no compiled line restates here: write the sum out")
    return dot_model(a.tolist(), b.tolist())


# numpy functions on the inputs that a traced law may not call: reductions and products whose float
# results (pairwise sums, BLAS kernels) no sequence of + and * restates
_REFUSED_FUNCTIONS = {np.vdot, np.inner, np.sum, np.prod, np.mean, np.einsum,
                      np.tensordot, np.cumsum, np.cumprod, np.average, np.linalg.norm}


class TracedInputs(np.ndarray):
    """An object array of symbols given to a traced law (its inputs, and the vectors it makes of
    traced values): elementwise arithmetic, indexing, and the numpy of this module (a function of
    one value, a product of two vectors) recorded where a compiled line gives numpy's float; other
    ufuncs and numpy's reductions refuse (TypeError), so the law keeps the Python loop."""

    def __array_ufunc__(self, ufunc: Any, method: str, *inputs: Any, **kwargs: Any) -> Any:
        return ufunc_call(ufunc, method, inputs, kwargs)

    def __array_function__(self, func: Any, types: Any, args: Any, kwargs: Any) -> Any:
        if func is np.dot and not kwargs:
            return dot(*args)
        if func in _REFUSED_FUNCTIONS or func is np.dot:
            raise TypeError(f"numpy's {func.__name__} on a value computed from its inputs")
        return super().__array_function__(func, types, args, kwargs)

    def dot(self, other: Any) -> Any:  # type: ignore[override]  (numpy's own would sum objects)
        return dot(self, other)


def inputs(symbols: Sequence[Any]) -> TracedInputs:
    """A traced vector of ``symbols`` (traced values or numbers)."""
    array = np.empty(len(symbols), dtype=object)
    array[:] = list(symbols)
    return array.view(TracedInputs)


class UserSymbol(Symbol):
    """A symbol of a traced user law: as :class:`Symbol`, and numpy on it recorded or refused
    (:func:`ufunc_call`) instead of refused outright; with a traced vector, elementwise."""

    __slots__ = ()

    def __array_ufunc__(self, ufunc: np.ufunc, method: str, *inputs: Any, **kwargs: Any) -> Any:
        return ufunc_call(ufunc, method, inputs, kwargs)

    # with an array: NotImplemented, so the array's operator runs (elementwise, __array_ufunc__)
    def __add__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__add__(self, other)

    def __radd__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__radd__(self, other)

    def __sub__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__sub__(self, other)

    def __rsub__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__rsub__(self, other)

    def __mul__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__mul__(self, other)

    def __rmul__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__rmul__(self, other)

    def __truediv__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__truediv__(self, other)

    def __rtruediv__(self, other: Any) -> Any:
        return NotImplemented if isinstance(other, np.ndarray) else Symbol.__rtruediv__(self, other)



class UserTrace(Trace):
    """A :class:`Trace` whose new locals are :class:`UserSymbol`\\ s."""

    def assign(self, expression: str) -> UserSymbol:
        name = self.name()
        self.lines.append(f"{name} = {expression}")
        return UserSymbol(name)


# ---- the law's own names, while it is traced ---------------------------------------------------

class _FloatType(type):
    def __instancecheck__(cls, value: Any) -> bool:
        return isinstance(value, builtins.float)

    def __subclasscheck__(cls, kind: type) -> bool:
        return issubclass(kind, builtins.float)


class TracedFloat(builtins.float, metaclass=_FloatType):
    """``float`` in a traced law's module: a traced value (or a 0-d array of one) is itself."""

    def __new__(cls, value: Any = 0.0) -> Any:  # noqa: PYI034 (a float, or a traced value)
        if isinstance(value, np.ndarray) and value.shape == () and isinstance(value[()], Symbol):
            value = value[()]
        return value if isinstance(value, Symbol) else builtins.float(value)


class TracedNumpy(types.ModuleType):
    """numpy in a traced law's module: ``array``/``asarray`` of values holding a traced one make a
    traced vector; everything else is numpy's."""

    def __init__(self) -> None:
        super().__init__("numpy")

    def __getattr__(self, name: str) -> Any:
        return getattr(np, name)

    @staticmethod
    def array(value: Any, *args: Any, **kwargs: Any) -> Any:
        return _vector(np.array, value, args, kwargs)

    @staticmethod
    def asarray(value: Any, *args: Any, **kwargs: Any) -> Any:
        return _vector(np.asarray, value, args, kwargs)


def _vector(make: Any, value: Any, args: tuple, kwargs: dict) -> Any:
    if isinstance(value, list | tuple) and not args and not kwargs and value and any(
            isinstance(v, Symbol) for v in value) and not isinstance(value[0], list | tuple | np.ndarray):
        return inputs([v.item() if isinstance(v, np.ndarray) else v for v in value])
    made = make(value, *args, **kwargs)  # (dtype=float here is the traced float: an object array)
    return made.view(TracedInputs) if made.dtype == object else made  # its reductions refused


class TracedMath(types.ModuleType):
    """math in a traced law's module: its functions of one traced value recorded
    (:func:`math_call`), the rest math's."""

    def __init__(self) -> None:
        super().__init__("math")

    def __getattr__(self, name: str) -> Any:
        value = getattr(math, name)
        return MathFunction(name) if name in _MATH_NAMES else value


class MathFunction:
    """``math.<name>``: of a traced value recorded (:func:`math_call`), of a number math's."""

    def __init__(self, name: str) -> None:
        self.name, self.function = name, getattr(math, name)

    def __call__(self, x: Any) -> Any:
        return math_call(self.name, x) if isinstance(x, Symbol) else self.function(x)


_NAMES = {"numpy": TracedNumpy(), "math": TracedMath()}


@contextlib.contextmanager
def traced_names(law: Any) -> Iterator[None]:
    """While a law is traced, ``float``, numpy and math in the modules of its class (and its
    bases outside qcontrol) are the traced ones above; restored afterwards."""
    modules = {sys.modules.get(k.__module__) for k in type(law).__mro__}
    modules = [m for m in modules if m is not None and m.__name__.partition(".")[0] not in
               ("builtins", "qcontrol", "numpy", "abc", "typing")]
    saved = []
    try:
        for module in modules:
            names = vars(module)
            swaps = {"float": TracedFloat} | {k: _NAMES[v.__name__] for k, v in names.items()
                                               if v is np or v is math}
            saved.append((names, {k: names.get(k, _MISSING) for k in swaps}))
            names.update(swaps)
        yield
    finally:
        for names, before in saved:
            for k, v in before.items():
                if v is _MISSING:
                    names.pop(k, None)
                else:
                    names[k] = v


_MISSING = object()
