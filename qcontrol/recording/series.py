"""The time series of a recording, made from the signal table's plots
(:data:`qcontrol.engine.signals.SIGNALS`), and the layout a recording opens with.

Series layout (``{L}`` a twin run's label, ``{a}`` the adaptive state's name, ``i`` from 1)::

    signals/tracking/y, y_d, y_{L}        signals/error/z1, z1_{L}       signals/input/u, u_{L}, u_applied
    signals/adaptive/{a}_i                signals/state/x{i}/x, signals/state/x{i}/q
    theory/lemma2/z{i}  (|e_zi| / L_zi)   theory/lemma2/bound  (the constant 1)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..engine import SIGNALS, Trajectory
from ..engine.signals import Plot, Signal

if TYPE_CHECKING:
    import rerun.blueprint as rrb

TIMELINE = "sim_time"
BLUE, ORANGE, GREY, GREEN, RED = (31, 119, 180), (255, 127, 14), (150, 150, 150), (44, 160, 44), (214, 39, 40)
PALETTE = (BLUE, ORANGE, GREEN, RED, (148, 103, 189), (140, 86, 75))
ROLE_COLORS = {"main": BLUE, "reference": ORANGE, "quantized": RED, "applied": GREEN}


@dataclass(frozen=True)
class Series:
    """One scalar time series: where it goes, how it is drawn, which column of a run it is."""

    path: str
    name: str
    color: tuple[int, int, int]
    step: bool
    values: Callable[[Trajectory], np.ndarray]


def _column(signal: Signal, i: int, per_bound: bool) -> Callable[[Trajectory], np.ndarray]:
    if signal.width == "1":
        return lambda run: run.signals[signal.name]
    if per_bound:
        return lambda run: run.signals[signal.name][:, i] / run.L_z[i]
    return lambda run: run.signals[signal.name][:, i]


def _components(signal: Signal, plot: Plot, run: Trajectory) -> range | tuple[int, ...]:
    if plot.components is not None:
        return plot.components
    array = run.signals[signal.name]
    return range(1 if array.ndim == 1 else array.shape[1])


def run_series(run: Trajectory, label: str, twin: str | None = None) -> list[Series]:
    """The series of a run: every plot of the table for the main run (its twin-drawn series'
    names tagged with ``label``), or, for a twin run labelled ``twin``, the twin-drawn plots at
    ``<path>_<twin>`` in grey."""
    tag = f" ({label})" if label else ""
    series = []
    for signal in SIGNALS:
        for plot in signal.plots:
            if twin is not None and not plot.twin:
                continue
            for i in _components(signal, plot, run):
                path = plot.path.format(i=i + 1, a=run.adaptive_name)
                name = plot.label.format(i=i + 1, a=run.adaptive_name)
                if twin is not None:
                    path, name, color = f"{path}_{twin}", f"{name} ({twin})", GREY
                else:
                    name += tag if plot.twin else ""
                    color = PALETTE[i % len(PALETTE)] if plot.color == "palette" else ROLE_COLORS[plot.color]
                series.append(Series(path, name, color, signal.held, _column(signal, i, plot.per_bound)))
    return series


def default_blueprint(n: int) -> rrb.Blueprint:
    """The layout a recording opens with: motion on the left, tracking and error on the right.

    Left column: the 3-D view (``world``) over tabs with the scenario text, the constants and the
    version. Right column, top to bottom: y with y_d (and the twin's y), the tracking error z1, the
    input u, and tabs for each x_i beside q(x_i), the adaptive estimates and the Lemma 2 ratios.
    """
    import rerun.blueprint as rrb

    detail = [
        rrb.TimeSeriesView(origin=f"signals/state/x{i + 1}", name=f"x{i + 1} and q(x{i + 1})")
        for i in range(n)
    ]
    detail += [
        rrb.TimeSeriesView(origin="signals/adaptive", name="adaptive estimates"),
        rrb.TimeSeriesView(origin="theory/lemma2", name="Lemma 2: |e_zi| / L_zi <= 1"),
    ]
    left = rrb.Vertical(
        rrb.Spatial3DView(origin="world", name="motion"),
        rrb.Tabs(
            rrb.TextDocumentView(origin="info/scenario", name="scenario"),
            rrb.TextDocumentView(origin="info/constants", name="constants"),
            rrb.TextDocumentView(origin="info/version", name="version"),
        ),
        row_shares=[3, 1],
    )
    right = rrb.Vertical(
        rrb.TimeSeriesView(origin="signals/tracking", name="output y and reference y_d"),
        rrb.TimeSeriesView(origin="signals/error", name="tracking error z1 = y - y_d"),
        rrb.TimeSeriesView(origin="signals/input", name="input u"),
        rrb.Tabs(*detail),
        row_shares=[1, 1, 1, 1.3],
    )
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[1, 1]),
        rrb.TimePanel(timeline=TIMELINE, expanded=True),
        rrb.BlueprintPanel(expanded=False),
        rrb.SelectionPanel(expanded=False),
    )
