"""The comparison law of the paper's reference [20], eq. (46), and its scenario keys.

Reference [20] assumes psi and phi globally Lipschitz and known in form, and feeds them the
quantized state directly. The paper does not print [20]'s adaptive law: the standard
tuning-function law ``theta_hat' = Gamma phi(x_q) zbar_n`` used here is our reconstruction, and
outputs label it so (docs/math.md, 'The comparison law').
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from functools import reduce
from operator import add, mul
from typing import Any

import numpy as np

from ..columns import ColumnForm, Terms
from ..errors import QcontrolInputError
from ..expr import Expression
from ..quantizer import QuantizedReading
from ..schema import Key, KindKeys, Table, number, read_keys, string
from .backstepping import Advance, BacksteppingLaw, Columns, ControlOutput, output
from .law import LawContext, LawKeys


class ComparisonLaw(BacksteppingLaw, compiled=True):
    """Comparison law of reference [20], eq. (46), with our reconstructed adaptive law.

    ``u = alphabar_n - psi(x_q) - theta_hat^T phi(x_q)`` with
    ``theta_hat' = Gamma phi(x_q) zbar_n`` (our reconstruction; the paper does not print it), or
    ``theta_hat = theta`` held fixed when ``known_theta`` is given.

    A public class to subclass: :meth:`adaptive_rate` (the adaptive law), or :meth:`control`,
    :meth:`initial_state` and :meth:`advancer` to change the input or add a state
    (docs/laws.md); :meth:`from_context` builds it from ``[controller.comparison]``.
    """

    state_name = "theta_hat"
    copies = None  # no per-copy parameters

    @classmethod
    def from_context(cls, context: LawContext) -> ComparisonLaw:
        """The law of the scenario's ``[controller.comparison]`` settings (``context.base``), its
        ``c``, ``delta`` and plant terms."""
        s = context.base
        if not isinstance(s, ComparisonSettings):
            raise QcontrolInputError(f"{cls.__name__}.from_context: the context carries no "
                                     "[controller.comparison] settings; register the law with "
                                     "extends=\"comparison\"")
        return cls(context.c, context.max_error, context.psi, context.phi, adaptation_gain=s.gain,
                   known_theta=context.theta if s.theta == "known" else None)

    def __init__(
        self,
        c: Sequence[float],
        max_error: float,
        psi: Expression | None,
        phi: Sequence[Expression],
        adaptation_gain: float = 1.0,
        known_theta: Sequence[float] | None = None,
    ) -> None:
        super().__init__(c, max_error)
        if not (np.isfinite(adaptation_gain) and adaptation_gain > 0):
            raise QcontrolInputError(
                "the comparison law's adaptation gain Gamma must be a finite number > 0, "
                f"got {adaptation_gain!r}"
            )
        self.psi = psi
        self.phi = tuple(phi)
        self.adaptation_gain = float(adaptation_gain)
        self.known_theta = None if known_theta is None else np.asarray(known_theta, dtype=float)
        self.state_size = len(self.phi)
        self._terms: dict[ColumnForm, Terms] = {}  # (terms_in)

    def initial_state(self, batch: int) -> np.ndarray:
        """``theta_hat(0) = 0``, or the true theta in the known-parameter case."""
        if self.known_theta is not None:
            return np.tile(self.known_theta, (batch, 1))
        return np.zeros((batch, len(self.phi)))

    def constants(self) -> dict[str, Any]:
        return {"comparison_gain": self.adaptation_gain}

    def control(self, reading: QuantizedReading, yd: Sequence[float], theta_hat: Columns,
                t: float = 0.0) -> ControlOutput:
        """Eq. (46) with the plant's own psi, phi evaluated at the quantized state; columns as in
        :meth:`PaperLaw.control <qcontrol.controller.proposed.PaperLaw.control>`."""
        if not isinstance(reading, QuantizedReading) or reading.max_error != self.max_error:
            self.check_reading(reading)
        q = reading.columns
        phi_q = self.terms_in(reading.form)(q)  # psi(x_q) (if present), then phi(x_q)
        zbar, alphabar = self.recursion(q, yd)  # eqs. (31)-(34)
        u = alphabar[-1]
        if self.psi is not None:
            u = u - phi_q.pop(0)
        rate: tuple = (0.0,) * len(phi_q)
        if phi_q:
            u = u - reduce(add, map(mul, theta_hat, phi_q))  # eq. (46): theta_hat^T phi(x_q)
            if self.known_theta is None:
                rate = self.adaptive_rate(zbar, phi_q)
        return output((u, tuple(zbar), rate, 0.0))

    def adaptive_rate(self, zbar: Sequence, phi_q: Sequence) -> tuple:
        """``theta_hat' = Gamma phi(x_q) zbar_n``, held until the next sample (columns)."""
        zn = zbar[-1]
        return tuple([self.adaptation_gain * p * zn for p in phi_q])

    def terms_in(self, form: ColumnForm) -> Terms:
        """psi (if present) and phi evaluated on columns of ``form`` (made once per form)."""
        terms = self._terms.get(form)
        if terms is None:
            exprs = ([self.psi] if self.psi is not None else []) + list(self.phi)
            terms = self._terms[form] = form.terms(exprs)
        return terms

    def advancer(self, h: float) -> Advance:
        """``theta_hat`` grown at the held rate over a fixed ``h`` (exact for ``x_q`` held), in
        column form (any form), made once per run."""
        return RateAdvance(h).advance


class RateAdvance:
    """``theta_hat`` over one step ``h`` at the rate held since the sample: ``e <- e + h rate``."""

    def __init__(self, h: float) -> None:
        self.h = h

    def advance(self, state: Columns, out: ControlOutput) -> Columns:
        h = self.h
        return tuple([e + h * t for e, t in zip(state, out.target)])  # noqa: B905 (equal lengths)


# --------------------------------------------------------------------------------------------
# Scenario keys: [controller] with kind = "comparison" (or [controller.comparison]); the former
# name "baseline" still loads (controller.law.KIND_ALIASES)

KEYS = KindKeys(
    "comparison",
    (
        Key("gain", number(positive=True), 1.0,
            meaning="adaptation gain Gamma of theta_hat' = Gamma phi(x_q) zbar_n", example="1.0"),
        Key("theta", string(("adaptive", "known")), "adaptive",
            meaning='"adaptive": theta_hat(0) = 0 and adapted; "known": theta_hat = the plant\'s theta, '
                    "held fixed", example='"adaptive"'),
    ),
    meaning="the comparison law (46) of the paper's reference [20], with our reconstructed adaptive law",
)


@dataclass(frozen=True)
class ComparisonSettings:
    gain: float
    theta: str


def parse(table: Table, ctx: LawContext) -> ComparisonSettings:
    v = read_keys(table, KEYS.keys, {"n": ctx.order})
    if any(e.variables[-1:] == ("t",) for e in (ctx.psi, *ctx.phi) if e is not None):
        raise table.error_at("plant", "law (46) evaluates psi and phi at the quantized state alone and "
                             "does not take terms in t", "use kind = \"proposed\" for a forced plant")
    return ComparisonSettings(v["gain"], v["theta"])


def structure(settings: ComparisonSettings, ctx: LawContext) -> Hashable:
    """Everything the law reads must be shared: its settings and, when theta is known, theta."""
    return settings, ctx.theta if settings.theta == "known" else None


LAW_KEYS = LawKeys(
    KEYS, parse, structure,
    divergence_hint="law (46) cancels psi and theta^T phi at the quantized state; a term that is not "
    "Lipschitz differs there from its true value by more the larger the state (docs/math.md, "
    "'The comparison law')",
)
