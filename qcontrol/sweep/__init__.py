"""Parameter sweeps: many variants of one scenario, batched (:mod:`.runs`), from grids of values
(:mod:`.grid`), tabulated (:mod:`.table`); the command ``qcontrol sweep`` is
:mod:`qcontrol.cli.sweep_command`."""

from .grid import grid_points, parse_grid
from .runs import CHUNK, SweepInterrupted, plan, run_batch, sweep_summaries
from .table import CSV_METRICS, csv_text, sweep_rows

__all__ = [
    "CHUNK",
    "CSV_METRICS",
    "SweepInterrupted",
    "csv_text",
    "grid_points",
    "parse_grid",
    "plan",
    "run_batch",
    "sweep_rows",
    "sweep_summaries",
]
