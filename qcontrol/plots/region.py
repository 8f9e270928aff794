"""The region-of-attraction maps: one panel per law (columns) and per measured region (rows: a
scenario at a control period), on the same axes, the scenario's x(0) and the box |x_i| <= 10
marked. The maps come as plain data (:class:`RegionMap`), made by :mod:`qcontrol.region`."""

from __future__ import annotations

import os
import re
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from .common import new_figure, save

OUTCOME_COLORS = {"bounded": "#BFE6D5", "diverged": "#D55E00", "lemma2": "#E69F00"}  # Okabe-Ito based
PANEL_CHARACTERS = 96  # characters of an 8-point title across the figure's width: a panel's share of them
OUTCOME_LABELS = {"bounded": "bounded, Lemma 2 holds", "diverged": "diverged", "lemma2": "Lemma 2 violated"}


@dataclass(frozen=True)
class RegionMap:
    """One panel: the grid values of its two axes, each start's outcome index into ``outcomes``
    (shape ``(len(ys), len(xs))``), the largest K T of each run (same shape; NaN where the law
    declares none), the scenario's x(0) on these axes, the half-width of the box drawn, its title
    and labels."""

    xs: np.ndarray
    ys: np.ndarray
    codes: np.ndarray
    gains: np.ndarray
    marker: tuple[float, float]
    box: float
    title: str
    xlabel: str
    ylabel: str


def _edges(values: np.ndarray) -> np.ndarray:
    """Cell edges around grid values (the midpoints, and half a step beyond the ends)."""
    mid = (values[1:] + values[:-1]) / 2.0
    return np.concatenate([[2 * values[0] - mid[0]], mid, [2 * values[-1] - mid[-1]]])


def _title(title: str, columns: int) -> str:
    """A panel's title "law: what failed" as the law on its own lines, wrapped at its commas to the
    panel's width, then what failed: it fits however many laws share the row and however long a
    law's label is."""
    width = max(12, PANEL_CHARACTERS // columns)
    law, sep, counts = title.rpartition(": ")
    if not sep:
        return textwrap.fill(title, width)
    lines = [""]
    for part in re.split(r"(?<=[:,])", law):  # the label as typed, broken after its ':' and ','
        if lines[-1] and len(lines[-1]) + len(part) > width:
            lines.append("")
        lines[-1] += part
    return "\n".join([*lines, counts])  # the counts on one line: at most about 30 characters


def _ylabel(label: str) -> str:
    """The row's label (the scenario, its control period, the vertical axis, a line each) on two
    lines: what the row is, then the axis."""
    *row, axis = label.split("\n")
    return "\n".join([", ".join(row), axis]) if row else axis


def region_panel(ax, m: RegionMap, outcomes: Sequence[str], show_ylabel: bool, show_xlabel: bool,
           columns: int = 1) -> None:
    cmap = ListedColormap([OUTCOME_COLORS[o] for o in outcomes])
    norm = BoundaryNorm(np.arange(len(outcomes) + 1) - 0.5, len(outcomes))
    ax.pcolormesh(_edges(m.xs), _edges(m.ys), m.codes, cmap=cmap, norm=norm, shading="flat")
    gains = np.where(np.isfinite(m.gains) & (m.gains > 0), m.gains, np.nan)
    if np.isfinite(gains).any() and np.nanmin(gains) < 1 < np.nanmax(gains):
        ax.contour(m.xs, m.ys, np.log10(gains), levels=[0.0], colors="black", linewidths=0.8, linestyles=":")
    ax.add_patch(Rectangle((-m.box, -m.box), 2 * m.box, 2 * m.box, fill=False, edgecolor="black",
                           linestyle="--", linewidth=1.0))
    ax.plot([m.marker[0]], [m.marker[1]], marker="*", color="black", markersize=10, linestyle="none")
    ax.set_title(_title(m.title, columns), fontsize=8)
    if show_xlabel:
        ax.set_xlabel(m.xlabel, fontsize=8)
    if show_ylabel:
        ax.set_ylabel(_ylabel(m.ylabel), fontsize=7)
    ax.set_xlim(_edges(m.xs)[[0, -1]])
    ax.set_ylim(_edges(m.ys)[[0, -1]])
    ax.tick_params(labelsize=7)


def fig_region(rows: Sequence[Sequence[RegionMap]], outcomes: Sequence[str], path: str | os.PathLike,
               title: str) -> Path:
    """A row of maps per measured region, a map per law: each start's outcome, the dotted line
    K T = 1 of the largest gain-period product where a law declares it, the box (dashed) and the
    scenario's x(0) (star)."""
    fig, axes = new_figure(len(rows), max(len(r) for r in rows))
    draw_maps(fig, axes, rows, outcomes)
    fig.suptitle(title, fontsize=10)
    return save(fig, path)


def draw_maps(parent, axes: np.ndarray, rows: Sequence[Sequence[RegionMap]], outcomes: Sequence[str]) -> None:
    """A map per panel of ``axes`` (a row of panels per entry of ``rows``, the panels a row does not
    need hidden) and the outcomes' legend below them on ``parent`` (a figure or a subfigure)."""
    cols = axes.shape[1]
    for i, maps in enumerate(rows):
        for j in range(cols):
            if j < len(maps):
                region_panel(axes[i, j], maps[j], outcomes, j == 0, i == len(rows) - 1, columns=cols)
            else:
                axes[i, j].set_visible(False)
    handles = legend_handles(outcomes, rows[0][0].box)
    parent.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=7, frameon=False)


def legend_handles(outcomes: Sequence[str], box: float) -> list:
    """The maps' legend: the outcomes' colours, the box, the scenario's x(0) and the line K T = 1."""
    handles: list = [Patch(color=OUTCOME_COLORS[o], label=OUTCOME_LABELS[o]) for o in outcomes]
    handles += [Line2D([], [], color="black", linestyle="--", label=f"box |x_i| <= {box:g}"),
                Line2D([], [], color="black", marker="*", linestyle="none", label="the scenario's x(0)"),
                Line2D([], [], color="black", linestyle=":", label="max K T = 1")]
    return handles
