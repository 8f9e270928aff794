"""The tuning-function law of adaptive backstepping for parametric strict-feedback plants, with
quantized states, and its scenario keys (docs/math.md, 'Strict-feedback plants').

The plant: ``x_i' = x_{i+1} + phi_i(x_1..x_i)^T theta`` (i < n), ``x_n' = u + psi + phi_n^T
theta``; the chain of eq. (1) is the case phi_i = 0 for i < n. The design is Krstic,
Kanellakopoulos and Kokotovic's (Nonlinear and Adaptive Control Design, 1995, Table 4.1, tracking
form), evaluated at the quantized states as the certainty-equivalence laws of the paper's
reference [20] are. With ``alpha_0 = 0``, ``tau_0 = 0``, ``z_0 = 0``, ``Gamma = gamma I``:

    z_i     = x_i - y_d^(i-1) - alpha_{i-1}
    w_i     = phi_i - sum_{k<i} (d alpha_{i-1} / d x_k) phi_k
    tau_i   = tau_{i-1} + w_i z_i
    alpha_i = -z_{i-1} - c_i z_i - w_i^T theta_hat
              + sum_{k<i} [ (d alpha_{i-1} / d x_k) x_{k+1} + (d alpha_{i-1} / d y_d^(k-1)) y_d^(k) ]
              + (d alpha_{i-1} / d theta_hat) Gamma tau_i
              + sum_{k=2..i-1} (d alpha_{k-1} / d theta_hat) Gamma w_i z_k
    u       = alpha_n + y_d^(n)
    theta_hat' = Gamma tau_n - gamma sigma theta_hat

Nothing is written by hand per plant: the virtual controls are built as expression trees over
``(x_1..x_n, theta_hat, y_d..y_d^(n))`` from the regressors' own trees, and every partial
derivative is the symbolic derivative of those trees (:func:`qcontrol.expr.calculus.differentiate`,
nested: alpha_2 holds d alpha_1 / d x_1, whose derivative alpha_3 needs). At each control sample
the trees are evaluated at the quantized reading x_q (:class:`~qcontrol.expr.calculus.Program`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..columns import ColumnForm, stack
from ..errors import QcontrolInputError
from ..expr import Expression
from ..expr.calculus import Program, add, differentiate, dot, mul, neg, number, sub, total
from ..expr.tree import Tree, Variable
from ..quantizer import QuantizedReading
from ..schema import Key, KindKeys, Table, read_keys
from ..schema import number as number_key
from .backstepping import Advance, BacksteppingLaw, Columns, ControlOutput, output
from .comparison import RateAdvance
from .law import STRICT_FEEDBACK, Diagnostic, LawContext, LawKeys
from .proposed import DecayAdvance


@dataclass(frozen=True)
class Design:
    """The tuning-function design as trees over the variables ``x_1..x_n`` (indices 0..n-1),
    ``theta_hat_1..theta_hat_l`` (n..n+l-1) and ``y_d..y_d^(n)`` (n+l..2n+l): ``u``, the errors
    ``z_1..z_n`` and ``tau_n`` (l trees)."""

    u: Tree
    z: tuple[Tree, ...]
    tau: tuple[Tree, ...]

    @classmethod
    def of(cls, rows: Sequence[Sequence[Tree]], c: Sequence[float], gamma: float) -> Design:
        """The design for regressor rows ``rows`` (n rows of l trees over x_1..x_n), gains ``c``
        and ``Gamma = gamma I`` (module docstring)."""
        n, m = len(rows), len(rows[0])
        x = [Variable(i) for i in range(n)]
        th = [Variable(n + j) for j in range(m)]
        yd = [Variable(n + m + j) for j in range(n + 1)]
        d = Derivatives()
        alpha: list[Tree] = [number(0.0)]  # alpha_0
        z: list[Tree] = []
        tau: list[Tree] = [number(0.0)] * m
        for i in range(1, n + 1):
            prev = alpha[i - 1]
            zi = sub(sub(x[i - 1], yd[i - 1]), prev)
            dx = [d(prev, x[k]) for k in range(i - 1)]
            w = [sub(rows[i - 1][j], total([mul(dx[k], rows[k][j]) for k in range(i - 1)])) for j in range(m)]
            tau = [add(tau[j], mul(w[j], zi)) for j in range(m)]
            terms = [neg(z[-1]) if z else number(0.0), neg(mul(number(c[i - 1]), zi)), neg(dot(w, th))]
            terms += [add(mul(dx[k], x[k + 1]), mul(d(prev, yd[k]), yd[k + 1])) for k in range(i - 1)]
            terms.append(mul(number(gamma), dot([d(prev, t) for t in th], tau)))
            terms += [mul(mul(number(gamma), dot([d(alpha[k - 1], t) for t in th], w)), z[k - 1])
                      for k in range(2, i)]
            z.append(zi)
            alpha.append(total(terms))
        return cls(add(alpha[n], yd[n]), tuple(z), tuple(tau))


class Derivatives:
    """Partial derivatives of the design's trees, sharing one memo (so that derivatives of trees
    that share subtrees share theirs): ``d(tree, variable)``."""

    def __init__(self) -> None:
        self.memo: dict[tuple[int, int], tuple[Tree, Tree]] = {}

    def __call__(self, tree: Tree, variable: Variable) -> Tree:
        return differentiate(tree, variable.index, self.memo)


class TuningLaw(BacksteppingLaw, compiled=True):
    """The tuning-function law (module docstring) for a plant of ``rows`` (n rows of l
    regressors), gains ``c``, ``Gamma = gamma I`` and the sigma-modification ``sigma >= 0``
    (0: Krstic, Kanellakopoulos and Kokotovic's law). Its adaptive state is ``theta_hat``, 0 at
    t = 0; its diagnostic ``z`` records the design's errors z_1..z_n at the quantized reading."""

    state_name = "theta_hat"
    copies = None

    @classmethod
    def from_context(cls, context: LawContext) -> TuningLaw:
        s = context.base
        return cls(context.c, context.max_error, context.regressor_rows, gamma=s.gamma, sigma=s.sigma)

    def __init__(self, c: Sequence[float], max_error: float, rows: Sequence[Sequence[Expression]],
                 gamma: float = 1.0, sigma: float = 0.0) -> None:
        super().__init__(c, max_error)
        if not (math.isfinite(gamma) and gamma > 0 and math.isfinite(sigma) and sigma >= 0):
            raise QcontrolInputError(f"the tuning law needs gamma > 0 and sigma >= 0, got {gamma!r}, "
                                     f"{sigma!r}")
        if len(rows) != self.n or not rows[0]:
            raise QcontrolInputError(f"the tuning law needs {self.n} regressor rows of length l >= 1")
        self.gamma, self.sigma = float(gamma), float(sigma)
        self.rows = tuple(tuple(row) for row in rows)
        self.state_size = len(self.rows[0])
        self.design = Design.of([[e._tree for e in row] for row in self.rows], self.c, self.gamma)
        self.program = Program([self.design.u, *self.design.tau, *self.design.z])
        self._programs: dict[ColumnForm, Callable] = {}  # the program in each form (values)
        self.z_program = Program(list(self.design.z))
        self.diagnostics = (Diagnostic("z_tuning", self.n, "state", "last", "the tuning design's errors "
                                       "z_1..z_n at the quantized reading", self._errors,
                                       label="z (tuning design)"),)

    def constants(self) -> dict[str, Any]:
        return {"tuning_gamma": self.gamma, "tuning_sigma": self.sigma}

    def values(self, q: Columns, state: Columns, yd: Sequence[Any], form: ColumnForm | None = None
               ) -> list[Any]:
        """``[u, tau_1..tau_l, z_1..z_n]`` at the reading ``q``, the estimate ``state`` and ``yd``,
        in the column form ``form`` (None: numpy's arrays, or plain floats)."""
        if form is None:
            return self.program([*q, *state, *yd])
        evaluate = self._programs.get(form)
        if evaluate is None:
            evaluate = self._programs[form] = form.program(self.program)
        return evaluate([*q, *state, *yd])

    def control(self, reading: QuantizedReading, yd: Sequence[float], theta_hat: np.ndarray | Columns,
                t: float = 0.0) -> ControlOutput:
        """u and the held adaptive target at the quantized reading (array or column form, as
        :meth:`~.comparison.ComparisonLaw.control`)."""
        if not isinstance(reading, QuantizedReading) or reading.max_error != self.max_error:
            self.check_reading(reading)
        if isinstance(theta_hat, np.ndarray):
            out = self.control(QuantizedReading(reading.values, reading.max_error), yd, tuple(theta_hat.T))
            batch = len(theta_hat)
            return ControlOutput(out.u, stack(out.zbar, batch), stack(out.target, batch), out.rate)
        values = self.values(reading.columns, theta_hat, yd, reading.form)
        u, tau, z = values[0], values[1:1 + self.state_size], values[1 + self.state_size:]
        if self.sigma > 0:  # theta_hat' = gamma sigma (tau / sigma - theta_hat): decays to tau / sigma
            target = tuple(t / self.sigma for t in tau)
        else:
            target = tuple(self.gamma * t for t in tau)  # theta_hat' = gamma tau_n
        return output((u, tuple(z), target, self.gamma * self.sigma))

    def advancer(self, h: float) -> Advance:
        """theta_hat over one step ``h`` with tau_n held: exactly (a decay towards tau_n / sigma,
        or a ramp at gamma tau_n when sigma = 0)."""
        if self.sigma > 0:
            return DecayAdvance(math.exp(-self.gamma * self.sigma * h)).advance
        return RateAdvance(h).advance

    def _errors(self, x_q: Columns, yd: Columns, state: Columns) -> np.ndarray:
        """The design's z_1..z_n on recorded rows (each column ``(rows, batch)``)."""
        z = self.z_program([*x_q, *state, *yd])
        shape = np.shape(x_q[0])
        return np.stack([np.broadcast_to(np.asarray(v, dtype=float), shape) for v in z], axis=-1)


# --------------------------------------------------------------------------------------------
# Scenario keys: [controller] with kind = "tuning" (or [controller.tuning])

KEYS = KindKeys(
    "tuning",
    (
        Key("gamma", number_key(positive=True), 1.0, meaning="adaptation gain: Gamma = gamma I",
            example="1.0"),
        Key("sigma", number_key(nonnegative=True), 0.0,
            meaning="sigma-modification of theta_hat' = Gamma tau_n - gamma sigma theta_hat (0: the "
                    "tuning-function law as published)", example="0.0"),
    ),
    meaning="the tuning-function law of adaptive backstepping for strict-feedback plants, at the "
            "quantized states",
)


@dataclass(frozen=True)
class TuningSettings:
    gamma: float
    sigma: float


def parse(table: Table, ctx: LawContext) -> TuningSettings:
    """Read and check gamma > 0, sigma >= 0; the plant must have regressors (phi) to adapt to."""
    v = read_keys(table, KEYS.keys, {"n": ctx.order})
    if not ctx.phi:
        raise QcontrolInputError(f"{ctx.source}: plant.phi: the tuning law needs regressors phi (theta^T phi "
                                 "in at least one equation); add plant.phi and plant.theta, or use another "
                                 "controller kind")
    if any(e.variables[-1:] == ("t",) for e in ctx.phi):
        raise QcontrolInputError(f"{ctx.source}: plant.phi: a regressor of the last row uses t, which the "
                                 "tuning law's design does not differentiate; write the term in t as psi, or "
                                 "use another controller kind")
    return TuningSettings(v["gamma"], v["sigma"])


def structure(settings: TuningSettings, ctx: LawContext) -> Hashable:
    """Variants share a batch when their settings are equal (gamma is inside the design's trees)."""
    return settings


LAW_KEYS = LawKeys(
    KEYS, parse, structure, plants=STRICT_FEEDBACK,
    divergence_hint="the tuning-function law cancels the regressors at the quantized state; its gains "
    "grow with the regressors' derivatives, so a large state or a coarse quantizer can destabilize the "
    "sampled loop (docs/math.md, 'Strict-feedback plants')",
)
