"""The compiled batch's metrics folded inside its loop (qcontrol.engine.compiled_folds): every
copy's summary values equal the array form's to the last bit, over blocks the loop folded and
blocks in which a copy stopped (reduced by the array form), with a control period of one and of
two steps; and the folded values are traced from their one definition: the tracking error, the
error rate's interpolation and the law's diagnostic changed in their one place change the
compiled batch and the array form alike."""

import dataclasses

import numpy as np
import pytest
from conftest import SCENARIOS

import qcontrol.engine.compiled_loop as compiled_loop
import qcontrol.engine.retention as retention
from qcontrol import error_rate
from qcontrol.assembly import assemble
from qcontrol.controller.proposed import PaperLaw
from qcontrol.engine import ClosedLoop, compiled_folds, reductions, signals
from qcontrol.scenario import load_scenario


@pytest.fixture(autouse=True)
def _short_blocks(monkeypatch) -> None:
    """Short runs compiled, reduced in blocks of 40 rows (copies stop in some blocks, not others)."""
    monkeypatch.setattr(compiled_loop, "MIN_ROWS", 0)
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)
    monkeypatch.setattr(retention, "METRICS_CHUNK", 40)
    monkeypatch.setattr(retention, "METRICS_BUFFER_ELEMENTS", 40)


def _variants(name: str, extra: tuple[str, ...] = ()) -> list:
    """Copies differing in kappa and x(0); the far ones diverge, at different rows."""
    x1, x2 = np.linspace(-3.0, 3.0, 12).tolist(), np.tile([-60.0, 0.3, 5.0, 60.0], 3).tolist()
    return [load_scenario(SCENARIOS / f"{name}.toml", ["simulation.duration=0.3", f"plant.x0=[{a!r}, {b!r}]",
                                                       f"controller.kappa_margin={m!r}", *extra])
            for a, b, m in zip(x1, x2, np.linspace(0.1, 2.0, 12).tolist(), strict=True)]


def _metrics(scs: list, monkeypatch, compiled: bool) -> tuple[list, list[bool]]:
    """The runs' metrics, and for each block the compiled loop folded whether it was merged."""
    merged: list[bool] = []
    merge = compiled_folds.Folds.merge

    def spy(self, *args):  # noqa: ANN001, ANN202
        left = merge(self, *args)
        merged.append(left is self.others)
        return left

    monkeypatch.setattr(compiled_folds.Folds, "merge", spy)
    if not compiled:
        monkeypatch.setenv("QCONTROL_COMPILE", "0")
    loop = ClosedLoop(dataclasses.replace(assemble(scs, "ode").spec, record="metrics"))
    runs = loop.run()
    monkeypatch.delenv("QCONTROL_COMPILE", raising=False)
    assert loop.handover == (None if compiled else 0)
    return runs, merged


def _bits(value) -> object:  # noqa: ANN001
    """A summary value's exact bits (floats and arrays), nested dicts kept."""
    if isinstance(value, dict):
        return {k: _bits(v) for k, v in value.items()}
    return np.asarray(value, dtype=float).tobytes()


def _same_metrics(scs: list, monkeypatch) -> list[bool]:
    compiled, merged = _metrics(scs, monkeypatch, compiled=True)
    array, _ = _metrics(scs, monkeypatch, compiled=False)
    for a, b in zip(compiled, array, strict=True):
        assert (a.steps, a.diverged, a.divergence_reason) == (b.steps, b.diverged, b.divergence_reason)
        assert _bits(a.values) == _bits(b.values)
    return merged


# (a control period of 3 rows: the chunks of 1000 rows start off a control sample)
@pytest.mark.parametrize(("name", "extra"), [("example1", ()), ("example2", ()),
                                             ("example2", ("simulation.control_period=0.003",))])
def test_folded_metrics_equal_the_array_form(monkeypatch, name: str, extra: tuple[str, ...]) -> None:
    scs = _variants(name, extra)
    merged = _same_metrics(scs, monkeypatch)
    assert any(merged) and not all(merged)  # blocks folded in the loop, and blocks where a copy stopped


def _late_error(block):  # noqa: ANN001, ANN202
    """The tracking error changed: x_1 - y_d, half again."""
    return (block["x"][..., :1] - block["yd"][..., :1]) * 1.5


def interpolated(ta, za, tc, zc, x):  # noqa: ANN001, ANN201 (the changed formula, compiled by name)
    slope = (zc - za) / (tc - ta)
    return slope * (x - ta) * 0.5 + za


def _folded_names(scs: list, monkeypatch) -> set[str]:
    """The reductions the compiled batch folded in its loop."""
    names: set[str] = set()
    merge = compiled_folds.Folds.merge

    def spy(self, *args):  # noqa: ANN001, ANN202
        names.update(fold.name for fold, _ in self.folded)
        return merge(self, *args)

    monkeypatch.setattr(compiled_folds.Folds, "merge", spy)
    ClosedLoop(dataclasses.replace(assemble(scs, "ode").spec, record="metrics")).run()
    monkeypatch.setattr(compiled_folds.Folds, "merge", merge)
    return names


def test_folded_values_change_with_their_one_definition(monkeypatch) -> None:
    """The tracking error, the error rate's interpolation, the law's diagnostic and the bound
    ratios and smallest r of (37)-(43) (folded in the loop: Example 2's terms are squares, sin and
    cos), each changed in its one place: the compiled batch and the array form change alike. The
    changes are made at once (one changed module to compile, not one per change): none of them
    changes the closed loop, and each is checked on the value it alone changes."""
    scs = _variants("example2", ("metrics.omega=[0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0]",))
    assert {"bound_constants", "smallest_r"} <= _folded_names(scs, monkeypatch)
    before, _ = _metrics(scs, monkeypatch, compiled=True)
    for owner in (reductions.ErrorRate, reductions.LastHalfLargestAbs):
        monkeypatch.setattr(owner, "values", staticmethod(_late_error))
    monkeypatch.setattr(error_rate, "interpolated", interpolated)
    gain = PaperLaw.robust_gain
    monkeypatch.setattr(PaperLaw, "robust_gain", lambda self, *a, **k: gain(self, *a, **k) * 3.0)
    ratios, bounds = signals.bound_ratios, signals.bounds
    monkeypatch.setattr(signals, "bound_ratios", lambda *a: [v * 2.0 for v in ratios(*a)])
    monkeypatch.setattr(signals, "bounds", lambda *a: [v + 0.5 for v in bounds(*a)])
    merged = _same_metrics(scs, monkeypatch)
    assert any(merged)
    after, _ = _metrics(scs, monkeypatch, compiled=True)
    kept = [i for i, run in enumerate(after) if not run.diverged]
    assert kept
    for i in kept:
        old, new = before[i].values, after[i].values
        assert new["max_abs_z1_last_half"] == 1.5 * old["max_abs_z1_last_half"]
        assert new["diagnostics"]["max"][0] == pytest.approx(3.0 * old["diagnostics"]["max"][0], rel=1e-12)
        np.testing.assert_array_equal(new["smallest_r"], old["smallest_r"] + 0.5)
        assert not np.array_equal(new["bound_constants"], old["bound_constants"])
    assert any(after[i].values["error_rate"] != before[i].values["error_rate"] for i in kept)


def _chosen_folds(scs: list, monkeypatch) -> set[str]:
    """The reductions the compiled batch would fold, as its run chooses them (its ``folds``), with
    the compile gate closed: the array form runs, nothing is compiled."""
    from qcontrol.engine.compiled_batch import CompiledBatch

    names: set[str] = set()
    folds = CompiledBatch.folds

    def spy(self, loop):  # noqa: ANN001, ANN202
        chosen = folds(self, loop)
        names.update(fold.name for fold, _ in chosen.folded)
        return chosen

    with monkeypatch.context() as patched:
        patched.setattr(CompiledBatch, "folds", spy)
        patched.setattr(compiled_loop, "compile_pays", lambda *args: False)
        ClosedLoop(dataclasses.replace(assemble(scs, "ode").spec, record="metrics")).run()
    return names


def test_a_term_whose_numpy_value_may_differ_is_reduced_by_the_array_form(monkeypatch) -> None:
    """A cube (numpy's power and libm's pow differ in the last bit on some values) or a
    hyperbolic tangent: the separation stays the array form's, the other reductions are folded.
    Each term's choice is checked alone and both together (no compile: the choice precedes it; a
    batch whose separation stays the array form is compiled and compared with it in
    tests/test_compiled_batch.py, whose exponential keeps it there, and a batch stepping with tanh
    in tests/test_tuning.py)."""
    terms = ("x1**3", "tanh(x1)")
    for a, b in (("x2**2*cos(x1)", terms[0]), ("x2**2*cos(x1)", terms[1]), terms):
        names = _chosen_folds(_variants("example2", (f'plant.phi=["x2", "{a}", "{b}"]',)), monkeypatch)
        assert "max_abs_u" in names and not {"bound_constants", "smallest_r"} & names
    assert {"sin", "cos", "sqrt", "abs"} >= signals.same_functions() >= {"sqrt", "abs"}



def test_compacting_the_fold_keeps_every_value_it_reads() -> None:
    """A local copying a value is replaced by it, one recomputing an earlier expression by the
    earlier one, one nothing reads left out; a value the fold writes (the partials) is not taken
    for a copy, nor an expression reading it for a recomputation."""
    every = ["f1 = x1", "f2 = f1 * f1", "f3 = x1 * x1", "f4 = f3 + lf[0]", "f5 = fp[0]", "fp[0] = f2",
             "f6 = fp[0]", "f7 = f5 + f6", "if f7 > fp[1]:", "    fp[1] = f7"]
    samples = ["f8 = x1 * x1", "fp[2] += f8"]
    assert compiled_folds.compact(every, samples) == (
        ["f2 = x1 * x1", "f5 = fp[0]", "fp[0] = f2", "f6 = fp[0]", "f7 = f5 + f6", "if f7 > fp[1]:",
         "    fp[1] = f7"], ["fp[2] += f2"])
