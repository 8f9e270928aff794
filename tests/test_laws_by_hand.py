"""The paper's law (44)-(45) written by hand in each documented form of a user law (a
``qcontrol.Law`` advanced by RK4, a ``qcontrol.Law`` with its own exact ``advance``, a
column-form ``qcontrol.BacksteppingLaw`` subclass) computes the built-in law's numbers to 1e-12,
single run and batch, on both backends: the bench's user-law rows compare like with like."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from conftest import ROOT

import qcontrol
from qcontrol.assembly import build_law, build_plant, build_quantizer, build_reference
from qcontrol.engine import RunSpec, simulate
from qcontrol.timegrid import TimeGrid

sys.path.insert(0, str(ROOT / "tools"))
import laws_by_hand  # noqa: E402

SIGNALS = ("x", "x_q", "u", "adaptive")


@pytest.fixture(autouse=True, scope="module")
def registered() -> None:
    laws_by_hand.register()


def _close(mine: np.ndarray, builtin: np.ndarray, name: str) -> None:
    assert mine.shape == builtin.shape, name
    np.testing.assert_allclose(mine, builtin, rtol=0, atol=1e-12, err_msg=name)


def _pair(form: str, backend: str, duration: float) -> tuple[qcontrol.Result, qcontrol.Result]:
    base = qcontrol.load_scenario("example2", {"simulation.duration": duration})
    mine = base.with_overrides(laws_by_hand.overrides(base, form))
    return qcontrol.run(base, backend=backend), qcontrol.run(mine, backend=backend)


@pytest.mark.parametrize("form", laws_by_hand.FORMS)
def test_each_form_computes_the_built_in_numbers_on_the_ode(form: str) -> None:
    builtin, mine = _pair(form, "ode", 3.0)
    for name in SIGNALS:
        a, b = getattr(builtin, name), getattr(mine, name)
        assert a.shape == b.shape, name
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12, err_msg=name)
    assert np.max(np.abs(builtin.adaptive)) > 0.1  # the adaptive law did move the estimates
    assert mine.summary["final_eps_hat"] == pytest.approx(builtin.summary["final_eps_hat"], abs=1e-12)


def test_the_stepped_form_computes_the_built_in_numbers_on_mujoco() -> None:
    builtin, mine = _pair("stepped", "mujoco", 1.0)
    for name in SIGNALS:
        _close(getattr(mine, name), getattr(builtin, name), name)


@pytest.mark.parametrize("form", laws_by_hand.FORMS)
def test_each_form_computes_the_built_in_numbers_in_a_batch(form: str) -> None:
    base = qcontrol.load_scenario("example2", {"simulation.duration": 1.0})
    starts = [[0.3, 0.3], [-0.4, 0.1], [0.5, -0.2]]
    runs = {}
    for name, extra in (("built-in", {}), ("mine", laws_by_hand.overrides(base, form))):
        scs = [base.with_overrides(extra | {"plant.x0": x0}) for x0 in starts]
        first = scs[0]
        plant = build_plant(first, "ode", batch=len(scs))
        runs[name] = simulate(RunSpec(plant=plant, law=build_law(scs), quantizer=build_quantizer(first),
                                      reference=build_reference(first), x0=[s.x0 for s in scs],
                                      grid=TimeGrid.of(1.0, first.simulation.dt)))
    for builtin, mine in zip(runs["built-in"], runs["mine"], strict=True):
        for name in ("x", "u", "adaptive"):
            _close(getattr(mine, name), getattr(builtin, name), name)
    first, second = runs["built-in"][0].x, runs["built-in"][1].x
    assert not np.allclose(first, second)  # the copies did start apart


def test_a_stepped_law_is_advanced_by_its_own_update_once_per_step() -> None:
    """A law's own advance is what moves the state (not RK4 of a rate it does not have): a
    discrete counter advanced by 1 per step ends at the number of steps."""

    class Counter:
        state_size = 1

        def __init__(self, table: dict, n: int) -> None:
            self.calls = 0

        def initial_state(self) -> np.ndarray:
            return np.zeros(1)

        def control(self, t, x_q, yd, state) -> float:
            return 0.0

        def advance(self, t, x_q, yd, state, h):
            return state + 1.0

    qcontrol.register_law("step-counter", Counter, state_name="steps_taken", replace=True)
    res = qcontrol.run(qcontrol.load_scenario("example2", {"controller.kind": "step-counter",
                                                          "simulation.duration": 0.5}), backend="ode")
    steps = res.summary["steps"]
    assert res.adaptive[:, 0].tolist() == [float(k) for k in range(len(res.adaptive))]
    assert res.summary["final_steps_taken"] == [float(steps)]


def test_a_law_with_neither_a_rate_nor_an_update_is_refused_with_one_line() -> None:
    class NoUpdate:
        state_size = 1

        def __init__(self, table: dict, n: int) -> None:
            pass

        def initial_state(self) -> np.ndarray:
            return np.zeros(1)

        def control(self, t, x_q, yd, state) -> float:
            return 0.0

    qcontrol.register_law("no-update", NoUpdate, replace=True)
    refusal = r"state_rate\(\) or advance\(\) \(the qcontrol.Law protocol\)"
    with pytest.raises(qcontrol.QcontrolInputError, match=refusal):
        qcontrol.load_scenario("example2", {"controller.kind": "no-update"})


def test_an_advance_of_the_wrong_shape_is_refused_naming_the_law_and_the_method() -> None:
    class WrongShape:
        state_size = 2

        def __init__(self, table: dict, n: int) -> None:
            pass

        def initial_state(self) -> np.ndarray:
            return np.zeros(2)

        def control(self, t, x_q, yd, state) -> float:
            return 0.0

        def advance(self, t, x_q, yd, state, h):
            return np.zeros(3)

    qcontrol.register_law("wrong-advance", WrongShape, replace=True)
    sc = qcontrol.load_scenario("example2", {"controller.kind": "wrong-advance", "simulation.duration": 0.1})
    with pytest.raises(qcontrol.QcontrolInputError,
                       match=r"'wrong-advance': advance\(\) must return shape \(2,\).*got shape \(3,\)"):
        qcontrol.run(sc, backend="ode")


def test_a_law_built_from_its_context_sees_the_runs_sampling() -> None:
    """A law class with ``from_context(context)`` gets the LawContext, so --dt and the control
    period reach the law (a law that needs T no longer assumes 1 ms), its keys declared."""
    seen = []

    class Sampled:
        state_size = 0

        @classmethod
        def from_context(cls, context: qcontrol.LawContext) -> Sampled:
            seen.append((context.n, context.dt, context.control_period, context.delta, tuple(context.c),
                         dict(context.settings)))
            return cls()

        def initial_state(self) -> np.ndarray:
            return np.zeros(0)

        def control(self, t, x_q, yd, state) -> float:
            return 0.0

        def advance(self, t, x_q, yd, state, h):
            return state

    qcontrol.register_law("sampled-law", Sampled, keys=["gain"], replace=True)
    sc = qcontrol.load_scenario("example2", {"controller.kind": "sampled-law", "simulation.dt": 0.002,
                                             "simulation.control_period": 0.006, "simulation.duration": 0.1,
                                             "controller.sampled-law.gain": 2.0})
    qcontrol.run(sc, backend="ode")
    assert len(seen) == 2 and all(s == (2, 0.002, 0.006, 0.01, (4.0, 3.0), {"gain": 2.0}) for s in seen)
    with pytest.raises(qcontrol.QcontrolInputError, match=r"gains=2.0: unknown key for kind 'sampled"):
        qcontrol.load_scenario("example2", {"controller.kind": "sampled-law", "controller.gains": 2.0})
    with pytest.raises(qcontrol.QcontrolInputError, match=r"^register_law: no argument with_context=; give"):
        qcontrol.register_law("sampled-law", Sampled, with_context=True, replace=True)
