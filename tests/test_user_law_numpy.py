"""A ``qcontrol.Law`` written with numpy the documented way (``float()``, ``np.array`` of values,
``@`` of vectors, numpy and ``math`` functions of one value, ``quantized_backstepping``) is
traced: each construct's recorded lines give the law's own Python results bit for bit (the
compiled loop runs those lines: tests/test_user_law_compiled.py; the one new operation of a
compiled line, the fused multiply-add, is checked here). A construct numpy computes differently
(its own tanh, a matrix product, ``**``) is refused, with its reason."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

import qcontrol
from qcontrol.controller.user import UserLaw
from qcontrol.engine import user_trace
from qcontrol.engine.user_numpy import fma, same_as_math

C = [4.0, 3.0]


class Base:
    state_size = 3

    def __init__(self, table: dict, n: int) -> None:
        self.c, self.gain = list(table["c"]), np.array([0.5, -0.25, 0.125])

    def initial_state(self) -> np.ndarray:
        return np.array([0.1, -0.2, 0.3])

    def control(self, t, x_q, yd, state):
        return float(qcontrol.quantized_backstepping(self.c, x_q, yd)[1][-1] - 0.5 * state[0])

    def state_rate(self, t, x_q, yd, state):
        return np.array([x_q[0] - yd[0], x_q[1] * state[0], -state[2]])


class Floated(Base):
    """float() of traced values, of a 0-d array, isinstance against float."""

    def control(self, t, x_q, yd, state):
        assert isinstance(1.5, float)
        return float(x_q[0]) * float(np.asarray(state[1])) + float(t) - 2.0 * x_q[1]


class Vectors(Base):
    """np.array/np.asarray of traced values: a vector meeting a value, constants and the inputs."""

    def control(self, t, x_q, yd, state):
        r = np.array([1 + x_q[1] * x_q[1], x_q[0] * 2.0, yd[1]])
        s = x_q[0] * x_q[0] / 3.0 + 0.7
        v = s * r - 0.5 * state + self.gain * np.asarray([state[2], state[0], x_q[1]])
        return v[0] - v[1] / 4.0 + (r / s)[2]

    def advance(self, t, x_q, yd, state, h):
        target = (x_q[0] * x_q[0] + 1.0) * np.array([1.0 + x_q[1] * x_q[1], 2.0, yd[0]]) / 0.3
        return target + (state - target) * math.exp(-0.8 * h)


class Products(Base):
    """``@``, np.dot and ndarray.dot of vectors (numpy's fused multiply-adds)."""

    def control(self, t, x_q, yd, state):
        r = np.array([1 + x_q[1] * x_q[1], x_q[0], 1.0])
        return float(state @ r) - np.dot(self.gain, state) * x_q[1] + x_q.dot(yd[:2]) + r @ r

    def state_rate(self, t, x_q, yd, state):
        return -state * (np.array([x_q[0], x_q[1], yd[0]]) @ np.array([x_q[1], 1.5, x_q[0]]))


class Functions(Base):
    """numpy's sqrt, sin and cos and math's of one traced value (recorded as math's)."""

    def control(self, t, x_q, yd, state):
        return np.sqrt(x_q[0] * x_q[0] + 1.0) + np.sin(x_q[1]) * np.cos(state[0]) + math.atan(x_q[0]) \
            + math.exp(-t) + np.sqrt(np.array([x_q[1] * x_q[1], 2.0]))[0]


class Backstepping(Base):
    """The documented numpy law (docs/laws.md, section 1): quantized_backstepping and float()."""


@pytest.mark.parametrize("law", [Floated, Vectors, Products, Functions, Backstepping])
def test_each_numpy_construct_traces_to_lines_equal_to_its_python(law, monkeypatch) -> None:
    if law is Functions and not (same_as_math(np.sin) and same_as_math(np.cos)):
        pytest.skip("numpy's sin or cos rounds differently from math's on this machine")
    user = UserLaw([law({"c": C}, 2)], C, 0.005, "eps", "x")
    assert user_trace.explain(user, 2, 1e-3) is None, user.compiled_form
    traces, _ = user_trace.trace_law(user, 2, 1e-3)
    monkeypatch.setattr(user_trace, "CHECKS", 40)  # 40 samples, bit for bit (u and the state on)
    assert user_trace.checked(traces[0], user.laws[0], user, 1e-3, 40) is None


class NumpyTanh(Base):
    def control(self, t, x_q, yd, state):
        return np.tanh(x_q[0]) - x_q[1]


class MatrixProduct(Base):
    def control(self, t, x_q, yd, state):
        return (np.array([[4.0, 3.0], [1.0, 0.0]]) @ x_q)[0]


class Squared(Base):
    def control(self, t, x_q, yd, state):
        return x_q[0] ** 2


class FilledArray(Base):
    def control(self, t, x_q, yd, state):
        filled = np.zeros(2)
        filled[0] = x_q[0]
        return filled[0]


@pytest.mark.parametrize(("law", "why"), [
    (NumpyTanh, "numpy's tanh on a value computed from its inputs (numpy's rounds differently"),
    (MatrixProduct, "matrix product of shapes (2, 2) and (2,)"), (FilledArray, "converts a value"),
    (Squared, "to a power with **"),
])
def test_what_numpy_computes_its_own_way_is_refused_with_its_reason(law, why) -> None:
    if law is NumpyTanh and same_as_math(np.tanh):
        pytest.skip("numpy's tanh equals math's on this machine")
    user = UserLaw([law({"c": C}, 2)], C, 0.005, "eps", "x")
    assert why in user_trace.explain(user, 2, 1e-3)


def test_numpy_tanh_differs_from_maths_where_the_probe_says_so() -> None:
    """The refusal above is real: somewhere numpy's float64 tanh is not math's."""
    if same_as_math(np.tanh):
        pytest.skip("numpy's tanh equals math's on this machine")
    x = np.random.default_rng(0).normal(0, 3, 2000)
    assert any(float(np.tanh(v)) != math.tanh(v) for v in x.tolist())


def test_fma_rounds_once() -> None:
    """Python's fma (Dekker's product, fsum) and the compiled one equal exact rounding, edges included."""
    from numba import njit

    from qcontrol.engine.user_numpy import compiled_fma

    fused = compiled_fma()
    compiled = njit(lambda a, b, c: fused(a, b, c))
    e = 2.0 ** -30
    cases = [(1 + e, 1 + e, -(1 + 2 * e)), (-0.0, 1.0, -0.0), (0.0, -1.0, 0.0), (1e-200, 1e-200, 1e-300),
             (1e300, 1e10, -1e308), (5e-324, 0.5, 0.0), (3.0, 1 / 3, -1.0), (1e308, 10.0, 0.0)]
    rng = np.random.default_rng(1)
    cases += [tuple(rng.normal(0, 1, 3) * 10.0 ** rng.integers(-5, 5, 3)) for _ in range(200)]
    for a, b, c in cases:
        try:
            exact = float(Fraction(a) * Fraction(b) + Fraction(c))
        except OverflowError:
            exact = math.copysign(math.inf, a * b)
        if exact == 0.0:
            exact = a * b + c  # the sign of an exact zero: the IEEE sum's
        for got in (fma(a, b, c), compiled(a, b, c)):
            assert got == exact and math.copysign(1, got) == math.copysign(1, exact), (a, b, c)


def test_quantized_backstepping_rows_equal_single_readings_and_the_recursion() -> None:
    rng = np.random.default_rng(2)
    q, yd = rng.normal(0, 1, (6, 3)), rng.normal(0, 1, 4)
    zbar, alphabar = qcontrol.quantized_backstepping([4.0, 3.0, 2.0], q, yd)
    law = qcontrol.BacksteppingLaw([4.0, 3.0, 2.0], 0.1)
    for row in range(6):
        z, a = qcontrol.quantized_backstepping([4.0, 3.0, 2.0], q[row], yd)
        assert z.tobytes() == zbar[row].tobytes() and a.tobytes() == alphabar[row].tobytes()
        assert [z.tolist(), a.tolist()] == [list(v) for v in law.recursion(q[row].tolist(), yd.tolist())]
        by_matrices = law.quantized_errors(q[row], yd)  # the coefficients' product: the same to rounding
        assert np.allclose(np.concatenate(by_matrices), np.concatenate([z, a]), rtol=1e-13, atol=1e-13)
