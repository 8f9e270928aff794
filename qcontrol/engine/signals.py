"""The one table of recorded signals (:data:`SIGNALS`).

Every signal of a run is declared here once: its name, width, unit, whether it is held over the
step (drawn as steps) or interpolated, what it means, and either that the loop records it every
row or the function that derives it from recorded ones (for many rows at once, after the loop
recorded them). The engine's row buffers, the fields of :class:`~qcontrol.engine.results.Trajectory`,
the metrics of :class:`~qcontrol.engine.results.RunMetrics` (each signal's ``reductions``), the
saved trajectory files and the rerun series are all made from this table. The table holds data
only: how recordings draw a signal (entity paths, colours, panels, twins) is
:data:`qcontrol.recording.styles.PLOTS`, keyed by the signal's name.

Adding a signal is one row plus the function that computes it; a derived signal may read the
signals above it in the table.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from ..columns import ARRAYS, ColumnForm
from ..compiled.traced import Row, TracedForm
from ..controller.backstepping import Backstepping
from ..controller.law import Diagnostic
from ..expr import Expression
from ..expr.operations import POWER
from ..plants.base import applied_as_commanded
from ..quantizers import SensorQuantizer
from .lemma2 import Lemma2Largest
from .reductions import (
    BoundConstants,
    DiagnosticValues,
    ErrorRate,
    FinalValue,
    InputQuantizedFraction,
    LargestAbs,
    LargestAbsApplied,
    LargestInputQuantizationError,
    LastHalfLargestAbs,
    ReadingSaturatedFraction,
    Reduction,
    SaturatedFraction,
    SmallestBound,
)

Block = Mapping[str, np.ndarray]  # signals of rows [first, stop): (rows, batch, width); y_d (rows, 1, n+1)


@dataclass(frozen=True)
class Separation:
    """The separation of eqs. (37)-(43) to check along a run: each uncertain term (``phi_1 ..
    phi_l``, then ``psi``) and its bounding function r_i (over ``q1..qn``), named ``names``."""

    names: tuple[str, ...]
    terms: tuple[Expression, ...]
    r: tuple[Expression, ...]


@dataclass(frozen=True)
class SignalContext:
    """What derivations may read besides the block: the coordinates of the recorded errors, the
    separation to check (None: not checked; its signal then has no columns), the plant's actuator
    (commanded u -> applied u, :meth:`~qcontrol.plants.base.Plant.actuator`; ``actuator_limited``:
    whether it can clip at all) and where the controller's x2 came from (``"sensor"`` or
    ``"difference"``, see :mod:`qcontrol.engine.velocity`)."""

    coordinates: Backstepping
    separation: Separation | None = None
    actuator: Callable[[np.ndarray], np.ndarray] = applied_as_commanded
    velocity_source: str = "sensor"
    actuator_limited: bool = False
    diagnostics: tuple[Diagnostic, ...] = ()  # the law's own signals
    quantizer: Any = None  # the state's quantizer (its ``saturated`` readings, if it has a range)
    input_quantizer: Any = None  # the input's quantizer q_u of [quantizer.input] (None: u as computed)
    chain: bool = True  # the plant is the chain of eq. (1) (Lemma 2 applies to it)
    # the form of the block's columns: arrays for a block of rows, the traced form for one row of
    # one copy (a :class:`~qcontrol.compiled.traced.Row` per signal) in a compiled batch's folds
    form: ColumnForm = ARRAYS

    @property
    def terms(self) -> int:
        return 0 if self.separation is None else len(self.separation.terms)

    @property
    def diagnostic_width(self) -> int:
        return sum(d.width for d in self.diagnostics)


Derive = Callable[[Block, SignalContext], np.ndarray]


def _columns(values: Any) -> list[Any]:
    """A signal's values as columns (its last axis): ``(rows, batch)`` views of a block's array, the
    symbols of a traced row."""
    return [values[..., i] for i in range(np.shape(values)[-1])]


def _side_by_side(columns: list[Any], like: Any) -> Any:
    """Columns as the last axis of a signal's values shaped as ``like``'s rows and copies: a traced
    row of them (a :class:`~qcontrol.compiled.traced.Row`), else an array."""
    if isinstance(like, Row):
        return Row(columns)
    out = np.empty(like.shape[:-1] + (len(columns),))
    for i, column in enumerate(columns):
        out[..., i] = column
    return out


def _errors(values: Any, yd: Any, ctx: SignalContext, quantized: bool = False) -> Any:
    """The errors of eqs. (7)-(8) of a state, or with ``quantized`` of eqs. (31)-(33) of a quantized
    reading: of a block of rows by the coordinates' matrix products (derived from the recursion
    (31)-(34)), of a traced row by that recursion itself."""
    if isinstance(values, Row):
        return Row(ctx.coordinates.recursion(tuple(values), tuple(yd))[0])
    if quantized:
        return ctx.coordinates.quantized_errors(values, yd)[0]
    return ctx.coordinates.errors(values, yd)


def _z(block: Block, ctx: SignalContext) -> np.ndarray:
    """The true errors (7)-(8) from the true state."""
    return _errors(block["x"], block["yd"], ctx)


def _zbar(block: Block, ctx: SignalContext) -> np.ndarray:
    """The quantized errors (31)-(33) from the quantized reading (what the controller computed)."""
    return _errors(block["x_q"], block["yd"], ctx, quantized=True)


def _u_quantized(block: Block, ctx: SignalContext) -> np.ndarray:
    """The input's quantizer applied to u, ``q_u(u)`` (u itself without one)."""
    u = block["u"]
    if ctx.input_quantizer is None:
        return u
    return ctx.input_quantizer(u[..., None])[..., 0]


def _u_applied(block: Block, ctx: SignalContext) -> np.ndarray:
    """What the actuator applied for the commanded u (``q_u(u)`` with an input quantizer, clipped
    at the actuator's limit; u itself for an actuator without either)."""
    return ctx.actuator(block["u_quantized"])


def _input_quantization_error(block: Block, ctx: SignalContext) -> np.ndarray:
    """``q_u(u) - u``: what the input's quantizer changed (0 without one)."""
    return block["u_quantized"] - block["u"]


def _input_quantized(block: Block, ctx: SignalContext) -> np.ndarray:
    """1 where the applied ``q_u(u)`` differed from the command u, else 0 (NaN where u is not finite)."""
    u = block["u"]
    if ctx.input_quantizer is None:
        return u * 0.0
    return np.where(np.isfinite(u), (block["u_quantized"] != u).astype(float), np.nan)


def _reading_saturated(block: Block, ctx: SignalContext) -> np.ndarray:
    """1 where a reading saturated at its channel's range, else 0 (NaN where it is not finite)."""
    x_meas = block["x_meas"]
    if not isinstance(ctx.quantizer, SensorQuantizer):  # the paper's quantizer: no range
        return x_meas[..., 0] * 0.0
    return ctx.quantizer.saturated(x_meas)


def _saturated(block: Block, ctx: SignalContext) -> np.ndarray:
    """1 where the actuator clipped the command, 0 where it applied it (NaN where u is not finite)."""
    u, applied = block["u_quantized"], block["u_applied"]
    if not ctx.actuator_limited:  # nothing clipped; u * 0 keeps NaN where u is not finite
        return u * 0.0
    return np.where(np.isfinite(u), (applied != u).astype(float), np.nan)


def _e_z(block: Block, ctx: SignalContext) -> np.ndarray:
    """Lemma 2's errors ``|z(x_meas) - zbar|``: the errors of the very reading the quantizer saw."""
    return abs(_errors(block["x_meas"], block["yd"], ctx) - block["zbar"])


def bounds(separation: Separation | None, form: ColumnForm, at_q: Sequence[Any]) -> list[Any]:
    """The bounding functions ``r_i(x_q)`` of (37)-(43), one column each, from the columns of the
    quantized reading (any form: arrays for a block of rows, symbols for the compiled folds)."""
    return [] if separation is None else form.terms(separation.r)(at_q)


def bound_ratios(separation: Separation | None, form: ColumnForm, at_x: Sequence[Any], at_q: Sequence[Any],
                 r: Sequence[Any]) -> list[Any]:
    """``|term_i| / r_i(x_q)`` with the term at the true state and at x_q (the centre of the
    quantization cell (37)-(43) must bound), whichever is larger; NaN or Inf where either is."""
    if separation is None:
        return []
    terms = form.terms(separation.terms)
    return [form.maximum(abs(a), abs(b)) / ri for a, b, ri in zip(terms(at_x), terms(at_q), r, strict=True)]


def _r(block: Block, ctx: SignalContext) -> np.ndarray:
    """The bounding functions ``r_i(x_q)`` of (37)-(43) at the quantized reading (:func:`bounds`)."""
    x_q = block["x_q"]
    return _side_by_side(bounds(_separation(ctx), ctx.form, _columns(x_q)), x_q)


def _bound_ratio(block: Block, ctx: SignalContext) -> np.ndarray:
    """The ratios of :func:`bound_ratios` at every row."""
    x, x_q, r = (_columns(block[name]) for name in ("x", "x_q", "r"))
    return _side_by_side(bound_ratios(_separation(ctx), ctx.form, x, x_q, r), block["x"])


@cache
def same_functions() -> frozenset[str]:
    """The functions (besides + - * / and squares) whose value numpy's ``on_columns`` and the
    traced form's ``math`` (libm) give alike: abs and sqrt (correctly rounded by both), and sin
    and cos where a probe finds numpy's equal to libm's on this machine (a numpy with its own
    vectorised sine would differ in the last bit on some percent of values: then they are left
    out, and the separation keeps the array form)."""
    probe = np.linspace(-40.0, 40.0, 4001)
    alike = {"sqrt", "abs"}
    for name in ("sin", "cos"):
        ours = np.array([getattr(math, name)(v) for v in probe.tolist()])
        if np.array_equal(getattr(np, name)(probe), ours):
            alike.add(name)
    return frozenset(alike)


def _traced_alike(node: Any) -> bool:
    """Whether the tree's traced evaluation (math) gives numpy's value (:meth:`Expression.on_columns`)."""
    operation = getattr(node, "operation", None)
    if operation is None:  # a number or a variable
        return True
    if operation is POWER:  # numpy squares a power 2 (np.square); other powers differ from math.pow
        exponent_two = node.operands[1].constant == 2.0
        return exponent_two and _traced_alike(node.operands[0])
    if not operation.is_operator and operation.arity != 0 and operation.name not in same_functions():
        return False
    return all(_traced_alike(operand) for operand in node.operands)


def _separation(ctx: SignalContext) -> Separation | None:
    """The separation, to evaluate in ``ctx.form``. The traced form evaluates it by ``math`` (the
    compiled folds), which must give the array form's numbers to the last bit: a term where it
    might not (a power other than a square, exp, log, ...) raises TypeError there (its signals
    are then the array form's)."""
    separation = ctx.separation
    if separation is not None and isinstance(ctx.form, TracedForm) and not all(
            _traced_alike(e._tree) for e in (*separation.terms, *separation.r)):
        raise TypeError("a separation term whose numpy value may differ from math's")
    return separation


def _quantization_error(block: Block, ctx: SignalContext) -> np.ndarray:
    """What quantization took from the reading, ``x_meas - q(x_meas)``: within +-delta/2, eq. (4)."""
    return block["x_meas"] - block["x_q"]


def _diagnostics(block: Block, ctx: SignalContext) -> np.ndarray:
    """The law's declared diagnostics side by side, each evaluated from the reading, the reference
    row and the law's state recorded at the row (exactly what the law saw at a control sample)."""
    x_q = block["x_q"]
    rows = x_q.shape[:-1]
    out = np.empty(rows + (ctx.diagnostic_width,))
    if not ctx.diagnostics:
        return out
    columns = tuple(tuple(np.moveaxis(block[name], -1, 0)) for name in ("x_q", "yd", "adaptive"))
    first = 0
    for diagnostic in ctx.diagnostics:
        values = np.asarray(diagnostic.evaluate(*columns), dtype=float)
        out[..., first : first + diagnostic.width] = np.broadcast_to(values.reshape(
            values.shape[: len(rows)] + (diagnostic.width,)), rows + (diagnostic.width,))
        first += diagnostic.width
    return out


@dataclass(frozen=True)
class Signal:
    """One recorded signal.

    ``width``: ``"n"`` (one per state), ``"n+1"`` (y_d and its n derivatives), ``"m"`` (one per
    adaptive state), ``"terms"`` (one per uncertain term of eq. (1) whose bound is checked) or
    ``"diagnostics"`` (one per column of the law's declared diagnostics) or
    ``"1"`` (a scalar: its arrays have no last axis). ``derive`` is None for
    the signals the loop records every row; a derivation may read the signals above it.
    ``shared``: one value for every copy of a batch (the reference, computed from the grid).
    ``reductions``: what a metrics-only run keeps of it (the summary reads them). Where and how
    recordings draw a signal is theirs to say (:data:`qcontrol.recording.styles.PLOTS`, keyed by
    the signal's name).
    """

    name: str
    width: str
    unit: str
    held: bool
    meaning: str
    derive: Derive | None = None
    shared: bool = False
    reductions: tuple[type[Reduction], ...] = ()
    reads: tuple[str, ...] = ()  # a derived signal: the signals its derivation reads

    @property
    def recorded(self) -> bool:
        """Recorded by the loop every row (not derived, not the reference)."""
        return self.derive is None and not self.shared

    def size(self, n: int, m: int, terms: int = 0, diagnostics: int = 0) -> int:
        return {"n": n, "n+1": n + 1, "m": m, "1": 1, "terms": terms, "diagnostics": diagnostics}[self.width]


SIGNALS: tuple[Signal, ...] = (
    Signal("x", "n", "state", False, "true state x_1..x_n of eq. (1) (never shown to the controller)"),
    Signal("x_meas", "n", "state", False, "sensor reading of x, before quantization"),
    Signal("x_q", "n", "state", True, "quantized reading q(x_meas), eq. (3): all the controller sees"),
    Signal("u", "1", "input", True, "input held over [t_k, t_k + dt): law (44), (46) or a user law",
           reductions=(LargestAbs,)),
    Signal("u_quantized", "1", "input", True, "q_u(u): u after the input's quantizer ([quantizer.input]; u "
           "itself without one)", _u_quantized, reads=("u",)),
    Signal("u_applied", "1", "input", True, "input the actuator applied: q_u(u), clipped where the actuator "
           "saturates (the plant's actuator)", _u_applied, reads=("u_quantized",),
           reductions=(LargestAbsApplied,)),
    Signal("saturated", "1", "-", True, "1 where the actuator clipped the command u over the step, else 0",
           _saturated, reads=("u_quantized", "u_applied"), reductions=(SaturatedFraction,)),
    Signal("input_quantization_error", "1", "input", True, "q_u(u) - u: what the input's quantizer "
           "changed", _input_quantization_error, reads=("u", "u_quantized"),
           reductions=(LargestInputQuantizationError,)),
    Signal("input_quantized", "1", "-", True, "1 where the applied q_u(u) differed from the command u, "
           "else 0", _input_quantized, reads=("u", "u_quantized"), reductions=(InputQuantizedFraction,)),
    Signal("adaptive", "m", "adaptive", False, "adaptive estimates (eps_hat of (45), theta_hat of (46), ...)",
           reductions=(FinalValue,)),
    Signal("yd", "n+1", "y", False, "reference y_d and its derivatives y_d', ..., y_d^(n)", shared=True),
    Signal("z", "n", "state", False, "errors z_i of eqs. (7)-(8), from the true state", _z,
           reads=("x", "yd"), reductions=(ErrorRate, LastHalfLargestAbs)),
    Signal("zbar", "n", "state", False, "quantized errors zbar_i of eqs. (31)-(33)", _zbar,
           reads=("x_q", "yd")),
    Signal("e_z", "n", "state", False, "Lemma 2 errors |z_i(x_meas) - zbar_i| (bound L_zi)", _e_z,
           reads=("x_meas", "yd", "zbar"),
           reductions=(Lemma2Largest,)),
    Signal("r", "terms", "r", False,
           "bounding functions r_i(x_q) of the separation (37)-(43) (phi_1..phi_l, then psi): >= 1 required",
           _r, reads=("x_q",), reductions=(SmallestBound,)),
    Signal("bound_ratio", "terms", "ratio", False,
           "|term_i| / r_i(x_q) of the separation (37)-(43) (phi_1..phi_l, then psi), at x and at x_q",
           _bound_ratio, reads=("x", "x_q", "r"), reductions=(BoundConstants,)),
    Signal("reading_saturated", "1", "-", False, "1 where a reading lay beyond its channel's range (the "
           "[quantizer] table's range), else 0", _reading_saturated, reads=("x_meas",),
           reductions=(ReadingSaturatedFraction,)),
    Signal("quantization_error", "n", "state", False,
           "quantization error x_meas - q(x_meas) of the reading the quantizer saw (|.| <= delta/2)",
           _quantization_error, reads=("x_meas", "x_q")),
    Signal("diagnostics", "diagnostics", "law", True,
           "the law's own diagnostics (e.g. gain_period, K T of law (44)), from the row's reading and state",
           _diagnostics, reads=("x_q", "yd", "adaptive"), reductions=(DiagnosticValues,)),
)
RECORDED = tuple(s for s in SIGNALS if s.recorded)
DERIVED = tuple(s for s in SIGNALS if s.derive is not None)
REDUCTIONS: tuple[type[Reduction], ...] = tuple(r for s in SIGNALS for r in s.reductions)
assert tuple(s.name for s in RECORDED) == ("x", "x_meas", "x_q", "u", "adaptive"), (
    "the loop records exactly these, in this order (see qcontrol.engine.row_buffer)")


@dataclass(frozen=True)
class ColumnNaming:
    """What names a run's columns in saved files besides the signal table: the adaptive state's
    name, the terms whose separation is checked and the law's diagnostic columns."""

    adaptive_name: str
    bound_names: tuple[str, ...] = ()
    diagnostic_columns: tuple[str, ...] = ()


def _state_column(signal: Signal, i: int, naming: ColumnNaming) -> str:
    return f"{signal.name}{i + 1}"  # x1 .. xn


def _reference_column(signal: Signal, i: int, naming: ColumnNaming) -> str:
    return f"{signal.name}_{i}"  # yd_0 .. yd_n


def _adaptive_column(signal: Signal, i: int, naming: ColumnNaming) -> str:
    return f"{naming.adaptive_name}_{i + 1}"


def _term_column(signal: Signal, i: int, naming: ColumnNaming) -> str:
    return f"{signal.name}_{naming.bound_names[i]}"


def _diagnostic_column(signal: Signal, i: int, naming: ColumnNaming) -> str:
    return naming.diagnostic_columns[i]


COLUMN_NAMES: dict[str, Callable[[Signal, int, ColumnNaming], str]] = {  # by width: column i's name
    "n": _state_column,
    "n+1": _reference_column,
    "m": _adaptive_column,
    "terms": _term_column,
    "diagnostics": _diagnostic_column,
}


def column_names(signal: Signal, count: int, naming: ColumnNaming) -> tuple[str, ...]:
    """The names of a signal's ``count`` columns in saved files: ``x1 .. xn``, ``yd_0 .. yd_n``,
    ``<adaptive name>_1 ..``, ``bound_ratio_<term>``, the law's diagnostics by name; a scalar
    signal's one column is its name."""
    if signal.width == "1":
        return (signal.name,)
    return tuple(COLUMN_NAMES[signal.width](signal, i, naming) for i in range(count))


def needed(names: tuple[str, ...]) -> tuple[str, ...]:
    """The derived signals that ``names`` need, directly or through what they read, in table order."""
    wanted = set(names)
    for signal in reversed(DERIVED):
        if signal.name in wanted:
            wanted.update(signal.reads)
    return tuple(s.name for s in DERIVED if s.name in wanted)


def derive(block: dict[str, np.ndarray], ctx: SignalContext, names: tuple[str, ...] | None = None
           ) -> dict[str, np.ndarray]:
    """Add derived signals, in table order, to ``block`` (which holds the recorded signals of some
    rows and ``yd`` shaped ``(rows, 1, n+1)``) and return it: all of them, or those of ``names``
    (see :func:`needed`)."""
    with np.errstate(all="ignore"):  # rows of a diverged copy may hold NaN/Inf
        for signal in DERIVED:
            if names is None or signal.name in names:
                block[signal.name] = signal.derive(block, ctx)
    return block
