"""Figures of the robustness study: each imperfection alone and all together (MuJoCo beside the
ODE twin), and the margins (each imperfection pushed beyond the hardware)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes

from ..plots.common import COLORS, new_figure, save
from .robustness_report import E, show_amount

LAW_COLORS = {"proposed": COLORS[0], "comparison": COLORS[1]}
EXAMPLE_TITLES = {"example2": "Example 2, the arm", "example1": "Example 1, the cart"}
Z_FLOOR = 1e-3  # the log axis of max |z1| starts here


def _law_color(law: str, index: int) -> str:
    """The built-in laws' colours; a law given with ``--law`` takes the next colour of the cycle."""
    return LAW_COLORS.get(law, COLORS[index % len(COLORS)])


def _value(cell: Mapping, metric: str) -> tuple[float, float, float]:
    """(median, min, max) of a metric of an aggregated row (NaN when there is none)."""
    spread = cell["error_rate"][E] if metric == "E" else cell[metric]
    values = [spread[k] for k in ("median", "min", "max")]
    return tuple(math.nan if v is None else float(v) for v in values)  # type: ignore[return-value]


def _bars(ax: Axes, labels: Sequence[str], cells: Mapping[str, Sequence[Mapping]],
          twins: Mapping[str, Sequence[Mapping]] | None, metric: str, log: bool, seeded: bool = True) -> None:
    """Horizontal bars per label and law (MuJoCo, with the range over seeds), the ODE twin (if
    given) as a black tick, and "diverged k/n" written at the axis' end."""
    y = np.arange(len(labels))
    height = 0.8 / len(cells)
    top = 1.0 if metric == "E" else 0.0
    for j, (law, rows) in enumerate(cells.items()):
        offset = y - 0.4 + height * (j + 0.5)
        values = np.array([_value(row, metric) for row in rows])
        diverged = np.array([row["diverged"] > 0 for row in rows])
        median = np.where(np.isfinite(values[:, 0]), values[:, 0], np.nan)
        if log:
            median = np.maximum(median, Z_FLOOR)
        low = np.clip(median - values[:, 1], 0, None)
        high = np.clip(values[:, 2] - median, 0, None)
        note = " (median; whisker: range over the seeds)" if j == len(cells) - 1 > 0 and seeded else ""
        ax.barh(offset, np.nan_to_num(median, nan=0.0), height=height * 0.9, color=_law_color(law, j),
                xerr=[np.nan_to_num(low), np.nan_to_num(high)], error_kw={"elinewidth": 1, "capsize": 2},
                label=f"{law} law on MuJoCo{note}")
        if twins is not None:
            twin = np.array([_value(row, metric)[0] for row in twins[law]])
            ax.plot(np.maximum(twin, Z_FLOOR) if log else twin, offset, "|", color="black", markersize=9,
                    label="ODE twin" if j == 0 else None)
        finite = values[np.isfinite(values)]
        top = max(top, float(finite.max()) if finite.size else top)
        for yy, row, gone in zip(offset, rows, diverged, strict=True):
            if gone:
                ax.annotate(f"{law} law: diverged ({row['diverged']}/{row['runs']} runs)", (0.02, yy),
                            xycoords=("axes fraction", "data"), ha="left", va="center", fontsize=7,
                            color="red", bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5})
    ax.set_yticks(y, labels, fontsize=8)
    ax.invert_yaxis()
    if log:
        ax.set_xscale("log")
        ax.set_xlim(Z_FLOOR, max(top * 2.0, 1.0))
    else:
        ax.set_xlim(0.0, 1.05)
    ax.grid(True, axis="x", alpha=0.3)


def fig_robustness(study: Mapping, path: str | os.PathLike) -> Path:
    """E(0.100) and max |z1| over the last half for every row of ``robustness.json``, one row of
    panels per example."""
    examples = list(dict.fromkeys(row["example"] for row in study["rows"]))
    fig, axes = new_figure(len(examples), 2)
    for i, example in enumerate(examples):
        rows = [r for r in study["rows"] if r["example"] == example]
        laws = list(dict.fromkeys(r["law"] for r in rows))
        labels = list(dict.fromkeys(r["imperfection"] for r in rows))
        cells = {law: [r["mujoco"] for r in rows if r["law"] == law] for law in laws}
        twins = {law: [r["ode"] for r in rows if r["law"] == law] for law in laws}
        for j, (metric, log, xlabel) in enumerate((
            ("E", False, r"error rate E($\omega$ = 0.1)"),
            ("max_abs_z1_last_half", True, r"max $|z_1|$ over the last half"),
        )):
            ax = axes[i, j]
            _bars(ax, labels, cells, twins, metric, log)
            ax.set_xlabel(xlabel, fontsize=8)
            ax.set_title(EXAMPLE_TITLES.get(example, example), fontsize=9)
    _figure_legend(fig, axes[0, 0])
    fig.suptitle("Robustness: each imperfection of the realistic hardware alone, and all together",
                 fontsize=10)
    return save(fig, path)


def _figure_legend(fig, ax: Axes) -> None:
    handles, names = ax.get_legend_handles_labels()
    # three a row: the built-in laws and the ODE twin; a law given with --law starts a second row
    fig.legend(handles, names, loc="outside lower center", ncols=min(len(names), 3), fontsize=7,
               frameon=False)


def fig_margins(study: Mapping, path: str | os.PathLike) -> Path:
    """max |z1| over the last half for each imperfection pushed beyond the hardware (margins)."""
    examples = list(dict.fromkeys(row["example"] for row in study["margins"]))
    fig, axes = new_figure(1, len(examples))
    for ax, example in zip(axes[0], examples, strict=True):
        rows = [r for r in study["margins"] if r["example"] == example]
        laws = list(dict.fromkeys(r["law"] for r in rows))
        labels = list(dict.fromkeys(f"{r['imperfection']} {show_amount(r)}" for r in rows))
        cells = {law: [r["mujoco"] for r in rows if r["law"] == law] for law in laws}
        _bars(ax, labels, cells, None, "max_abs_z1_last_half", True, seeded=False)
        ax.set_xlabel(r"max $|z_1|$ over the last half (MuJoCo)", fontsize=8)
        ax.set_title(EXAMPLE_TITLES.get(example, example), fontsize=9)
    _figure_legend(fig, axes[0, 0])
    fig.suptitle("Margins: each imperfection alone, beyond the hardware, until it breaks the loop",
                 fontsize=10)
    return save(fig, path)
