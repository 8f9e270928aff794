"""What a closed-loop run returns: one type, a :class:`RunRecord` (how the run went, its ``steps``
and its metrics, :meth:`RunRecord.reduced`), which is a full :class:`Trajectory` (every row kept)
or, for sweeps and long runs, a :class:`RunMetrics` (the metrics only), as the run's ``record``
mode asked. Their array fields and metrics are made from the signal table
(:data:`~qcontrol.engine.signals.SIGNALS`), so every recorded signal is an attribute here."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..controller.law import Diagnostic
from ..controller.user_diagnostics import diagnostic_columns
from ..errors import QcontrolInputError
from .reductions import Chunk, MetricSettings
from .signals import REDUCTIONS, SIGNALS, ColumnNaming


@dataclass(kw_only=True)
class RunRecord:
    """What every record of a run carries: the adaptive state's name, the Lemma 2 bounds ``L_z``,
    the step and horizon, the control period in steps (``hold``), where the controller's x2 came
    from (``velocity_source``), whether the actuator could clip u, and how the run ended.

    Every record also has ``steps`` (the steps taken) and :meth:`reduced` (the metrics, by the
    reductions of the signal table), whichever of the two kinds it is: what
    :func:`qcontrol.metrics.run_summary` reads."""

    adaptive_name: str
    L_z: np.ndarray
    dt: float
    duration: float
    hold: int = 1
    velocity_source: str = "sensor"
    actuator_limited: bool = False  # whether the plant's actuator could clip u (u_applied may differ)
    diverged: bool = False
    diverged_time: float | None = None
    divergence_reason: str = ""
    law_failure: str | None = None  # a user law's failure that stopped the run (also its divergence_reason)
    wall_time_s: float = 0.0
    metrics: MetricSettings = field(default_factory=MetricSettings)  # the error rate's omegas and samples
    bound_names: tuple[str, ...] = ()  # the terms whose separation (37)-(43) was checked
    law_diagnostics: tuple[Diagnostic, ...] = ()  # what the law declared (the diagnostics signal's columns)
    quantizer_sector: float | None = None  # a logarithmic quantizer's xi (Lemma 2 does not apply), else None
    reading_range: bool = False  # whether a reading could saturate at its channel's range
    quantized_input: bool = False  # whether u passed an input quantizer before the actuator

    @property
    def diagnostic_columns(self) -> tuple[str, ...]:
        """The names of the diagnostics signal's columns: a diagnostic's name, or ``name_1 ..
        name_w`` for one of width w."""
        return diagnostic_columns(self.law_diagnostics)

    @property
    def naming(self) -> ColumnNaming:
        """What names the columns of its signals in saved files (:func:`~.signals.column_names`)."""
        return ColumnNaming(self.adaptive_name, self.bound_names, self.diagnostic_columns)

    def reduced(self) -> dict[str, Any]:
        """The metrics of the run (each kind of record gives them)."""
        raise NotImplementedError


@dataclass(kw_only=True)
class Trajectory(RunRecord):
    """Everything one closed-loop run recorded; arrays are time-major (row k is ``t[k] = k dt``).

    ``signals`` maps each name of the signal table to its array: ``(rows, n)`` for a state-wide
    signal, ``(rows, n+1)`` for ``yd``, ``(rows, m)`` for ``adaptive``, ``(rows,)`` for ``u``. Each
    is also an attribute (``traj.x``, ``traj.x_q``, ``traj.u``, ...; see the table for what each
    means). A diverged run ends with the row that stopped it.
    """

    t: np.ndarray
    signals: dict[str, np.ndarray] = field(repr=False)

    @property
    def y(self) -> np.ndarray:
        """The output ``y = x_1``."""
        return self.signals["x"][:, 0]

    @property
    def steps(self) -> int:
        return len(self.t) - 1

    def diagnostic(self, name: str) -> np.ndarray:
        """The law's diagnostic ``name`` at every row: ``(rows,)`` for a width of 1, else
        ``(rows, width)`` (NaN-free only where the run was)."""
        first = 0
        for d in self.law_diagnostics:
            if d.name == name:
                values = self.signals["diagnostics"][:, first : first + d.width]
                return values[:, 0] if d.width == 1 else values
            first += d.width
        declared = ", ".join(d.name for d in self.law_diagnostics) or "none"
        raise QcontrolInputError(f"diagnostic {name!r}: the law declares no diagnostic of that name "
                                 f"(its diagnostics: {declared})")

    def with_signals(self, **arrays: np.ndarray) -> Trajectory:
        """A copy with the named signals replaced (e.g. ``traj.with_signals(x=x, u=u)``)."""
        unknown = set(arrays) - set(self.signals)
        if unknown:
            raise ValueError(f"no signal named {sorted(unknown)[0]!r}; signals are {', '.join(self.signals)}")
        return replace(self, signals=self.signals | arrays)

    def reduced(self) -> dict[str, Any]:
        """The metrics of the run, by the same reductions as a metrics-only run (one chunk)."""
        rows = len(self.t)
        chunk = Chunk(0, self.t, np.array([rows]), np.array([self.diverged]), self.hold)
        block = {name: array[:, None] for name, array in self.signals.items()}  # one copy
        values = {}
        for reduction in REDUCTIONS:
            array = self.signals[reduction.signal]
            fold = reduction(1, array.shape[-1] if array.ndim > 1 else 1, self.duration, self.metrics)
            fold.add(chunk, fold.values(block))
            values[reduction.name] = fold.value(0)
        return values


class Entry:
    """Reads one entry of a record's table: ``Entry("signals", "x")(traj)`` is
    ``traj.signals["x"]``; the getter of the attributes made from the signal table."""

    __slots__ = ("table", "key")

    def __init__(self, table: str, key: str) -> None:
        self.table, self.key = table, key

    def __call__(self, record: RunRecord) -> Any:
        return getattr(record, self.table)[self.key]


for _signal in SIGNALS:
    setattr(Trajectory, _signal.name, property(Entry("signals", _signal.name),
                                               doc=f"{_signal.meaning} ({_signal.width} wide)"))


@dataclass(kw_only=True)
class RunMetrics(RunRecord):
    """What a run recorded in metrics mode keeps: the reductions of the signal table (``values``,
    each also an attribute: ``error_rate``, ``max_abs_u``, ...), in memory that does not grow with
    the run's length; ``steps`` the steps taken."""

    steps: int
    values: dict[str, Any] = field(repr=False)

    def reduced(self) -> dict[str, Any]:
        return self.values


for _reduction in REDUCTIONS:
    setattr(RunMetrics, _reduction.name, property(Entry("values", _reduction.name),
                                                  doc=f"{_reduction.name}, reduced from {_reduction.signal}"))
del _signal, _reduction
