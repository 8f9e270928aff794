"""Quantizers as sensors and the literature model them: one per state channel, and the
``[quantizer]`` table that chooses them (:data:`QUANTIZER_KINDS`).

The paper quantizes every state with one uniform step, eq. (3) (:class:`~.quantizer.UniformQuantizer`,
which ``controller.delta`` still means). Each kind here quantizes the channels of a
``(batch, n)`` reading, each channel with its own parameters, and declares what Lemma 2 needs:

* ``worst_case_error``: per channel, the smallest m_i with ``|q_i(x) - x| <= m_i`` for every x
  (``inf`` where none exists). Lemma 2's bounds with one bound per channel
  (:func:`~.controller.backstepping.lemma2_bounds`) and the law's L are computed from it.
* ``max_error``: the per-channel errors the law's L is computed from: ``worst_case_error``
  where it is finite. A logarithmic quantizer has none (its error grows with |x|): its L is then
  a design constant, computed from the error in its dead zone, and ``lemma2_applies`` is False.
* ``sector``: the logarithmic quantizer's relative bound ``|q(x) - x| <= sector |x|`` (None for
  the others).

Kinds:

* uniform, step delta_i (eq. (3) per channel), ``m_i = delta_i / 2``; with a finite ``range`` R_i
  the reading saturates at ``q(+-R_i)`` (then the error grows without bound: m_i = delta_i / 2
  only while ``|x_i| <= R_i + delta_i / 2``);
* hysteresis, step delta_i: the reading keeps its level until the signal is a whole step away,
  then jumps to the nearest level; ``m_i = delta_i``. It has memory (one level per copy and
  channel), cleared by :meth:`HysteresisQuantizer.reset` at the start of every run;
* logarithmic, ratio rho and smallest level u_min: levels ``+-u_min rho^(-j)``, relative error
  ``xi = (1 - rho) / (1 + rho)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .errors import QcontrolInputError
from .quantizer import UniformQuantizer, uniform
from .schema import (
    OPTIONAL,
    REQUIRED,
    Key,
    KindKeys,
    Section,
    Table,
    custom,
    kind_table,
    number,
    read_keys,
    string,
)

Channels = tuple[float, ...]


@runtime_checkable
class SensorQuantizer(Protocol):
    """What the kinds of this module declare beside the :class:`~.quantizer.Quantizer` protocol
    (``__call__`` and ``max_error``, here one per channel), which the engine and the summary read:
    ``worst_case_error`` (m_i per channel, inf where none exists), ``lemma2_applies``, ``sector``
    (a logarithmic quantizer's xi, else None), ``saturated(x)`` (1 where a reading lay beyond its
    channel's range) and ``reset()`` (forget what earlier readings left: a run's start)."""

    worst_case_error: Channels
    lemma2_applies: bool
    sector: float | None

    def __call__(self, x: np.ndarray) -> np.ndarray: ...

    def saturated(self, x: np.ndarray) -> np.ndarray: ...

    def reset(self) -> None: ...


def _channels(values: float | Sequence[float], n: int, what: str) -> np.ndarray:
    """One value per channel, each finite and > 0: a number for all, or a list of n."""
    array = np.broadcast_to(np.asarray(values, dtype=float), (n,)) if np.ndim(values) == 0 else np.asarray(
        values, dtype=float)
    if array.shape != (n,):
        raise QcontrolInputError(f"quantizer {what}: give a number or a list of {n}, got {values!r}")
    if not (np.all(np.isfinite(array)) and np.all(array > 0)):
        raise QcontrolInputError(f"quantizer {what} must be finite numbers > 0, got {values!r}")
    return array.copy()


class ChannelQuantizer:
    """Uniform quantizer with a step per channel, eq. (3), and optionally a finite range per
    channel: readings saturate at ``q(+-R_i)``. Property (4) per channel: ``m_i = delta_i / 2``
    (within the range)."""

    lemma2_applies = True
    sector = None

    def __init__(self, delta: float | Sequence[float], n: int, range_: float | Sequence[float] | None = None
                 ) -> None:
        self.delta = _channels(delta, n, "delta")
        self.range = None if range_ is None else _channels(range_, n, "range")
        if self.range is not None:
            self.low, self.high = uniform(-self.range, self.delta), uniform(self.range, self.delta)
        self.worst_case_error: Channels = tuple((self.delta / 2.0).tolist())
        self.max_error: Channels = self.worst_case_error

    def reset(self) -> None:
        """Nothing to forget: the reading depends on the signal alone."""

    def __call__(self, x: np.ndarray) -> np.ndarray:
        q = uniform(np.asarray(x, dtype=float), self.delta)
        return q if self.range is None else within_range(q, self.low, self.high)

    def apply_channel(self, i: int, x: Any, form: Any) -> Any:
        """Channel ``i`` (from 0) of :meth:`__call__` on one column of ``form`` (its ``floor``,
        ``minimum`` and ``maximum``): the same operations, channel by channel (the compiled loop's
        quantizer)."""
        q = uniform(x, float(self.delta[i]), form.floor)
        if self.range is None:
            return q
        return within_range(q, float(self.low[i]), float(self.high[i]), form.minimum, form.maximum)

    def saturated(self, x: np.ndarray) -> np.ndarray:
        """Where a reading ``x`` (``(..., n)``) lies beyond its channel's range: 1 where any
        channel's ``q(x)`` left ``[q(-R), q(R)]``, else 0 (NaN where x is not finite), ``(...,)``."""
        x = np.asarray(x, dtype=float)
        if self.range is None:
            return x[..., 0] * 0.0
        q = uniform(x, self.delta)
        out = ((q < self.low) | (q > self.high)).any(axis=-1).astype(float)
        return np.where(np.isfinite(x).all(axis=-1), out, np.nan)

    def __repr__(self) -> str:
        limits = None if self.range is None else self.range.tolist()
        return f"ChannelQuantizer(delta={self.delta.tolist()!r}, range={limits!r})"


def within_range(q: Any, low: Any, high: Any, minimum: Callable[[Any, Any], Any] = np.minimum,
                 maximum: Callable[[Any, Any], Any] = np.maximum) -> Any:
    """A channel's reading with a finite range: its level ``q`` of eq. (3) held in ``[low, high]``,
    the levels ``q(-R_i)`` and ``q(R_i)``, as ``minimum(maximum(q, low), high)`` (NaN stays NaN).
    The one definition of the range, on arrays (``low``, ``high`` per channel, numpy's functions)
    or on one column of any form with that form's ``minimum`` and ``maximum``."""
    return minimum(maximum(q, low), high)


class HysteresisQuantizer:
    """Uniform levels ``l delta_i`` with hysteresis: the reading keeps its level while
    ``|x - level| < delta_i`` and then jumps to the nearest level ``delta_i floor(x / delta_i + 1/2)``
    (no chattering between two levels under noise). The first reading of a run is the uniform
    one. ``m_i = delta_i``. One level per copy and channel is kept between calls."""

    lemma2_applies = True
    sector = None

    def __init__(self, delta: float | Sequence[float], n: int) -> None:
        self.delta = _channels(delta, n, "delta")
        self.worst_case_error: Channels = tuple(self.delta.tolist())
        self.max_error: Channels = self.worst_case_error
        self.level: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the levels: the next reading is the uniform one (a run's start)."""
        self.level = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        nearest = uniform(x, self.delta)
        if self.level is None or self.level.shape != x.shape:
            self.level = nearest
        else:
            self.level = held_level(x, self.level, nearest, self.delta, np.where)
        return self.level.copy()

    def apply_channel(self, i: int, x: Any, level: Any, form: Any) -> Any:
        """Channel ``i`` (from 0) of :meth:`__call__` on one column of ``form`` (its ``floor`` and
        ``where``), given the channel's level before the reading (NaN before a run's first
        reading, whose level is then the nearest one, as :meth:`__call__` gives it): the level
        after it, which is the reading (the compiled loop's quantizer, which keeps the levels)."""
        delta = float(self.delta[i])
        return held_level(x, level, uniform(x, delta, form.floor), delta, form.where)

    def saturated(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, dtype=float)[..., 0] * 0.0

    def __repr__(self) -> str:
        return f"HysteresisQuantizer(delta={self.delta.tolist()!r})"


def held_level(x: Any, level: Any, nearest: Any, delta: Any, where: Callable[[Any, Any, Any], Any]) -> Any:
    """The hysteresis quantizer's level after reading ``x``: ``level`` kept while
    ``|x - level| < delta``, else ``nearest`` (``where``: the form's select, numpy's for arrays)."""
    return where(abs(x - level) < delta, level, nearest)


class LogarithmicQuantizer:
    """Logarithmic quantizer: levels ``+-u_j``, ``u_j = u_min rho^(-j)`` (j = 0, 1, ...), and 0.
    With ``xi = (1 - rho) / (1 + rho)``: ``q(x) = sign(x) u_j`` for ``u_j / (1 + xi) < |x| <=
    u_j / (1 - xi)`` and ``q(x) = 0`` for ``|x| <= u_min / (1 + xi)``. The error is relative,
    ``|q(x) - x| <= xi |x|`` outside the dead zone and ``|x| <= u_min / (1 + xi)`` inside it: no
    constant bounds it, so Lemma 2 does not apply (``worst_case_error`` is inf). The law's L is
    computed from the dead zone's bound ``u_min / (1 + xi)`` (a design constant, not a bound)."""

    lemma2_applies = False

    def __init__(self, rho: float, u_min: float, n: int) -> None:
        if not (math.isfinite(rho) and 0.0 < rho < 1.0):
            raise QcontrolInputError(f"quantizer rho must lie in (0, 1), got {rho!r}")
        if not (math.isfinite(u_min) and u_min > 0.0):
            raise QcontrolInputError(f"quantizer u_min must be a finite number > 0, got {u_min!r}")
        self.rho, self.u_min = float(rho), float(u_min)
        self.sector = (1.0 - self.rho) / (1.0 + self.rho)  # xi
        self.worst_case_error: Channels = (math.inf,) * n
        self.max_error: Channels = (self.u_min / (1.0 + self.sector),) * n

    def reset(self) -> None:
        """Nothing to forget: the reading depends on the signal alone."""

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        size = np.abs(x)
        xi, u_min = self.sector, self.u_min
        with np.errstate(divide="ignore", invalid="ignore"):
            j = np.ceil(np.log(size * (1.0 + xi) / u_min) / -math.log(self.rho)) - 1.0
            j = np.maximum(j, 0.0)
            level = u_min * self.rho ** -j
            # rounding at a cell's edge: move to the cell that holds |x|
            level = np.where(size > level / (1.0 - xi), level / self.rho, level)
            level = np.where((size <= level / (1.0 + xi)) & (level > u_min), level * self.rho, level)
        q = np.where(size <= u_min / (1.0 + xi), 0.0, np.sign(x) * level)
        return np.where(np.isfinite(x), q, x)

    def saturated(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, dtype=float)[..., 0] * 0.0

    def __repr__(self) -> str:
        return f"LogarithmicQuantizer(rho={self.rho!r}, u_min={self.u_min!r})"


# --------------------------------------------------------------------------------------------
# Scenario keys: [quantizer] and [quantizer.input], one kind each


def _per_channel(table: Table, key: str, default: Any, sizes: Any) -> float | tuple[float, ...]:
    """A number > 0 for every channel, or a list of one per channel."""
    value = table.get(key, default)
    if isinstance(value, list):
        return table.numbers(key, sizes["channels"], positive=True)
    return table.number(key, default, positive=True)


def _per_channel_key(name: str, unit: str, meaning: str, example: str, default: Any = REQUIRED) -> Key:
    return Key(name, custom("number > 0, or a list of one per channel", _per_channel), default, unit, meaning,
               example)


@dataclass(frozen=True)
class QuantizerKind:
    """One kind of quantizer: its keys and how it is made from them (``make(values, n)``)."""

    keys: KindKeys
    make: Callable[[dict[str, Any], int], Any]


DELTA = _per_channel_key("delta", "state", "the step delta_i of every channel (a number), or one per channel",
                         "[0.0015, 0.05]")
RANGE = _per_channel_key("range", "state", "the range R_i: readings saturate at q(+-R_i) (default: no limit)",
                         "[3.1416, 20.0]", OPTIONAL)

QUANTIZER_KINDS: dict[str, QuantizerKind] = {
    "uniform": QuantizerKind(
        KindKeys("uniform", (DELTA, RANGE), "eq. (3) per channel: q_i(x) = delta_i floor(x / delta_i + 1/2), "
                 "saturated at q(+-R_i) with a range; m_i = delta_i / 2"),
        lambda v, n: (UniformQuantizer(v["delta"]) if np.ndim(v["delta"]) == 0 and v["range"] is None
                      else ChannelQuantizer(v["delta"], n, v["range"]))),
    "hysteresis": QuantizerKind(
        KindKeys("hysteresis", (DELTA,), "uniform levels with hysteresis: a level is kept until the signal "
                 "is a whole step away; m_i = delta_i"),
        lambda v, n: HysteresisQuantizer(v["delta"], n)),
    "logarithmic": QuantizerKind(
        KindKeys("logarithmic", (
            Key("rho", number(positive=True), unit="-", meaning="ratio of successive levels, 0 < rho < 1",
                example="0.9"),
            Key("u_min", number(positive=True), unit="state", meaning="the smallest level u_min > 0",
                example="0.001")),
            "levels +-u_min rho^(-j): relative error xi = (1 - rho) / (1 + rho); Lemma 2 does not apply"),
        lambda v, n: LogarithmicQuantizer(v["rho"], v["u_min"], n)),
}


QUANTIZER = Section(
    "quantizer",
    (Key("kind", string(tuple(QUANTIZER_KINDS)), "uniform", meaning="the quantizer of every state channel"),),
    "the sensors' quantizers, one per state channel (default: controller.delta's uniform step on every "
    "channel); an optional [quantizer.input] table, with the same keys, quantizes u before the actuator",
    {name: kind.keys for name, kind in QUANTIZER_KINDS.items()},
    stand_in="controller.delta",
)
INPUT = "input"  # the sub-table of the input's quantizer


@dataclass(frozen=True)
class QuantizerSpec:
    """A quantizer as a scenario states it: its kind, its keys' values and its channels (n for the
    state, 1 for the input). Frozen and comparable (a batch shares it); :meth:`build` makes a new
    quantizer each time (a hysteresis quantizer's levels belong to one run)."""

    kind: str
    values: tuple[tuple[str, Any], ...]
    channels: int

    def build(self) -> Any:
        return QUANTIZER_KINDS[self.kind].make(dict(self.values), self.channels)


def read_quantizer(table: Table, channels: int, common: Sequence[str] = ("kind",)) -> QuantizerSpec:
    """The :class:`QuantizerSpec` of a ``[quantizer]`` or ``[quantizer.input]`` table: the keys of
    its kind (a key of another kind refused with the keys that apply), each value checked once by
    building the quantizer; problems are one line naming the file and the key."""
    kind = table.string("kind", "uniform", tuple(QUANTIZER_KINDS))
    merged = kind_table(table, common, {k: q.keys for k, q in QUANTIZER_KINDS.items()}, kind)
    values = read_keys(merged, QUANTIZER_KINDS[kind].keys.keys, {"channels": channels})
    spec = QuantizerSpec(kind, tuple((k, v) for k, v in values.items()), channels)
    try:
        spec.build()
    except QcontrolInputError as exc:
        message = str(exc).removeprefix("quantizer ")
        key = next((k for k in ("rho", "u_min", "range", "delta") if message.startswith(k)), "kind")
        raise merged.error(key, message.split(" ", 1)[1] if " " in message else message,
                           FIXES.get(key, "give a valid value")) from None
    return spec


FIXES = {"rho": "write a ratio between 0 and 1, e.g. rho = 0.9",
         "u_min": "write a number > 0, e.g. u_min = 0.001", "range": "write a number > 0, or one per channel",
         "delta": "write a number > 0, or one per channel"}


def read_quantizers(table: Table, order: int) -> tuple[QuantizerSpec, QuantizerSpec | None]:
    """``[quantizer]`` (the state's, n channels) and its optional ``[quantizer.input]`` (u's, 1
    channel)."""
    data = dict(table.data)
    inner = data.get(INPUT)
    state = read_quantizer(Table(data, table.source, table.name), order, ("kind", INPUT))
    if inner is None:
        return state, None
    if not isinstance(inner, dict):
        raise table.error(INPUT, "must be a table of the input quantizer's keys",
                          f"write [{table.path(INPUT)}]")
    where = Table(inner, table.source, table.path(INPUT))
    if inner.get("kind") == "hysteresis":
        raise where.error("kind", "hysteresis is not available for the input (its levels' memory would have "
                          "to be recorded with u)", "use kind = \"uniform\" or \"logarithmic\"")
    return state, read_quantizer(where, 1)


def channel_bounds(spec: QuantizerSpec | None) -> tuple[float, ...] | None:
    """The per-channel bounds the law's L is computed from (None without a ``[quantizer]`` table:
    ``controller.delta / 2``)."""
    if spec is None:
        return None
    made = spec.build()
    return None if isinstance(made, UniformQuantizer) else made.max_error


def quantizer_step(controller: Table, delta: float | None, spec: QuantizerSpec | None) -> float:
    """``controller.delta``: as given without a ``[quantizer]`` table (then required); with one
    (which must then state the step alone), its uniform step, or twice its largest per-channel
    bound (what recordings draw the quantization error's band with)."""
    if spec is None:
        if delta is None:
            raise controller.error("delta", "missing", "add it (the quantizer step, e.g. delta = 0.01), or "
                                   "a [quantizer] table")
        return delta
    if delta is not None:
        raise controller.error("delta", "given together with a [quantizer] table",
                               "give the step in one place: remove controller.delta, or the [quantizer] "
                               "table")
    made = spec.build()
    return made.delta if isinstance(made, UniformQuantizer) else 2.0 * max(made.max_error)
