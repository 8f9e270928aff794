"""The paper's law and the comparison law as public classes: a subclass that overrides nothing
computes the built-in numbers exactly, a subclass that adds a state or changes the robust term or
the adaptive law runs with the [controller.<kind>] settings handed on through its context, and
`has_compiled_equivalent` says which objects a compiled form may stand in for."""

from __future__ import annotations

import numpy as np
import pytest

import qcontrol
from qcontrol.errors import QcontrolInputError

SHORT = {"simulation.duration": 1.0}


class SamePaperLaw(qcontrol.PaperLaw):
    """Overrides nothing but its name."""


class IntegralPaperLaw(qcontrol.PaperLaw):
    """Law (44)-(45) with integral action on zbar_1: u = (44) - k_i * integral of zbar_1."""

    state_name = "eps_hat_and_integral"

    @classmethod
    def from_context(cls, context: qcontrol.LawContext) -> IntegralPaperLaw:
        law = super().from_context(context)
        law.k_i = float(context.settings.get("k_i", 0.5))
        law.seen = (context.n, context.dt, context.control_period, context.delta, tuple(context.c))
        law.state_size += 1
        return law

    def initial_state(self, batch: int) -> np.ndarray:
        return np.hstack([super().initial_state(batch), np.zeros((batch, 1))])

    def control(self, reading, yd, state, t=0.0):
        *eps_hat, integral = state
        out = super().control(reading, yd, tuple(eps_hat), t)
        return out._replace(u=out.u - self.k_i * integral)

    def advancer(self, h):
        paper = super().advancer(h)

        def advance(state, out):
            *eps_hat, integral = state
            return (*paper(tuple(eps_hat), out), integral + h * out.zbar[0])
        return advance


class HalfRobust(qcontrol.PaperLaw):
    """Half of law (44)'s robust term."""

    def robust_term(self, zbar, r, eps_hat, law):
        return 0.5 * super().robust_term(zbar, r, eps_hat, law)


class SlowComparison(qcontrol.ComparisonLaw):
    """Law (46) adapting at a tenth of its rate."""

    def adaptive_rate(self, zbar, phi_q):
        return tuple([0.1 * p for p in super().adaptive_rate(zbar, phi_q)])


@pytest.fixture(autouse=True, scope="module")
def registered() -> None:
    qcontrol.register_law("same-paper", SamePaperLaw, extends="proposed", replace=True)
    qcontrol.register_law("paper-integral", IntegralPaperLaw, extends="proposed", keys=["k_i"],
                                replace=True)
    qcontrol.register_law("half-robust", HalfRobust, extends="proposed", replace=True)
    qcontrol.register_law("slow-comparison", SlowComparison, extends="comparison", replace=True)


def _run(kind: str, **more: object) -> qcontrol.Result:
    sc = qcontrol.load_scenario("example2", {"controller.kind": kind, **SHORT, **more})
    return qcontrol.run(sc, backend="ode")


def test_a_subclass_that_overrides_nothing_computes_the_built_in_numbers_exactly() -> None:
    builtin, same = _run("proposed"), _run("same-paper")
    assert np.array_equal(builtin.u, same.u) and np.array_equal(builtin.adaptive, same.adaptive)
    assert builtin.summary["max_gain_period"] == same.summary["max_gain_period"]


def test_integral_action_on_the_paper_law_reads_its_settings_and_adds_a_state() -> None:
    builtin, integral = _run("proposed"), _run("paper-integral", **{"controller.paper-integral.k_i": 2.0})
    assert integral.adaptive.shape[1] == builtin.adaptive.shape[1] + 1
    z1bar = integral.x_q[:, 0] - integral.yd[:, 0]
    assert integral.adaptive[-1, -1] == pytest.approx(1e-3 * z1bar[:-1].sum(), rel=1e-9)
    assert not np.array_equal(builtin.u, integral.u)
    assert integral.summary["final_eps_hat_and_integral"][-1] == integral.adaptive[-1, -1]
    # [controller.proposed]'s gamma reaches the subclass: a different gamma, a different run
    other = _run("paper-integral", **{"controller.proposed.gamma": 3.0})
    assert not np.array_equal(other.adaptive[-1], integral.adaptive[-1])


def test_the_context_carries_n_dt_period_delta_c() -> None:
    from qcontrol.assembly import build_law
    sc = qcontrol.load_scenario("example2", {"controller.kind": "paper-integral", "simulation.dt": 5e-4,
                                             "simulation.control_period": 1e-3, **SHORT})
    law = build_law([sc])
    assert law.seen == (2, 5e-4, 1e-3, 0.01, (4.0, 3.0))


def test_overriding_the_robust_term_and_the_adaptive_law_changes_the_run() -> None:
    assert not np.array_equal(_run("proposed").u, _run("half-robust").u)
    slow, builtin = _run("slow-comparison"), _run("comparison")
    assert np.abs(slow.adaptive[-1]).max() < np.abs(builtin.adaptive[-1]).max()


def test_has_compiled_equivalent_only_without_overrides() -> None:
    from qcontrol.assembly import build_law
    laws = {kind: build_law([qcontrol.load_scenario("example2", {"controller.kind": kind, **SHORT})])
            for kind in ("proposed", "comparison", "same-paper", "paper-integral", "half-robust",
                         "slow-comparison")}
    flags = {kind: law.has_compiled_equivalent for kind, law in laws.items()}
    assert flags == {"proposed": True, "comparison": True, "same-paper": True, "paper-integral": False,
                     "half-robust": False, "slow-comparison": False}


def test_a_sweep_over_a_subclass_key() -> None:
    rows = qcontrol.sweep(qcontrol.load_scenario("example2", {"controller.kind": "paper-integral", **SHORT}),
                          grid={"controller.paper-integral.k_i": [0.0, 3.0]}, backend="ode")
    assert rows[0]["max_abs_u"] != rows[1]["max_abs_u"]
    assert rows[0]["max_abs_u"] == _run("proposed").summary["max_abs_u"]  # k_i = 0: the paper's law


@pytest.mark.parametrize("call, message", [
    (lambda: qcontrol.register_law("x-law", object, extends="proposed"), "take a column-form law"),
    (lambda: qcontrol.register_law("x-law", HalfRobust, extends="nope"), "extends='nope'"),
    (lambda: qcontrol.register_law("x law", HalfRobust), "must be letters, digits"),
    (lambda: qcontrol.register_law("proposed", HalfRobust), "is built in and cannot be replaced"),
    (lambda: _run("paper-integral", **{"controller.paper-integral.k_j": 1.0}),
     "controller.paper-integral.k_j=1.0: unknown key for kind 'paper-integral'; keys of this kind are k_i"),
    (lambda: _run("half-robust", **{"controller.proposed.kappa_margin": -1.0}),
     "controller.proposed.kappa_margin"),
])
def test_misuse_is_one_line(call, message: str) -> None:
    with pytest.raises(QcontrolInputError, match=None) as caught:
        call()
    assert message in str(caught.value) and "\n" not in str(caught.value)


# --------------------------------------------------------------------------------------------
# One rule for "a compiled form of the built-in law may stand in for this object": the property,
# which the engine's compiled loop asks (qcontrol.engine.compiled_loop.compilable)

LONG = ["simulation.duration=5.0"]  # 5001 rows: the engine compiles the built-in law's run


class DoubledRobustGain(qcontrol.PaperLaw):
    """Law (44)'s K doubled where it is reported (the diagnostic gain_period)."""

    def robust_gain(self, q, yd, eps_hat):
        return 2.0 * super().robust_gain(q, yd, eps_hat)


class FlippedHeldFactor(qcontrol.PaperLaw):
    def held_factor(self, gain_period):
        return -super().held_factor(gain_period)


class WithHelper(qcontrol.PaperLaw):
    def describe(self) -> str:
        return "law (44)"


class NotedInFromContext(qcontrol.PaperLaw):
    @classmethod
    def from_context(cls, context):
        law = super().from_context(context)
        law.note = "tuned by hand"
        return law


class ComparisonWithHelper(qcontrol.ComparisonLaw):
    def describe(self) -> str:
        return "law (46)"


class DocumentedOnly(qcontrol.PaperLaw):
    """Nothing but this docstring: the built-in law."""


class DocumentedComparison(qcontrol.ComparisonLaw):
    """Nothing but this docstring: the built-in comparison law."""


OWN = {"doubled-gain": DoubledRobustGain, "flipped-held": FlippedHeldFactor, "with-helper": WithHelper,
       "noted": NotedInFromContext, "comparison-helper": ComparisonWithHelper}
SAME = {"documented": DocumentedOnly, "documented-comparison": DocumentedComparison}


@pytest.fixture
def equivalence_kinds(monkeypatch) -> None:
    import qcontrol.engine.compiled_loop as compiled_loop
    monkeypatch.delenv("QCONTROL_COMPILE", raising=False)
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", compiled_loop.MIN_ROWS)  # numba may not be started
    for kind, cls in {**OWN, **SAME}.items():
        extends = "comparison" if issubclass(cls, qcontrol.ComparisonLaw) else "proposed"
        qcontrol.register_law(kind, cls, extends=extends, replace=True)


def _closed_loop(kind: str, law=None):
    """The loop of example 2 over 5 s with ``kind``'s law (or ``law``) and its record."""
    from qcontrol.assembly import build_controller, build_plant, build_separation, run_spec
    from qcontrol.engine import ClosedLoop
    sc = qcontrol.load_scenario("example2", [f"controller.kind=\"{kind}\"", *LONG])
    law = law or build_controller(sc)
    loop = ClosedLoop(run_spec(sc, build_plant(sc, "ode"), law, [sc.x0], build_separation(sc), "full"))
    return law, loop, loop.run()[0]


def _signal(record, name: str) -> bytes:
    return np.asarray(record.signals[name]).tobytes()


@pytest.mark.parametrize("kind", list(OWN))
def test_a_subclass_with_anything_of_its_own_runs_its_own_python(equivalence_kinds, kind: str) -> None:
    from qcontrol.engine.compiled_loop import compilable
    law, loop, record = _closed_loop(kind)
    builtin = "comparison" if kind.startswith("comparison") else "proposed"
    _, builtin_loop, builtin_record = _closed_loop(builtin)
    assert builtin_loop.handover is None  # the built-in law's run of the same length is compiled
    assert law.has_compiled_equivalent is False and not compilable(law)
    assert loop.handover == 0  # this one runs in Python from its first row
    assert _signal(record, "u") == _signal(builtin_record, "u")  # none of these members enters u


def test_a_doubled_robust_gain_reports_its_own_gain_period(equivalence_kinds) -> None:
    builtin, doubled = (qcontrol.run(qcontrol.load_scenario("example2", {"controller.kind": kind,
                                                                         "simulation.duration": 5.0}),
                                     backend="ode") for kind in ("proposed", "doubled-gain"))
    assert doubled.summary["max_gain_period"] == 2.0 * builtin.summary["max_gain_period"] > 0.0


def test_the_noted_law_keeps_its_attribute_and_a_helper_is_callable(equivalence_kinds) -> None:
    noted, _, _ = _closed_loop("noted")
    assert noted.note == "tuned by hand" and "note" not in noted._built_attributes
    flipped, _, _ = _closed_loop("flipped-held")
    assert flipped.held_factor(0.25) == -0.75  # its own held factor, not 1 - K T


def test_an_instance_attribute_alone_makes_the_object_not_equivalent(equivalence_kinds) -> None:
    """A built-in object given an attribute of its own, here a ``control`` that shifts u: the
    compiled loop would not see it, so it must not stand in."""
    from qcontrol.assembly import build_controller
    law = build_controller(qcontrol.load_scenario("example2", LONG))
    assert law.has_compiled_equivalent
    paper = law.control

    def shifted_control(reading, yd, state, t=0.0):
        out = paper(reading, yd, state, t)
        return out._replace(u=out.u + 1.0)
    law.control = shifted_control
    assert not law.has_compiled_equivalent
    _, loop, shifted = _closed_loop("proposed", law)
    _, _, builtin = _closed_loop("proposed")
    assert loop.handover == 0
    assert np.asarray(shifted.signals["u"])[0] == np.asarray(builtin.signals["u"])[0] + 1.0


@pytest.mark.parametrize("kind", list(SAME))
def test_a_subclass_with_only_a_docstring_is_the_compiled_built_in_law(equivalence_kinds, kind: str) -> None:
    from qcontrol.engine.compiled_loop import compilable
    SAME[kind].__annotations__  # noqa: B018 (Python then adds an empty __annotations__ to the class)
    law, loop, record = _closed_loop(kind)
    _, _, builtin = _closed_loop("comparison" if "comparison" in kind else "proposed")
    assert law.has_compiled_equivalent and compilable(law)
    assert loop.handover is None
    for name in record.signals:
        assert _signal(record, name) == _signal(builtin, name), name


class OwnAdvancer(qcontrol.PaperLaw):
    def advancer(self, h):
        return ("own advancer", h)


class ComparisonOwnAdvancer(qcontrol.ComparisonLaw):
    def advancer(self, h):
        return ("own advancer", h)


@pytest.mark.parametrize(("cls", "extends"), [(OwnAdvancer, "proposed"),
                                              (ComparisonOwnAdvancer, "comparison")])
def test_the_advancer_in_any_form_defers_to_an_overridden_advancer(cls, extends: str) -> None:
    from qcontrol.assembly import build_law
    from qcontrol.engine.fastpath import FLOATS
    qcontrol.register_law("own-advancer", cls, extends=extends, replace=True)
    law = build_law([qcontrol.load_scenario("example2", {"controller.kind": "own-advancer", **SHORT})])
    assert law.advancer_in(FLOATS, 1e-3) == ("own advancer", 1e-3)  # the engine's float path uses it


class SaturatedPaperLaw(qcontrol.BacksteppingLaw):
    """The paper's law wrapped (not subclassed): its u clipped to [-u_max, u_max]."""

    @classmethod
    def from_context(cls, context: qcontrol.LawContext) -> SaturatedPaperLaw:
        law = cls(context.c, context.max_error)
        law.paper = qcontrol.PaperLaw.from_context(context)
        law.u_max = float(context.settings.get("u_max", 10.0))
        law.state_name, law.state_size = law.paper.state_name, law.paper.state_size
        return law

    def initial_state(self, batch):
        return self.paper.initial_state(batch)

    def control(self, reading, yd, state, t=0.0):
        out = self.paper.control(reading, yd, state, t)
        return out._replace(u=np.clip(out.u, -self.u_max, self.u_max))

    def advancer(self, h):
        return self.paper.advancer(h)

    def advancer_in(self, form, h):
        return self.paper.advancer_in(form, h)


@pytest.mark.parametrize("u_max", [1e9, 5.0])
def test_a_law_that_wraps_the_paper_law_runs_its_numbers_or_clips_them(u_max: float) -> None:
    """Wrapping: with a bound it never reaches, the wrapped law computes the paper's law bit for bit;
    with 5, |u| stays at most 5 and the run differs."""
    qcontrol.register_law("paper-wrapped", SaturatedPaperLaw, extends="proposed", keys=["u_max"],
                                replace=True)
    builtin = _run("proposed")
    wrapped = _run("paper-wrapped", **{"controller.paper-wrapped.u_max": u_max})
    if u_max > 1e6:
        for name in ("x", "u", "adaptive"):
            assert np.array_equal(getattr(wrapped, name), getattr(builtin, name)), name
    else:
        assert np.max(np.abs(wrapped.u)) <= 5.0 < np.max(np.abs(builtin.u))


def test_has_compiled_equivalent_is_one_mechanism_of_the_base_class() -> None:
    """Declared once (``compiled=True``): a law without a compiled form is never equivalent, a
    built-in object stops being so once it holds an attribute of its own."""
    from qcontrol.controller.backstepping import BacksteppingLaw
    from qcontrol.controller.linear import LinearLaw

    class Own(BacksteppingLaw):
        pass

    assert Own.compiled_class is None and not Own([1.0, 2.0], 0.005).has_compiled_equivalent
    linear = LinearLaw([1.0, 2.0], 0.005)
    assert LinearLaw.compiled_class is LinearLaw and linear.has_compiled_equivalent
    linear.extra = 1.0
    assert not linear.has_compiled_equivalent
