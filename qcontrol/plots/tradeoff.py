"""The reproduction's trade-off figure: a row of region maps per example (a map per law, as
:mod:`.region` draws them), and below them each law's error rates E(omega) from x(0) and the plane
of E(0.100) against the starts it fails from."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from .common import FIG_DPI, FIG_HEIGHT_PX, FIG_WIDTH_PX, save
from .region import RegionMap, draw_maps

MARKERS = ("o", "s", "^", "D")  # one per example in the trade-off plane
# a colour and a line style per law (Okabe-Ito; none the maps' "diverged" colour; a law that gives
# the same rates as the one before it, the exact hold, still shows through its dashes)
LAW_COLORS = ("#0072B2", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442")
FLOOR = 1e-3  # the error rates' axes are logarithmic from here (an E of 0 is drawn on the axis)
RATE_TICKS = (0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)
LAW_LINES = ("-", "--", "-", "-", "-.", "-", ":")


def fig_tradeoff(maps: Sequence[Sequence[RegionMap]], rows: Sequence[Mapping[str, Any]],
                 outcomes: Sequence[str], path: str | os.PathLike, title: str) -> Path:
    """``maps``: a list of maps per example (a map per law); ``rows``: the study's rows (``example``,
    ``name``, ``error_rate``, ``failing_in_box``, ``points_in_box``), the laws in the maps' order."""
    fig = Figure(figsize=(FIG_WIDTH_PX / FIG_DPI, FIG_HEIGHT_PX / FIG_DPI), dpi=FIG_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    top, bottom = fig.subfigures(2, 1, height_ratios=(1.9, 1.3))
    draw_maps(top, top.subplots(len(maps), max(len(m) for m in maps), squeeze=False), maps, outcomes)
    examples = list(dict.fromkeys(r["example"] for r in rows))
    names = list(dict.fromkeys(r["name"] for r in rows))
    style = {name: (LAW_COLORS[i % len(LAW_COLORS)], LAW_LINES[i % len(LAW_LINES)])
             for i, name in enumerate(names)}
    panels = bottom.subplots(1, len(examples) + 1, squeeze=False)[0]
    for ax, example in zip(panels, examples, strict=False):
        for r in (r for r in rows if r["example"] == example):
            color, line = style[r["name"]]
            ax.plot([float(w) for w in r["error_rate"]], list(r["error_rate"].values()), marker=".",
                    color=color, linestyle=line, label=r["name"])
        ax.set_title(f"{example}: E(omega) from x(0)", fontsize=8)
        ax.set_xlabel("omega", fontsize=8)
        _rate_axis(ax)
        ax.tick_params(labelsize=7)
    plane = panels[-1]
    for r in rows:
        plane.plot([r["failing_in_box"] / r["points_in_box"]], [r["error_rate"]["0.100"]], linestyle="none",
                   marker=MARKERS[examples.index(r["example"]) % len(MARKERS)], color=style[r["name"]][0],
                   markersize=7, alpha=0.85)
    plane.set_title("E(0.100) against the starts that fail", fontsize=8)
    plane.set_xlabel("share of the box's starts that fail", fontsize=8)
    plane.set_xlim(-0.05, 1.05)
    _rate_axis(plane)
    plane.tick_params(labelsize=7)
    shapes = [Line2D([], [], marker=MARKERS[i % len(MARKERS)], linestyle="none", color="gray", label=example)
              for i, example in enumerate(examples)]
    plane.legend(handles=shapes, fontsize=7, frameon=False, loc="center right")
    laws = [Line2D([], [], color=c, linestyle=line, marker=".", label=name)
            for name, (c, line) in style.items()]
    bottom.legend(handles=laws, loc="outside lower center", ncols=len(laws), fontsize=7, frameon=False)
    fig.suptitle(title, fontsize=9)
    return save(fig, path)


def _rate_axis(ax: Any) -> None:
    """A logarithmic axis of error rates from :data:`FLOOR` to 1, its ticks written as numbers."""
    ax.set_yscale("log")
    ax.set_ylim(FLOOR, 1.0)
    ax.set_yticks(RATE_TICKS, [f"{v:g}" for v in RATE_TICKS])
    ax.minorticks_off()
    ax.grid(True, axis="y", linewidth=0.4, alpha=0.5)
