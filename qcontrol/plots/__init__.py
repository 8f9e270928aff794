"""Figures (paper Figs. 1-8, backend overlay, sensitivity studies, Table 1): :mod:`.run_figures`
draws runs, :mod:`.studies` studies and tables, :mod:`.common` holds what they share (the
robustness study's figures belong to :mod:`qcontrol.reproduce.robustness_figures`).

Every function draws one matplotlib figure on the Agg canvas (never pyplot's global state, never
a display), writes it as a PNG of exactly ``FIG_WIDTH_PX x FIG_HEIGHT_PX`` pixels and returns the
path. The file is written atomically (:func:`qcontrol.outputs.write_file`), so a reader never
sees half a PNG. Missing folders are created.

The signatures follow one pattern: the data first, then ``path`` and ``title``, then keywords.
Trajectory figures take a :class:`Units` (``EXAMPLE1_UNITS`` or ``EXAMPLE2_UNITS``) for the axis
labels; :data:`PAPER_TITLES` holds the paper's captions, e.g.
``fig_output(traj, "fig1.png", PAPER_TITLES[1], EXAMPLE1_UNITS)``.

All figures tolerate a diverged (truncated) trajectory and NaN samples: NaNs are drawn as gaps,
the time axis always spans the full scheduled duration, and the divergence instant is marked.
"""

from .common import (
    EXAMPLE1_UNITS,
    EXAMPLE2_UNITS,
    FIG_DPI,
    FIG_HEIGHT_PX,
    FIG_WIDTH_PX,
    LOG_FLOOR,
    PAPER_TITLES,
    Units,
)
from .run_figures import (
    DEFAULT_METHOD_LABELS,
    fig_adaptive,
    fig_backend_overlay,
    fig_compare_error,
    fig_compare_output,
    fig_input,
    fig_output,
    fig_run,
    fig_tracking_error,
    output_difference,
    scenario_units,
)
from .studies import fig_sensitivity, fig_table1

__all__ = [
    "DEFAULT_METHOD_LABELS",
    "EXAMPLE1_UNITS",
    "EXAMPLE2_UNITS",
    "FIG_DPI",
    "FIG_HEIGHT_PX",
    "FIG_WIDTH_PX",
    "LOG_FLOOR",
    "PAPER_TITLES",
    "Units",
    "fig_adaptive",
    "fig_backend_overlay",
    "fig_compare_error",
    "fig_compare_output",
    "fig_input",
    "fig_output",
    "fig_run",
    "scenario_units",
    "fig_sensitivity",
    "fig_table1",
    "fig_tracking_error",
    "output_difference",
]
