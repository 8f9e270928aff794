"""A known input gain b, x_n' = b u + psi + theta^T phi: the plants apply b u, the built-in laws
divide their input by b, a user law reads b from its context, and MuJoCo's b (gear / I) is
checked against the scenario's."""

from __future__ import annotations

import numpy as np
import pytest

import qcontrol
from qcontrol.assembly import build_controller, run_scenario
from qcontrol.plants.mujoco.mjcf import compiled

SHORT = {"simulation.duration": 1.5}


def _run(name: str, backend: str, **overrides: object) -> qcontrol.Trajectory:
    return run_scenario(qcontrol.load_scenario(name, SHORT | overrides), backend=backend)


@pytest.mark.parametrize("kind", ["proposed", "comparison"])
def test_a_power_of_two_gain_leaves_the_state_bit_for_bit(kind: str) -> None:
    """With b = 2 the law's input is halved and the plant doubles it again: both are exact in
    floating point, so the closed loop's state is the unit-gain run's to the last bit and u is
    exactly half of it (a law that forgot to divide, or a plant that forgot b, would differ)."""
    one = _run("example2", "ode", **{"controller.kind": kind})
    two = _run("example2", "ode", **{"controller.kind": kind, "plant.input_gain": 2.0})
    assert np.array_equal(one.x, two.x)
    assert np.array_equal(one.u, 2.0 * two.u)
    assert not np.array_equal(one.u, two.u)


def test_another_gain_gives_the_same_closed_loop_to_rounding() -> None:
    one = _run("chain3", "ode")
    three = _run("chain3", "ode", **{"plant.input_gain": 3.0})
    assert np.max(np.abs(one.x - three.x)) < 1e-12
    assert np.max(np.abs(one.u - 3.0 * three.u)) < 1e-10


def test_the_law_context_carries_b_and_a_user_law_sees_it() -> None:
    seen = []

    class Sees:
        state_size = 0

        @classmethod
        def from_context(cls, context: qcontrol.LawContext) -> Sees:
            seen.append(context.input_gain)
            return cls()

        def initial_state(self) -> np.ndarray:
            return np.zeros(0)

        def control(self, t, x_q, yd, state) -> float:
            return 0.0

        def advance(self, t, x_q, yd, state, h):
            return state

    qcontrol.register_law("sees-gain", Sees, replace=True)
    sc = qcontrol.load_scenario("example2", {"controller.kind": "sees-gain", "plant.input_gain": 0.25,
                                             "simulation.duration": 0.01})
    qcontrol.run(sc, backend="ode")
    assert set(seen) == {0.25}
    assert qcontrol.load_scenario("example2").law_context.input_gain == 1.0
    # a built-in law is divided by b; its constants say so
    built = build_controller(qcontrol.load_scenario("example2", {"plant.input_gain": 0.25}))
    assert built.constants()["input_gain"] == 0.25


def test_mujoco_realises_gear_over_inertia_and_agrees_with_the_ode() -> None:
    """The rigid pendulum (I = 12.25 kg m^2, gear 1) realises b = 1 / I for its motor's own
    command. Stated so, u is the torque: the run agrees with the ODE of the same b and with the
    default form (u per unit inertia, the command scaled by I), whose u is the torque / I."""
    sc = qcontrol.load_scenario("example2-rigid")
    built = compiled(sc.backends["mujoco"], sc.simulation.dt)
    b = built.ids.actuator_gain / built.inertia
    assert b == pytest.approx(1 / 12.25, rel=1e-12)
    stated = _run("example2-rigid", "mujoco", **{"plant.input_gain": b})
    scaled = _run("example2-rigid", "mujoco")
    ode = _run("example2-rigid", "ode", **{"plant.input_gain": b})
    assert np.max(np.abs(stated.x - ode.x)) < 1e-12
    assert np.max(np.abs(stated.x - scaled.x)) < 1e-12
    assert np.max(np.abs(stated.u * b - scaled.u)) < 1e-10


def test_a_stated_gain_the_model_does_not_realise_is_refused_with_both_numbers() -> None:
    sc = qcontrol.load_scenario("example2-rigid", {"plant.input_gain": 1.0})
    built = compiled(sc.backends["mujoco"], sc.simulation.dt)
    realised = built.ids.actuator_gain / built.inertia
    with pytest.raises(qcontrol.QcontrolInputError) as refused:
        qcontrol.run(sc, backend="mujoco")
    message = str(refused.value)
    assert "plant.input_gain: is 1.0" in message and repr(realised) in message
    assert repr(built.inertia) in message and "\n" not in message
    # the ODE twin of the same scenario runs: b is a property of the plant it is given to
    qcontrol.run(sc.with_overrides(SHORT), backend="ode")
