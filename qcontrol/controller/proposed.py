"""The paper's quantized adaptive law: control law (44) and adaptive law (45), and its scenario keys.

The scalar parameters (kappa, gamma, sigma, r_scale) may be given per copy, as arrays of shape
``(batch,)``: a parameter sweep then runs as one batch through the same formulas (a single run
has scalar parameters).
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field, replace
from functools import reduce
from operator import add, attrgetter, mul
from typing import Any, NamedTuple

import numpy as np

from ..columns import ARRAYS, ColumnForm, Terms
from ..errors import QcontrolInputError
from ..expr import Expression, compile_expression
from ..quantizer import QuantizedReading
from ..schema import OPTIONAL, Key, KindKeys, Table, expressions, number, read_keys, string
from ..sharing import kept_for
from .backstepping import (
    Advance,
    BacksteppingLaw,
    Column,
    Columns,
    ControlOutput,
    Parameter,
    output,
    parameter,
)
from .law import Diagnostic, LawContext, LawKeys

HOLDS = ("paper", "exact")  # how law (44) is held over a control period (see PaperLaw)

R_CHECK_SAMPLES = 2000  # quantized states at which every r_i is checked to be finite and >= 1
R_CHECK_RANGE = 10.0  # ... drawn uniformly from [-R_CHECK_RANGE, R_CHECK_RANGE]^n (and the origin)


class LawConstants(NamedTuple):
    """The constants the column formulas read, in one :class:`~qcontrol.columns.ColumnForm`."""

    kappa: Column
    gain: Column  # 1 / (kappa (kappa - L))
    sigma: Column
    r_scale: Column | None  # None when r_scale == 1 everywhere
    rate: Column  # gamma sigma
    terms: Terms  # the bounding functions r evaluated on the reading's columns: terms(q) -> [r_i]
    expm1: Any  # the form's exp(x) - 1 (the exact hold's 1 - exp(-K T))


class PaperLaw(BacksteppingLaw, compiled=True):
    """The paper's quantized adaptive controller, control law (44) and adaptive law (45).

    ``s = zbar_n^2 / kappa + L``,
    ``u = -(zbar_n / kappa) / (kappa - L) * s * eps_hat^T r(x_q) + alphabar_n``,
    ``eps_hat' = gamma (s r(x_q) - sigma eps_hat)``, ``eps_hat(0) = 0``.

    ``r`` are the bounding functions of eqs. (37)-(43), expressions over ``q1..qn``; each is
    multiplied by ``r_scale`` (any constant >= 1 keeps the bounds of (37)-(43) valid).

    Written as ``u = alphabar_n - K zbar_n``, the robust term's gain is
    ``K = s eps_hat^T r(x_q) / (kappa (kappa - L))``. ``hold`` says how u is held over the control
    period ``period`` (T): ``"paper"`` applies (44) as printed; ``"exact"`` replaces K by
    ``K_T = (1 - exp(-K T)) / T``, the gain whose held input maps ``zbar_n`` over one period as the
    continuous-time robust term ``zbar_n' = -K zbar_n`` would (docs/math.md, 'Sampling the law').
    Either way the law declares the diagnostic ``gain_period``, ``K T`` at every control sample;
    a subclass's class attribute ``diagnostics`` adds its own after it.

    A public class to subclass: :meth:`robust_term` (the term subtracted from ``alphabar_n``),
    :meth:`adaptive_target` (eq. (45)'s held target), :meth:`bounding_terms`, or
    :meth:`control`, :meth:`initial_state` and :meth:`advancer` to add a state (docs/laws.md).
    Every formula takes columns in the reading's form (a ``(batch,)`` array each in the array
    form) and the constants in that form (:meth:`constants_in`).
    :meth:`from_context` builds it from a scenario's ``[controller.proposed]`` settings.
    """

    state_name = "eps_hat"

    @classmethod
    def from_context(cls, context: LawContext) -> PaperLaw:
        """The law of the scenario's ``[controller.proposed]`` settings (``context.base``, a
        :class:`ProposedSettings`), its ``c``, ``delta`` and control period. A subclass with keys
        of its own reads them from ``context.settings`` in its ``__init__`` or here."""
        s = context.base
        if not isinstance(s, ProposedSettings):
            raise QcontrolInputError(f"{cls.__name__}.from_context: the context carries no "
                                     "[controller.proposed] settings; register the law with "
                                     "extends=\"proposed\"")
        return cls(context.c, context.max_error, kappa=s.kappa, gamma=s.gamma, sigma=s.sigma, r=s.r_expr,
                   r_scale=s.r_scale, expected_terms=context.uncertain_terms, hold=s.hold,
                   period=context.control_period)

    def __init__(
        self,
        c: Sequence[float],
        max_error: float,
        kappa: float,
        gamma: float,
        sigma: float,
        r: Sequence[Expression],
        r_scale: float = 1.0,
        expected_terms: int | None = None,
        hold: str = "paper",
        period: float = 1e-3,
    ) -> None:
        super().__init__(c, max_error)
        if hold not in HOLDS:
            raise QcontrolInputError(f"controller hold {hold!r}: use one of {', '.join(HOLDS)}")
        if not (math.isfinite(period) and period > 0):
            raise QcontrolInputError(f"controller period must be a finite number > 0, got {period!r}")
        self.hold, self.period = hold, float(period)
        self.diagnostics = (Diagnostic(  # then those a subclass declares as a class attribute
            "gain_period", 1, "-", "max", "K T: the robust gain K of law (44) times the control period T; "
            "above 1 the held input overshoots the continuous-time law's decay of zbar_n over one period",
            self._gain_period, "gain_period = K T of (44) (> 1: the held input overshoots)"),
            *type(self).diagnostics)
        gamma, sigma, r_scale = (parameter(k, v) for k, v in (("gamma", gamma), ("sigma", sigma),
                                                                ("r_scale", r_scale)))
        kappa_array = np.asarray(kappa, dtype=float)
        if not (np.all(np.isfinite(kappa_array)) and np.all(kappa_array > self.L)):
            raise QcontrolInputError(
                f"controller kappa must exceed L = L_z{self.n} = {self.L:g} (Theorem 1), got {kappa!r}"
            )
        kappa = parameter("kappa", kappa)
        if len(r) == 0:
            raise QcontrolInputError("controller r must list at least one bounding function")
        if expected_terms is not None and len(r) != expected_terms:
            raise QcontrolInputError(
                f"controller r has {len(r)} bounding function(s) but the plant has "
                f"{expected_terms} uncertain term(s) (one per phi_i, plus one for psi)"
            )
        sizes = {v.size for v in (kappa, gamma, sigma, r_scale) if isinstance(v, np.ndarray)}
        if len(sizes) > 1:
            raise QcontrolInputError(f"controller per-copy parameters have different lengths {sorted(sizes)}")
        self.copies: int | None = sizes.pop() if sizes else None  # batch size the parameters fix
        self.kappa, self.gamma, self.sigma, self.r_scale = kappa, gamma, sigma, r_scale
        self.r = tuple(r)
        self.state_size = len(self.r)
        self._constants: dict[ColumnForm, LawConstants] = {}  # (constants_in)

    def constants_in(self, form: ColumnForm) -> LawConstants:
        """The constants of the column formulas in ``form``, computed once per form: eq. (45)'s
        decay rate ``gamma sigma``, eq. (44)'s gain ``1 / (kappa (kappa - L))``, and r evaluated
        on the form's columns."""
        known = self._constants.get(form)
        if known is not None:
            return known
        kappa, sigma, r_scale = self.kappa, self.sigma, self.r_scale
        gain = 1.0 / (kappa * (kappa - self.L))  # (44): u = -zbar_n s eps^T r / (kappa (kappa - L))
        scaled = not np.all(np.asarray(r_scale) == 1.0)
        made = self._constants[form] = LawConstants(
            form.column(kappa), form.column(gain), form.column(sigma),
            form.column(r_scale) if scaled else None, form.column(self.gamma * sigma),
            form.terms(self.r), form.expm1)
        return made

    def initial_state(self, batch: int) -> np.ndarray:
        """``eps_hat(0) = 0``: one estimate per bounding function r_i (a subclass that adds states
        appends its own columns to these)."""
        return np.zeros((batch, len(self.r)))

    def constants(self) -> dict[str, Any]:
        return {"kappa": self.kappa, "gamma": self.gamma, "sigma": self.sigma, "r_scale": self.r_scale}

    def robust_gain(self, q: Columns, yd: Sequence[Column], eps_hat: Columns, form: ColumnForm = ARRAYS
                    ) -> Column:
        """``K = s eps_hat^T r(x_q) / (kappa (kappa - L))`` of law (44) over columns of any shape
        (``(rows, batch)`` when evaluated on a record; per-copy constants broadcast on the last
        axis), or over the columns of ``form`` (one row of each copy, in the compiled batch)."""
        law = self.constants_in(form)
        zn = self.recursion(q, yd)[0][-1]
        r = law.terms(q)
        if law.r_scale is not None:
            r = [ri * law.r_scale for ri in r]
        s = zn * zn / law.kappa + self.L
        return s * reduce(add, map(mul, eps_hat, r)) * law.gain

    def _gain_period(self, q: Columns, yd: Columns, eps_hat: Columns, form: ColumnForm = ARRAYS
                     ) -> np.ndarray:
        """The diagnostic ``gain_period``: ``K T`` (in ``form``: see :meth:`robust_gain`)."""
        if form is ARRAYS:  # (a subclass may define robust_gain without the form)
            return np.asarray(self.robust_gain(q, yd, eps_hat)) * self.period
        return self.robust_gain(q, yd, eps_hat, form) * self.period

    def held_factor(self, gain_period: Column) -> Column:
        """What the held robust term does to ``zbar_n`` over one period, ``1 - K_T T``: ``1 - K T``
        for the paper's law (outside [0, 1] once K T > 1, a flip once K T > 2), ``exp(-K T)`` in
        (0, 1] for the exact hold."""
        if self.hold == "paper":
            return 1.0 - gain_period
        return np.exp(-np.asarray(gain_period))

    def control(self, reading: QuantizedReading, yd: Sequence[float], eps_hat: Columns,
                t: float = 0.0) -> ControlOutput:
        """Eq. (44) for the current quantized reading; eq. (45)'s held terms for the advance:
        ``u = alphabar_n - robust_term(...)``, targets from :meth:`adaptive_target`.

        ``eps_hat`` is a tuple of m columns in the reading's form (``tuple(eps.T)`` of a
        ``(batch, m)`` array in the array form); ``yd`` holds ``y_d .. y_d^(n)``.
        """
        if not isinstance(reading, QuantizedReading) or reading.max_error != self.max_error:
            self.check_reading(reading)
        law = self.constants_in(reading.form)
        q = reading.columns
        zbar, alphabar = self.recursion(q, yd)  # eqs. (31)-(34)
        r = self.bounding_terms(q, law)
        u = alphabar[-1] - self.robust_term(zbar, r, eps_hat, law)  # eq. (44)
        return output((u, zbar, self.adaptive_target(zbar, r, law), law.rate))

    def bounding_terms(self, q: Columns, law: LawConstants) -> list[Column]:
        """``r(x_q)`` of eqs. (37)-(43), each times ``r_scale``."""
        r = law.terms(q)  # r(x_q)
        if law.r_scale is not None:
            r = [ri * law.r_scale for ri in r]
        return r

    def robust_term(self, zbar: Sequence[Column], r: Sequence[Column], eps_hat: Columns,
                    law: LawConstants) -> Column:
        """The term law (44) subtracts from ``alphabar_n``: ``zbar_n K`` with
        ``K = s eps_hat^T r / (kappa (kappa - L))``, ``s = zbar_n^2 / kappa + L`` (``K_T`` in
        place of K with ``hold = "exact"``). ``law`` holds the constants in the columns' form
        (``law.kappa``, ``law.gain = 1 / (kappa (kappa - L))``, ``law.sigma``, ``law.rate``)."""
        zn = zbar[-1]
        s = zn * zn / law.kappa + self.L
        robust = reduce(add, map(mul, eps_hat, r))  # eps_hat^T r(x_q), per copy, summed in order
        if self.hold == "paper":
            return zn * s * robust * law.gain
        return zn * (-law.expm1(-(s * robust * law.gain) * self.period) / self.period)

    def adaptive_target(self, zbar: Sequence[Column], r: Sequence[Column], law: LawConstants) -> list[Column]:
        """What eq. (45) drives each estimate towards while the sample is held, ``s r_i / sigma``
        (``eps_hat' = gamma sigma (target - eps_hat)``)."""
        zn = zbar[-1]
        s = zn * zn / law.kappa + self.L
        sigma = law.sigma
        return [s * ri / sigma for ri in r]

    def advancer(self, h: float) -> Advance:
        """Eq. (45) over a fixed step ``h`` with ``x_q`` held, exact for the linear ODE
        ``eps_hat' = gamma sigma (target - eps_hat)``, in the array form: a function ``(state,
        out) -> state`` made once per run (``exp(-gamma sigma h)`` is computed here, not every
        step). :meth:`advancer_in` gives it in any form."""
        return self._decay_advance(self.constants_in(ARRAYS), h)

    def advancer_in(self, form: ColumnForm, h: float) -> Advance:
        """:meth:`advancer` for a state in ``form`` (:class:`~.law.AnyColumnForm`); a subclass's
        own :meth:`advancer` when it overrides it (its formulas serve every form too)."""
        if type(self).advancer is not PaperLaw.advancer:
            return self.advancer(h)
        return self._decay_advance(self.constants_in(form), h)

    def _decay_advance(self, law: LawConstants, h: float) -> Advance:
        decay = np.exp(-np.asarray(law.rate) * h)
        return DecayAdvance(decay if decay.ndim else float(decay)).advance


class DecayAdvance:
    """Eq. (45) over one step with the sample held: each estimate decays towards its held target,
    ``eps <- t + (eps - t) exp(-gamma sigma h)`` (``decay`` computed once per run)."""

    def __init__(self, decay: Parameter) -> None:
        self.decay = decay

    def advance(self, state: Columns, out: ControlOutput) -> Columns:
        decay = self.decay
        # zip without strict=: the lengths are equal by construction (strict= costs ~0.3 us)
        return tuple([t + (e - t) * decay for e, t in zip(state, out.target)])  # noqa: B905


# --------------------------------------------------------------------------------------------
# Scenario keys: [controller] with kind = "proposed" (or [controller.proposed])

KEYS = KindKeys(
    "proposed",
    (
        Key("kappa", number(positive=True), OPTIONAL,
            meaning="kappa > L of law (44); give it or kappa_margin"),
        Key("kappa_margin", number(positive=True), OPTIONAL,
            meaning="kappa = L + kappa_margin (the paper writes kappa = 1.1 + L)", example="1.1"),
        Key("gamma", number(positive=True), meaning="adaptation gain gamma of law (45)", example="1.0"),
        Key("sigma", number(positive=True), meaning="sigma-modification sigma of law (45)", example="1.0"),
        Key("r", expressions("q1..qn"),
            meaning="bounding functions r_i(x_q) >= 1 of eqs. (37)-(43): one per phi_i, then one for psi",
            example='["1 + q2**2", "1 + 2*q2**2", "1"]'),
        Key("r_scale", number(positive=True), 1.0, meaning="constant factor >= 1 on every r_i"),
        Key("hold", string(HOLDS), "paper",
            meaning="how u is held over the control period T: \"paper\", law (44) as printed; \"exact\", the "
            "robust gain K replaced by (1 - exp(-K T)) / T, bounded in the sampled loop (docs/math.md)"),
    ),
    meaning="the paper's law (44) with the adaptive law (45)",
    alternatives=(("kappa", "kappa_margin"),),
)


@dataclass(frozen=True)
class ProposedSettings:
    """The validated keys of the proposed law; ``kappa`` is resolved (given, or L + margin)."""

    kappa: float
    kappa_margin: float | None
    gamma: float
    sigma: float
    r: tuple[str, ...]
    r_scale: float
    r_expr: tuple[Expression, ...] = field(default=(), repr=False, compare=False)
    hold: str = "paper"


def parse(table: Table, ctx: LawContext) -> ProposedSettings:
    """Read and check the proposed law's keys (Theorem 1's kappa > L, r_i >= 1, one r_i per term)."""
    v = read_keys(table, KEYS.keys, {"n": ctx.order})
    if ctx.uncertain_terms == 0:
        raise table.error_at("plant", "has no uncertain term (psi or phi) for the proposed law to bound and "
                             "adapt to (eqs. (37)-(45))", "add psi or phi to [plant], or use controller "
                             "kind \"comparison\"")
    kappa = _kappa(table, ctx, v["kappa"], v["kappa_margin"])
    r = v["r"]
    if len(r) != ctx.uncertain_terms:
        raise table.error("r", f"has {len(r)} bounding function(s) but the plant has {ctx.uncertain_terms} "
                          "uncertain term(s)", "give one r_i per phi_i, plus one for psi (eqs. (37)-(43))")
    if v["r_scale"] < 1.0:
        raise table.error("r_scale", f"must be >= 1 to keep r_i >= 1, got {v['r_scale']:g}",
                          "use a scale >= 1")
    q_names = [f"q{i + 1}" for i in range(ctx.order)]
    r_expr = tuple(compile_expression(e, q_names, f"{table.source}: {table.path(f'r[{i}]')}")
                   for i, e in enumerate(r))
    kept_for("bounding functions", (r, ctx.order, ctx.delta), _check_bounding_functions, table, r_expr, ctx)
    return ProposedSettings(kappa, v["kappa_margin"], v["gamma"], v["sigma"], r, v["r_scale"], r_expr,
                            v["hold"])


def _kappa(table: Table, ctx: LawContext, kappa: float | None, margin: float | None) -> float:
    """kappa as given, or L + kappa_margin; both must exceed L = L_zn (Theorem 1)."""
    if kappa is not None and margin is not None:
        raise table.error("kappa", "given together with kappa_margin",
                          "give either kappa or kappa_margin (kappa = L + kappa_margin), not both")
    if kappa is None and margin is None:
        raise table.error("kappa_margin", "missing", "give kappa_margin (kappa = L + margin) or kappa")
    # Lemma 2 with the quantizer's bound per channel
    L, n = kept_for("L", (ctx.c, ctx.max_error), attrgetter("L"), ctx), ctx.order
    if not math.isfinite(L):
        raise table.error_at("controller.delta", f"with c = {list(ctx.c)} gives L = L_z{n} = {L:g}, not a "
                             "finite number", "use a smaller quantizer step delta or smaller gains c")
    if kappa is not None:
        if kappa <= L:
            raise table.error("kappa", f"must exceed L = L_z{n} = {L:g} (Theorem 1), got {kappa:g}",
                              f"use kappa > {L:g}, or kappa_margin = kappa - L > 0")
        return kappa
    if not math.isfinite(L + margin):
        raise table.error("kappa_margin", f"{margin:g} makes kappa = L + kappa_margin overflow (L = {L:g})",
                          "use a smaller margin")
    if not L + margin > L:
        raise table.error("kappa_margin", f"{margin:g} is lost in floating point next to L = L_z{n} = {L:g}, "
                          "so kappa = L + kappa_margin would not exceed L",
                          f"use kappa_margin > {max(L, 1.0) * 1e-12:g}, or a smaller delta or gains c")
    return L + margin


def _check_bounding_functions(table: Table, r_expr: Sequence[Expression], ctx: LawContext) -> None:
    """Every r_i must be finite and >= 1 on quantized states (eqs. (37)-(43)): checked at the origin
    and at :data:`R_CHECK_SAMPLES` states drawn with a fixed seed."""
    rng = np.random.default_rng(0)
    samples = np.vstack([np.zeros(ctx.order),
                         rng.uniform(-R_CHECK_RANGE, R_CHECK_RANGE, size=(R_CHECK_SAMPLES, ctx.order))])
    samples = ctx.delta * np.round(samples / ctx.delta)
    for i, expr in enumerate(r_expr):
        with np.errstate(all="ignore"):
            value = expr(samples)
        bad = ~np.isfinite(value) | (value < 1.0 - 1e-12)
        if bad.any():
            first = np.flatnonzero(bad)[0]
            raise table.error(f"r[{i}]", f"{expr.source!r} must be finite and >= 1 for every quantized "
                              f"state (eqs. (37)-(43)) but is {float(value[first]):g} at q = "
                              f"{samples[first].tolist()}", "e.g. add 1 to it")


def per_copy_settings(settings: Sequence[ProposedSettings]) -> ProposedSettings:
    """The variants of one batch as one settings object: kappa, gamma, sigma and r_scale as
    per-copy arrays (a number for a single copy); r and the hold shared (see :func:`structure`)."""
    first = settings[0]
    return replace(first, kappa=_per_copy([s.kappa for s in settings]),
                   gamma=_per_copy([s.gamma for s in settings]), sigma=_per_copy([s.sigma for s in settings]),
                   r_scale=_per_copy([s.r_scale for s in settings]))


def _per_copy(values: list[float]) -> float | np.ndarray:
    return values[0] if len(values) == 1 else np.array(values)


def structure(settings: ProposedSettings, ctx: LawContext) -> Hashable:
    """Variants sharing a batch must share r and the hold; kappa, gamma, sigma and r_scale go per
    copy."""
    return settings.r, settings.hold


def bounding_functions(settings: ProposedSettings) -> tuple[Expression, ...]:
    """The law's bounding functions r_i(x_q) of (37)-(43), compiled from ``r``."""
    return settings.r_expr


def also_measure(settings: ProposedSettings) -> tuple[tuple[tuple[str, str], ...], ...]:
    """Beside the law held as printed, a study also measures its exact hold (docs/math.md)."""
    return ((("hold", "exact"),),) if settings.hold == "paper" else ()


LAW_KEYS = LawKeys(
    KEYS, parse, structure, combine=per_copy_settings, bounds=bounding_functions, also_measure=also_measure,
    divergence_hint="the law's gain grows with |x_q| (eq. (44)), so at a fixed sampling period a large "
    "state destabilizes the sampled loop once K T > 2 (docs/math.md, 'Sampling the law'); "
    "[controller.proposed] hold = \"exact\" holds its robust term exactly",
)
