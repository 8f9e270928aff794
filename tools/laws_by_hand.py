"""The paper's law (44)-(45) written by hand, as a user would write it, in the documented
forms of a user law (docs/laws.md): the bench times them against the built-in kind ``proposed``
(tools/bench_laws.py), the tests check that each computes the built-in numbers
(tests/test_laws_by_hand.py).

* :class:`PaperLawRK4`: a ``qcontrol.Law``; eq. (45) as a rate, advanced by the engine's RK4;
* :class:`PaperLawStepped`: a ``qcontrol.Law`` with its own ``advance``; eq. (45) solved exactly
  over each step with the sample held, ``eps <- target + (eps - target) exp(-gamma sigma h)``;
* :class:`PaperLawRateFloats` and :class:`PaperLawFloats`: the same two ``qcontrol.Law`` forms
  on Python floats: each call computes with arithmetic on floats (no numpy on arrays of n
  numbers), cheaper where the law's own Python runs (``QCONTROL_COMPILE=0``). The engine finds a
  compiled form of each of the four (:mod:`qcontrol.engine.compiled_user`; the numpy forms
  through :mod:`qcontrol.engine.user_numpy`);
* :class:`PaperLawColumns`: a ``qcontrol.BacksteppingLaw`` subclass in column form (floats for a
  single run, ``(batch,)`` arrays for a batch), registered with ``register_law`` as the others.

Each reads ``kappa``, ``gamma``, ``sigma`` and ``r`` from ``[controller.<kind>]``
(:func:`overrides` gives them from a scenario's ``[controller.proposed]`` settings).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import reduce
from operator import add, mul

import numpy as np

import qcontrol

KEYS = ["kappa", "gamma", "sigma", "r"]
KINDS = {"rk4": "paper-by-hand-rk4", "stepped": "paper-by-hand-stepped",
         "rate-floats": "paper-by-hand-rate-floats", "floats": "paper-by-hand-floats",
         "columns": "paper-by-hand-columns"}
FORMS = tuple(KINDS)


class PaperLawRK4:
    """Law (44) with eq. (45) as a rate: ``eps_hat' = gamma (s r(x_q) - sigma eps_hat)``."""

    def __init__(self, table: dict, n: int) -> None:
        qcontrol.check_keys(table, KEYS)
        self.c = [float(v) for v in table["c"]]
        self.L = float(qcontrol.lemma2_bounds(self.c, table["delta"])[-1])
        self.kappa, self.gamma, self.sigma = (float(table[k]) for k in ("kappa", "gamma", "sigma"))
        names = tuple(f"q{i + 1}" for i in range(n))
        self.r = [qcontrol.expression(e, variables=names) for e in table["r"]]
        self.state_size = len(self.r)

    def initial_state(self) -> np.ndarray:
        return np.zeros(self.state_size)

    def terms(self, x_q: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """zbar, alphabar (eqs. (31)-(34)), r(x_q) and s = zbar_n^2 / kappa + L."""
        zbar, alphabar = qcontrol.quantized_backstepping(self.c, x_q, yd)
        r = np.array([e.on_floats(x_q) for e in self.r])
        return zbar, alphabar, r, zbar[-1] * zbar[-1] / self.kappa + self.L

    def control(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> float:
        """Eq. (44): ``u = alphabar_n - zbar_n s eps_hat^T r / (kappa (kappa - L))``."""
        zbar, alphabar, r, s = self.terms(x_q, yd)
        return float(alphabar[-1] - zbar[-1] * s * float(state @ r) / (self.kappa * (self.kappa - self.L)))

    def state_rate(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> np.ndarray:
        _, _, r, s = self.terms(x_q, yd)
        return self.gamma * (s * r - self.sigma * state)


class PaperLawStepped(PaperLawRK4):
    """The same law, its state moved by the exact solution of eq. (45) over each step."""

    def advance(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray, h: float) -> np.ndarray:
        _, _, r, s = self.terms(x_q, yd)
        target = s * r / self.sigma
        return target + (state - target) * math.exp(-self.gamma * self.sigma * h)


class PaperLawFloatTerms:
    """What the two float forms share: the terms of eqs. (31)-(34) and (44), each call on Python
    floats: the reading and the reference turned into floats once (``tolist()``), eqs. (31)-(34) by
    ``BacksteppingLaw.recursion`` (which serves floats as it serves columns), r by ``on_floats``,
    sums written out, ``u`` returned as computed, a numpy array made only for the
    state the update returns. Only arithmetic on the inputs: such a law has a compiled form
    (docs/laws.md, 'Speed')."""

    def __init__(self, table: dict, n: int) -> None:
        by_arrays = PaperLawRK4(table, n)  # the same settings, read and checked the same way
        self.kappa, self.gamma, self.sigma = by_arrays.kappa, by_arrays.gamma, by_arrays.sigma
        self.L, self.r, self.state_size = by_arrays.L, by_arrays.r, by_arrays.state_size
        self.backstepping = qcontrol.BacksteppingLaw(by_arrays.c, table["delta"] / 2)

    def initial_state(self) -> np.ndarray:
        return np.zeros(self.state_size)

    def terms(self, x_q: np.ndarray, yd: np.ndarray) -> tuple[list, list, list, float]:
        """zbar, alphabar (eqs. (31)-(34)), r(x_q) and s = zbar_n^2 / kappa + L, as floats."""
        q = x_q.tolist()
        zbar, alphabar = self.backstepping.recursion(q, yd.tolist())
        zn = zbar[-1]
        return zbar, alphabar, [e.on_floats(q) for e in self.r], zn * zn / self.kappa + self.L

    def control(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> float:
        """Eq. (44)."""
        zbar, alphabar, r, s = self.terms(x_q, yd)
        robust = sum([e * ri for e, ri in zip(state.tolist(), r, strict=True)])  # eps_hat^T r(x_q)
        return alphabar[-1] - zbar[-1] * s * robust / (self.kappa * (self.kappa - self.L))


class PaperLawFloats(PaperLawFloatTerms):
    """The stepped law on floats: eq. (45) solved exactly over each step with the sample held."""

    def advance(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray, h: float) -> np.ndarray:
        """Eq. (45), exact with the sample held."""
        _, _, r, s = self.terms(x_q, yd)
        decay = math.exp(-self.gamma * self.sigma * h)
        targets = [s * ri / self.sigma for ri in r]
        return np.array([g + (e - g) * decay for e, g in zip(state.tolist(), targets, strict=True)])


class PaperLawRateFloats(PaperLawFloatTerms):
    """The law on floats with eq. (45) as a rate, advanced by the engine's RK4."""

    def state_rate(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> np.ndarray:
        """Eq. (45): ``eps_hat' = gamma (s r(x_q) - sigma eps_hat)``."""
        _, _, r, s = self.terms(x_q, yd)
        rates = [self.gamma * (s * ri - self.sigma * e) for e, ri in zip(state.tolist(), r, strict=True)]
        return np.array(rates)


class PaperLawColumns(qcontrol.BacksteppingLaw):
    """Law (44)-(45) in column form: every formula takes columns in the reading's form
    (``reading.form``: a float per column for a single run, a ``(batch,)`` array per column for a
    batch), r evaluated by that form."""

    state_name = "eps_hat"

    @classmethod
    def from_context(cls, context: qcontrol.LawContext) -> PaperLawColumns:
        law = cls(context.c, context.max_error)
        settings = context.settings
        law.kappa, law.gamma, law.sigma = (float(settings[k]) for k in ("kappa", "gamma", "sigma"))
        names = tuple(f"q{i + 1}" for i in range(context.n))
        law.r = [qcontrol.expression(e, variables=names) for e in settings["r"]]
        law.state_size = len(law.r)
        law.terms_by_form = {}
        return law

    def control(self, reading, yd, state, t=0.0) -> qcontrol.ControlOutput:
        q = reading.columns
        zbar, alphabar = self.recursion(q, yd)  # eqs. (31)-(34) on columns
        r = self.bounding_terms(reading.form)(q)
        zn = zbar[-1]
        s = zn * zn / self.kappa + self.L
        robust = reduce(add, map(mul, state, r))  # eps_hat^T r(x_q)
        u = alphabar[-1] - zn * s * robust / (self.kappa * (self.kappa - self.L))  # eq. (44)
        return qcontrol.ControlOutput(u, zbar, [s * ri / self.sigma for ri in r], self.gamma * self.sigma)

    def bounding_terms(self, form):
        """r evaluated on columns of ``form`` (the reading's), made once per form."""
        if form not in self.terms_by_form:
            self.terms_by_form[form] = form.terms(self.r)
        return self.terms_by_form[form]

    def advancer(self, h: float):
        decay = math.exp(-self.gamma * self.sigma * h)

        def advance(state, out):  # eq. (45), exact with the sample held
            return tuple([t + (e - t) * decay for e, t in zip(state, out.target, strict=True)])
        return advance


def register() -> None:
    """Register the forms under :data:`KINDS` (again after an edit: replace=True)."""
    qcontrol.register_law(KINDS["rk4"], PaperLawRK4, state_name="eps_hat", replace=True)
    qcontrol.register_law(KINDS["stepped"], PaperLawStepped, state_name="eps_hat", replace=True)
    qcontrol.register_law(KINDS["rate-floats"], PaperLawRateFloats, state_name="eps_hat", replace=True)
    qcontrol.register_law(KINDS["floats"], PaperLawFloats, state_name="eps_hat", replace=True)
    qcontrol.register_law(KINDS["columns"], PaperLawColumns, keys=KEYS, replace=True)


def overrides(sc: qcontrol.Scenario, form: str) -> dict:
    """Overrides that select the form ``form`` with the settings of ``sc``'s ``[controller.proposed]``
    (kappa resolved: given, or L + kappa_margin)."""
    controller: Mapping = sc.data["controller"]
    proposed = controller.get("proposed", {})
    kappa = proposed.get("kappa")
    if kappa is None:
        L = float(qcontrol.lemma2_bounds(controller["c"], controller["delta"])[-1])
        kappa = L + proposed["kappa_margin"]
    kind = KINDS[form]
    return {"controller.kind": kind, f"controller.{kind}.kappa": kappa,
            f"controller.{kind}.gamma": proposed["gamma"], f"controller.{kind}.sigma": proposed["sigma"],
            f"controller.{kind}.r": list(proposed["r"])}
