"""A ``qcontrol.Law`` whose code is arithmetic on its inputs gets a compiled form: its own Python
run once on traced inputs, checked against itself, then compiled with the quantizer and the
plant. Its compiled run equals its Python run bit for bit (a single run that hands over to
Python where an expression refuses, and a batch); a law that cannot be traced, keeps state on
itself or rounds differently keeps the Python loop and says why, and tracing it changes nothing."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest
from conftest import ROOT

import qcontrol
from qcontrol.assembly import build_law, build_plant, build_quantizer, build_reference
from qcontrol.controller.user import UserLaw
from qcontrol.engine import RunSpec, compiled_loop
from qcontrol.engine.compiled_batch import CompiledBatch
from qcontrol.engine.compiled_loop import TracedParts
from qcontrol.engine.compiled_user import CompiledUserBatch, CompiledUserLoop, column_parts
from qcontrol.engine.loop import ClosedLoop
from qcontrol.engine.user_trace import explain, unchanged
from qcontrol.timegrid import TimeGrid

pytest.importorskip("numba")  # the compiled form is numba's; a run alone pays for it once numba is loaded
import numba  # noqa: E402, F401


class RootIntegral:
    """u = alphabar_2 - k_i * integral - 0.01 sqrt(q1 + offset) + 0.001 t, the integral of
    (q1 - y_d) advanced by the engine's RK4 of ``state_rate``; on floats (the documented fast form).
    Where q1 < -offset the square root refuses (math) and the run continues in Python (numpy: NaN)."""

    state_size = 1

    def __init__(self, table: dict, n: int) -> None:
        qcontrol.check_keys(table, ["offset"])
        self.recursion = qcontrol.BacksteppingLaw(table["c"], table["delta"] / 2).recursion
        self.root = qcontrol.expression("sqrt(q1)", variables=("q1",))
        self.offset, self.k_i = float(table.get("offset", 2.0)), 0.5

    def initial_state(self) -> np.ndarray:
        return np.zeros(1)

    def control(self, t, x_q, yd, state):
        q = x_q.tolist()
        _, alphabar = self.recursion(q, yd.tolist())
        root = self.root.on_floats([q[0] + self.offset])
        return alphabar[-1] - self.k_i * state[0] - 0.01 * root + 0.001 * t

    def state_rate(self, t, x_q, yd, state):
        return np.array([x_q[0] - yd[0]])


@pytest.fixture(scope="module", autouse=True)
def registered() -> None:
    qcontrol.register_law("root-integral", RootIntegral, state_name="integral", replace=True)


def _loop(offsets: list[float], duration: float, monkeypatch: pytest.MonkeyPatch,
          compiled: bool) -> ClosedLoop:
    """The closed loop of Example 1 (ODE) with the law, one copy per offset, from spread starts."""
    monkeypatch.setenv("QCONTROL_COMPILE", "1" if compiled else "0")
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)  # compiled even where the structure is new
    base = qcontrol.load_scenario("example1", {"controller.kind": "root-integral",
                                               "simulation.duration": duration})
    scs = [base.with_overrides({"controller.offset": o, "plant.x0": [0.3 - 0.1 * i, 0.2]})
           for i, o in enumerate(offsets)]
    sc, batch = scs[0], len(scs)
    return ClosedLoop(RunSpec(plant=build_plant(sc, "ode", batch=batch), law=build_law(scs),
                              quantizer=build_quantizer(sc), reference=build_reference(sc),
                              x0=[s.x0 for s in scs] if batch > 1 else sc.x0,
                              grid=TimeGrid.of(sc.simulation.duration, sc.simulation.dt), record="full"))


def _same(x: object, y: object) -> bool:
    if isinstance(x, np.ndarray):
        return x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()  # NaN included
    if isinstance(x, dict):
        return x.keys() == y.keys() and all(_same(x[k], y[k]) for k in x)
    return repr(x) == repr(y)


def _same_records(a: list, b: list) -> None:
    """Every field of every copy's record bit for bit (signals, divergence), wall times aside."""
    assert len(a) == len(b)
    for mine, python in zip(a, b, strict=True):
        for field in dataclasses.fields(mine):
            if "wall" not in field.name:
                assert _same(getattr(mine, field.name), getattr(python, field.name)), field.name


def test_a_single_run_compiles_and_hands_over_to_python_where_an_expression_refuses(monkeypatch) -> None:
    loop = _loop([0.25], 5.0, monkeypatch, compiled=True)
    assert isinstance(loop.compiled, CompiledUserLoop) and loop.law.compiled_form == "compiled"
    records = loop.run()
    # y_d takes q1 below -0.25 after t = 2 s: the compiled loop hands over to Python there
    assert 2000 < loop.handover < 4000 and records[0].diverged
    python = _loop([0.25], 5.0, monkeypatch, compiled=False)
    assert python.compiled is None
    _same_records(records, python.run())


def test_a_short_run_steps_on_the_traced_calls_and_equals_its_python(monkeypatch) -> None:
    """Below the compiled loop's length the Python loop calls the law's traced lines as plain Python
    (its own code at its first calls, and where an expression refuses: the test above)."""
    loop = _loop([0.25], 3.0, monkeypatch, compiled=True)
    assert loop.compiled is None and loop.law.fast is not None
    records = loop.run()
    python = _loop([0.25], 3.0, monkeypatch, compiled=False)
    assert python.law.fast is None
    _same_records(records, python.run())


def test_a_batch_compiles_with_a_parameter_per_copy_and_equals_its_python_copy_by_copy(monkeypatch) -> None:
    offsets = [2.0, 2.0, 3.0, 3.0, 4.5]  # equal copies side by side take one trace, the others their own
    loop = _loop(offsets, 2.0, monkeypatch, compiled=True)  # 5 x 2001 rows: enough for a batch
    assert isinstance(loop.compiled, CompiledUserBatch)
    constants = loop.compiled.parts.constants
    assert constants.shape[0] == 5  # one row of constants per copy
    assert constants[0].tobytes() == constants[1].tobytes() != constants[2].tobytes()
    assert constants[2].tobytes() == constants[3].tobytes() != constants[4].tobytes()
    # compiled though the gate would wait (a new structure): without its compiled form a user law's
    # batch runs each copy's law through Python floats, hundreds of times the compiled batch
    monkeypatch.setattr(compiled_loop, "compile_pays", lambda *args: False)
    records = loop.run()
    assert loop.handover is None  # every row compiled, none redone
    _same_records(records, _loop(offsets, 2.0, monkeypatch, compiled=False).run())


class Branching(RootIntegral):
    def control(self, t, x_q, yd, state):
        return -x_q[0] if x_q[0] > 0 else x_q[1]


class Counting(RootIntegral):
    calls = 0

    def control(self, t, x_q, yd, state):
        self.calls += 1
        return -4.0 * x_q[0] - 3.0 * x_q[1]


class Noisy(RootIntegral):
    def control(self, t, x_q, yd, state):
        return -4.0 * x_q[0] - 3.0 * x_q[1] + 1e-3 * np.random.standard_normal()  # noqa: NPY002


class MatrixProduct(RootIntegral):
    def control(self, t, x_q, yd, state):
        return -(np.array([[4.0, 3.0]]) @ x_q)[0]


@pytest.mark.parametrize(("law", "why"), [
    (Branching, "compares or branches"), (Counting, "changes its own attributes"),
    (Noisy, "differently at each call"), (MatrixProduct, "matrix product"),
])
def test_a_law_that_cannot_be_compiled_keeps_python_and_says_why(law, why) -> None:
    table = {"kind": "x", "c": [4.0, 3.0], "delta": 0.01}
    user = UserLaw([law(table, 2)], [4.0, 3.0], 0.005, "integral", "x")
    before = np.random.get_state()[1].copy()  # noqa: NPY002
    reason = explain(user, 2, 1e-3)
    assert reason is not None and why in reason, reason
    assert user.compiled_form == reason
    assert np.array_equal(np.random.get_state()[1], before)  # noqa: NPY002 (tracing drew nothing)
    if law is Counting:
        assert user.laws[0].calls == 0  # traced on copies of it


def test_check_says_whether_a_user_law_has_a_compiled_form() -> None:
    sc = qcontrol.load_scenario("example2", {"controller.kind": "root-integral"})
    report = qcontrol.check(sc, "ode")
    assert report.compiled_form == "compiled" and "the law's compiled form: compiled" in report.line()
    assert qcontrol.check(qcontrol.load_scenario("example2"), "ode").compiled_form is None


def test_a_column_form_law_is_traced_and_checked_against_its_float_form() -> None:
    """A BacksteppingLaw subclass of the user's: its formulas traced as the built-in laws' are,
    the lines checked against its float form; one that keeps a count of its calls is refused."""
    sys.path.insert(0, str(ROOT / "tools"))
    import laws_by_hand

    laws_by_hand.register()
    base = qcontrol.load_scenario("example2", {})
    sc = base.with_overrides(laws_by_hand.overrides(base, "columns"))
    law = build_law([sc])
    parts = column_parts(build_quantizer(sc), law, 2, 1e-3)
    assert isinstance(parts, TracedParts) and any("held[0]" in line for line in parts.control)

    class CountingColumns(laws_by_hand.PaperLawColumns):
        def control(self, reading, yd, state, t=0.0):
            self.calls = getattr(self, "calls", 0) + 1
            return super().control(reading, yd, state, t)

    qcontrol.register_law("counting-columns", CountingColumns, keys=laws_by_hand.KEYS, replace=True)
    kind = laws_by_hand.KINDS["columns"]
    chosen = {key.replace(kind, "counting-columns"): value
              for key, value in laws_by_hand.overrides(base, "columns").items()}
    counting = build_law([base.with_overrides(chosen | {"controller.kind": "counting-columns"})])
    assert "changes its own attributes" in column_parts(build_quantizer(sc), counting, 2, 1e-3)
    assert not hasattr(counting, "calls")  # traced on copies of it


def _columns_loop(starts: list, record: str, monkeypatch: pytest.MonkeyPatch, compiled: bool = True
                   ) -> ClosedLoop:
    """The closed loop of Example 2 (ODE, 2 s) with the paper's law written as a column-form class
    (tools/laws_by_hand.py), one copy per start."""
    sys.path.insert(0, str(ROOT / "tools"))
    import laws_by_hand

    laws_by_hand.register()
    monkeypatch.setenv("QCONTROL_COMPILE", "1" if compiled else "0")
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)  # compiled even where the structure is new
    base = qcontrol.load_scenario("example2", {"simulation.duration": 2.0})
    scs = [base.with_overrides(laws_by_hand.overrides(base, "columns") | {"plant.x0": x0}) for x0 in starts]
    sc, batch = scs[0], len(scs)
    return ClosedLoop(RunSpec(plant=build_plant(sc, "ode", batch=batch), law=build_law(scs),
                              quantizer=build_quantizer(sc), reference=build_reference(sc),
                              x0=[s.x0 for s in scs] if batch > 1 else sc.x0,
                              grid=TimeGrid.of(sc.simulation.duration, sc.simulation.dt), record=record))


@pytest.mark.parametrize("record", ["full", "metrics"])
def test_a_column_form_law_s_batch_is_compiled_and_each_copy_is_its_run_alone(record, monkeypatch) -> None:
    """A batch of a column-form law runs its one checked trace for every copy in the compiled
    batch (before, its array form): each copy's record is its run alone's and the array form's, bit
    for bit, a copy that diverges included."""
    starts = [[0.3, -0.2], [-0.5, 0.4], [2.5, 2.5], [0.1, 0.0], [0.3, -0.2]]  # 5 x 2001 copy-rows
    loop = _columns_loop(starts, record, monkeypatch)
    assert type(loop.compiled) is CompiledBatch  # the built-in laws' batch, the law's lines in it
    constants = loop.compiled.parts.constants
    assert constants.shape[0] == 5 and len({row.tobytes() for row in constants}) == 1  # one trace
    records = loop.run()
    assert loop.handover is None and [r.diverged for r in records] == [False, False, True, False, False]
    _same_records(records, _columns_loop(starts, record, monkeypatch, compiled=False).run())
    for x0, copy in zip(starts, records, strict=True):
        _same_records([copy], _columns_loop([x0], record, monkeypatch).run())


@pytest.mark.parametrize(("a", "b", "same"), [
    (1.0, 1.0, True), (0.0, -0.0, False), (float("nan"), float("nan"), True), (float("nan"), 1.0, False),
    (1.0, float(np.nextafter(1.0, 2.0)), False), (np.float64(-np.nan), np.float64(np.nan), False),
])
def test_a_number_of_a_law_is_unchanged_only_to_the_bit(a, b, same) -> None:
    """What decides that a law kept no state, and that a batch's copy traces as the copy before it."""
    assert unchanged({"k": a}, {"k": b}) is same


def test_the_protocol_test_of_a_law_is_typings() -> None:
    """The engine tests each copy's law against the protocols with their members listed once
    (typing lists them at every test): the same answers as isinstance."""
    from qcontrol.controller.law import conforms
    from qcontrol.controller.user import Law, _Advancing, _FromContext
    from qcontrol.controller.user_diagnostics import LawDiagnostics

    class Rate:
        state_size = 1

        def initial_state(self):
            return np.zeros(1)

        def control(self, t, x_q, yd, state):
            return 0.0

        def state_rate(self, t, x_q, yd, state):
            return state

    class Stepped(Rate):
        state_rate = None  # (typing's way to block a method)

        def advance(self, t, x_q, yd, state, h):
            return state

    class Declared(Law):  # derives from the protocol, members missing: typing says yes
        pass

    class Unsized:  # no state_size, unless an object sets its own
        initial_state, control, state_rate = Rate.initial_state, Rate.control, Rate.state_rate

    sized = Unsized()
    sized.state_size = 2
    objects = [Rate(), Stepped(), Unsized(), sized, Declared(), object(), 3.0, Rate, qcontrol.PaperLaw]
    for protocol in (Law, _Advancing, _FromContext, LawDiagnostics):
        assert [conforms(o, protocol) for o in objects] == [isinstance(o, protocol) for o in objects]
