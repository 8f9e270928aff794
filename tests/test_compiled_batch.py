"""The compiled batch of ODE copies (qcontrol.engine.compiled_batch): each copy's numbers equal its
run alone and the array form's batch to the last bit, on both examples, with copies that diverge
(and whose code math refuses after they stopped); a copy refused before it stopped has the batch
done again in the array form; formulas whose numpy form differs from math's keep the array form."""

import dataclasses

import numpy as np
import pytest
from conftest import SCENARIOS

import qcontrol.engine.compiled_loop as compiled_loop
from qcontrol.assembly import assemble
from qcontrol.engine import ClosedLoop, RunSpec
from qcontrol.expr import compile_expression
from qcontrol.plants.ode import ChainPlant
from qcontrol.scenario import load_scenario


@pytest.fixture(autouse=True)
def _compile_short_runs(monkeypatch) -> None:
    """Short runs here (which the engine would leave to the array form) run the compiled batch."""
    monkeypatch.setattr(compiled_loop, "MIN_ROWS", 0)
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)


def _variants(name: str, extra: list[str] = ()) -> list:
    """Copies of ``name`` differing in kappa and x(0); the far ones diverge."""
    x1, x2 = np.linspace(-3.0, 3.0, 24).tolist(), np.tile([-60.0, 0.3, 5.0, 60.0], 6).tolist()
    return [load_scenario(SCENARIOS / f"{name}.toml", ["simulation.duration=0.3", f"plant.x0=[{a!r}, {b!r}]",
                                                       f"controller.kappa_margin={m!r}", *extra])
            for a, b, m in zip(x1, x2, np.linspace(0.1, 2.0, 24).tolist(), strict=True)]


def _run(spec: RunSpec, monkeypatch=None, compiled: bool = True) -> tuple[ClosedLoop, list]:
    if not compiled:
        monkeypatch.setenv("QCONTROL_COMPILE", "0")
    loop = ClosedLoop(spec)
    runs = loop.run()
    monkeypatch.delenv("QCONTROL_COMPILE", raising=False)
    return loop, runs


def _meta(run) -> dict:
    return {k: repr(v) for k, v in vars(run).items() if k not in ("wall_time_s", "signals", "t")}


def _same(a, b, names=None) -> None:
    if names is None:
        assert _meta(a) == _meta(b)
    assert (a.diverged, a.divergence_reason, a.steps) == (b.diverged, b.divergence_reason, b.steps)
    for name, values in getattr(a, "signals", {}).items():
        if names is None or name in names:
            assert np.asarray(values).tobytes() == np.asarray(b.signals[name]).tobytes(), name


def _spec(scs, record: str) -> RunSpec:
    return dataclasses.replace(assemble(scs, "ode").spec, record=record)


@pytest.mark.parametrize("name", ["example1", "example2"])
def test_every_copy_equals_its_run_alone_and_the_array_form(monkeypatch, name: str) -> None:
    scs = _variants(name)
    for record in ("metrics", "full"):
        loop, compiled = _run(_spec(scs, record), monkeypatch)
        assert loop.handover is None  # the compiled batch ran to the end
        _, array = _run(_spec(scs, record), monkeypatch, compiled=False)
        for a, b in zip(compiled, array, strict=True):
            _same(a, b)
    assert 0 < sum(r.diverged for r in compiled) < len(scs)  # some copies stopped, others ran on
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    for i in (0, 1, 6, 7):  # a run alone (float form) of a few copies, stopped ones among them
        _same(compiled[i], assemble([scs[i]], "ode").run()[0], ("x", "x_meas", "x_q", "u", "adaptive"))


def test_the_lemma2_figure_of_a_batch_is_its_runs_alone(monkeypatch) -> None:
    """With c_1 = 3 a batch's matrix product of the Lemma 2 coordinates rounds otherwise than a
    run alone's row by row; the figure is still each run alone's, in the compiled batch (the rows
    it notes in its loop recomputed; with three slots the first block overflows and is reduced in
    the array form, the later 40-row blocks are merged) and in the array form."""
    import qcontrol.engine.lemma2 as lemma2
    import qcontrol.engine.retention as retention

    monkeypatch.setattr(lemma2, "CANDIDATES", 3)
    monkeypatch.setattr(retention, "METRICS_CHUNK", 40)
    monkeypatch.setattr(retention, "METRICS_BUFFER_ELEMENTS", 40)
    scs = _variants("example2", ["controller.c=[3.0, 5.0]"])
    loop, compiled = _run(_spec(scs, "metrics"), monkeypatch)
    assert loop.handover is None
    _, array = _run(_spec(scs, "metrics"), monkeypatch, compiled=False)
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    for sc, a, b in zip(scs, compiled, array, strict=True):
        alone = assemble([sc], "ode").run(record="metrics")[0].e_z_max.tobytes()
        assert a.e_z_max.tobytes() == alone == b.e_z_max.tobytes()


def test_one_module_serves_every_batch_size(monkeypatch) -> None:
    """The batch size is a run-time value: batches of 3 and 24 copies of one structure run the
    same generated text (one module, one cache entry), and a copy's numbers are the same in both."""
    import qcontrol.compiled.cache as cache

    texts, generated = [], cache.generated_module
    monkeypatch.setattr(cache, "generated_module", lambda kind, source: (
        texts.append(source) if kind == "batch" else None, generated(kind, source))[1])
    scs, runs = _variants("example2"), []
    for copies in (scs[:3], scs):
        loop, done = _run(_spec(copies, "metrics"), monkeypatch)
        assert loop.handover is None and len(done) == len(copies)
        runs.append(done)
    assert len(texts) == 2 and texts[0] == texts[1]
    assert "def pair_rows" not in texts[0]  # (fewer copy-rows than PAIRS_MIN_ROWS: one copy at a time)
    for a, b in zip(runs[0], runs[1], strict=False):
        _same(a, b)


def test_paired_copies_are_each_their_run_alone_wherever_one_stops(monkeypatch) -> None:
    """A large batch's ODE copies run two at a time in lockstep (here from 2 copies on); where math
    refuses one's step or its control (copies that diverge), the other goes on alone from where it
    was: at the row it had reached, with its step first or not. Each case arises with the refused
    copy first and with it second in its pair: a step refused inside a block (the default blocks;
    copy 5 in blocks of 3) or as a block's first step (blocks of 1 and 3 rows), a control refused
    (r's cos(q2) once q2 is infinite: copy 18, twice, first in one pair and second in another).
    An odd batch's last copy runs beside a twin of itself. Every copy's numbers are still the array
    form's and its run alone's, to the last bit, and no copy is refused before it stopped (no batch
    redone). (Example 2 with one term, x2^2 cos(x1), and one estimate: a pair form about a quarter
    cheaper to compile than the full example's; one structure for every case.)"""
    import qcontrol.compiled.cache as cache
    import qcontrol.engine.compiled_batch as compiled_batch
    import qcontrol.engine.retention as retention

    texts, generated = [], cache.generated_module
    monkeypatch.setattr(cache, "generated_module", lambda kind, source: (
        texts.append(source) if kind == "batch" else None, generated(kind, source))[1])
    monkeypatch.setattr(compiled_batch, "PAIRS_MIN_ROWS", 2)
    one_term = ["plant.mujoco.native_terms=[]", 'plant.phi=["x2**2*cos(x1)"]', "plant.theta=[-3.5]",
                'controller.r=["1 + 2*q2**2 + 1e-300*cos(q2)"]']
    copies = _variants("example2", one_term)  # (stopping at rows 2, 3 and 6)
    scs = [*copies[:17], copies[18], copies[17], copies[18], *copies[20:23]]
    _, array = _run(_spec(scs, "metrics"), monkeypatch, compiled=False)
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    alone = [assemble([sc], "ode").run(record="metrics")[0] for sc in scs]
    monkeypatch.delenv("QCONTROL_COMPILE")
    blocks = ("METRICS_CHUNK", "METRICS_MIN_CHUNK", "METRICS_BUFFER_ELEMENTS")
    defaults = {name: getattr(retention, name) for name in blocks}
    for rows in (1, 3, None):  # (None: the default blocks, longer than the run)
        for name in blocks:
            monkeypatch.setattr(retention, name, rows or defaults[name])
        loop, compiled = _run(_spec(scs, "metrics"), monkeypatch)
        assert loop.handover is None and "def pair_rows" in texts[-1]
        assert 0 < sum(r.diverged for r in compiled) < len(scs)
        for a, b, c in zip(compiled, array, alone, strict=True):
            _same(a, b)
            _same(a, c)
    assert len(set(texts)) == 1

def _refusing(x1: list[float]) -> RunSpec:
    """A batch whose plant term sqrt(x1) math refuses (numpy answers NaN) where x1 < 0. (A full
    record: the redone run is a fresh array form's, whatever the record, and every signal of every
    copy is compared; without the folds, a module about half a metrics record's to compile.)"""
    x = ["x1", "x2"]
    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=0.2"])
    spec = _spec([sc] * len(x1), "full")
    plant = ChainPlant(2, compile_expression("sqrt(x1)", x), [compile_expression("x2", x)], [1.0],
                       batch=len(x1))
    return dataclasses.replace(spec, plant=plant, x0=[[v, 0.0] for v in x1])


def test_a_copy_refused_before_it_stopped_has_the_batch_done_in_the_array_form(monkeypatch) -> None:
    loop, compiled = _run(_refusing([0.5, -0.5, 1.0]), monkeypatch)
    assert loop.handover == 0  # the compiled batch was chosen, and the array form redid the run
    _, array = _run(_refusing([0.5, -0.5, 1.0]), monkeypatch, compiled=False)
    assert compiled[1].diverged and not compiled[0].diverged
    for a, b in zip(compiled, array, strict=True):
        _same(a, b)


def test_a_power_exp_and_expm1_are_compiled_and_each_copy_is_its_run_alone(monkeypatch) -> None:
    """numba's exp and expm1 are libm's, as the math a run alone and the Python loop step with, and
    a constant power 0.5 stays libm's pow in compiled code (LLVM would take a square root): a batch
    with the exact hold (expm1) and terms with an exponential and powers is compiled (one module
    for each record, not one for each function), and each copy's numbers are the array form's and
    its run alone's, compiled or in the Python loop, signals and metrics. With theta_1 = -30 and
    h = 0.01 the power's last bit reaches the state: with the square root, copies 1, 5, 14, 17, 18,
    22 and 23 differ from the array form."""
    terms = ['controller.hold="exact"', "plant.theta=[-30.0, -3.5, -34.3]", "simulation.dt=0.01",
             'plant.phi=["x2*abs(x2)**0.5", "x2**2*cos(x1)", "spow(x1, 0.5)*exp(-0.1*x1*x1)"]',
             "simulation.duration=3.0"]
    scs = _variants("example2", terms)
    for record in ("metrics", "full"):
        loop, compiled = _run(_spec(scs, record), monkeypatch)
        assert loop.handover is None  # compiled from row 0 to the end
        _, array = _run(_spec(scs, record), monkeypatch, compiled=False)
        for a, b in zip(compiled, array, strict=True):
            _same(a, b)
        for i in (1, 15, 17, 22):  # (copy 15 diverges)
            if record == "metrics":
                monkeypatch.setenv("QCONTROL_COMPILE", "0")
                _same(compiled[i], assemble([scs[i]], "ode").run(record=record)[0])
                monkeypatch.delenv("QCONTROL_COMPILE")
                continue
            alone, python = (_run(_spec([scs[i]], "full"), monkeypatch, compiled=c) for c in (True, False))
            assert python[0].handover == 0 and (alone[0].handover is None or compiled[i].diverged)
            _same(compiled[i], alone[1][0], ("x", "x_meas", "x_q", "u", "adaptive"))
            _same(compiled[i], python[1][0], ("x", "x_meas", "x_q", "u", "adaptive"))


def test_a_constant_power_is_libm_pow_in_generated_code() -> None:
    """Generated code's ``x**0.5``, ``spow(x, 0.5)`` and ``x**-1.0`` equal Python's ``math.pow`` to
    the last bit: LLVM sees no constant exponent, else it takes ``sqrt(x)`` and ``1 / x``, which
    libm's pow does not always equal (about 1 value of x**0.5 in 1200)."""
    from qcontrol.expr.source import FLAG, Statements, float_source

    texts = ("x**0.5", "spow(x, 0.5)", "x**-1.0")
    expressions = [compile_expression(text, ["x"]) for text in texts]
    lines = ["def powers(xs, ys):", "    for i in range(xs.size):", f"        x, {FLAG} = xs[i], False"]
    for j, expression in enumerate(expressions):
        out = Statements(f"e{j}_")
        value = float_source(expression._tree, ["x"], out)
        lines += [f"        {line}" for line in out.lines] + [f"        ys[i, {j}] = {value}"]
    namespace = {}
    exec("import math\nimport numba\nfrom qcontrol.compiled.pointers import opaque\n"  # noqa: S102
         "@numba.njit(error_model='numpy')\n" + "\n".join(lines), namespace)
    xs = np.random.default_rng(0).uniform(0.0, 3.0, 20_000)
    ys = np.empty((xs.size, len(texts)))
    namespace["powers"](xs, ys)
    expected = np.array([[e.on_floats([x]) for e in expressions] for x in xs.tolist()])
    assert ys.tobytes() == expected.tobytes()
