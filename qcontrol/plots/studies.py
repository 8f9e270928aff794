"""Figures of studies: an error rate against a swept parameter, and Table 1 beside the paper's."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .common import (
    COLORS,
    finite_or_note,
    legend,
    new_figure,
    save,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes

# --------------------------------------------------------------------------------------------
# Sensitivity studies and Table 1
# --------------------------------------------------------------------------------------------


def _omega_label(key: str) -> str:
    return rf"$\omega$ = {key}"


def fig_sensitivity(
    x_values: Sequence[float | str],
    rates: Mapping[str, Sequence[float]],
    xlabel: str,
    path: str | os.PathLike,
    title: str,
    paper_rates: Mapping[str, float] | None = None,
    markers: Mapping[str, float] | None = None,
    xscale: str = "linear",
) -> Path:
    """Error rate ``E(omega)`` against a swept parameter, one line per ``omega``.

    ``rates`` maps an omega key (``"0.100"``, as :func:`qcontrol.metrics.omega_key`) to one rate
    per entry of ``x_values``; NaN or None are gaps. ``x_values`` are numbers (e.g. ``kappa - L``
    or an ``r`` scale; use ``xscale="log"`` for a geometric sweep) or strings: categories (e.g.
    plant variants), drawn as groups of bars, one bar per omega (no line joins unrelated cases).
    ``paper_rates`` (omega key -> rate, the paper's proposed row) are drawn as dashed horizontal
    lines in the colour of that omega; ``markers`` (label -> x) as dotted vertical lines, e.g.
    ``{"paper: kappa - L = 1.1": 1.1}``.
    """
    categorical = any(isinstance(v, str) for v in x_values)
    xs = np.arange(len(x_values), dtype=float) if categorical else np.asarray(x_values, dtype=float)
    fig, axes = new_figure()
    ax = axes[0, 0]
    width = 0.8 / max(1, len(rates))
    for i, (key, values) in enumerate(rates.items()):
        ys = np.array([np.nan if v is None else float(v) for v in values], dtype=float)
        if ys.shape != xs.shape:
            raise ValueError(f"fig_sensitivity: {len(ys)} rate(s) for omega {key} but {len(xs)} x value(s)")
        color = COLORS[i % len(COLORS)]
        if categorical:
            ax.bar(xs - 0.4 + width * (i + 0.5), ys, width=width * 0.95, color=color, label=_omega_label(key))
        else:
            ax.plot(xs, ys, color=color, marker="o", markersize=5, linewidth=1.5, label=_omega_label(key))
        if paper_rates is not None and paper_rates.get(key) is not None:
            ax.axhline(float(paper_rates[key]), color=color, linestyle="--", linewidth=1.0, alpha=0.8)
    if paper_rates:
        ax.plot([], [], color="gray", linestyle="--", linewidth=1.0, label="paper (proposed), dashed")
    for j, (label, x) in enumerate((markers or {}).items()):
        ax.axvline(float(x), color="black", linestyle=":", linewidth=1.2 + 0.4 * j, label=label)
    if categorical:
        ax.set_xticks(xs, [str(v) for v in x_values])
    elif xscale != "linear":
        ax.set_xscale(xscale)
    all_rates = [v for vals in rates.values() for v in vals if v is not None and math.isfinite(float(v))]
    if not all_rates:
        finite_or_note(ax, np.array([np.nan]))
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(r"error rate E($\omega$) = fraction of samples with $|z_1| > \omega$")
    ax.grid(True, alpha=0.3)
    ax.set_title(title)
    legend(ax, fontsize=8)
    return save(fig, path)


def fig_table1(
    table: Mapping[str, Mapping[str, Mapping[str, float | None]]],
    path: str | os.PathLike,
    title: str = r"Table 1. Error rate E($\omega$) (Example 2): ours vs the paper",
) -> Path:
    """Grouped bar chart of Table 1: one column per method; above, bars per omega for every
    source; below, the difference of each other source from the first (``ours - paper``).

    ``table`` maps method (e.g. ``"proposed"``, ``"comparison"``) -> source (e.g. ``"paper"``,
    ``"MuJoCo"``, ``"ODE"``) -> omega key -> rate. Each panel has its own y scale (the two methods
    differ by a factor ~40); missing / NaN rates are left out and marked "n/a".
    """
    methods = list(table)
    if not methods:
        raise ValueError("fig_table1: the table is empty")
    fig, axes = new_figure(2, len(methods))
    for ax, method in zip(axes[1], methods, strict=True):
        _table1_differences(ax, table[method])
    for ax, method in zip(axes[0], methods, strict=True):
        sources = table[method]
        omegas: list[str] = []
        for rates in sources.values():
            omegas.extend(k for k in rates if k not in omegas)
        omegas.sort(key=float)
        width = 0.8 / max(1, len(sources))
        top = 0.0
        for s, (source, rates) in enumerate(sources.items()):
            offsets = np.arange(len(omegas)) - 0.4 + width * (s + 0.5)
            values = np.array(
                [np.nan if rates.get(k) is None else float(rates[k]) for k in omegas], dtype=float
            )
            shown = np.isfinite(values)
            bars = ax.bar(
                offsets[shown],
                values[shown],
                width=width * 0.95,
                color=COLORS[s % len(COLORS)],
                hatch="//" if source.lower().startswith("paper") else None,
                edgecolor="white",
                label=source,
            )
            ax.bar_label(bars, fmt="%.3f", fontsize=6, rotation=90, padding=2)
            for x in offsets[~shown]:
                ax.text(x, 0.0, "n/a", rotation=90, ha="center", va="bottom", fontsize=7, color="gray")
            if shown.any():
                top = max(top, float(values[shown].max()))
        ax.set_xticks(np.arange(len(omegas)), omegas)
        ax.set_xlabel(r"$\omega$ [rad]")
        ax.set_ylabel(r"E($\omega$)")
        ax.set_ylim(0.0, max(top * 1.55, 1e-3))  # room for the legend above the bars
        ax.grid(True, axis="y", alpha=0.3)
        ax.set_title(f"{method} law")
        legend(ax, fontsize=8, loc="upper center", ncol=len(sources))
    fig.suptitle(title)
    return save(fig, path)


def _table1_differences(ax: Axes, sources: Mapping[str, Mapping[str, float | None]]) -> None:
    """Bars of ``source - first source`` per omega (first: the paper), labelled with the value."""
    names = list(sources)
    paper = sources[names[0]]
    omegas = sorted(paper, key=float)
    others = names[1:]
    width = 0.8 / max(1, len(others))
    for s, source in enumerate(others, start=1):
        offsets = np.arange(len(omegas)) - 0.4 + width * (s - 0.5)
        values = np.array([np.nan if sources[source].get(k) is None or paper.get(k) is None
                           else float(sources[source][k]) - float(paper[k]) for k in omegas])
        shown = np.isfinite(values)
        bars = ax.bar(offsets[shown], values[shown], width=width * 0.95, color=COLORS[s % len(COLORS)],
                      edgecolor="white", label=f"{source} - {names[0]}")
        ax.bar_label(bars, fmt="%+.3f", fontsize=6, rotation=90, padding=2)
    ax.axhline(0.0, color="black", linewidth=0.8)
    ax.set_xticks(np.arange(len(omegas)), omegas)
    ax.set_xlabel(r"$\omega$ [rad]")
    ax.set_ylabel(f"difference from the {names[0]}")
    low, high = ax.get_ylim()
    span = max(high - low, 1e-3)
    ax.set_ylim(min(low, 0.0) - 0.3 * span, max(high, 0.0) + 0.6 * span)  # room for the legend above
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_title(f"ours - {names[0]}")
    legend(ax, fontsize=8, loc="upper center", ncol=len(others))
