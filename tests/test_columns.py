"""The two column forms: the array form every part serves and the engine's float form give the same
numbers for every member a formula uses, and MuJoCo's one-pass observe reads what its state and
sensors read."""

import math

import numpy as np
import pytest
from conftest import EX2

from qcontrol.assembly import build_plant
from qcontrol.columns import ARRAYS
from qcontrol.engine.fastpath import FLOATS
from qcontrol.expr import compile_expression
from qcontrol.scenario import load_scenario

X2 = ("x1", "x2")
SOURCES = ("x2", "x2**2*cos(x1)", "sin(x1)", "sqrt(x1) + log(x2)", "2.5")
EXPRESSIONS = [compile_expression(e, X2) for e in SOURCES]


def test_terms_and_combinations_agree_in_both_forms() -> None:
    rng = np.random.default_rng(11)
    rows = rng.uniform(-3, 3, (200, 2))
    coefficients = [None, -0.5, 2.0, 1.5, -1.0]  # None: the term as it is (psi)
    with np.errstate(all="ignore"):
        on_arrays = ARRAYS.terms(EXPRESSIONS)(ARRAYS.columns(rows))
        combined = ARRAYS.combination(EXPRESSIONS, coefficients)(ARRAYS.columns(rows))
    floats_terms, floats_combined = FLOATS.terms(EXPRESSIONS), FLOATS.combination(EXPRESSIONS, coefficients)
    for b, row in enumerate(rows):
        values = floats_terms(FLOATS.columns(row[None, :]))
        assert all(type(v) is float for v in values)
        for v, expected in zip(values, on_arrays, strict=True):
            expected = float(np.broadcast_to(expected, (len(rows),))[b])
            assert v == pytest.approx(expected, rel=1e-14) or (math.isnan(v) and math.isnan(expected))
        by_hand = values[0] - 0.5 * values[1] + 2.0 * values[2] + 1.5 * values[3] - 1.0 * values[4]
        got = floats_combined(row.tolist())
        assert got == by_hand or (math.isnan(got) and math.isnan(by_hand))  # same order, same bits
        assert got == pytest.approx(float(combined[b]), rel=1e-13) or math.isnan(got)


def test_where_math_refuses_the_float_form_takes_numpys_answer() -> None:
    terms = FLOATS.terms(EXPRESSIONS)
    values = terms([-1.0, 0.0])  # sqrt(-1) and log(0): math raises, numpy gives NaN and -inf
    assert math.isnan(values[3]) and values[0] == 0.0 and values[2] == math.sin(-1.0)
    assert FLOATS.combination(EXPRESSIONS[3:4], [2.0])([1.0, 0.0]) == -math.inf


def test_parameters_columns_and_arrays_convert_both_ways() -> None:
    assert FLOATS.column(2.5) == 2.5 and type(FLOATS.column(np.array([2.5]))) is float
    with pytest.raises(ValueError, match="2 per-copy values for a batch of one"):
        FLOATS.column(np.array([1.0, 2.0]))
    per_copy = np.array([1.0, 2.0, 3.0])
    assert ARRAYS.column(per_copy) is per_copy and ARRAYS.column(1.5) == 1.5
    rows = np.arange(6.0).reshape(3, 2)
    np.testing.assert_array_equal(ARRAYS.array(ARRAYS.columns(rows), 3), rows)
    assert FLOATS.columns(rows[:1]) == [0.0, 1.0]
    np.testing.assert_array_equal(FLOATS.array([0.0, 1.0], 1), rows[:1])
    assert FLOATS.array((), 1).shape == (1, 0) and ARRAYS.array((), 3).shape == (3, 0)
    np.testing.assert_array_equal(ARRAYS.array([np.array([1.0, 2.0]), 5.0], 2), [[1.0, 5.0], [2.0, 5.0]])
    assert FLOATS.expm1 is math.expm1 and ARRAYS.expm1 is np.expm1


def _noisy_mujoco(batch: int):
    sc = load_scenario(EX2, ["plant.mujoco.sensor_noise=[0.01, 0.05]", "plant.mujoco.noise_seed=4"])
    return build_plant(sc, "mujoco", batch=batch)


@pytest.mark.parametrize("batch", [1, 2])
def test_mujoco_observe_reads_its_state_and_sensors_in_one_pass(batch: int) -> None:
    one, other = _noisy_mujoco(batch), _noisy_mujoco(batch)
    x0 = np.array([[0.5, -0.2]] * batch)
    with one, other:
        for plant in (one, other):
            plant.reset(x0)
        for _ in range(5):
            x, reading = one.observe()
            np.testing.assert_array_equal(x, other.state())
            np.testing.assert_array_equal(reading, other.read_sensors())  # the same noise draw
            assert not np.array_equal(reading, x)  # the noise is there
            for plant in (one, other):
                plant.step(np.full(batch, 0.3), 1e-3)
        if one._threads:  # the threaded batch reads its copies in compiled code, marks its own dead
            return
        one._dead[0] = other._dead[0] = True  # a copy MuJoCo reported unstable reads NaN
        x, reading = one.observe()
        assert np.isnan(x[0]).all() and np.isnan(reading[0]).all()
        np.testing.assert_array_equal(reading, other.read_sensors())
