"""Realistic physics: the actuator's limit, external disturbances, x2 differenced from the encoder,
and the shipped hardware scenarios; each against an independent computation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import SCENARIOS

from qcontrol.assembly import build_plant, build_reference, input_inertia, loads, run_scenario
from qcontrol.cli import main
from qcontrol.cli import status as _status
from qcontrol.controller.backstepping import Backstepping, output
from qcontrol.disturbance import Disturbance, Schedule
from qcontrol.engine import RunSpec, simulate
from qcontrol.errors import QcontrolInputError
from qcontrol.metrics import summary
from qcontrol.quantizer import UniformQuantizer
from qcontrol.scenario import load_scenario
from qcontrol.timegrid import TimeGrid


class OpenLoop(Backstepping):
    """u = 0 whatever it reads (an open-loop run through the engine); keeps every reading."""

    state_name, state_size, copies = "none", 0, None

    def __init__(self, c: list[float], max_error: float) -> None:
        super().__init__(c, max_error)
        self.seen: list[tuple[float, ...]] = []

    def initial_state(self, batch: int) -> np.ndarray:
        return np.zeros((batch, 0))

    def control(self, reading, yd, state, t=0.0):
        self.seen.append(tuple(reading.columns))
        return output((0.0, (), (), 0.0))

    def advancer(self, h: float):
        return lambda state, out: state

    def advancer_in(self, form, h: float):  # any form: it reads the reading's columns as they come
        return self.advancer(h)

    def constants(self) -> dict:
        return {}


def open_loop(sc, backend: str, duration: float, control_period: float | None = None,
              velocity_source: str = "sensor"):
    """The scenario's plant, with its disturbances, and u = 0: (trajectory, the law's readings)."""
    law = OpenLoop(list(sc.controller.c), sc.controller.delta / 2)
    plant = build_plant(sc, backend)
    traj = simulate(RunSpec(plant=plant, law=law, quantizer=UniformQuantizer(sc.controller.delta),
                            reference=build_reference(sc), x0=np.array(sc.x0),
                            grid=TimeGrid.of(duration, sc.simulation.dt, control_period), loads=loads(sc),
                            velocity_source=velocity_source))[0]
    return traj, law.seen


# ---------------------------------------------------------------------------------------------
# the actuator: what it applies is the command clipped at its limit


def test_applied_force_is_the_command_clipped_at_the_limit() -> None:
    """A 2.5 kg cart on a frictionless rail, force limit 4 N: one RK4 step of a constant force
    from rest gives v = F dt / m exactly, so the force MuJoCo applied is measured by the motion."""
    sc = load_scenario(SCENARIOS / "example1.toml", ['plant.psi="0*x2"', "plant.mujoco.torque_limit=4.0",
                                                     "plant.mujoco.parameters={mass = 2.5}"])
    plant = build_plant(sc, "mujoco")
    assert input_inertia(sc) == pytest.approx(2.5)
    commands = np.linspace(-3.0, 3.0, 25)  # u in m/s^2: force 2.5 u N, clipped at 4 N
    measured = []
    with plant:
        for u in commands:
            plant.reset(np.array([[0.0, 0.0]]))
            plant.step(np.array([u]), 1e-3)
            measured.append(plant.state()[0, 1] / 1e-3 * 2.5)  # the force, N
    expected = np.clip(2.5 * commands, -4.0, 4.0)
    np.testing.assert_allclose(measured, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(2.5 * plant.actuator(commands), expected, rtol=1e-12)
    inside = np.abs(2.5 * commands) <= 4.0
    assert np.array_equal(plant.actuator(commands)[inside], commands[inside])  # exactly u where it fits


def test_saturation_is_reported_per_control_sample() -> None:
    sc = load_scenario(SCENARIOS / "example2.toml", ["plant.mujoco.torque_limit=12.0",
                                                     "simulation.control_period=0.003",
                                                     "simulation.duration=3.0"])
    traj = run_scenario(sc)
    s = summary(traj, sc.name, "mujoco")
    samples = traj.u[:: 3]  # control samples: every third row (I = 1, gain 1: the torque is u)
    assert s["saturated_fraction"] == pytest.approx(np.mean(np.abs(samples) > 12.0), abs=1e-15)
    assert 0.0 < s["saturated_fraction"] < 1.0
    assert s["max_abs_u"] > 12.0 and s["max_abs_u_applied"] == pytest.approx(12.0, rel=1e-12)
    np.testing.assert_allclose(traj.u_applied, np.clip(traj.u, -12.0, 12.0), rtol=1e-12)
    ideal = summary(run_scenario(load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=1.0"]),
                                 "ode"), "example2", "ode")
    assert ideal["saturated_fraction"] == 0.0 and ideal["max_abs_u_applied"] == ideal["max_abs_u"]


# ---------------------------------------------------------------------------------------------
# disturbances


@pytest.mark.parametrize("backend", ["mujoco", "ode"])
def test_an_impulse_changes_the_momentum_by_its_integral(backend: str) -> None:
    """A 2.5 kg cart, no other force: m (v_end - v_0) = force * duration, with a start and a
    duration that fall inside steps (the schedule holds each step's average force)."""
    push = 'disturbance=[{kind = "impulse", start = 0.1234, duration = 0.0567, force = 3.0}]'
    sc = load_scenario(SCENARIOS / "example1.toml", ['plant.psi="0*x2"', "plant.x0=[0.0, 0.4]", push,
                                                     "plant.mujoco.parameters={mass = 2.5}"])
    traj, _ = open_loop(sc, backend, 0.3)
    momentum = 2.5 * traj.x[:, 1]
    assert momentum[-1] - momentum[0] == pytest.approx(3.0 * 0.0567, rel=1e-12)
    before = traj.t < 0.123
    np.testing.assert_allclose(traj.x[before, 1], 0.4, rtol=1e-14)  # nothing acts before the push


def test_the_schedule_holds_each_steps_average_force() -> None:
    items = (Disturbance("impulse", 0.0125, 0.0125 + 0.0301, 2.0), Disturbance("step", 0.02, math.inf, -1.5))
    schedule = Schedule(items)
    dt, rows = 0.004, 30
    per_row = schedule.per_row(dt, rows)
    assert [schedule.on_step(k, dt) for k in range(rows)] == per_row.tolist()
    assert per_row[:3].tolist() == [0.0, 0.0, 0.0] and per_row[-1] == -1.5
    assert per_row[3] == pytest.approx(2.0 * (0.016 - 0.0125) / dt)  # a part of step 3
    impulse_only = Schedule(items[:1]).per_row(dt, rows)
    assert impulse_only.sum() * dt == pytest.approx(2.0 * 0.0301, rel=1e-12)
    changes = schedule.changes(dt, rows)
    assert [k for k, _ in changes] == sorted({k for k, _ in changes}) and changes[0][0] == 0


def test_a_step_load_shifts_the_equilibrium() -> None:
    """The pendulum, open loop, a constant 10 N m from t = 0.5 s: it comes to rest where gravity
    balances the load, M g l sin(x1) = 10, x1 = asin(10 / 34.3) (damping 10 N m s: settled within
    the run); MuJoCo and the ODE (the load as d = F / I) alike."""
    load = 'disturbance=[{kind = "step", start = 0.5, value = 10.0}]'
    sc = load_scenario(SCENARIOS / "example2.toml", ["plant.x0=[0.0, 0.0]", load,
                                                     "plant.theta=[-10.0, -3.5, -34.3]",
                                                     "plant.mujoco.parameters={damping = 10.0}"])
    for backend in ("mujoco", "ode"):
        traj, _ = open_loop(sc, backend, 6.5)
        assert traj.x[traj.t < 0.5].max() == 0.0  # at rest in the bottom until the load comes
        assert traj.x[-1, 0] == pytest.approx(math.asin(10.0 / 34.3), abs=1e-9)
        assert abs(traj.x[-1, 1]) < 1e-9


def test_disturbances_are_checked_at_load() -> None:
    cases = {
        'disturbance=[{kind = "kick", start = 1.0}]': "disturbance[0].kind",
        'disturbance=[{kind = "impulse", start = 1.0, force = 2.0}]': "disturbance[0].duration: missing",
        'disturbance=[{kind = "impulse", start = 1.0, duration = -0.1, force = 2.0}]': "must be > 0",
        'disturbance=[{kind = "step", start = -1.0, value = 2.0}]': "disturbance[0].start",
        'disturbance=[{kind = "step", start = 1.0, value = 2.0, duration = 1.0}]': "unknown key",
        "disturbance=3": "must be a list of tables",
    }
    for override, needle in cases.items():
        with pytest.raises(QcontrolInputError, match=needle.replace("[", r"\[").replace("]", r"\]")):
            load_scenario(SCENARIOS / "example2.toml", [override])


# ---------------------------------------------------------------------------------------------
# x2 from the encoder


@pytest.mark.parametrize("batch", [1, 2])
def test_the_differenced_velocity_is_the_quantized_position_over_the_period(batch: int) -> None:
    sc = load_scenario(SCENARIOS / "example1.toml", ["plant.x0=[0.8, 1.5]"])
    delta, hold, dt = sc.controller.delta, 3, sc.simulation.dt
    law = OpenLoop(list(sc.controller.c), delta / 2)
    traj = simulate(RunSpec(plant=build_plant(sc, "mujoco", batch=batch), law=law,
                            quantizer=UniformQuantizer(delta), reference=build_reference(sc),
                            x0=np.array(sc.x0), grid=TimeGrid.of(0.4, dt, hold * dt),
                            velocity_source="difference"))[0]
    q1 = delta * np.floor(traj.x_meas[:, 0] / delta + 0.5)
    previous = np.concatenate([np.full(hold, q1[0]), q1[:-hold]])
    expected = (q1 - previous) / (hold * dt)
    np.testing.assert_allclose(traj.x_q[:, 1], expected, rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(traj.x_q[:, 0], q1)
    seen = np.array(law.seen)[:, 1]  # x2 at each control sample ((samples, batch) for a batch)
    np.testing.assert_allclose(seen[:, 0] if batch > 1 else seen, expected[::hold], rtol=1e-12, atol=1e-9)
    assert np.abs(expected).max() > 0  # the cart moved: the test compared real differences


def test_lemma2_does_not_decide_the_exit_status_when_x2_is_differenced(short_example2) -> None:
    import dataclasses

    import qcontrol

    base = dataclasses.replace(qcontrol.run(short_example2, "ode", record="metrics").typed_summary,
                               diverged=False, lemma2_max_ratio=5.0)
    assert _status(dataclasses.replace(base, lemma2_applies=True)) == 1
    assert _status(dataclasses.replace(base, lemma2_applies=False)) == 0
    assert _status(dataclasses.replace(base, lemma2_applies=False, diverged=True)) == 1


# ---------------------------------------------------------------------------------------------
# the shipped hardware scenarios


@pytest.mark.parametrize("name", ["example2-arm", "example1-cart"])
@pytest.mark.parametrize("law", ["proposed", "comparison"])
def test_the_realistic_scenarios_run_to_the_end_and_stay_bounded(request: pytest.FixtureRequest, name: str,
                                                                 law: str) -> None:
    """Both laws on both realistic plants, the full 10 s with their disturbance: no divergence,
    the states stay within a few times the reference, Lemma 2 holds for what the quantizer read.
    (The comparison law's runs in the Python loop: their compiled forms are met nowhere else.)"""
    if law == "comparison":
        request.getfixturevalue("python_loop")
    sc = load_scenario(SCENARIOS / f"{name}.toml", [f"controller.kind={law}"])
    assert sc.simulation.control_period == 0.002 and sc.disturbances
    s = summary(run_scenario(sc, record="metrics"), sc.name, "mujoco")
    assert not s["diverged"] and s["steps"] == 10_000
    assert s["max_abs_z1_last_half"] < 1.0 and s["max_abs_u_applied"] < 30.0
    assert s["lemma2_applies"] and s["lemma2_max_ratio"] <= 1 + 1e-9


def test_compare_says_which_realism_option_makes_the_gap(tmp_path) -> None:
    out = tmp_path / "cmp"
    assert main(["compare", str(SCENARIOS / "example2-arm.toml"), "--duration", "2", "-q", "--out",
                 str(out)]) == 0
    result = json.loads((out / "compare.json").read_text())
    parts = result["realism_alone"]
    assert list(parts) == result["consistency"]["realism"]
    # the torque limit never clips here: alone it leaves MuJoCo on the ODE to rounding
    assert result["mujoco"]["saturated_fraction"] == 0.0 and parts["torque_limit"]["max_abs_dy"] < 1e-9
    for name in ("frictionloss", "armature", "rod_mass", "sensor_noise", "sensor_delay"):
        assert parts[name]["max_abs_dy"] > 1e-6  # each is a real difference from eq. (1)
    assert result["max_abs_dy"] > 1e-3  # all together: far above the 1e-13 of the ideal model
