"""A batch of one runs on plain floats (the engine's FLOATS form), a larger batch on numpy columns:
both go through the same controller and plant code, written over columns of any form, so they
must give the same numbers."""


import numpy as np
import pytest
from conftest import SCENARIOS

from qcontrol.assembly import build_controller, build_plant, build_quantizer, build_reference
from qcontrol.columns import ARRAYS
from qcontrol.controller import ComparisonLaw, PaperLaw
from qcontrol.engine import RunSpec, simulate
from qcontrol.engine.fastpath import COPIES, FLOATS, float_quantizer
from qcontrol.expr import compile_expression
from qcontrol.plants.ode import ChainPlant
from qcontrol.quantizer import QuantizedReading, UniformQuantizer, quantize
from qcontrol.scenario import load_scenario
from qcontrol.timegrid import TimeGrid

Q2, X2 = ["q1", "q2"], ["x1", "x2"]
PHI = ["x2", "x2**2*cos(x1)", "sin(x1)"]


def _controllers():
    r = [compile_expression(e, Q2) for e in ("1 + q2**2", "1 + 2*q2**2", "1")]
    phi = [compile_expression(e, X2) for e in PHI]
    psi = compile_expression("0.1*x2**2 - sqrt(abs(x1))", X2)
    return {
        "proposed": PaperLaw([4.0, 3.0], 0.005, kappa=1.125, gamma=1.5, sigma=0.7, r=r),
        "proposed-r_scale": PaperLaw([4.0, 3.0], 0.005, kappa=1.125, gamma=1.5, sigma=0.7, r=r,
                                               r_scale=2.5),
        "baseline": ComparisonLaw([4.0, 3.0], 0.005, psi, phi, adaptation_gain=2.0),
        "baseline-known": ComparisonLaw([4.0, 3.0], 0.005, None, phi, known_theta=[-1.0, -3.5, -34.3]),
    }


@pytest.mark.parametrize("name", list(_controllers()))
def test_float_columns_and_numpy_columns_give_the_same_control(name: str) -> None:
    ctrl = _controllers()[name]
    quantizer = UniformQuantizer(0.01)
    rng = np.random.default_rng(5)
    x = rng.uniform(-2, 2, (40, 2))
    state = rng.uniform(-1, 1, (40, ctrl.state_size))
    yd = [0.3, -0.2, 1.1]
    on_arrays = ctrl.control(quantize(quantizer, x), yd, tuple(np.ascontiguousarray(state.T)))
    advanced = ctrl.advancer(1e-3)(tuple(np.ascontiguousarray(state.T)), on_arrays)
    to_floats = float_quantizer(quantizer)
    for b in range(len(x)):
        reading = to_floats(x[b].tolist())
        assert reading.form is FLOATS and all(type(v) is float for v in reading.columns)
        out = ctrl.control(reading, yd, tuple(state[b].tolist()))
        assert type(out.u) is float
        assert out.u == pytest.approx(on_arrays.u[b], rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(out.zbar, [z[b] for z in on_arrays.zbar], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out.target, [np.broadcast_to(t, (40,))[b] for t in on_arrays.target],
                                   rtol=1e-12, atol=1e-12)
        stepped = ctrl.advancer_in(FLOATS, 1e-3)(tuple(state[b].tolist()), out)
        assert all(type(v) is float for v in stepped)
        np.testing.assert_allclose(stepped, [a[b] for a in advanced], rtol=1e-12, atol=1e-12)


class _Seen:
    """Wraps a controller and notes whether each reading came as floats."""

    def __init__(self, inner):
        self.inner, self.forms = inner, set()

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def control(self, reading, yd, adaptive, t=0.0):
        self.forms.add(reading.form)
        return self.inner.control(reading, yd, adaptive, t)


@pytest.mark.parametrize("overrides", [[], ["controller.kind=comparison"], ["controller.r_scale=2.0"],
                                       ["controller.kind=comparison", "controller.theta=known"],
                                       ["simulation.control_period=0.004"]])
@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_batch_of_one_on_floats_equals_the_numpy_batch(overrides: list[str], backend: str) -> None:
    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=2.0"] + overrides)
    runs = {}
    for batch in (1, 3):
        ctrl = _Seen(build_controller(sc))
        plant = build_plant(sc, backend, batch=batch)
        runs[batch] = simulate(RunSpec(plant=plant, law=ctrl, quantizer=build_quantizer(sc),
                                       reference=build_reference(sc), x0=sc.x0,
                                       grid=TimeGrid.of(sc.simulation.duration, sc.simulation.dt,
                                                        sc.simulation.control_period)))
        assert ctrl.forms == {FLOATS if batch == 1 else COPIES}  # floats for one copy, else numpy columns
    one = runs[1][0]
    for copy in runs[3]:
        assert not one.diverged and not copy.diverged and len(one.t) == len(copy.t)
        for field in ("x", "x_meas", "x_q", "u", "adaptive", "zbar", "e_z"):  # bit for bit
            assert getattr(one, field).tobytes() == getattr(copy, field).tobytes(), field


@pytest.mark.parametrize(("bound", "reason"), [(10.0, "bound"), (1e300, "NaN")])
def test_float_path_records_a_diverging_run_like_the_numpy_path(bound: float, reason: str) -> None:
    phi = [compile_expression("x2**3", X2)]  # x2' = 20 x2^3 + u blows up within milliseconds
    runs = {}
    for batch in (1, 2):
        sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=2.0"])
        plant = ChainPlant(2, None, phi, [20.0], batch=batch)
        runs[batch] = simulate(RunSpec(plant=plant, law=build_controller(sc),
                                       quantizer=build_quantizer(sc), reference=build_reference(sc),
                                       x0=[1.0, 4.0], grid=TimeGrid.of(2.0, 1e-3), state_bound=bound))
    one, other = runs[1][0], runs[2][1]
    assert one.diverged and other.diverged and one.diverged_time == other.diverged_time
    assert one.divergence_reason == other.divergence_reason and reason in one.divergence_reason
    np.testing.assert_allclose(one.x, other.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(one.adaptive, other.adaptive, rtol=0, atol=1e-12)


def test_float_quantizer_matches_the_array_quantizer_bit_for_bit() -> None:
    quantizer = UniformQuantizer(0.01)
    rng = np.random.default_rng(2)
    values = np.concatenate([rng.normal(0, 3, 500), np.arange(-50, 51) * 0.005,
                             [np.nan, np.inf, -np.inf, 1e300, -0.0]])
    expected = quantizer(values)
    to_floats = float_quantizer(quantizer)
    got = np.array([to_floats([v]).columns[0] for v in values.tolist()])
    np.testing.assert_array_equal(got, expected)


def test_quantized_reading_of_floats_offers_the_array_view() -> None:
    reading = QuantizedReading(None, 0.005, columns=(0.31, -0.42), form=FLOATS, batch=1)
    np.testing.assert_array_equal(reading.values, [[0.31, -0.42]])
    ctrl = _controllers()["proposed"]
    with pytest.raises(TypeError, match="QuantizedReading"):
        ctrl.control((0.31, -0.42), [0.0, 0.0, 0.0], (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="Lemma 2"):
        ctrl.control(QuantizedReading(None, 0.05, columns=(0.3, 0.4), form=FLOATS, batch=1), [0.0, 0.0, 0.0],
                     (0.0, 0.0, 0.0))


def test_on_floats_falls_back_to_numpys_answer() -> None:
    e = compile_expression("sqrt(x1) + log(x2) + 1/x1 + exp(x2)", X2)
    with np.errstate(all="ignore"):
        for values in ([4.0, 2.0], [-1.0, 2.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1000.0], [np.nan, 1.0]):
            expected = float(e(np.array([values]))[0])
            got = e.on_floats(values)
            assert type(got) is float
            assert got == pytest.approx(expected, rel=1e-14) or (np.isnan(got) and np.isnan(expected))


@pytest.mark.parametrize("record", ["full", "metrics"])
@pytest.mark.parametrize("with_progress", [False, True])
@pytest.mark.parametrize("bound", [0.5, 0.74, 1.1])
def test_a_batch_of_one_stops_at_the_first_row_out_of_bounds(python_loop, bound: float, with_progress: bool,
                                                             record: str) -> None:
    """A batch of one tests its rows in blocks (when they are written), not every step; it must
    still stop at exactly the first row whose state leaves the bound, whether that row falls
    before, on or between the rows where progress, flushes and metric chunks happen, and agree
    with a batch of two, which tests every row: in the array form, always (``python_loop``: else
    the batch of two would be compiled or not depending on the runs before it, through the
    compile gate's count; the compiled batch's stops are the array form's in
    tests/test_compiled_batch.py)."""
    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=3.0"])
    free = simulate(RunSpec(plant=build_plant(sc, "ode"), law=build_controller(sc),
                            quantizer=build_quantizer(sc), reference=build_reference(sc), x0=sc.x0,
                            grid=TimeGrid.of(3.0, 1e-3)))[0]
    first = int(np.argmax((np.abs(free.x) > bound).any(axis=1)))  # the independent answer
    assert 0 < first < len(free.t) - 1
    seen: list[int] = []
    runs = {}
    for batch in (1, 2):
        runs[batch] = simulate(RunSpec(plant=build_plant(sc, "ode", batch=batch), law=build_controller(sc),
                                       quantizer=build_quantizer(sc), reference=build_reference(sc),
                                       x0=sc.x0, grid=TimeGrid.of(3.0, 1e-3), state_bound=bound,
                                       record=record,
                                       progress=(lambda k, total: seen.append(k)) if with_progress else None))
    for run in (runs[1][0], *runs[2]):
        assert run.diverged and run.diverged_time == pytest.approx(first * 1e-3, abs=1e-12)
        assert "left the bound" in run.divergence_reason
        if record == "full":
            assert len(run.t) == first + 1
            np.testing.assert_array_equal(run.x, free.x[: first + 1])
            np.testing.assert_array_equal(run.adaptive, free.adaptive[: first + 1])
        else:
            assert run.steps == first
            np.testing.assert_array_equal(run.final_adaptive, free.adaptive[first])
    if record == "metrics":
        one, two = runs[1][0], runs[2][0]
        assert one.error_rate == two.error_rate and one.max_abs_u == two.max_abs_u
        assert one.max_abs_z1_last_half == two.max_abs_z1_last_half or (
            np.isnan(one.max_abs_z1_last_half) and np.isnan(two.max_abs_z1_last_half))


class _ArrayOnly:
    """A plant with only the core of the Plant protocol, in array form (no step in other column
    forms, no load, no actuator of its own): it must run at every batch size."""

    def __init__(self, inner: ChainPlant) -> None:
        self.inner, self.n, self.batch = inner, inner.n, inner.batch

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def reset(self, x0):
        self.inner.reset(x0)

    def observe(self):
        x = self.inner.state()
        return x, x.copy()

    def step(self, u, h):
        assert isinstance(u, np.ndarray) and u.shape == (self.batch,)
        self.inner.step(u, h)

    def close(self):
        pass


@pytest.mark.parametrize("batch", [1, 3])
def test_a_plant_with_only_the_array_form_runs_at_every_batch_size(batch: int) -> None:
    from qcontrol.plants import ColumnStepping, Plant

    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=0.5"])
    plant = _ArrayOnly(build_plant(sc, "ode", batch=batch))
    assert isinstance(plant, Plant) and not isinstance(plant, ColumnStepping)
    runs = [simulate(RunSpec(plant=p, law=build_controller(sc), quantizer=build_quantizer(sc),
                             reference=build_reference(sc), x0=sc.x0,
                             grid=TimeGrid.of(sc.simulation.duration, sc.simulation.dt)))
            for p in (plant, build_plant(sc, "ode", batch=batch))]
    for mine, native in zip(*runs, strict=True):  # numpy's sin, cos against math's for one copy
        assert not mine.diverged and len(mine.t) == len(native.t) == 501
        for field in ("x", "x_q", "u", "adaptive"):
            np.testing.assert_allclose(getattr(mine, field), getattr(native, field), rtol=1e-12, atol=1e-14,
                                       err_msg=field)


class _ArrayOnlyLaw:
    """The paper's law seen through the array form of BatchLaw only (no AnyColumnForm): it must
    run at every batch size, a batch of one through the engine's adapter."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.state_name, self.state_size, self.copies = inner.state_name, inner.state_size, inner.copies
        self.coordinates, self.diagnostics = inner.coordinates, inner.diagnostics
        self.forms: set[str] = set()

    def initial_state(self, batch):
        return self.inner.initial_state(batch)

    def control(self, reading, yd, state, t=0.0):
        assert reading.form is ARRAYS and all(isinstance(e, np.ndarray) for e in (*reading.columns, *state))
        self.forms.add(f"array{len(reading.values)}")
        return self.inner.control(reading, yd, state, t)

    def advancer(self, h):
        return self.inner.advancer(h)

    def constants(self):
        return self.inner.constants()


@pytest.mark.parametrize("batch", [1, 3])
def test_a_law_with_only_the_array_form_runs_at_every_batch_size(batch: int) -> None:
    from qcontrol.controller import AnyColumnForm

    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=0.5"])
    law = _ArrayOnlyLaw(build_controller(sc))
    assert not isinstance(law, AnyColumnForm) and isinstance(build_controller(sc), AnyColumnForm)
    runs = [simulate(RunSpec(plant=build_plant(sc, "ode", batch=batch), law=lw,
                             quantizer=build_quantizer(sc), reference=build_reference(sc), x0=sc.x0,
                             grid=TimeGrid.of(sc.simulation.duration, sc.simulation.dt)))
            for lw in (law, build_controller(sc))]
    assert law.forms == {f"array{batch}"}
    for mine, native in zip(*runs, strict=True):
        assert not mine.diverged and len(mine.t) == len(native.t) == 501
        for field in ("x", "x_q", "u", "adaptive"):
            np.testing.assert_allclose(getattr(mine, field), getattr(native, field), rtol=1e-12, atol=1e-14,
                                       err_msg=field)
