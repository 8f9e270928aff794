"""The closed-loop engine: the loop (:mod:`.loop`), the signal table (:mod:`.signals`), and the
parts of a run, each with one job: row buffers (:mod:`.row_buffer`), divergence bookkeeping
(:mod:`.divergence`), the reference at the rows (:mod:`.reference_rows`), what a run keeps
(:mod:`.retention`, :mod:`.reductions`) and what it returns (:mod:`.results`)."""

from .loop import ClosedLoop, simulate
from .reductions import MetricSettings
from .results import RunMetrics, RunRecord, Trajectory
from .retention import Observer
from .signals import SIGNALS, Separation, Signal
from .spec import RECORD_MODES, ProgressCallback, RunSpec

__all__ = [
    "RECORD_MODES",
    "SIGNALS",
    "ClosedLoop",
    "MetricSettings",
    "Observer",
    "ProgressCallback",
    "RunMetrics",
    "RunRecord",
    "RunSpec",
    "Separation",
    "Signal",
    "Trajectory",
    "simulate",
]
