"""One run, specified: :class:`RunSpec` holds everything :func:`~qcontrol.engine.simulate` needs
(the parts of the closed loop, the time grid, what to record and who watches), checked once when
it is made. :mod:`qcontrol.assembly` builds it from a scenario."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..controller.law import BatchLaw
from ..expr import Expression
from ..plants.base import Plant
from ..quantizer import Quantizer
from ..reference import Reference
from ..timegrid import TimeGrid
from .reductions import MetricSettings
from .retention import OBSERVE_EVERY, Observer
from .signals import Separation
from .velocity import VELOCITY_SOURCES

ProgressCallback = Callable[[int, int], None]  # (row reached, last row)
RECORD_MODES = ("full", "metrics")


@dataclass(frozen=True, kw_only=True)
class RunSpec:
    """A closed-loop run for every copy of ``plant``'s batch.

    The loop: ``plant``, ``law``, ``quantizer``, ``reference`` from ``x0`` (``(n,)`` for every
    copy, or ``(batch, n)``) over ``grid`` (the step, the horizon and the control period).
    When a copy stops: its state turns non-finite or leaves ``|x_i| <= state_bound``. What it
    keeps: ``record`` ``"full"`` (every row) or ``"metrics"`` (the reductions only, memory that does
    not grow with the run), ``metrics`` (the error rate's thresholds and samples), ``separation``
    (the terms of eq. (1) and their bounding functions to check along the run, eqs. (37)-(43);
    None: not checked). What it applies: ``loads``, ``(row, d)`` where the external load changes
    (u's units, :mod:`qcontrol.disturbance`); ``velocity_source``, ``"sensor"`` or
    ``"difference"`` (x2 differenced from the quantized position, :mod:`.velocity`); ``chain``,
    whether the plant is the chain of eq. (1) (else Lemma 2 does not apply). What explains a
    NaN: ``terms``, the plant's expressions by name (``("plant.psi", psi)``), evaluated where a copy
    turned NaN to say which term went out of its domain. Who watches:
    ``progress(row, last row)`` about every 1% of the run; ``observer`` every ``observe_every``
    rows and at the end, with the rows that became final. ``input_quantizer``: q_u between the
    law and the actuator (the plant is stepped with ``q_u(u)``; None: with u).
    """

    plant: Plant
    law: BatchLaw
    quantizer: Quantizer
    reference: Reference
    x0: np.ndarray | Sequence
    grid: TimeGrid
    state_bound: float = 1e6
    record: str = "full"
    metrics: MetricSettings | None = field(default_factory=MetricSettings)
    separation: Separation | None = None
    loads: Sequence[tuple[int, float]] = ()
    velocity_source: str = "sensor"
    chain: bool = True  # the plant is the chain of eq. (1), the class Lemma 2's bounds are derived for
    terms: Sequence[tuple[str, Expression]] = ()
    progress: ProgressCallback | None = None
    observer: Observer | None = None
    observe_every: int = OBSERVE_EVERY
    input_quantizer: Quantizer | None = None

    def __post_init__(self) -> None:
        if self.record not in RECORD_MODES:
            raise ValueError(f"record must be one of {RECORD_MODES}, got {self.record!r}")
        if self.velocity_source not in VELOCITY_SOURCES:
            raise ValueError(f"velocity_source must be one of {VELOCITY_SOURCES}, "
                             f"got {self.velocity_source!r}")
        if self.metrics is None:  # given as None: the paper's Table 1
            object.__setattr__(self, "metrics", MetricSettings())
        if self.law.copies is not None and self.law.copies != self.plant.batch:
            raise ValueError(f"the controller has per-copy parameters for {self.law.copies} copies, "
                             f"the plant {self.plant.batch}")
