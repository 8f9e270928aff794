"""The compiled loop (qcontrol.engine.compiled_loop) against the Python loop: every recorded and
derived signal identical to the last bit, row by row, on every shipped scenario on both backends
and for each built-in law; the runs it must leave to Python; the hand-over to Python where the
compiled code cannot reproduce an evaluation."""

import dataclasses
import sys

import numpy as np
import pytest
from conftest import SCENARIOS

import qcontrol.engine.compiled_loop as compiled_loop
from qcontrol.assembly import build_controller, build_plant, build_separation, run_spec
from qcontrol.controller import PaperLaw
from qcontrol.engine import ClosedLoop, RunSpec
from qcontrol.expr import compile_expression
from qcontrol.plants.ode import ChainPlant
from qcontrol.quantizer import UniformQuantizer
from qcontrol.quantizers import HysteresisQuantizer
from qcontrol.reference import Constant
from qcontrol.scenario import load_scenario
from qcontrol.timegrid import TimeGrid

SHIPPED = sorted(p.stem for p in SCENARIOS.glob("*.toml"))
CASES = [(name, backend) for name in SHIPPED for backend in ("ode", "mujoco")
         if backend == "ode" or "[plant.mujoco]" in (SCENARIOS / f"{name}.toml").read_text()]
@pytest.fixture(autouse=True)
def _compile_short_runs(monkeypatch) -> None:
    """Short runs here (which the engine would leave to Python) run the compiled loop."""
    monkeypatch.setattr(compiled_loop, "MIN_ROWS", 0)
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)


LAWS = {"exact hold": ["controller.hold=\"exact\""], "comparison law": ["controller.kind=\"comparison\""],
        "linear law": ["controller.kind=\"linear\""], "tuning law": ["controller.kind=\"tuning\""]}


def _loop(sc, backend: str, record: str = "full", law=None) -> tuple[ClosedLoop, object]:
    spec = run_spec(sc, build_plant(sc, backend), law or build_controller(sc), [sc.x0], build_separation(sc),
                    record)
    loop = ClosedLoop(spec)
    return loop, loop.run()[0]


def _both(monkeypatch, sc, backend: str, record: str = "full", law=None):
    compiled = _loop(sc, backend, record, law)
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    python = _loop(sc, backend, record, law)
    monkeypatch.delenv("QCONTROL_COMPILE")
    return compiled, python


def _assert_identical(a, b) -> None:
    assert a.diverged == b.diverged and a.divergence_reason == b.divergence_reason
    assert a.t.tobytes() == b.t.tobytes()
    for name, values in a.signals.items():
        assert np.asarray(values).tobytes() == np.asarray(b.signals[name]).tobytes(), name


def _scenario(name: str, extra: list[str] = ()):
    return load_scenario(SCENARIOS / f"{name}.toml", ["simulation.duration=0.4", *extra])


@pytest.mark.parametrize(("name", "backend"), CASES)
def test_compiled_and_python_loops_agree_on_every_shipped_scenario(monkeypatch, name: str,
                                                                   backend: str) -> None:
    sc = _scenario(name)
    (loop, compiled), (python_loop, python) = _both(monkeypatch, sc, backend)
    assert python_loop.handover == 0  # QCONTROL_COMPILE=0: all of it in Python
    # terms in t are evaluated at each stage's time in Python: the Python loop; so are the
    # strict-feedback plants (the ODE's regressors before the last equation, MuJoCo's order 3,
    # which the tuning-function law drives); sensor noise (the realistic scenarios) is compiled:
    # drawn ahead, the same values
    strict = bool(sc.terms.rows)  # (regressor rows before the last equation: order 3 on MuJoCo, too)
    python_only = sc.terms.timed or strict or not compiled_loop.compilable(build_controller(sc))
    assert loop.handover == (0 if python_only else None)
    _assert_identical(compiled, python)


# the comparison law adds psi and phi to its u (eq. (46)): on Example 1 (psi only) and Example 2 (phi
# only); the exact hold changes how the law's own constants hold u (no plant term): on Example 2, as
# each plant's lines are checked with the default law above (each further plant is one more module
# to compile); the tuning law's design (its program of shared trees) on Example 2's sin and cos.
# On the ODE only: a law's lines are traced from the law alone (traced_parts: no plant in them) and
# the same text runs between the lines of either plant (checked below, uncompiled), whose own lines
# every shipped scenario runs on both backends above (a MuJoCo module per law: 0.6-0.8 s of compile)
LAW_CASES = [("exact hold", "example2"), ("comparison law", "example1"), ("comparison law", "example2"),
             ("linear law", "example2"), ("tuning law", "example2")]


def _same_lines_on_mujoco(sc, loop: ClosedLoop) -> None:
    """The compiled loop of ``sc`` on MuJoCo (generated, not compiled) runs the quantizer's and the
    law's lines of ``loop`` (the ODE's, compiled and checked) unchanged, between its plant's."""
    mujoco = ClosedLoop(run_spec(sc, build_plant(sc, "mujoco"), build_controller(sc), [sc.x0], None))
    parts, ode = mujoco.compiled.parts, loop.compiled.parts
    assert parts._replace(constants=None, memory=None) == ode._replace(constants=None, memory=None)
    assert parts.constants.tobytes() == ode.constants.tobytes() and type(parts.memory) is type(ode.memory)
    with mujoco.plant:  # (its passive callback installed, as in a run: the plant's lines given)
        source = mujoco.compiled.source(mujoco.plant.native_stepper(mujoco.grid.dt, mujoco.grid.rows))
    assert "read_copy(" in source and "step_copy(" in source
    stripped = "\n".join(line.strip() for line in source.splitlines())
    for lines in (ode.quantize, ode.control, ode.advance, ode.applied):
        assert "\n".join(line.strip() for line in lines) in stripped


@pytest.mark.parametrize(("law", "name"), LAW_CASES)
def test_compiled_and_python_loops_agree_for_each_built_in_law(monkeypatch, law: str, name: str) -> None:
    (loop, compiled), (_, python) = _both(monkeypatch, _scenario(name, LAWS[law]), "ode")
    assert loop.handover is None
    _assert_identical(compiled, python)
    _same_lines_on_mujoco(_scenario(name, LAWS[law]), loop)


# one structure (one module to compile), two starts: math's exp and tanh (numpy's round otherwise)
# to the end, and exp(x1) overflowing in the first step (row 0 compiled, Python from row 1)
@pytest.mark.parametrize(("x0", "handover"), [("[0.5, 0.0]", None), ("[705.0, 0.0]", 1)])
def test_the_tuning_law_is_compiled_and_hands_over_where_math_refuses(monkeypatch, x0: str,
                                                                    handover: int | None) -> None:
    phi = '["x2", "exp(x1)*x2", "tanh(x1)"]'
    sc = _scenario("example2", ["controller.kind=\"tuning\"", f"plant.phi={phi}", f"plant.x0={x0}"])
    (loop, compiled), (_, python) = _both(monkeypatch, sc, "ode")
    assert loop.handover == handover
    _assert_identical(compiled, python)


# (on the ODE, the MuJoCo loop's text checked: the quantizers' lines are the plant's neighbours only)
@pytest.mark.parametrize("keys", [
    ['quantizer.kind="hysteresis"', "quantizer.delta=[0.0015, 0.05]"],  # levels kept row to row
    ["quantizer.delta=[0.0015, 0.05]", "quantizer.input.delta=0.5"],  # the plant stepped with q_u(u)
    ["quantizer.delta=0.01", "quantizer.input.delta=0.5", "simulation.control_period=0.005"],
])
def test_hysteresis_and_an_input_quantizer_are_compiled(monkeypatch, keys: list[str]) -> None:
    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=0.4", *keys],
                       unset=["controller.delta"])
    (loop, compiled), (_, python) = _both(monkeypatch, sc, "ode")
    assert loop.handover is None
    _assert_identical(compiled, python)
    _same_lines_on_mujoco(sc, loop)


@pytest.mark.parametrize("input_delta", [None, 0.5])
def test_hysteresis_levels_and_the_input_quantizer_carry_over_a_hand_over(monkeypatch,
                                                                          input_delta: float | None) -> None:
    """The bounding function divides by zero where q1 reaches 0.25 (math raises; numpy's inf
    times 1e-300 is inf): the Python loop takes over with the levels the compiled loop kept (a row
    read again keeps its level) and steps with q_u(u). The state moves slowly there, so a level
    the loop did not carry over would read otherwise (x2's held level is not its nearest one)."""
    def spec() -> RunSpec:
        base = _refusing_run("0", "1 + 1e-300 * (1 / (q1 - 0.25))", [0.27, -0.35])
        law = PaperLaw([1.0, 1.0], (0.01, 0.01), kappa=3.0, gamma=1.0, sigma=1.0, r=base.law.r)
        applied = None if input_delta is None else UniformQuantizer(input_delta)
        return dataclasses.replace(base, law=law, quantizer=HysteresisQuantizer(0.01, 2),
                                   input_quantizer=applied)
    loop = ClosedLoop(spec())
    compiled = loop.run()[0]
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    python = ClosedLoop(spec()).run()[0]
    row = loop.handover
    assert row is not None and row > 0
    assert compiled.x_q[row, 0] == 0.25  # (the refused reading)
    nearest = 0.01 * np.floor(compiled.x_meas[row] / 0.01 + 0.5)
    assert np.any(compiled.x_q[row] != nearest)  # a level held there, not the nearest one
    _assert_identical(compiled, python)


def test_a_quantizer_per_channel_with_a_range_is_compiled(monkeypatch) -> None:
    """A step per channel and a range the state leaves (its angle readings saturate at q(0.35));
    on the ODE, the MuJoCo loop's text checked."""
    keys = ["simulation.duration=0.4", "quantizer.delta=[0.0015, 0.05]", "quantizer.range=[0.35, 20.0]"]
    sc = load_scenario(SCENARIOS / "example2.toml", keys, unset=["controller.delta"])
    (loop, compiled), (_, python) = _both(monkeypatch, sc, "ode")
    assert loop.handover is None
    assert np.max(compiled.x_q[:, 0]) < np.max(compiled.x_meas[:, 0])  # saturated
    _assert_identical(compiled, python)
    _same_lines_on_mujoco(sc, loop)


@pytest.mark.parametrize("realism", [["plant.mujoco.sensor_delay=0.002"],
                                     ["plant.mujoco.sensor_period=0.002"],
                                     ["simulation.control_period=0.003"]])
def test_sensors_with_history_and_held_samples_are_compiled_too(monkeypatch, realism: list[str]) -> None:
    """Sensors reading MuJoCo's history (the loop then calls mj_sensorPos/Vel) and a control
    period of several steps."""
    (loop, compiled), (_, python) = _both(monkeypatch, _scenario("example2", realism), "mujoco")
    assert loop.handover is None
    _assert_identical(compiled, python)


@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_a_load_changing_mid_run_is_applied_between_the_chunks(monkeypatch, backend: str) -> None:
    sc = _scenario("example2")
    runs = []
    for compiled in ("1", "0", "0"):
        monkeypatch.setenv("QCONTROL_COMPILE", compiled)
        spec = run_spec(sc, build_plant(sc, backend), build_controller(sc), [sc.x0], None)
        loop = ClosedLoop(dataclasses.replace(spec, loads=[(123, 2.5), (251, 0.0)] if len(runs) < 2 else []))
        runs.append((loop, loop.run()[0]))
    assert runs[0][0].handover is None
    _assert_identical(runs[0][1], runs[1][1])
    assert runs[1][1].signals["x"].tobytes() != runs[2][1].signals["x"].tobytes()  # the load did act


@pytest.mark.parametrize("backend", ["ode", "mujoco"])
@pytest.mark.parametrize("x0", ["[10.0, 10.0]", "[3.0, 3.0]"])
def test_a_diverging_run_stops_at_the_same_row(monkeypatch, backend: str, x0: str) -> None:
    """Example 2 from a large state: the sampled loop blows up within milliseconds (on MuJoCo the
    copy is reset by MuJoCo and read as NaN from then on)."""
    (loop, compiled), (_, python) = _both(monkeypatch, _scenario("example2", [f"plant.x0={x0}"]), backend)
    assert compiled.diverged and len(compiled.t) < 100
    _assert_identical(compiled, python)


def test_a_short_run_stays_in_python(monkeypatch) -> None:
    monkeypatch.setattr(compiled_loop, "MIN_ROWS", 5000)
    loop, _ = _loop(_scenario("example2"), "ode")
    assert loop.handover == 0


def test_a_process_without_numba_compiles_only_long_runs(monkeypatch) -> None:
    import numba  # noqa: F401 (in sys.modules, as after any compiled run)

    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 50_000)
    sc = _scenario("example2")
    spec = run_spec(sc, build_plant(sc, "ode"), build_controller(sc), [sc.x0], None)
    assert compiled_loop.compiled_loop(spec) is not None
    monkeypatch.setattr(compiled_loop.compiled_paths, "enabled", lambda: True)  # (it imports numba)
    monkeypatch.delitem(sys.modules, "numba")  # only looked up below, never imported
    assert compiled_loop.compiled_loop(spec) is None
    assert compiled_loop.compiled_loop(dataclasses.replace(spec, grid=TimeGrid.of(50.0, 1e-3))) is not None


def test_a_structure_not_compiled_before_compiles_once_its_runs_reach_cold_min_rows(monkeypatch,
                                                                                    tmp_path) -> None:
    """A structure not compiled before is compiled only once the rows run without it reach
    COLD_MIN_ROWS (about a compile's cost in Python): a shorter run keeps Python, compiles nothing
    and counts its rows in the cache folder; a structure compiled before is taken at once."""
    import numba  # noqa: F401 (a process that has started numba: numba_pays lets short runs compile)

    from qcontrol.compiled import cache

    monkeypatch.setenv("QCONTROL_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(cache, "_LOADED", {k: v for k, v in cache._LOADED.items()  # no loop loaded here
                                           if not k.startswith("qcontrol_loop_")})
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 1000)
    sc = _scenario("example2")  # 401 rows: the compiled loop's, were it compiled before
    for _ in range(2):
        loop, _ = _loop(sc, "ode")
        assert loop.compiled is not None and loop.handover == 0  # all of it in Python
    counts = list(tmp_path.glob("qcontrol_loop_*.rows"))
    assert len(counts) == 1 and counts[0].read_text() == "802"
    assert not list(tmp_path.glob("qcontrol_loop_*.py")) and not list(tmp_path.glob("__pycache__/*loop*"))
    source = loop.compiled.source(loop.plant.native_stepper(loop.grid.dt, loop.grid.rows))
    assert cache.uncompiled_rows("loop", source) == 802
    assert not compiled_loop.compile_pays("loop", source, 197)  # 999 rows without it
    assert compiled_loop.compile_pays("loop", source, 1)  # 1000: compiled
    cache.generated_module("loop", source)  # compiled (numba compiles at the first call; taken from now on)
    assert cache.uncompiled_rows("loop", source) is None and not counts[0].exists()
    assert compiled_loop.compile_pays("loop", f"{source}# another\n", 1000)  # pays for its compile at once


def test_a_metrics_run_reduces_the_same_rows(monkeypatch) -> None:
    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=3.2"])
    (loop, compiled), (_, python) = _both(monkeypatch, sc, "mujoco", record="metrics")
    assert loop.handover is None
    assert compiled.steps == python.steps and compiled.values.keys() == python.values.keys()
    for name, value in compiled.values.items():
        other = python.values[name]
        same = (np.asarray(value).tobytes() == np.asarray(other).tobytes() if isinstance(value, np.ndarray)
                else repr(value) == repr(other))  # floats and dicts of floats: repr is exact
        assert same, name


class Integral(PaperLaw):
    def control(self, reading, yd, state, t=0.0):
        return super().control(reading, yd, state, t)


class Renamed(PaperLaw):
    """Changes nothing of the law's numbers."""


@pytest.mark.parametrize(("what", "overrides", "backend", "law_class"), [
    ("a subclass that overrides a method", [], "ode", Integral),
])
def test_what_keeps_the_python_loop(monkeypatch, what: str, overrides: list[str], backend: str,
                                    law_class) -> None:
    sc = _scenario("example2", overrides)
    law = None
    if law_class is not None:
        base = build_controller(sc)
        law = law_class(base.c, base.max_error, kappa=base.kappa, gamma=base.gamma, sigma=base.sigma,
                        r=base.r)
    (loop, compiled), (_, python) = _both(monkeypatch, sc, backend, law=law)
    assert loop.handover == 0, what
    _assert_identical(compiled, python)


@pytest.mark.parametrize(("backend", "period"), [("mujoco", None), ("ode", 0.005), ("mujoco", 0.02)])
def test_velocity_differencing_is_compiled(monkeypatch, backend: str, period: float | None) -> None:
    """x2 differenced from the encoder over the control period (every row without one)."""
    timing = [] if period is None else [f"simulation.control_period={period!r}"]
    sc = _scenario("example2", ["simulation.velocity_source=\"difference\"", *timing])
    (loop, compiled), (_, python) = _both(monkeypatch, sc, backend)
    assert loop.handover is None
    _assert_identical(compiled, python)
    q1, v = compiled.signals["x_q"][:, 0], compiled.signals["x_q"][:, 1]
    hold = round((period or sc.simulation.dt) / sc.simulation.dt)
    past = np.r_[np.full(hold, q1[0]), q1[:-hold]]  # the position one period before, q1(0) before the run
    assert np.array_equal(v, (q1 - past) / (hold * sc.simulation.dt), equal_nan=True)


def test_a_subclass_that_changes_nothing_is_compiled(monkeypatch) -> None:
    sc = _scenario("example2")
    base = build_controller(sc)
    law = Renamed(base.c, base.max_error, kappa=base.kappa, gamma=base.gamma, sigma=base.sigma, r=base.r)
    (loop, compiled), (_, python) = _both(monkeypatch, sc, "ode", law=law)
    assert loop.handover is None
    _assert_identical(compiled, python)


def _refusing_run(psi: str, r: str, x0: list[float], velocity: str = "sensor") -> RunSpec:
    """An ODE run whose plant term or bounding function overflows ``math`` (the Python form then
    takes numpy's inf) part of the way through; ``velocity="difference"``: x2 differenced over a
    5-row control period (the hand-over carries the positions the compiled loop kept)."""
    x = ["x1", "x2"]
    plant = ChainPlant(2, compile_expression(psi, x), [compile_expression("x2", x)], [1.0])
    law = PaperLaw([1.0, 1.0], 0.005, kappa=3.0, gamma=1.0, sigma=1.0,
                             r=[compile_expression(r, ["q1", "q2"]), compile_expression("1", ["q1", "q2"])])
    return RunSpec(plant=plant, law=law, quantizer=UniformQuantizer(0.01), reference=Constant(0.0),
                   x0=x0, grid=TimeGrid.of(0.5, 1e-3, 0.005 if velocity == "difference" else None),
                   state_bound=1e300, velocity_source=velocity)


@pytest.mark.parametrize(("psi", "r", "x0", "velocity"), [
    ("exp(x1)", "1", [700.0, 2000.0], "sensor"),  # the plant's term overflows inside a step
    ("0", "1 + exp(q1 / 2)", [0.0, 2000.0], "sensor"),  # the bounding function overflows at a sample
    ("exp(x1)", "1", [0.0, 2000.0], "difference"),  # (a step from row 8: the last 5 positions kept)
    ("0", "1 + exp(q1 / 2)", [0.0, 2000.0], "difference"),  # (a sample at row 15)
])
def test_the_python_loop_takes_over_where_math_refuses(monkeypatch, psi: str, r: str,
                                                       x0: list[float], velocity: str) -> None:
    loop = ClosedLoop(_refusing_run(psi, r, x0, velocity))
    compiled = loop.run()[0]
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    python = ClosedLoop(_refusing_run(psi, r, x0, velocity)).run()[0]
    assert loop.handover is not None and loop.handover > (5 if velocity == "difference" else 0)
    _assert_identical(compiled, python)


def test_expression_text_never_becomes_code(monkeypatch, tmp_path) -> None:
    """An expression's text (a comment may hold anything) appears in generated modules only as a
    string literal: a comment that would close a docstring runs nothing."""
    monkeypatch.setenv("QCONTROL_CACHE_DIR", str(tmp_path))
    payload = '# """; import os; os.environ["QCONTROL_INJECTED"] = "1"; """'
    sc = _scenario("example2", [f"controller.r=['1 + q2**2 {payload}', '1 + 2*q2**2', '1']",
                                f"plant.phi=['x2', 'x2**2*cos(x1) {payload}', 'sin(x1)']"])
    for backend in ("ode", "mujoco"):
        (loop, compiled), (_, python) = _both(monkeypatch, sc, backend)
        assert loop.handover is None
        _assert_identical(compiled, python)
    assert "QCONTROL_INJECTED" not in __import__("os").environ
    assert any(payload in path.read_text() for path in tmp_path.glob("*.py"))  # it was there, as text
