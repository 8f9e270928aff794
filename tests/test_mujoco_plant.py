"""The MuJoCo plant: MJCF models vs the ODE of eq. (1), callbacks, readings, input errors."""

from __future__ import annotations

import math
import pathlib

import mujoco
import numpy as np
import pytest
from conftest import ROOT, SCENARIOS

from qcontrol.controller import PaperLaw
from qcontrol.engine import RunSpec, simulate
from qcontrol.errors import QcontrolInputError
from qcontrol.expr import compile_expression, scalar_function
from qcontrol.plants import mujoco as mujoco_backend
from qcontrol.plants.backends import PlantContext
from qcontrol.plants.base import PlantTerms
from qcontrol.plants.mujoco import callbacks as qmj
from qcontrol.plants.mujoco.mjcf import build_model
from qcontrol.plants.mujoco.options import MujocoOptions
from qcontrol.plants.mujoco.plant import MujocoPlant
from qcontrol.plants.ode import ChainPlant
from qcontrol.quantizer import UniformQuantizer
from qcontrol.reference import Sine
from qcontrol.schema import Table
from qcontrol.timegrid import TimeGrid

X, Q = ["x1", "x2"], ["q1", "q2"]

SLIDER = {"model": "../models/slider.xml", "joint": "slide", "position_sensor": "position",
          "velocity_sensor": "velocity", "actuator": "force"}
PENDULUM = {"model": "../models/pendulum.xml", "joint": "hinge", "position_sensor": "angle",
            "velocity_sensor": "angular_velocity", "actuator": "torque", "native_terms": ["phi1", "phi3"]}
RIGID = PENDULUM | {"parameters": {"mass": 1.0, "length": 3.5, "damping": 12.25}}
PHI = ["x2", "x2**2*cos(x1)", "sin(x1)"]

# the paper's Section 4: plant, controller and reference of each example
EXAMPLES = {
    "example1": dict(table=SLIDER, psi="0.1*x2**2", phi=[], theta=[], delta=0.1, c=[2.0, 2.0],
                     kappa=6.0 + 0.15, gamma=0.75, sigma=0.5, r=["0.6*q2**2 + 1"], freq=1.0, x0=[0.8, 1.5]),
    "example2": dict(table=PENDULUM, psi=None, phi=PHI, theta=[-1.0, -3.5, -34.3], delta=0.01, c=[4.0, 3.0],
                     kappa=1.1 + 0.025, gamma=1.0, sigma=1.0, r=["1 + q2**2", "1 + 2*q2**2", "1"], freq=1.5,
                     x0=[0.3, 0.3]),
}
EXAMPLES["example2-rigid"] = EXAMPLES["example2"] | dict(table=RIGID, theta=[-1.0, -1.0 / 3.5, -2.8])


def options(table: dict, name: str = "test.toml", n_phi: int = 3, has_psi: bool = False,
            base: pathlib.Path = SCENARIOS) -> MujocoOptions:
    """The options of a ``[plant.mujoco]`` table, checked as a scenario's are when it loads (the
    model compiled with dt = 1 ms)."""
    psi = compile_expression("0", X) if has_psi else None
    terms = PlantTerms(2, psi, tuple(compile_expression("x1", X) for _ in range(n_phi)), (0.0,) * n_phi)
    return mujoco_backend.parse(Table(table, name, "plant.mujoco", None), PlantContext(terms, base, 1e-3))


def mujoco_plant(opts: MujocoOptions, n: int, psi, phi, theta, batch: int = 1,
                 timestep: float | None = None) -> MujocoPlant:
    return MujocoPlant(opts, PlantTerms(n, psi, tuple(phi), tuple(theta)), batch=batch, timestep=timestep)


def expressions(ex: dict) -> tuple:
    psi = compile_expression(ex["psi"], X) if ex["psi"] else None
    return psi, [compile_expression(p, X) for p in ex["phi"]]


def plants(name: str, batch: int = 1) -> tuple[MujocoPlant, ChainPlant]:
    ex = EXAMPLES[name]
    psi, phi = expressions(ex)
    opts = options(ex["table"], name, len(phi), psi is not None)
    return (mujoco_plant(opts, 2, psi, phi, ex["theta"], batch=batch, timestep=1e-3),
            ChainPlant(2, psi, phi, ex["theta"], batch=batch))


def controller(name: str) -> tuple[PaperLaw, UniformQuantizer]:
    ex = EXAMPLES[name]
    q = UniformQuantizer(ex["delta"])
    r = [compile_expression(s, Q) for s in ex["r"]]
    return PaperLaw(ex["c"], q.max_error, ex["kappa"], ex["gamma"], ex["sigma"], r), q


class Spy:
    """Wraps a controller and keeps every reading it is handed."""

    def __init__(self, inner: PaperLaw) -> None:
        self.inner = inner
        self.seen: list[np.ndarray] = []

    def __getattr__(self, name: str):
        return getattr(self.inner, name)

    def control(self, reading, yd, adaptive, t=0.0):
        self.seen.append(np.array(reading.values))
        return self.inner.control(reading, yd, adaptive, t)

    def quantized_errors(self, values, yd):
        self.seen.append(np.array(values))
        return self.inner.quantized_errors(values, yd)


# ---------------------------------------------------------------------------------------------
# model consistency: MuJoCo's acceleration is the ODE right-hand side


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_mujoco_acceleration_equals_ode_rhs(name: str) -> None:
    mj, ode = plants(name)
    assert mj.consistency_report["ok"] and mj.consistency_report["max_relative_mismatch"] <= 1e-9
    rng = np.random.default_rng(7)
    x = np.column_stack([rng.uniform(-3, 3, 200), rng.uniform(-3, 3, 200)])
    u = rng.uniform(-30, 30, 200)
    expected = ode.rhs(x, u)[:, 1]
    data = mj._datas[0]
    got = np.empty(200)
    with mj:
        for i in range(200):
            data.qpos[0], data.qvel[0] = x[i]
            data.ctrl[0] = mj.inertia * u[i]
            mujoco.mj_forward(mj.model, data)
            got[i] = data.qacc[0]
    scale = 1.0 + np.abs(expected) + np.abs(u)
    assert np.max(np.abs(got - expected) / scale) <= 1e-9


def test_inertia_comes_from_the_model() -> None:
    assert plants("example1")[0].inertia == pytest.approx(1.0, abs=1e-12)
    assert plants("example2")[0].inertia == pytest.approx(1.0, abs=1e-12)
    assert plants("example2-rigid")[0].inertia == pytest.approx(12.25, abs=1e-12)


@pytest.mark.parametrize(
    ("table", "theta", "term"),
    [
        (PENDULUM, [-1.0, -3.5, -30.0], "phi3 = sin(x1)"),
        (PENDULUM, [-2.0, -3.5, -34.3], "phi1 = x2"),
        (PENDULUM | {"native_terms": ["phi1"]}, [-1.0, -3.5, -34.3], "phi3 = sin(x1)"),
        (RIGID, [-1.0, -3.5, -34.3], "phi"),
    ],
)
def test_inconsistent_model_is_refused_naming_the_term(table: dict, theta: list, term: str) -> None:
    phi = [compile_expression(p, X) for p in PHI]
    with pytest.raises(QcontrolInputError) as err:
        mujoco_plant(options(table), 2, None, phi, theta, timestep=1e-3)
    message = str(err.value)
    assert "\n" not in message and term in message and "differs" in message


def test_rk4_calls_the_passive_callback_at_every_stage(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("QCONTROL_COMPILE", "0")  # the Python callback, which can count its calls
    mj, _ = plants("example2")
    assert mj._native is None
    with mj:
        mj.reset(np.array([[0.3, 0.3]]))
        key = id(mj._datas[0])
        inner, calls = qmj._ENTRIES[key], []
        qmj._ENTRIES[key] = lambda: (calls.append(1), inner())
        mj.step(np.zeros(1), 1e-3)
        assert len(calls) == 4
        mj.step(np.zeros(1), 3e-3)  # three mj_steps
        assert len(calls) == 16


def test_scalar_callback_code_matches_the_vectorized_expressions() -> None:
    rng = np.random.default_rng(1)
    x = rng.uniform(-2, 2, (50, 2))
    sources = ["x2**2*cos(x1)", "0.1*x2**2", "-x1/3 + sign(x2)*abs(x2)**1.5", "max(x1, x2, 0.5)",
               "tanh(x1) - exp(-x2**2) + sqrt(1 + x1**2) + log(2 + sin(x2)) * pi", "min(x1, 1) - tan(x2/4)"]
    for source in sources:
        expr = compile_expression(source, X)
        fn = scalar_function(expr)
        np.testing.assert_allclose([fn(tuple(row.tolist())) for row in x], expr(x), rtol=1e-14, atol=1e-14)


# ---------------------------------------------------------------------------------------------
# closed loop: the same controller on both backends


@pytest.fixture(scope="module")
def closed_loops() -> dict:
    runs = {}
    for name, ex in EXAMPLES.items():
        mj, ode = plants(name)
        results = []
        for plant in (mj, ode):
            ctrl, q = controller(name)
            spy = Spy(ctrl)
            tr = simulate(RunSpec(plant=plant, law=spy, quantizer=q, reference=Sine(1.0, ex["freq"]),
                                  x0=ex["x0"], grid=TimeGrid.of(10.0, 1e-3)))[0]
            results.append((tr, spy))
        runs[name] = results
    return runs


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_backends_agree_over_the_full_run(closed_loops: dict, name: str) -> None:
    (mj, _), (ode, _) = closed_loops[name]
    assert not mj.diverged and not ode.diverged and mj.steps == ode.steps == 10_000
    assert np.max(np.abs(mj.y - ode.y)) <= 1e-9
    assert np.max(np.abs(mj.x - ode.x)) <= 1e-9
    assert np.max(np.abs(mj.u - ode.u)) <= 1e-6


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_controller_only_receives_grid_values_from_mujoco(closed_loops: dict, name: str) -> None:
    (tr, spy), _ = closed_loops[name]
    delta = EXAMPLES[name]["delta"]
    seen = np.concatenate([s.reshape(-1) for s in spy.seen])
    assert seen.size >= 2 * 10_001
    for values in (seen, tr.x_q.reshape(-1)):
        levels = values / delta
        assert np.max(np.abs(levels - np.round(levels))) < 1e-9
    # and the readings are the sensors' (sensordata), quantized: |x_meas - x_q| <= delta/2
    assert np.max(np.abs(tr.x_meas - tr.x_q)) <= delta / 2 + 1e-12


def test_readings_come_from_sensordata_not_qpos() -> None:
    ex = EXAMPLES["example1"]
    psi, _ = expressions(ex)
    plant = mujoco_plant(options(SLIDER | {"sensor_delay": 0.003}, n_phi=0, has_psi=True), 2, psi, [], [],
                        timestep=1e-3)
    states, readings = [], []
    with plant:
        plant.reset(np.array([[0.0, 1.0]]))
        for _ in range(10):
            states.append(plant.state()[0])
            readings.append(plant.read_sensors()[0])
            plant.step(np.array([0.5]), 1e-3)
    states, readings = np.array(states), np.array(readings)
    np.testing.assert_allclose(readings[3:], states[:-3], atol=1e-12)  # delayed by 3 steps
    np.testing.assert_allclose(readings[:3], np.tile(states[0], (3, 1)), atol=1e-12)
    assert np.max(np.abs(readings[3:] - states[3:])) > 1e-4


# ---------------------------------------------------------------------------------------------
# the process-global callback is always removed


def _previous(model, data) -> None:  # a callback someone else installed
    return None


def test_callback_is_removed_after_a_run_and_the_previous_one_restored() -> None:
    mj, _ = plants("example2")
    ctrl, q = controller("example2")
    mujoco.set_mjcb_passive(_previous)
    try:
        simulate(RunSpec(plant=mj, law=ctrl, quantizer=q, reference=Sine(1.0, 1.5), x0=[0.3, 0.3],
                         grid=TimeGrid.of(0.05, 1e-3)))
        assert mujoco.get_mjcb_passive() is _previous
        assert not qmj._ENTRIES
    finally:
        mujoco.set_mjcb_passive(None)
    simulate(RunSpec(plant=mj, law=ctrl, quantizer=q, reference=Sine(1.0, 1.5), x0=[0.3, 0.3],
                     grid=TimeGrid.of(0.05, 1e-3)))
    assert mujoco.get_mjcb_passive() is None


def test_callback_is_removed_when_the_run_raises() -> None:
    mj, _ = plants("example2")
    ctrl, q = controller("example2")

    class Boom(Spy):
        def control(self, reading, yd, adaptive, t=0.0):
            assert mujoco.get_mjcb_passive() is not None  # installed during the run
            if len(self.seen) > 5:
                raise RuntimeError("boom")
            return super().control(reading, yd, adaptive, t)

    with pytest.raises(RuntimeError, match="boom"):
        simulate(RunSpec(plant=mj, law=Boom(ctrl), quantizer=q, reference=Sine(1.0, 1.5), x0=[0.3, 0.3],
                         grid=TimeGrid.of(1.0, 1e-3)))
    assert mujoco.get_mjcb_passive() is None and not qmj._ENTRIES


def test_step_outside_a_with_block_is_refused() -> None:
    mj, _ = plants("example2")
    mj.reset(np.array([[0.3, 0.3]]))
    with pytest.raises(RuntimeError, match="with"):
        mj.step(np.zeros(1), 1e-3)


# ---------------------------------------------------------------------------------------------
# bad input: one clear line


def _one_line_error(fn, *needles: str) -> str:
    with pytest.raises(QcontrolInputError) as err:
        fn()
    message = str(err.value)
    assert "\n" not in message, message
    for needle in needles:
        assert needle in message, message
    return message


@pytest.mark.parametrize(
    ("change", "needles"),
    [
        ({"model": "../models/nope.xml"}, ["plant.mujoco.model", "nope.xml", "not found"]),
        ({"joint": "elbow"}, ["plant.mujoco.joint", "'elbow'", "'hinge'"]),
        ({"position_sensor": "theta"}, ["plant.mujoco.position_sensor", "'theta'", "'angle'"]),
        ({"velocity_sensor": "angle"}, ["plant.mujoco.velocity_sensor", "jointvel"]),
        ({"actuator": "motor"}, ["plant.mujoco.actuator", "'torque'"]),
        ({"colour": "red"}, ["plant.mujoco.colour", "unknown key", "native_terms"]),
        ({"native_terms": ["phi4"]}, ["plant.mujoco.native_terms", "'phi4'", "phi1, phi2, phi3"]),
        ({"integrator": "RK45"}, ["plant.mujoco.integrator", "RK4, Euler"]),
        ({"parameters": {"lenght": 3.5}}, ["plant.mujoco.parameters.lenght", "mass, length"]),
        ({"sensor_noise": 0.01}, ["plant.mujoco.noise_seed", "seed"]),
        ({"frictionloss": -1}, ["plant.mujoco.frictionloss", ">= 0"]),
    ],
)
def test_bad_tables_are_one_line_errors(change: dict, needles: list) -> None:
    _one_line_error(lambda: options(PENDULUM | change), "test.toml: ", *needles)


def test_missing_required_key_and_mjcf_that_does_not_compile(tmp_path: pathlib.Path) -> None:
    table = dict(PENDULUM)
    del table["joint"]
    _one_line_error(lambda: options(table), "plant.mujoco.joint", "missing")
    broken = tmp_path / "broken.xml"
    broken.write_text((ROOT / "models" / "pendulum.xml").read_text().replace("</worldbody>", ""))
    _one_line_error(lambda: options(PENDULUM | {"model": "broken.xml"}, base=tmp_path),
                    "plant.mujoco.model", "cannot load broken.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text((ROOT / "models" / "pendulum.xml").read_text().replace('mass="12.25"', 'mass="-1"'))
    _one_line_error(lambda: options(PENDULUM | {"model": "bad.xml"}, base=tmp_path), "plant.mujoco.model")


def test_plant_order_other_than_two_is_refused() -> None:
    phi = [compile_expression(p, ["x1", "x2", "x3"]) for p in PHI]
    _one_line_error(lambda: mujoco_plant(options(PENDULUM), 3, None, phi, [-1, -3.5, -34.3]), "order 3")


# ---------------------------------------------------------------------------------------------
# realism options: reported, not refused


def test_realism_options_report_their_mismatch_instead_of_refusing() -> None:
    phi = [compile_expression(p, X) for p in PHI]
    theta = [-1.0, -3.5, -34.3]
    armed = mujoco_plant(options(PENDULUM | {"armature": 0.25}), 2, None, phi, theta, timestep=1e-3)
    report = armed.consistency_report
    assert not report["ok"] and report["realism"] == ["armature"]
    assert armed.inertia == pytest.approx(1.0, abs=1e-12)  # the gain uses the nominal inertia
    assert report["terms"]["u"]["mujoco"] == pytest.approx(1 / 1.25, rel=1e-9)
    assert report["terms"]["phi3"]["mujoco"] == pytest.approx(-34.3 / 1.25, rel=1e-9)
    limited = mujoco_plant(options(PENDULUM | {"torque_limit": 5.0}), 2, None, phi, theta, timestep=1e-3)
    assert limited.model.actuator_ctrlrange[0].tolist() == [-5.0, 5.0]
    assert limited.consistency_report["max_abs_mismatch"] > 1.0
    rod = mujoco_plant(options(PENDULUM | {"rod_mass": 0.5}), 2, None, phi, theta, timestep=1e-3)
    length = 1 / 3.5
    inertia = 1.0 + 0.5 * length**2 / 3.0
    assert rod.consistency_report["terms"]["u"]["mujoco"] == pytest.approx(1 / inertia, rel=1e-9)
    friction = mujoco_plant(options(PENDULUM | {"frictionloss": 0.5}), 2, None, phi, theta, timestep=1e-3)
    assert friction.model.dof_frictionloss[0] == 0.5 and not friction.consistency_report["ok"]


def test_sensor_noise_is_seeded_and_sized() -> None:
    phi = [compile_expression(p, X) for p in PHI]
    table = PENDULUM | {"sensor_noise": [0.001, 0.01], "noise_seed": 5}
    runs = []
    for _ in range(2):
        plant = mujoco_plant(options(table), 2, None, phi, [-1.0, -3.5, -34.3], timestep=1e-3)
        assert plant.consistency_report["ok"]  # noise does not change the dynamics
        with plant:
            plant.reset(np.array([[0.3, 0.3]]))
            noise = []
            for _ in range(400):
                noise.append(plant.read_sensors()[0] - plant.state()[0])
                plant.step(np.zeros(1), 1e-3)
        runs.append(np.array(noise))
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_allclose(runs[0].std(axis=0), [0.001, 0.01], rtol=0.2)


def test_noise_drawn_ahead_is_the_noise_read_one_by_one() -> None:
    """What the compiled loop adds (the run's noise drawn ahead, passed over where the Python loop
    takes over) is what the Python form reads, reading by reading, across the draw-ahead blocks;
    each copy's column is its seed's normal values times the deviations, in order."""
    from qcontrol.plants.mujoco.noise import BLOCK, SensorNoise

    std, seeds, count = [0.001, 0.01], [5, 9, 5], 2 * BLOCK + 500
    one = SensorNoise(std, seeds)
    each = np.array([one.draw() for _ in range(count)])
    other = SensorNoise(std, seeds)
    ahead = other.ahead(BLOCK + 900)
    other.skip(BLOCK + 700)
    rest = np.array([other.draw() for _ in range(count - BLOCK - 700)])
    assert ahead.tobytes() == each[:BLOCK + 900].tobytes()
    assert rest.tobytes() == each[BLOCK + 700:].tobytes()
    for copy, seed in enumerate(seeds):
        normals = np.random.default_rng(seed).normal(0.0, 1.0, size=(count, 2))
        assert (normals * std).tobytes() == each[:, copy].tobytes()


def test_build_model_applies_parameters_through_mjspec() -> None:
    model = build_model(options(RIGID))
    assert model.body_mass[1] == 1.0 and model.dof_damping[0] == 12.25
    assert np.linalg.norm(model.body_ipos[1]) == pytest.approx(3.5)
    assert model.opt.gravity[2] == -9.8 and not math.isnan(model.geom_size[0, 0])


def test_a_copy_mujoco_resets_after_blowing_up_reads_as_nan(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the instability warning to ./MUJOCO_LOG.TXT
    mj, _ = plants("example2", batch=2)
    with mj:
        mj.reset(np.array([[0.3, 0.3], [0.0, 0.0]]))
        for _ in range(2000):  # open loop: theta2 x2^2 cos(x1) blows up in finite time from (0.3, 0.3)
            mj.step(np.array([0.0, 0.0]), 1e-3)
        x, meas = mj.state(), mj.read_sensors()
    assert np.isnan(x[0]).all() and np.isnan(meas[0]).all()
    assert np.isfinite(x[1]).all() and np.abs(x[1]).max() < 1e-12


def test_mujoco_warnings_are_kept_not_written_to_the_working_directory(tmp_path, monkeypatch):
    """A blow-up makes MuJoCo warn; the plant keeps the message instead of MUJOCO_LOG.TXT."""
    from qcontrol.assembly import build_plant
    from qcontrol.scenario import load_scenario

    root = pathlib.Path(__file__).resolve().parents[1]
    monkeypatch.chdir(tmp_path)
    sc = load_scenario(root / "scenarios" / "example1.toml", ['plant.psi="exp(x2)**2"'])
    plant = build_plant(sc, "mujoco")
    with plant:
        plant.reset(np.array([[0.8, 30.0]]))  # exp(30)^2 ~ 1e26: MuJoCo resets the copy and warns
        plant.step(np.array([0.0]), 1e-3)
        assert np.isnan(plant.state()).all()
    assert plant.warnings and "unstable" in plant.warnings[0]
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    # after the run the handler found before it is back: importing or running changes nothing
    # process-wide (the model checks at load keep their warnings in memory the same way)
    assert mujoco.get_mju_user_warning() is None


def test_the_warning_handler_is_installed_for_a_block_and_restored_after_it():
    def previous(message: str) -> None:
        pass

    mujoco.set_mju_user_warning(previous)
    try:
        sink: list[str] = []
        with qmj.collect_warnings(sink):
            assert mujoco.get_mju_user_warning() is qmj._warn
            with qmj.kept_aside():
                assert mujoco.get_mju_user_warning() is qmj._warn
            model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><joint/><geom size='0.1'/>"
                                                   "</body></worldbody></mujoco>")
            data = mujoco.MjData(model)
            data.qpos[0] = np.nan
            mujoco.mj_step(model, data)  # MuJoCo warns of the bad qpos and resets the data
        assert mujoco.get_mju_user_warning() is previous
        assert len(sink) == 1 and "QPOS" in sink[0]
    finally:
        mujoco.set_mju_user_warning(None)


def test_the_model_check_is_measured_once_per_model_and_terms(monkeypatch) -> None:
    """Plants built together (under sharing) that differ in a noise seed or the law share one
    measured report, equal to a fresh measurement; another theta (another force) or another model
    is measured again; plants built apart measure it each."""
    from qcontrol.assembly import assemble
    from qcontrol.plants.mujoco import consistency
    from qcontrol.scenario import load_scenario
    from qcontrol.sharing import sharing

    measured = []
    original = consistency._measured
    monkeypatch.setattr(consistency, "_measured", lambda *args: measured.append(args) or original(*args))

    def report(*overrides: str) -> dict:
        sc = load_scenario(SCENARIOS / "example2-arm.toml", list(overrides))
        return assemble(sc, "mujoco").spec.plant.consistency_report

    with sharing():
        a = report("plant.mujoco.noise_seed=3")
        b = report("plant.mujoco.noise_seed=4", "controller.kind=comparison")
        assert len(measured) == 1 and a == b and a is not b
        assert original(*measured[0]) == a  # the kept report is the measurement
        assert report("plant.theta=[-1.0, 3.5, -34.3]") != a and len(measured) == 2
        assert report("plant.mujoco.frictionloss=3.0") != a and len(measured) == 3
    assert report("plant.mujoco.noise_seed=3") == a and len(measured) == 4


def test_runs_step_without_mujocos_profiling_timer_and_put_it_back() -> None:
    """The bindings' timer (installed with every MjData) is off inside a run and restored after;
    a timer of the user's own is left running."""
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><joint/><geom size='0.1'/></body></worldbody></mujoco>")
    data = mujoco.MjData(model)
    slot = qmj._timer_slot()
    found = slot.value
    assert found  # the bindings' timer
    with qmj.untimed():
        assert slot.value is None
        mujoco.mj_step(model, data)
    assert slot.value == found and data.timer[0].number == 1 and data.timer[0].duration == 0.0
    calls = []
    mujoco.set_mjcb_time(lambda: float(len(calls.append(0) or calls)))
    try:
        with qmj.untimed():
            mujoco.mj_step(model, data)
        assert calls and data.timer[0].duration > 0.0
    finally:
        mujoco.set_mjcb_time(None)
