"""The time series of a recording, made from the signal table
(:data:`qcontrol.engine.signals.SIGNALS`) drawn as :data:`.styles.PLOTS` says.

Series layout (``{L}`` a ghost run's label, ``{a}`` the adaptive state's name, ``i`` from 1)::

    signals/tracking/y, y_d, y_{L}        signals/error/z1, z1_{L}       signals/input/u, u_{L}, u_applied
    signals/adaptive/{a}  (one instance per estimate)
    signals/state/x{i}/x, signals/state/x{i}/q
    signals/quantization/x{i}/error       (x_meas - q(x_meas)) and band (+delta/2, -delta/2)
    theory/lemma2/ratios  (|e_zi| / L_zi, one instance per i)   theory/lemma2/bound  (the constant 1)
    signals/difference/y/{L}, signals/difference/u/{L}   |main - twin|, for a twin run

Each series belongs to a panel, its path's parent (``signals/input``, ``signals/state/x2``): the
layout (:mod:`.layout`) makes one plot per panel, so a series added to the table under an existing
panel shows there, and one under a new panel gets a tab of its own. A plot whose path has no
``{i}`` draws its components as instances of one entity (one legend entry each): one send per
batch of rows for all of them.

Three roles of a run: the *main* run (its colours); a *twin* (the same closed loop on another
backend: its series thin and light on top of the main run's, which are then drawn wide, so both
show where they coincide, and ``|main - twin|`` as series of their own); a *comparison* run
(another controller: its series in their own colour).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..engine import SIGNALS, Trajectory
from ..engine.signals import Signal
from .styles import PLOTS, Plot

TIMELINE = "sim_time"
Rows = slice | np.ndarray  # the rows of a run a series is read at
BLUE, ORANGE, GREEN, RED = (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40)
PURPLE, BROWN, OLIVE, LIGHT = (148, 103, 189), (140, 86, 75), (188, 189, 34), (245, 245, 245)
PALETTE = (BLUE, ORANGE, GREEN, RED, PURPLE, BROWN)
ROLE_COLORS = {"main": BLUE, "reference": ORANGE, "quantized": RED, "applied": OLIVE}
# the colour of the k-th ghost run (k = 0, 1, ...): a twin (light first, the ODE beside MuJoCo),
# another law beside the main one (green first), and a twin's |main - twin| series
TWIN_COLORS = (LIGHT, PURPLE, OLIVE, BROWN)
COMPARISON_COLORS = (GREEN, PURPLE, BROWN, OLIVE)
DIFFERENCE_COLORS = (BLUE, PURPLE, OLIVE, BROWN)


WIDE, THIN = 5.0, 1.5  # line widths (points) of a main run beside its twin, and of the twin


def shade_of(colors: tuple, k: int) -> tuple[int, int, int]:
    """The colour of the ``k``-th ghost run among ``colors`` (cycling)."""
    return colors[k % len(colors)]


@dataclass(frozen=True)
class Panel:
    """One plot of the layout: its entity ``origin``, the ``key`` it is styled by (the origin
    before ``{i}`` is filled in), the component ``index`` it shows (from 1; 0 for all) and a
    ``title`` made from the run (empty: the layout's title for the key)."""

    origin: str
    key: str
    index: int = 0
    title: str = ""


@dataclass(frozen=True)
class Series:
    """One entity of scalar time series (one per component it shows): where it goes, how it is
    drawn, which columns of a run it holds (``values``: ``(rows,)``, or ``(rows, k)`` for k)."""

    path: str
    labels: tuple[str, ...]
    tag: str  # the run it belongs to, in the legend: "y (mujoco)"
    colors: tuple[tuple[int, int, int], ...]
    step: bool
    values: Callable[[Trajectory, Rows], np.ndarray]
    panel: Panel
    drawn_for_twin: bool = False
    width: float | None = None

    @property
    def names(self) -> list[str]:
        return [f"{label} ({self.tag})" if self.tag else label for label in self.labels]

    def beside_twin(self) -> Series:
        """The main run's series once a twin is drawn on top of it: wide, and labelled so."""
        return replace(self, tag=f"{self.tag}, wide" if self.tag else "wide", width=WIDE)


@dataclass(frozen=True)
class GuideLine:
    """Constant lines of a panel (a bound): their path, legend names and levels."""

    path: str
    names: tuple[str, ...]
    levels: tuple[float, ...]


def _columns(signal: Signal, shown: tuple[int, ...], per_bound: bool
             ) -> Callable[[Trajectory, Rows], np.ndarray]:
    """The values of components ``shown`` at some rows (the rows first: a batch of a long run
    copies only its own rows); ``per_bound``: divided by the Lemma 2 bounds."""
    if signal.width == "1":
        return lambda run, rows: run.signals[signal.name][rows]
    index = shown[0] if len(shown) == 1 else list(shown)
    if per_bound:
        return lambda run, rows: run.signals[signal.name][rows][:, index] / run.L_z[index]
    return lambda run, rows: run.signals[signal.name][rows][:, index]


def _groups(signal: Signal, plot: Plot, run: Trajectory) -> list[tuple[int, ...]]:
    """The components of each entity a plot draws: one each if its path has ``{i}``, else all."""
    if plot.components is not None:
        shown = tuple(plot.components)
    else:
        array = run.signals[signal.name]
        shown = tuple(range(1 if array.ndim == 1 else array.shape[1]))
    return [(i,) for i in shown] if "{i}" in plot.path or "{d}" in plot.path else [shown]


def _names(run: Trajectory, i: int) -> dict[str, str | int]:
    """What a plot's path and label may name: ``{i}`` the component's number from 1, ``{a}`` the
    adaptive state's name, ``{d}`` the name of the law's diagnostic column i."""
    columns = run.diagnostic_columns
    return {"i": i + 1, "a": run.adaptive_name, "d": columns[i] if i < len(columns) else ""}


def _panel(plot: Plot, i: int, run: Trajectory) -> Panel:
    key = plot.path.rsplit("/", 1)[0]
    title = "" if plot.title is None else plot.title(run)
    return Panel(key.format(**_names(run, i)), key, i + 1 if "{i}" in key else 0, title)


def _plots(run: Trajectory, twin_drawn_only: bool):
    """(signal, plot, components) of every entity the table draws for a run."""
    for signal in SIGNALS:
        for plot in PLOTS.get(signal.name, ()):
            if ((twin_drawn_only and not plot.twin) or (plot.only_if_clipping and not run.actuator_limited)
                    or (plot.only_if_input_quantized and not run.quantized_input)):
                continue
            for shown in _groups(signal, plot, run):
                yield signal, plot, shown


def run_series(run: Trajectory, label: str, role: str = "main", suffix: str = "",
               shade: int = 0) -> list[Series]:
    """The series of a run: every plot of the table for the main run (its twin-drawn series
    tagged with ``label``); for a ghost run (``role`` "twin" or "comparison", entity ``suffix``,
    the ``shade``-th ghost of the recording), the twin-drawn plots at ``<path>_<suffix>``, thin and
    light for the first twin, green for the first other run, each further ghost a colour of its own."""
    series = []
    for signal, plot, shown in _plots(run, role != "main"):
        first = shown[0]
        path = plot.path.format(**_names(run, first))
        labels = tuple(plot.label.format(**_names(run, i)) for i in shown)
        panel = _panel(plot, first, run)
        values = _columns(signal, shown, plot.per_bound)
        if role == "main":
            colors = tuple(PALETTE[i % len(PALETTE)] if plot.color == "palette" else ROLE_COLORS[plot.color]
                           for i in shown)
            series.append(Series(path, labels, label if plot.twin else "", colors, signal.held, values, panel,
                                 plot.twin))
        elif role == "twin":
            colors = (shade_of(TWIN_COLORS, shade),) * len(shown)
            series.append(Series(f"{path}_{suffix}", labels, f"{label}, thin", colors, signal.held, values,
                                 panel, True, THIN))
        else:
            colors = (shade_of(COMPARISON_COLORS, shade),) * len(shown)
            series.append(Series(f"{path}_{suffix}", labels, label, colors, signal.held, values, panel, True))
    return series


def guide_lines(run: Trajectory) -> list[GuideLine]:
    """The constant lines of the table's guides (Lemma 2's bound 1, the band +-delta/2), once per
    panel, at the levels of this run's bounds ``L_z``."""
    lines, seen = [], set()
    for _, plot, shown in _plots(run, False):
        if plot.guide is None:
            continue
        panel = _panel(plot, shown[0], run)
        if panel.origin not in seen:
            seen.add(panel.origin)
            guide = plot.guide
            lines.append(GuideLine(f"{panel.origin}/{guide.name}", guide.labels,
                                   tuple(float(v) for v in guide.levels(run.L_z))))
    return lines


def differences(run: Trajectory, main_label: str, twin_label: str, suffix: str,
                shade: int = 0) -> list[Series]:
    """The series ``|main - twin|`` of every plot that names a difference panel (one component
    each), for a twin run; their ``values`` read either run's column."""
    found = []
    for signal, plot, shown in _plots(run, True):
        if plot.difference is None:
            continue
        (i,) = shown
        text = plot.label.format(**_names(run, i))
        name = f"log10 |{text} ({main_label}) - {text} ({twin_label})|"
        values = _columns(signal, shown, plot.per_bound)
        found.append(Series(f"{plot.difference}/{suffix}", (name,), "", (shade_of(DIFFERENCE_COLORS, shade),),
                            signal.held, values,
                            Panel(plot.difference, plot.difference)))
    return found
