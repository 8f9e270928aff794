"""Figures of the reproduction (paper Figs. 1-8, backend overlay, sensitivity studies, Table 1).

Every function draws one matplotlib figure on the Agg canvas (never pyplot's global state, never
a display), writes it as a PNG of exactly ``FIG_WIDTH_PX x FIG_HEIGHT_PX`` pixels and returns the
path. The file is written atomically (:func:`qcontrol.outputs.atomic_path`), so a reader never
sees half a PNG. Missing folders are created.

The signatures follow one pattern: the data first, then ``path`` and ``title``, then keywords.
Trajectory figures take a :class:`Units` (``EXAMPLE1_UNITS`` or ``EXAMPLE2_UNITS``) for the axis
labels; :data:`PAPER_TITLES` holds the paper's captions, e.g.
``fig_output(traj, "fig1.png", PAPER_TITLES[1], EXAMPLE1_UNITS)``.

All figures tolerate a diverged (truncated) trajectory and NaN samples: NaNs are drawn as gaps,
the time axis always spans the full scheduled duration, and the divergence instant is marked.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .engine import Trajectory
from .outputs import atomic_path

FIG_WIDTH_PX = 1200
"""Width of every PNG written here, in pixels."""
FIG_HEIGHT_PX = 800
"""Height of every PNG written here, in pixels."""
FIG_DPI = 150
"""Resolution used to render; the figure size in inches is ``(FIG_WIDTH_PX, FIG_HEIGHT_PX) / FIG_DPI``."""

LOG_FLOOR = 1e-18
"""Default floor of the log-scale difference plot: exact zeros (and anything smaller) are drawn here."""

PAPER_TITLES: dict[int, str] = {
    1: "Fig. 1. Output y and reference $y_d$ (Example 1)",
    2: "Fig. 2. Tracking error $y - y_d$ (Example 1)",
    3: r"Fig. 3. Estimated parameter $\hat{\xi}$ (Example 1)",
    4: "Fig. 4. Control input with quantized states (Example 1)",
    5: "Fig. 5. Output y of the proposed scheme and the method of [20], and $y_d$ (Example 2)",
    6: "Fig. 6. Tracking error $y - y_d$ of the proposed scheme and the method of [20] (Example 2)",
    7: r"Fig. 7. Estimated parameters $\hat{\varepsilon}_i$, i = 1, 2, 3 (Example 2)",
    8: "Fig. 8. Control input with state quantization (Example 2)",
}
"""The paper's figure captions (numbered as in the paper), usable as ``title`` arguments."""

# Colour-blind-safe palette (Okabe-Ito); the reference is always drawn dashed black.
_COLORS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000")
_REF_STYLE = {"color": "black", "linestyle": "--", "linewidth": 1.2}


@dataclass(frozen=True)
class Units:
    """Physical units for axis labels of trajectory figures.

    ``y``: output (``x_1``), ``u``: control input, ``adaptive``: the adaptive estimates
    (dimensionless gains for the proposed law, hence ``"-"`` by default), ``t``: time.
    """

    y: str
    u: str
    adaptive: str = "-"
    t: str = "s"


EXAMPLE1_UNITS = Units(y="m", u="N/kg")
"""Example 1 (robot on a rail): position [m], force per unit mass [N/kg]."""
EXAMPLE2_UNITS = Units(y="rad", u="rad/s$^2$")
"""Example 2 (one-link arm): angle [rad], torque per unit inertia [rad/s^2]."""


# --------------------------------------------------------------------------------------------
# Internals
# --------------------------------------------------------------------------------------------


def _new_figure(rows: int = 1, cols: int = 1, **subplot_kw) -> tuple[Figure, np.ndarray]:
    """A constrained-layout figure of the fixed size on its own Agg canvas, with its axes array."""
    fig = Figure(figsize=(FIG_WIDTH_PX / FIG_DPI, FIG_HEIGHT_PX / FIG_DPI), dpi=FIG_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, **subplot_kw)
    return fig, axes


def _save(fig: Figure, path: str | os.PathLike) -> Path:
    """Write ``fig`` as a PNG to ``path`` atomically (missing folders are created)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=FIG_DPI)
    return target


def _unit(unit: str) -> str:
    return f" [{unit}]" if unit else ""


def _time_axis(ax: Axes, trajs: Sequence[Trajectory], units: Units) -> None:
    """Label the time axis and make it span the longest scheduled duration (truncation stays visible)."""
    ax.set_xlabel(f"t{_unit(units.t)}")
    end = max((tr.duration for tr in trajs if np.isfinite(tr.duration) and tr.duration > 0), default=None)
    if end is not None:
        ax.set_xlim(0.0, end)
    ax.grid(True, alpha=0.3)


def _mark_divergence(ax: Axes, traj: Trajectory, name: str = "", color: str = "red") -> None:
    """A dotted vertical line at the instant a diverged run stopped, labelled for the legend."""
    if not traj.diverged:
        return
    when = traj.diverged_time
    if when is None or not np.isfinite(when):
        when = float(traj.t[-1]) if len(traj.t) else 0.0
    who = f"{name} " if name else ""
    ax.axvline(when, color=color, linestyle=":", linewidth=1.5, label=f"{who}diverged at t = {when:.3g} s")


def _finite_or_note(ax: Axes, *arrays: np.ndarray) -> None:
    """Write a note on axes whose data are all NaN/Inf (otherwise the panel would just be empty)."""
    if not any(np.isfinite(np.asarray(a, dtype=float)).any() for a in arrays):
        ax.text(0.5, 0.5, "no finite samples", transform=ax.transAxes, ha="center", va="center", color="gray")


def _legend(ax: Axes, **kw) -> None:
    handles, _ = ax.get_legend_handles_labels()
    if handles:
        ax.legend(loc=kw.pop("loc", "best"), framealpha=0.85, fontsize=kw.pop("fontsize", 9), **kw)


def _finish(fig: Figure, ax: Axes, trajs: Sequence[Trajectory], units: Units, title: str,
            path: str | os.PathLike) -> Path:
    """The common end of a time-series figure: time axis, title, legend, atomic save."""
    _time_axis(ax, trajs, units)
    ax.set_title(title)
    _legend(ax)
    return _save(fig, path)


def _omega_band(ax: Axes, omega: float | None) -> None:
    if omega is not None and np.isfinite(omega) and omega > 0:
        ax.axhspan(-omega, omega, color="gray", alpha=0.12, label=rf"$|z_1| \leq \omega$ = {omega:g}")


def _adaptive_labels(traj: Trajectory, count: int) -> list[str]:
    symbol = {"eps_hat": r"\hat{\varepsilon}", "theta_hat": r"\hat{\theta}", "xi_hat": r"\hat{\xi}"}
    base = symbol.get(traj.adaptive_name)
    if base is None:
        return [traj.adaptive_name if count == 1 else f"{traj.adaptive_name}_{i + 1}" for i in range(count)]
    if count == 1:
        return [f"${base}$"]
    return [f"${base}_{{{i + 1}}}$" for i in range(count)]


def _column(values: np.ndarray, index: int) -> np.ndarray:
    """Column ``index`` of a time-major array as float (a 1-D array is its own column 0)."""
    arr = np.asarray(values, dtype=float)
    return arr if arr.ndim == 1 else arr[:, index]


def _reference(*trajs: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y_d)`` from the longest of the trajectories (a diverged one may be truncated)."""
    longest = max(trajs, key=lambda tr: len(tr.t))
    return np.asarray(longest.t, dtype=float), _column(longest.yd, 0)


# --------------------------------------------------------------------------------------------
# Single-run figures (paper Figs. 1-4, 7, 8)
# --------------------------------------------------------------------------------------------


def fig_output(traj: Trajectory, path: str | os.PathLike, title: str, units: Units) -> Path:
    """Fig. 1: output ``y = x_1`` and the reference ``y_d`` against time."""
    fig, axes = _new_figure()
    ax = axes[0, 0]
    t_ref, yd = _reference(traj)
    ax.plot(t_ref, yd, label="$y_d$ (reference)", **_REF_STYLE)
    ax.plot(traj.t, traj.y, color=_COLORS[0], linewidth=1.5, label="y (output)")
    _mark_divergence(ax, traj)
    _finite_or_note(ax, traj.y, yd)
    ax.set_ylabel(f"y, $y_d${_unit(units.y)}")
    return _finish(fig, ax, [traj], units, title, path)


def fig_tracking_error(
    traj: Trajectory, path: str | os.PathLike, title: str, units: Units, omega: float | None = None
) -> Path:
    """Fig. 2: tracking error ``z_1 = y - y_d``; ``omega`` optionally shades ``|z_1| <= omega``."""
    fig, axes = _new_figure()
    ax = axes[0, 0]
    _omega_band(ax, omega)
    ax.axhline(0.0, color="black", linewidth=0.6)
    ax.plot(traj.t, _column(traj.z, 0), color=_COLORS[0], linewidth=1.5, label="$z_1 = y - y_d$")
    _mark_divergence(ax, traj)
    _finite_or_note(ax, _column(traj.z, 0))
    ax.set_ylabel(f"$y - y_d${_unit(units.y)}")
    return _finish(fig, ax, [traj], units, title, path)


def fig_adaptive(
    traj: Trajectory,
    path: str | os.PathLike,
    title: str,
    units: Units,
    labels: Sequence[str] | None = None,
) -> Path:
    """Fig. 3 / Fig. 7: the adaptive estimates, one line per component.

    ``labels`` name the components (mathtext allowed, e.g. ``[r"$\\hat{\\xi}$"]`` for Fig. 3);
    by default they follow ``traj.adaptive_name`` (``eps_hat`` -> epsilon-hat_i, ``theta_hat`` ->
    theta-hat_i).
    """
    fig, axes = _new_figure()
    ax = axes[0, 0]
    adaptive = np.asarray(traj.adaptive, dtype=float)
    if adaptive.ndim == 1:
        adaptive = adaptive[:, None]
    count = adaptive.shape[1]
    names = list(labels) if labels is not None else _adaptive_labels(traj, count)
    if len(names) != count:
        raise ValueError(f"fig_adaptive: {len(names)} label(s) for {count} adaptive component(s)")
    for i in range(count):
        ax.plot(traj.t, adaptive[:, i], color=_COLORS[i % len(_COLORS)], linewidth=1.5, label=names[i])
    _mark_divergence(ax, traj)
    _finite_or_note(ax, adaptive)
    what = "estimate" if count == 1 else "estimates"
    ax.set_ylabel(f"adaptive {what}{_unit(units.adaptive)}")
    return _finish(fig, ax, [traj], units, title, path)


def fig_input(traj: Trajectory, path: str | os.PathLike, title: str, units: Units) -> Path:
    """Fig. 4 / Fig. 8: the control input ``u`` (held over each step) against time."""
    fig, axes = _new_figure()
    ax = axes[0, 0]
    ax.plot(traj.t, np.asarray(traj.u, dtype=float), color=_COLORS[0], linewidth=1.2, label="u")
    _mark_divergence(ax, traj)
    _finite_or_note(ax, traj.u)
    ax.set_ylabel(f"u{_unit(units.u)}")
    return _finish(fig, ax, [traj], units, title, path)


# --------------------------------------------------------------------------------------------
# Comparison figures (paper Figs. 5, 6)
# --------------------------------------------------------------------------------------------

DEFAULT_METHOD_LABELS = ("proposed", "method of [20]")


def fig_compare_output(
    proposed: Trajectory,
    comparison: Trajectory,
    path: str | os.PathLike,
    title: str,
    units: Units,
    labels: tuple[str, str] = DEFAULT_METHOD_LABELS,
) -> Path:
    """Fig. 5: output ``y`` of the proposed and the comparison method, with ``y_d``."""
    fig, axes = _new_figure()
    ax = axes[0, 0]
    t_ref, yd = _reference(proposed, comparison)
    ax.plot(t_ref, yd, label="$y_d$ (reference)", **_REF_STYLE)
    for traj, label, color in zip((proposed, comparison), labels, _COLORS, strict=False):
        ax.plot(traj.t, traj.y, color=color, linewidth=1.5, label=f"y, {label}")
        _mark_divergence(ax, traj, label, color=color)
    _finite_or_note(ax, proposed.y, comparison.y, yd)
    ax.set_ylabel(f"y, $y_d${_unit(units.y)}")
    return _finish(fig, ax, [proposed, comparison], units, title, path)


def fig_compare_error(
    proposed: Trajectory,
    comparison: Trajectory,
    path: str | os.PathLike,
    title: str,
    units: Units,
    labels: tuple[str, str] = DEFAULT_METHOD_LABELS,
    omega: float | None = None,
) -> Path:
    """Fig. 6: tracking errors ``y - y_d`` of both methods; ``omega`` optionally shades ``|z_1| <= omega``."""
    fig, axes = _new_figure()
    ax = axes[0, 0]
    _omega_band(ax, omega)
    ax.axhline(0.0, color="black", linewidth=0.6)
    for traj, label, color in zip((proposed, comparison), labels, _COLORS, strict=False):
        ax.plot(traj.t, _column(traj.z, 0), color=color, linewidth=1.5, label=f"$y - y_d$, {label}")
        _mark_divergence(ax, traj, label, color=color)
    _finite_or_note(ax, _column(proposed.z, 0), _column(comparison.z, 0))
    ax.set_ylabel(f"$y - y_d${_unit(units.y)}")
    return _finish(fig, ax, [proposed, comparison], units, title, path)


# --------------------------------------------------------------------------------------------
# Backend overlay (MuJoCo vs its ODE twin)
# --------------------------------------------------------------------------------------------


def output_difference(first: Trajectory, second: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """``(t, |y_first - y_second|)`` over the instants both runs cover.

    On a common time grid the rows are compared directly; otherwise ``second`` is linearly
    interpolated onto ``first``'s instants (finite samples only). NaN where either is undefined.
    """
    t1, y1 = np.asarray(first.t, dtype=float), np.asarray(first.y, dtype=float)
    t2, y2 = np.asarray(second.t, dtype=float), np.asarray(second.y, dtype=float)
    common = min(len(t1), len(t2))
    if common and np.allclose(t1[:common], t2[:common], rtol=0.0, atol=1e-9 * max(1.0, abs(t1[-1]))):
        return t1[:common], np.abs(y1[:common] - y2[:common])
    ok = np.isfinite(t2) & np.isfinite(y2)
    other = np.full_like(t1, np.nan)
    if ok.sum() >= 2:
        inside = (t1 >= t2[ok][0]) & (t1 <= t2[ok][-1])
        other[inside] = np.interp(t1[inside], t2[ok], y2[ok])
    return t1, np.abs(y1 - other)


def fig_backend_overlay(
    mujoco: Trajectory,
    ode: Trajectory,
    path: str | os.PathLike,
    title: str,
    units: Units,
    labels: tuple[str, str] = ("MuJoCo", "ODE"),
    floor: float = LOG_FLOOR,
) -> Path:
    """A MuJoCo run and its ODE twin: ``y`` of both (and ``y_d``) on top, ``|y_1 - y_2|`` below.

    The difference is drawn on a log axis; values below ``floor`` (in particular exact zeros of
    bit-identical runs) are clipped to ``floor``, which the axis label and legend state.
    """
    if not (np.isfinite(floor) and floor > 0):
        raise ValueError(f"fig_backend_overlay: floor must be a finite number > 0, got {floor!r}")
    fig, axes = _new_figure(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    top, bottom = axes[0, 0], axes[1, 0]
    t_ref, yd = _reference(mujoco, ode)
    top.plot(t_ref, yd, label="$y_d$", color="gray", linestyle="--", linewidth=1.0)
    top.plot(mujoco.t, mujoco.y, color=_COLORS[0], linewidth=2.2, label=f"y, {labels[0]}")
    top.plot(ode.t, ode.y, color=_COLORS[1], linewidth=1.1, linestyle="-", label=f"y, {labels[1]}")
    for traj, label, color in zip((mujoco, ode), labels, _COLORS, strict=False):
        _mark_divergence(top, traj, label, color=color)
    _finite_or_note(top, mujoco.y, ode.y)
    top.set_ylabel(f"y{_unit(units.y)}")
    top.grid(True, alpha=0.3)
    top.set_title(title)
    _legend(top)

    t_diff, diff = output_difference(mujoco, ode)
    finite = np.isfinite(diff)
    below = int(np.count_nonzero(diff[finite] < floor))
    clipped = np.where(finite, np.maximum(diff, floor), np.nan)
    note = f"{below} of {int(finite.sum())} samples below floor" if below else "none below floor"
    bottom.semilogy(t_diff, clipped, color=_COLORS[2], linewidth=1.2, label=f"|difference| ({note})")
    bottom.axhline(floor, color="gray", linestyle=":", linewidth=1.0, label=f"floor {floor:.0e}")
    if not finite.any():
        _finite_or_note(bottom, diff)
        bottom.set_ylim(floor, 1.0)
    else:
        top_value = float(np.nanmax(clipped))
        bottom.set_ylim(floor / 10.0, max(top_value * 10.0, floor * 100.0))
    bottom.set_ylabel(f"|y({labels[0]}) - y({labels[1]})|{_unit(units.y)}\nlog scale, clipped at {floor:.0e}")
    _time_axis(bottom, [mujoco, ode], units)
    _legend(bottom, fontsize=8)
    return _save(fig, path)


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
    or an ``r`` scale; use ``xscale="log"`` for a geometric sweep) or strings, which are placed as
    categories (e.g. plant variants). ``paper_rates`` (omega key -> rate, the paper's proposed
    row) are drawn as dashed horizontal lines in the colour of that omega; ``markers`` (label ->
    x) as dotted vertical lines, e.g. ``{"paper: kappa - L = 1.1": 1.1}``.
    """
    categorical = any(isinstance(v, str) for v in x_values)
    xs = np.arange(len(x_values), dtype=float) if categorical else np.asarray(x_values, dtype=float)
    fig, axes = _new_figure()
    ax = axes[0, 0]
    for i, (key, values) in enumerate(rates.items()):
        ys = np.array([np.nan if v is None else float(v) for v in values], dtype=float)
        if ys.shape != xs.shape:
            raise ValueError(f"fig_sensitivity: {len(ys)} rate(s) for omega {key} but {len(xs)} x value(s)")
        color = _COLORS[i % len(_COLORS)]
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
        _finite_or_note(ax, np.array([np.nan]))
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(r"error rate E($\omega$) = fraction of samples with $|z_1| > \omega$")
    ax.grid(True, alpha=0.3)
    ax.set_title(title)
    _legend(ax, fontsize=8)
    return _save(fig, path)


def fig_table1(
    table: Mapping[str, Mapping[str, Mapping[str, float | None]]],
    path: str | os.PathLike,
    title: str = r"Table 1. Error rate E($\omega$) (Example 2): ours vs the paper",
) -> Path:
    """Grouped bar chart of Table 1: one panel per method, bars per omega for every source.

    ``table`` maps method (e.g. ``"proposed"``, ``"comparison"``) -> source (e.g. ``"paper"``,
    ``"MuJoCo"``, ``"ODE"``) -> omega key -> rate. Each panel has its own y scale (the two methods
    differ by a factor ~40); missing / NaN rates are left out and marked "n/a".
    """
    methods = list(table)
    if not methods:
        raise ValueError("fig_table1: the table is empty")
    fig, axes = _new_figure(1, len(methods))
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
                color=_COLORS[s % len(_COLORS)],
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
        ax.set_ylim(0.0, max(top * 1.3, 1e-3))
        ax.grid(True, axis="y", alpha=0.3)
        ax.set_title(f"{method} method")
        _legend(ax, fontsize=8, loc="upper right")
    fig.suptitle(title)
    return _save(fig, path)


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
    "fig_sensitivity",
    "fig_table1",
    "fig_tracking_error",
    "output_difference",
]
