"""How the engine calls a ``qcontrol.Law``: every call gets arrays of its own, so a law that
changes (or keeps) what it is given computes what a law that leaves them alone computes, single
run and batch, for ``state_rate`` (RK4, four calls a step) and ``advance``; and each form of the
paper's law written by hand computes, copy by copy, what the same law computes alone."""

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

STARTS = ([0.3, 0.3], [-0.4, 0.1], [0.5, -0.2])


class Leaky:
    """u = -4 x_q1 - 3 x_q2 - state_1; state' = (x_q1 - y_d - state_1, x_q2 - state_2): a law
    that leaves its arguments alone."""

    state_size = 2

    def __init__(self, table: dict, n: int) -> None:
        pass

    def initial_state(self) -> np.ndarray:
        return np.array([0.1, -0.2])

    def control(self, t, x_q, yd, state) -> float:
        return float(-4.0 * x_q[0] - 3.0 * x_q[1] - state[0])

    def state_rate(self, t, x_q, yd, state) -> np.ndarray:
        return np.array([x_q[0] - yd[0] - state[0], x_q[1] - state[1]])


class Scribbling(Leaky):
    """The same law, which writes over every array it is given after using it and keeps them."""

    def __init__(self, table: dict, n: int) -> None:
        self.kept: list[np.ndarray] = []

    def _scribble(self, *arrays: np.ndarray) -> None:
        for a in arrays:
            a[:] = 1e6
        self.kept = list(arrays)

    def control(self, t, x_q, yd, state) -> float:
        u = super().control(t, x_q, yd, state)
        self._scribble(x_q, yd, state)
        return u

    def state_rate(self, t, x_q, yd, state) -> np.ndarray:
        rate = super().state_rate(t, x_q, yd, state)
        self._scribble(x_q, yd, state)
        return rate


class LeakyStepped(Leaky):
    """Leaky with an explicit Euler step of its rate for an update."""

    def advance(self, t, x_q, yd, state, h) -> np.ndarray:
        return state + h * self.state_rate(t, x_q, yd, state)


class ScribblingStepped(Scribbling):
    def advance(self, t, x_q, yd, state, h) -> np.ndarray:
        new = state + h * Leaky.state_rate(self, t, x_q, yd, state)
        self._scribble(x_q, yd, state)
        return new


def _runs(kind: str, starts: tuple[list[float], ...], duration: float = 0.3, form: str | None = None) -> list:
    base = qcontrol.load_scenario("example2")
    base = base.with_overrides(laws_by_hand.overrides(base, form) if form else {"controller.kind": kind})
    scs = [base.with_overrides({"plant.x0": x0}) for x0 in starts]
    first = scs[0]
    return simulate(RunSpec(plant=build_plant(first, "ode", batch=len(scs)), law=build_law(scs),
                            quantizer=build_quantizer(first), reference=build_reference(first),
                            x0=[s.x0 for s in scs] if len(scs) > 1 else first.x0,
                            grid=TimeGrid.of(duration, first.simulation.dt)))


@pytest.mark.parametrize(("clean", "scribbling"), [(Leaky, Scribbling), (LeakyStepped, ScribblingStepped)])
def test_a_law_that_writes_over_its_arguments_computes_what_one_that_does_not_computes(clean, scribbling):
    qcontrol.register_law("calls-clean", clean, state_name="s", replace=True)
    qcontrol.register_law("calls-scribbling", scribbling, state_name="s", replace=True)
    for starts in (STARTS[:1], STARTS):  # a single run (floats), a batch (arrays)
        for a, b in zip(_runs("calls-clean", starts), _runs("calls-scribbling", starts), strict=True):
            for name in ("x", "x_q", "u", "adaptive"):
                np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)
            assert not b.diverged
            assert np.ptp(a.adaptive[:, 0]) > 1e-3  # the state did move


@pytest.mark.parametrize("form", ["rk4", "floats"])
def test_each_copy_of_a_batch_computes_what_the_same_law_computes_alone(form: str) -> None:
    laws_by_hand.register()
    batch = _runs("", STARTS, form=form)
    for x0, copy in zip(STARTS, batch, strict=True):
        alone = _runs("", (x0,), form=form)[0]
        for name in ("x", "u", "adaptive"):
            np.testing.assert_array_equal(getattr(copy, name), getattr(alone, name), err_msg=name)
