"""Quantizer of eq. (3) and property (4), checked with hypothesis."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qcontrol.errors import QcontrolInputError
from qcontrol.quantizer import QuantizedReading, UniformQuantizer, quantize

deltas = st.floats(min_value=1e-4, max_value=10.0, allow_nan=False)
xs = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


def _slack(x: float, delta: float) -> float:
    """Floating-point slack for x/delta rounding at large |x|."""
    return 4 * np.finfo(float).eps * (abs(x) + delta)


@settings(max_examples=400, deadline=None)
@given(delta=deltas, x=xs)
def test_error_bound_property_4(delta: float, x: float) -> None:
    q = UniformQuantizer(delta)(np.array([x]))[0]
    assert abs(q - x) <= delta / 2 + _slack(x, delta)


@settings(max_examples=300, deadline=None)
@given(delta=deltas, x=xs)
def test_idempotent(delta: float, x: float) -> None:
    quant = UniformQuantizer(delta)
    once = quant(np.array([x]))
    assert np.array_equal(quant(once), once)


@settings(max_examples=300, deadline=None)
@given(delta=deltas, x=xs)
def test_level_membership(delta: float, x: float) -> None:
    """q(x) = l delta with (2l-1) delta/2 <= x < (2l+1) delta/2 (eq. (3))."""
    q = UniformQuantizer(delta)(np.array([x]))[0]
    level = q / delta
    assert abs(level - round(level)) < 1e-6
    level_index = round(level)
    slack = _slack(x, delta)
    assert (2 * level_index - 1) * delta / 2 - slack <= x < (2 * level_index + 1) * delta / 2 + slack


@settings(max_examples=300, deadline=None)
@given(delta=deltas, x=xs)
def test_odd_symmetry_away_from_boundaries(delta: float, x: float) -> None:
    frac = x / delta - 0.5 - math.floor(x / delta - 0.5)
    if min(frac, 1 - frac) < 1e-6:  # within rounding of a half-step boundary
        return
    quant = UniformQuantizer(delta)
    assert quant(np.array([-x]))[0] == -quant(np.array([x]))[0]


def test_mid_tread_levels_by_hand() -> None:
    """Binary-exact step 0.25: levels switch at +-0.125, +-0.375; intervals are [lower, upper)."""
    quant = UniformQuantizer(0.25)
    x = np.array([0.0, 0.1249, 0.125, 0.3749, 0.375, -0.125, -0.1251, -0.375, -0.3751])
    expected = np.array([0.0, 0.0, 0.25, 0.25, 0.5, 0.0, -0.25, -0.25, -0.5])
    np.testing.assert_array_equal(quant(x), expected)


def test_quantize_carries_the_bound() -> None:
    reading = quantize(UniformQuantizer(0.02), np.array([[0.013, -0.5]]))
    assert isinstance(reading, QuantizedReading)
    assert reading.max_error == 0.01
    np.testing.assert_allclose(reading.values, [[0.02, -0.5]])


@pytest.mark.parametrize("delta", [0.0, -0.1, float("nan"), float("inf")])
def test_bad_delta(delta: float) -> None:
    with pytest.raises(QcontrolInputError, match="delta"):
        UniformQuantizer(delta)
