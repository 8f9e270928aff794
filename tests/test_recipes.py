"""The recipes of docs/architecture.md ("How to add ..."), each done here the way the page says:
a control law kind, a plant backend, a recorded signal, a command. Each adds its part to the
registry or table the page names (restored after the test) and runs it through the real code."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from conftest import EX2

from qcontrol.assembly import run_scenario
from qcontrol.cli import COMMANDS, main
from qcontrol.cli.arguments import EXIT_OK, add_scenario_options, scenario_from_args
from qcontrol.controller import LAW_KINDS, Backstepping, LawKind
from qcontrol.controller.backstepping import Columns, ControlOutput, output
from qcontrol.engine import retention, signals
from qcontrol.plants import BACKENDS, Backend
from qcontrol.plants.ode import ChainPlant
from qcontrol.recording import series, styles
from qcontrol.scenario import load_scenario


# ---- a control law kind: a class following BatchLaw (Backstepping gives the coordinates) and its LawKind
class VirtualControlLaw(Backstepping):
    """u = alphabar_n - gain * zbar_n (no adaptation): the recipe's smallest law."""

    state_name, state_size, copies = "none", 0, None

    def __init__(self, c, max_error: float, gain: float) -> None:
        super().__init__(c, max_error)
        self.gain = gain

    def initial_state(self, batch: int) -> np.ndarray:
        return np.zeros((batch, 0))

    def control(self, reading, yd, state: Columns, t: float = 0.0) -> ControlOutput:
        self.check_reading(reading)
        zbar, alphabar = self.recursion(reading.columns, yd)  # eqs. (31)-(34), on floats or arrays
        return output((alphabar[-1] - self.gain * zbar[-1], zbar, (), 0.0))

    def advancer(self, h: float):  # the array form only: the engine's float path adapts it
        return NoState().advance

    def constants(self) -> dict:
        return {"gain": self.gain}


class NoState:
    def advance(self, state: Columns, out: ControlOutput) -> Columns:
        return state


def test_recipe_a_control_law_kind(monkeypatch) -> None:
    kind = LawKind("virtual", None, parse=lambda table, ctx: dict(table.data),
                   build=lambda settings, ctx: VirtualControlLaw(ctx.c, ctx.max_error, 2.0),
                   structure=lambda settings, ctx: None)
    monkeypatch.setitem(LAW_KINDS, "virtual", kind)
    sc = load_scenario(EX2, ["controller.kind=virtual", "simulation.duration=0.3"])
    traj = run_scenario(sc, "ode")
    assert not traj.diverged and traj.adaptive.shape == (301, 0)
    law = VirtualControlLaw(sc.controller.c, sc.controller.delta / 2, 2.0)
    zbar, alphabar = law.quantized_errors(traj.x_q[:1], traj.yd[:1])
    np.testing.assert_allclose(traj.u[0], alphabar[0, -1] - 2.0 * zbar[0, -1], rtol=1e-12)


# ---- a plant backend: a plant class with the core Plant (array form) and its Backend, by keywords
class CorePlant:
    """eq. (1) with only the core of the Plant protocol (observe, step, reset, close)."""

    def __init__(self, terms) -> None:
        first = terms[0]
        self.inner = ChainPlant(first.order, first.psi, first.phi, first.theta, batch=len(terms))
        self.n, self.batch = self.inner.n, self.inner.batch

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def reset(self, x0) -> None:
        self.inner.reset(x0)

    def observe(self):
        x = self.inner.state()
        return x, x

    def step(self, u, h) -> None:
        self.inner.step(u, h)

    def close(self) -> None:
        pass


def test_recipe_a_plant_backend(monkeypatch) -> None:
    backend = Backend(name="core", build=lambda terms, options, dt: CorePlant(terms),
                      structure=lambda terms, options: terms.order, summary="eq. (1) through the core only")
    monkeypatch.setitem(BACKENDS, "core", backend)
    sc = load_scenario(EX2, ["simulation.duration=0.3"])
    mine, ideal = run_scenario(sc, "core"), run_scenario(sc, "ode")
    for name in ("x", "x_q", "u", "adaptive", "e_z"):
        np.testing.assert_array_equal(mine.signals[name], ideal.signals[name], err_msg=name)


# ---- a recorded signal: a row of the signal table (and, to draw it, an entry of recording/styles.py)
def _sensor_error(block, ctx) -> np.ndarray:
    return block["x_meas"] - block["x"]


def test_recipe_a_recorded_signal(monkeypatch) -> None:
    row = signals.Signal("sensor_error", "n", "state", False, "x_meas - x", _sensor_error,
                         reads=("x", "x_meas"))
    table = (*signals.SIGNALS, row)
    for module in (signals, retention):
        monkeypatch.setattr(module, "SIGNALS", table)
        monkeypatch.setattr(module, "DERIVED", (*signals.DERIVED, row))
    monkeypatch.setitem(styles.PLOTS, "sensor_error", (styles.Plot("signals/sensor/x{i}", "x{i} error"),))
    monkeypatch.setattr(series, "SIGNALS", table)
    noisy = ["simulation.duration=0.2", "plant.mujoco.sensor_noise=[0.01, 0.0]", "plant.mujoco.noise_seed=3"]
    traj = run_scenario(load_scenario(EX2, noisy), "mujoco")
    error = traj.signals["sensor_error"]
    np.testing.assert_array_equal(error, traj.x_meas - traj.x)
    assert np.abs(error[:, 0]).max() > 0 and not error[:, 1].any()  # the noise is on x1 only
    assert {"signals/sensor/x1", "signals/sensor/x2"} <= {s.path for s in series.run_series(traj, "mujoco")}


# ---- a command: a module with its parser (the shared scenario options) and handler, one COMMANDS entry
def add_steps_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("steps", help="print how many steps a scenario takes")
    add_scenario_options(p)


def cmd_steps(args: argparse.Namespace) -> int:
    sc = scenario_from_args(args)
    print(f"{sc.name}: {round(sc.simulation.duration / sc.simulation.dt)} steps")
    return EXIT_OK


def test_recipe_a_command(monkeypatch, capsys) -> None:
    monkeypatch.setitem(COMMANDS, "steps", (add_steps_parser, cmd_steps))
    assert main(["steps", "example2", "--duration", "0.5", "--set", "simulation.dt=0.002"]) == 0
    assert capsys.readouterr().out == "example2: 250 steps\n"
    assert main(["steps", "example2", "--set", "controller.kappa=-1"]) == 2  # bad input: one line, status 2


def test_the_recipes_are_the_documented_ones() -> None:
    from conftest import ROOT

    page = (ROOT / "docs" / "architecture.md").read_text()
    for anchor in ("**A control law in the package**", "**A plant backend**", "**A recorded signal**",
                   "**A command**", "tests/test_recipes.py"):
        assert anchor in page, anchor
    assert dataclasses.fields(Backend)[0].kw_only
