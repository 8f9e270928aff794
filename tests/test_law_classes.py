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
    qcontrol.register_law_class("same-paper", SamePaperLaw, extends="proposed", replace=True)
    qcontrol.register_law_class("paper-integral", IntegralPaperLaw, extends="proposed", keys=["k_i"],
                                replace=True)
    qcontrol.register_law_class("half-robust", HalfRobust, extends="proposed", replace=True)
    qcontrol.register_law_class("slow-comparison", SlowComparison, extends="comparison", replace=True)


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
    (lambda: qcontrol.register_law_class("x-law", object), "must be a class deriving from qcontrol.PaperLaw"),
    (lambda: qcontrol.register_law_class("x-law", HalfRobust, extends="nope"), "extends='nope'"),
    (lambda: qcontrol.register_law_class("x law", HalfRobust), "must be letters, digits"),
    (lambda: qcontrol.register_law_class("proposed", HalfRobust), "is built in and cannot be replaced"),
    (lambda: _run("paper-integral", **{"controller.paper-integral.k_j": 1.0}),
     "controller.paper-integral.k_j=1.0: unknown key for kind 'paper-integral'; keys of this kind are k_i"),
    (lambda: _run("half-robust", **{"controller.proposed.kappa_margin": -1.0}),
     "controller.proposed.kappa_margin"),
])
def test_misuse_is_one_line(call, message: str) -> None:
    with pytest.raises(QcontrolInputError, match=None) as caught:
        call()
    assert message in str(caught.value) and "\n" not in str(caught.value)
