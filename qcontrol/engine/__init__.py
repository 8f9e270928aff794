"""The closed-loop engine: the loop (:mod:`.loop`), the signal table (:mod:`.signals`), and the
parts of a run, each with one job: row buffers (:mod:`.rows`), divergence bookkeeping
(:mod:`.divergence`), the reference at the rows (:mod:`.reference_rows`), what a run keeps
(:mod:`.records`, :mod:`.reductions`) and what it returns (:mod:`.results`)."""

from .loop import RECORD_MODES, ClosedLoop, ProgressCallback, simulate
from .reductions import MetricSettings
from .results import RunMetrics, RunRecord, Trajectory
from .retention import Observer
from .signals import SIGNALS, Separation, Signal

__all__ = [
    "RECORD_MODES",
    "SIGNALS",
    "ClosedLoop",
    "MetricSettings",
    "Observer",
    "ProgressCallback",
    "RunMetrics",
    "RunRecord",
    "Separation",
    "Signal",
    "Trajectory",
    "simulate",
]
