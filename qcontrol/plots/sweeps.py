"""The figure of a sweep, by the number of varied keys: one key, a line per metric against the
value (markers per category for a non-numeric key such as the law's kind); two keys, a heatmap per
metric; more, small multiples of heatmaps. Diverged runs are marked. With random initial states,
each grid point shows the median over its runs (and, on lines, the range)."""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes

from .common import COLORS, legend, new_figure, save

SMALL_MULTIPLES = 12  # panels at most in a sweep of three or more keys
OTHER_METRICS = (("max_abs_z1_last_half", "max |z1|, last half"), ("max_abs_u", "max |u|"),
                 ("lemma2_max_ratio", "Lemma 2 ratio max |e_zi| / L_zi"))


def _float(value: object) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def _axis_values(rows: Sequence[dict], key: str) -> tuple[list[str], np.ndarray | None]:
    """The distinct values of ``key`` in grid order, and their numbers (None: categories)."""
    values = list(dict.fromkeys(str(r[key]) for r in rows))
    numbers = np.array([_float(v) for v in values])
    if np.all(np.isfinite(numbers)):
        order = np.argsort(numbers, kind="stable")
        return [values[i] for i in order], numbers[order]
    return values, None


class _Points:
    """The runs of each grid point: per metric their median, minimum and maximum, and whether
    any run diverged there."""

    def __init__(self, rows: Sequence[dict], keys: Sequence[str]) -> None:
        self.keys = list(keys)
        self.groups: dict[tuple[str, ...], list[dict]] = {}
        for row in rows:
            self.groups.setdefault(tuple(str(row[k]) for k in keys), []).append(row)

    def stat(self, point: tuple[str, ...], metric: str) -> tuple[float, float, float]:
        values = np.array([_float(r[metric]) for r in self.groups.get(point, [])])
        values = values[np.isfinite(values)]
        if not values.size:
            return math.nan, math.nan, math.nan
        return float(np.median(values)), float(values.min()), float(values.max())

    def diverged(self, point: tuple[str, ...]) -> bool:
        return any(str(r["diverged"]) == "True" for r in self.groups.get(point, []))


def fig_sweep(rows: Sequence[dict], keys: Sequence[str], rate_columns: Sequence[str], path: str | os.PathLike,
              title: str) -> Path:
    """The sweep's figure (see the module docstring); ``keys`` are the grid's keys (with no grid,
    the runs themselves), ``rate_columns`` the error-rate columns ``error_rate_<omega>``."""
    keys = list(keys) or ["plant.x0"]
    points = _Points(rows, keys)
    runs_per_point = max(len(group) for group in points.groups.values())
    if runs_per_point > 1:
        title += f"\nmedian over {runs_per_point} initial states per point (on lines, their range shaded)"
    if len(keys) == 1:
        return _lines(rows, points, rate_columns, path, title)
    first, last = rate_columns[0], rate_columns[-1]
    metrics = [(first, f"E({first[11:]})"), (last, f"E({last[11:]})"), *OTHER_METRICS[:2]]
    if len(keys) == 2:
        fig, axes = new_figure(2, 2)
        for ax, (metric, label) in zip(axes.ravel(), metrics, strict=True):
            _heatmap(ax, rows, points, keys, (), metric, label)
    else:
        fig, axes = _small_multiples(rows, points, keys, metrics[0])
        title += f"\n{metrics[0][1]} over {keys[0]} and {keys[1]} (x: diverged)"
    fig.suptitle(title, fontsize=10)
    return save(fig, path)


def _lines(rows: Sequence[dict], points: _Points, rate_columns: Sequence[str], path: str | os.PathLike,
           title: str) -> Path:
    key = points.keys[0]
    labels, numbers = _axis_values(rows, key)
    xs = numbers if numbers is not None else np.arange(len(labels), dtype=float)
    fig, axes = new_figure(2, 2)
    panels = axes.ravel()
    categories = numbers is None  # a kind, a reference kind: grouped markers, no trend line
    for i, metric in enumerate(rate_columns):
        shift = (i - (len(rate_columns) - 1) / 2) * 0.06 if categories else 0.0
        _line(panels[0], points, labels, xs + shift, metric, rf"E($\omega$ = {metric[11:]})",
              COLORS[i % len(COLORS)], categories)
    panels[0].set_ylim(-0.03, 1.03)
    panels[0].set_ylabel(r"error rate E($\omega$)")
    for ax, (metric, label) in zip(panels[1:], OTHER_METRICS, strict=True):
        _line(ax, points, labels, xs, metric, label, COLORS[0], categories)
        ax.set_ylabel(label)
    for ax in panels:
        _mark_diverged(ax, points, labels, xs)
        if numbers is None:
            ax.set_xticks(xs, labels, rotation=30, ha="right", fontsize=7)
            ax.set_xlim(-0.5, len(labels) - 0.5)
        ax.set_xlabel(key)
        ax.ticklabel_format(axis="y", useOffset=False)  # 0.99998, not "1e-5 + 9.999e-1" above the axis
        ax.grid(True, alpha=0.3)
        legend(ax, fontsize=7)
    fig.suptitle(title)
    return save(fig, path)


def _line(ax: Axes, points: _Points, labels: list[str], xs: np.ndarray, metric: str, label: str,
          color: str, categories: bool = False) -> None:
    """The metric against a numeric key as a line (the range shaded); against categories as
    markers (the range as error bars), with nothing drawn between two categories."""
    stats = np.array([points.stat((v,), metric) for v in labels]).reshape(-1, 3)
    stats[[points.diverged((v,)) for v in labels]] = np.nan  # marked by _mark_diverged instead
    if categories:
        spread = np.array([stats[:, 0] - stats[:, 1], stats[:, 2] - stats[:, 0]])
        ax.errorbar(xs, stats[:, 0], yerr=spread, color=color, marker="o", markersize=5, linestyle="none",
                    capsize=3, label=label)
        return
    ax.plot(xs, stats[:, 0], color=color, marker="o", markersize=4, linewidth=1.3, label=label)
    if np.any(stats[:, 1] != stats[:, 2]):  # several runs per point: their range
        ax.fill_between(xs, stats[:, 1], stats[:, 2], color=color, alpha=0.15, linewidth=0)


def _mark_diverged(ax: Axes, points: _Points, labels: list[str], xs: np.ndarray) -> None:
    bad = [x for x, v in zip(xs, labels, strict=True) if points.diverged((v,))]
    for x in bad:
        ax.axvline(x, color="red", linestyle=":", linewidth=1.0)
    if bad:
        ax.plot([], [], color="red", linestyle=":", label="diverged")


def _heatmap(ax: Axes, rows: Sequence[dict], points: _Points, keys: Sequence[str], fixed: tuple[str, ...],
             metric: str, label: str) -> None:
    """A heatmap of ``metric`` over the first two keys (the others held at ``fixed``). A cell where
    a run diverged is left blank and marked: its values (max |u| of 1e17, say) would otherwise set
    the colour scale of the whole map."""
    xs, _ = _axis_values(rows, keys[0])
    ys, _ = _axis_values(rows, keys[1])
    diverged = np.array([[points.diverged((x, y, *fixed)) for x in xs] for y in ys])
    grid = np.array([[points.stat((x, y, *fixed), metric)[0] for x in xs] for y in ys])
    grid[diverged] = np.nan
    image = ax.imshow(np.ma.masked_invalid(grid), origin="lower", aspect="auto", cmap="viridis")
    ax.figure.colorbar(image, ax=ax, shrink=0.85)
    for j, i in itertools.product(range(len(ys)), range(len(xs))):
        if diverged[j, i]:
            ax.text(i, j, "x", ha="center", va="center", color="red", fontsize=12, fontweight="bold")
        elif len(xs) * len(ys) <= 64 and np.isfinite(grid[j, i]):
            light = image.norm(grid[j, i]) > 0.6  # viridis is light at its top: dark text there
            ax.text(i, j, f"{grid[j, i]:.3g}", ha="center", va="center", color="black" if light else "white",
                    fontsize=6)
    ax.set_xticks(range(len(xs)), xs, rotation=30, ha="right", fontsize=7)
    ax.set_yticks(range(len(ys)), ys, fontsize=7)
    ax.set_xlabel(keys[0])
    ax.set_ylabel(keys[1])
    ax.set_title(f"{label} (x: diverged)", fontsize=9)


def _small_multiples(rows: Sequence[dict], points: _Points, keys: Sequence[str],
                     metric: tuple[str, str]) -> tuple:
    """A heatmap over the first two keys for each value of the others (at most SMALL_MULTIPLES)."""
    others = [_axis_values(rows, k)[0] for k in keys[2:]]
    combos = list(itertools.product(*others))[:SMALL_MULTIPLES]
    cols = min(4, len(combos))
    fig, axes = new_figure(-(-len(combos) // cols), cols)
    for ax, combo in zip(axes.ravel(), combos, strict=False):
        _heatmap(ax, rows, points, keys, combo, *metric)
        ax.set_title(", ".join(f"{k} = {v}" for k, v in zip(keys[2:], combo, strict=True)), fontsize=7)
    for ax in axes.ravel()[len(combos):]:
        ax.axis("off")
    return fig, axes
