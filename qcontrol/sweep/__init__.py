"""Parameter sweeps: many variants of one scenario, batched (:mod:`.runs`), from grids of values
(:mod:`.grid`), tabulated (:mod:`.table`); the command ``qcontrol sweep`` (:mod:`.command`)."""

from .command import add_sweep_parser, cmd_sweep
from .grid import grid_points, parse_grid
from .runs import CHUNK, SweepInterrupted, plan, run_batch, sweep_summaries
from .table import CSV_METRICS, csv_text, sweep_rows

__all__ = [
    "CHUNK",
    "CSV_METRICS",
    "SweepInterrupted",
    "add_sweep_parser",
    "cmd_sweep",
    "csv_text",
    "grid_points",
    "parse_grid",
    "plan",
    "run_batch",
    "sweep_rows",
    "sweep_summaries",
]
