"""The time series of a recording, made from the signal table's plots
(:data:`qcontrol.engine.signals.SIGNALS`).

Series layout (``{L}`` a ghost run's label, ``{a}`` the adaptive state's name, ``i`` from 1)::

    signals/tracking/y, y_d, y_{L}        signals/error/z1, z1_{L}       signals/input/u, u_{L}
    signals/adaptive/{a}_i                signals/state/x{i}/x, signals/state/x{i}/q
    signals/quantization/x{i}/error       (x_meas - q(x_meas)) with band_upper, band_lower (+-delta/2)
    theory/lemma2/z{i}  (|e_zi| / L_zi)   theory/lemma2/bound  (the constant 1)
    signals/difference/y/{L}, signals/difference/u/{L}   |main - twin|, for a twin run

Each series belongs to a panel, its path's parent (``signals/input``, ``signals/state/x2``): the
layout (:mod:`.layout`) makes one plot per panel, so a series added to the table under an existing
panel shows there, and one under a new panel gets a tab of its own.

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
from ..engine.signals import Plot, Signal

TIMELINE = "sim_time"
BLUE, ORANGE, GREEN, RED = (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40)
PURPLE, BROWN, LIGHT = (148, 103, 189), (140, 86, 75), (245, 245, 245)
PALETTE = (BLUE, ORANGE, GREEN, RED, PURPLE, BROWN)
ROLE_COLORS = {"main": BLUE, "reference": ORANGE, "quantized": RED}
WIDE, THIN = 5.0, 1.5  # line widths (points) of a main run beside its twin, and of the twin
GHOST_ROLES = ("twin", "comparison")


@dataclass(frozen=True)
class Panel:
    """One plot of the layout: its entity ``origin``, the ``key`` it is styled by (the origin
    before ``{i}`` is filled in) and the component ``index`` it shows (from 1; 0 for all)."""

    origin: str
    key: str
    index: int = 0


@dataclass(frozen=True)
class Series:
    """One scalar time series: where it goes, how it is drawn, which column of a run it is."""

    path: str
    label: str
    tag: str  # the run it belongs to, in the legend: "y (mujoco)"
    color: tuple[int, int, int]
    step: bool
    values: Callable[[Trajectory], np.ndarray]
    panel: Panel
    drawn_for_twin: bool = False
    width: float | None = None

    @property
    def name(self) -> str:
        return f"{self.label} ({self.tag})" if self.tag else self.label

    def beside_twin(self) -> Series:
        """The main run's series once a twin is drawn on top of it: wide, and labelled so."""
        return replace(self, tag=f"{self.tag}, wide" if self.tag else "wide", width=WIDE)


@dataclass(frozen=True)
class GuideLine:
    """A constant line of a panel (a bound): its path, legend name and level."""

    path: str
    name: str
    level: float


@dataclass(frozen=True)
class Difference:
    """``|main - twin|`` of one twin-drawn series (``values`` is its column of either run)."""

    path: str
    name: str
    step: bool
    values: Callable[[Trajectory], np.ndarray]
    panel: Panel


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


def _panel(template: str, i: int, adaptive: str) -> Panel:
    key = template.rsplit("/", 1)[0]
    return Panel(key.format(i=i + 1, a=adaptive), key, i + 1 if "{i}" in key else 0)


def _plots(run: Trajectory, twin_drawn_only: bool):
    """(signal, plot, component) of every series the table draws for a run."""
    for signal in SIGNALS:
        for plot in signal.plots:
            if twin_drawn_only and not plot.twin:
                continue
            for i in _components(signal, plot, run):
                yield signal, plot, i


def run_series(run: Trajectory, label: str, role: str = "main", suffix: str = "") -> list[Series]:
    """The series of a run: every plot of the table for the main run (its twin-drawn series
    tagged with ``label``); for a ghost run (``role`` "twin" or "comparison", entity ``suffix``),
    the twin-drawn plots at ``<path>_<suffix>``, thin and light for a twin, green otherwise."""
    series = []
    for signal, plot, i in _plots(run, role != "main"):
        path = plot.path.format(i=i + 1, a=run.adaptive_name)
        text = plot.label.format(i=i + 1, a=run.adaptive_name)
        panel = _panel(plot.path, i, run.adaptive_name)
        values = _column(signal, i, plot.per_bound)
        if role == "main":
            color = PALETTE[i % len(PALETTE)] if plot.color == "palette" else ROLE_COLORS[plot.color]
            series.append(Series(path, text, label if plot.twin else "", color, signal.held, values, panel,
                                 plot.twin))
        elif role == "twin":
            series.append(Series(f"{path}_{suffix}", text, f"{label}, thin", LIGHT, signal.held, values,
                                 panel, True, THIN))
        else:
            series.append(Series(f"{path}_{suffix}", text, label, GREEN, signal.held, values, panel, True))
    return series


def guide_lines(run: Trajectory) -> list[GuideLine]:
    """The constant lines of the table's guides (Lemma 2's bound 1, the band +-delta/2), once per
    panel, at the levels of this run's bounds ``L_z``."""
    lines, seen = [], set()
    for _, plot, i in _plots(run, False):
        if plot.guide is None:
            continue
        panel = _panel(plot.path, i, run.adaptive_name)
        if panel.origin in seen:
            continue
        seen.add(panel.origin)
        for name, legend, level in plot.guide.lines:
            lines.append(GuideLine(f"{panel.origin}/{name}", legend, float(level(run.L_z))))
    return lines


def differences(run: Trajectory, main_label: str, twin_label: str, suffix: str) -> list[Difference]:
    """``|main - twin|`` of every plot that names a difference panel, for a twin run."""
    found = []
    for signal, plot, i in _plots(run, True):
        if plot.difference is None:
            continue
        text = plot.label.format(i=i + 1, a=run.adaptive_name)
        values = _column(signal, i, plot.per_bound)
        name = f"|{text} ({main_label}) - {text} ({twin_label})|"
        found.append(Difference(f"{plot.difference}/{suffix}", name, signal.held, values,
                                Panel(plot.difference, plot.difference)))
    return found
