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
    for a, b in zip(runs[0], runs[1], strict=False):
        _same(a, b)

def _refusing(x1: list[float]) -> RunSpec:
    """A batch whose plant term sqrt(x1) math refuses (numpy answers NaN) where x1 < 0."""
    x = ["x1", "x2"]
    sc = load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=0.2"])
    spec = _spec([sc] * len(x1), "metrics")
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


def test_functions_numpy_evaluates_otherwise_keep_the_array_form(monkeypatch) -> None:
    r = 'controller.proposed.r=["1 + q2**2", "1 + 2*q2**2", "1 + exp(0.1*q1)"]'  # math.exp in the law
    scs = _variants("example2", [r])[:3]
    loop, compiled = _run(_spec(scs, "metrics"), monkeypatch)
    assert loop.handover == 0  # the array form from row 0
    _, array = _run(_spec(scs, "metrics"), monkeypatch, compiled=False)
    for a, b in zip(compiled, array, strict=True):
        _same(a, b)


def test_the_exact_hold_is_compiled_with_the_array_forms_numbers(monkeypatch) -> None:
    """The exact hold's expm1 is math's in the batch's array form too (element by element)."""
    scs = _variants("example2", ['controller.hold="exact"'])[:3]
    loop, compiled = _run(_spec(scs, "metrics"), monkeypatch)
    assert loop.handover is None  # the compiled batch ran to the end
    _, array = _run(_spec(scs, "metrics"), monkeypatch, compiled=False)
    for a, b in zip(compiled, array, strict=True):
        _same(a, b)
