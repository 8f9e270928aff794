"""Figures of runs: the paper's Figs. 1-8 and a MuJoCo run beside its ODE twin."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..assembly import scene
from ..engine import Trajectory
from .common import (
    COLORS,
    EXAMPLE1_UNITS,
    EXAMPLE2_UNITS,
    LOG_FLOOR,
    REF_STYLE,
    Units,
    adaptive_labels,
    column,
    finish,
    finite_or_note,
    legend,
    mark_divergence,
    new_figure,
    omega_band,
    reference,
    save,
    time_axis,
    unit,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from ..scenario import Scenario

# --------------------------------------------------------------------------------------------
# Single-run figures (paper Figs. 1-4, 7, 8)
# --------------------------------------------------------------------------------------------


def fig_output(traj: Trajectory, path: str | os.PathLike, title: str, units: Units) -> Path:
    """Fig. 1: output ``y = x_1`` and the reference ``y_d`` against time."""
    fig, axes = new_figure()
    ax = axes[0, 0]
    t_ref, yd = reference(traj)
    ax.plot(t_ref, yd, label="$y_d$ (reference)", **REF_STYLE)
    ax.plot(traj.t, traj.y, color=COLORS[0], linewidth=1.5, label="y (output)")
    mark_divergence(ax, traj)
    finite_or_note(ax, traj.y, yd)
    ax.set_ylabel(f"y, $y_d${unit(units.y)}")
    return finish(fig, ax, [traj], units, title, path)


def fig_tracking_error(
    traj: Trajectory, path: str | os.PathLike, title: str, units: Units, omega: float | None = None
) -> Path:
    """Fig. 2: tracking error ``z_1 = y - y_d``; ``omega`` optionally shades ``|z_1| <= omega``."""
    fig, axes = new_figure()
    ax = axes[0, 0]
    omega_band(ax, omega)
    ax.axhline(0.0, color="black", linewidth=0.6)
    ax.plot(traj.t, column(traj.z, 0), color=COLORS[0], linewidth=1.5, label="$z_1 = y - y_d$")
    mark_divergence(ax, traj)
    finite_or_note(ax, column(traj.z, 0))
    ax.set_ylabel(f"$y - y_d${unit(units.y)}")
    return finish(fig, ax, [traj], units, title, path)


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
    fig, axes = new_figure()
    ax = axes[0, 0]
    adaptive = np.asarray(traj.adaptive, dtype=float)
    if adaptive.ndim == 1:
        adaptive = adaptive[:, None]
    count = adaptive.shape[1]
    names = list(labels) if labels is not None else adaptive_labels(traj, count)
    if len(names) != count:
        raise ValueError(f"fig_adaptive: {len(names)} label(s) for {count} adaptive component(s)")
    for i in range(count):
        ax.plot(traj.t, adaptive[:, i], color=COLORS[i % len(COLORS)], linewidth=1.5, label=names[i])
    mark_divergence(ax, traj)
    finite_or_note(ax, adaptive)
    what = "estimate" if count == 1 else "estimates"
    ax.set_ylabel(f"adaptive {what}{unit(units.adaptive)}")
    return finish(fig, ax, [traj], units, title, path)


def fig_input(traj: Trajectory, path: str | os.PathLike, title: str, units: Units) -> Path:
    """Fig. 4 / Fig. 8: the control input ``u`` (held over each step) against time."""
    fig, axes = new_figure()
    ax = axes[0, 0]
    ax.plot(traj.t, np.asarray(traj.u, dtype=float), color=COLORS[0], linewidth=1.2, label="u")
    mark_divergence(ax, traj)
    finite_or_note(ax, traj.u)
    ax.set_ylabel(f"u{unit(units.u)}")
    return finish(fig, ax, [traj], units, title, path)


# --------------------------------------------------------------------------------------------
# Comparison figures (paper Figs. 5, 6)
# --------------------------------------------------------------------------------------------

DEFAULT_METHOD_LABELS = ("proposed", "comparison law [20]")


@dataclass(frozen=True)
class MethodPair:
    """The two runs a comparison figure draws, the proposed law's first, with their legend labels."""

    proposed: Trajectory
    comparison: Trajectory
    labels: tuple[str, str] = DEFAULT_METHOD_LABELS

    @property
    def runs(self) -> list[Trajectory]:
        return [self.proposed, self.comparison]


def _methods_figure(pair: MethodPair, path: str | os.PathLike, title: str, units: Units, name: str,
                    values: Callable[[Trajectory], np.ndarray], ylabel: str,
                    background: Callable[[Axes], Sequence[np.ndarray]]) -> Path:
    """One line ``values(run)`` per method (labelled ``name, method``, its divergence marked) over
    what ``background`` draws first (it returns the arrays it drew, for the finite-values note)."""
    fig, axes = new_figure()
    ax = axes[0, 0]
    drawn = list(background(ax))
    for traj, label, color in zip(pair.runs, pair.labels, COLORS, strict=False):
        drawn.append(values(traj))
        ax.plot(traj.t, drawn[-1], color=color, linewidth=1.5, label=f"{name}, {label}")
        mark_divergence(ax, traj, label, color=color)
    finite_or_note(ax, *drawn)
    ax.set_ylabel(ylabel)
    return finish(fig, ax, pair.runs, units, title, path)


def _reference_line(pair: MethodPair, ax: Axes) -> list[np.ndarray]:
    t_ref, yd = reference(*pair.runs)
    ax.plot(t_ref, yd, label="$y_d$ (reference)", **REF_STYLE)
    return [yd]


def _band_and_zero(omega: float | None, ax: Axes) -> list[np.ndarray]:
    omega_band(ax, omega)
    ax.axhline(0.0, color="black", linewidth=0.6)
    return []


def _output(traj: Trajectory) -> np.ndarray:
    return traj.y


def _tracking_error(traj: Trajectory) -> np.ndarray:
    return column(traj.z, 0)


def fig_compare_output(proposed: Trajectory, comparison: Trajectory, path: str | os.PathLike, title: str,
                       units: Units, labels: tuple[str, str] = DEFAULT_METHOD_LABELS) -> Path:
    """Fig. 5: output ``y`` of the proposed and the comparison law, with ``y_d``."""
    pair = MethodPair(proposed, comparison, labels)
    return _methods_figure(pair, path, title, units, "y", _output, f"y, $y_d${unit(units.y)}",
                           partial(_reference_line, pair))


def fig_compare_error(proposed: Trajectory, comparison: Trajectory, path: str | os.PathLike, title: str,
                      units: Units, labels: tuple[str, str] = DEFAULT_METHOD_LABELS,
                      omega: float | None = None) -> Path:
    """Fig. 6: tracking errors ``y - y_d`` of both methods; ``omega`` optionally shades ``|z_1| <= omega``."""
    return _methods_figure(MethodPair(proposed, comparison, labels), path, title, units, "$y - y_d$",
                           _tracking_error, f"$y - y_d${unit(units.y)}", partial(_band_and_zero, omega))


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
    fig, axes = new_figure(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    top, bottom = axes[0, 0], axes[1, 0]
    t_ref, yd = reference(mujoco, ode)
    top.plot(t_ref, yd, label="$y_d$", color="gray", linestyle="--", linewidth=1.0)
    top.plot(mujoco.t, mujoco.y, color=COLORS[0], linewidth=2.2, label=f"y, {labels[0]}")
    top.plot(ode.t, ode.y, color=COLORS[1], linewidth=1.1, linestyle="-", label=f"y, {labels[1]}")
    for traj, label, color in zip((mujoco, ode), labels, COLORS, strict=False):
        mark_divergence(top, traj, label, color=color)
    finite_or_note(top, mujoco.y, ode.y)
    top.set_ylabel(f"y{unit(units.y)}")
    top.grid(True, alpha=0.3)
    top.set_title(title)
    legend(top)

    t_diff, diff = output_difference(mujoco, ode)
    finite = np.isfinite(diff)
    below = int(np.count_nonzero(diff[finite] < floor))
    clipped = np.where(finite, np.maximum(diff, floor), np.nan)
    note = f"{below} of {int(finite.sum())} samples below floor" if below else "none below floor"
    bottom.semilogy(t_diff, clipped, color=COLORS[2], linewidth=1.2, label=f"|difference| ({note})")
    bottom.axhline(floor, color="gray", linestyle=":", linewidth=1.0, label=f"floor {floor:.0e}")
    if not finite.any():
        finite_or_note(bottom, diff)
        bottom.set_ylim(floor, 1.0)
    else:
        top_value = float(np.nanmax(clipped))
        bottom.set_ylim(floor / 10.0, max(top_value * 10.0, floor * 100.0))
    bottom.set_ylabel(f"|y({labels[0]}) - y({labels[1]})|{unit(units.y)}\nlog scale, clipped at {floor:.0e}")
    time_axis(bottom, [mujoco, ode], units)
    legend(bottom, fontsize=8)
    return save(fig, path)


# --------------------------------------------------------------------------------------------
# The standard figure of one run (qcontrol run --plot)
# --------------------------------------------------------------------------------------------

GENERIC_UNITS = Units(y="", u="")


def scenario_units(sc: Scenario) -> Units:
    """The units of a scenario's axes: its MuJoCo joint's (a hinge: rad, and u in rad/s^n; a slide:
    m, and u in N/kg at n = 2), else those of the plant's own x1 (u: x1's n-th derivative, eq.
    (1)). With an input gain b other than 1, u is the actuator's own input (x1's n-th derivative
    is b u): drawn without a unit."""
    drawn = scene(sc)
    position = "x$_1$ unit" if drawn is None else "rad" if drawn.hinge else "m"
    if sc.terms.b != 1.0:
        return Units(y=position, u="")
    if drawn is not None and sc.order == 2:
        return EXAMPLE2_UNITS if drawn.hinge else EXAMPLE1_UNITS
    return Units(y=position, u=f"{position}/s$^{sc.order}$")


def fig_run(traj: Trajectory, path: str | os.PathLike, title: str, units: Units = GENERIC_UNITS,
            notes: Sequence[str] = ()) -> Path:
    """One run on one page: y and y_d, the tracking error z_1, the input u (held: steps), the
    adaptive estimates and the Lemma 2 ratio max_i |e_zi| / L_zi against its bound 1, plus
    ``notes`` (e.g. the summary's figures) in the sixth panel."""
    fig, axes = new_figure(3, 2)
    t_ref, yd = reference(traj)
    panels = axes.ravel()
    panels[0].plot(t_ref, yd, label="$y_d$", **REF_STYLE)
    panels[0].plot(traj.t, traj.y, color=COLORS[0], linewidth=1.3, label="y")
    panels[0].set_ylabel(f"y, $y_d${unit(units.y)}")
    panels[1].axhline(0.0, color="black", linewidth=0.6)
    panels[1].plot(traj.t, column(traj.z, 0), color=COLORS[0], linewidth=1.3, label="$z_1 = y - y_d$")
    panels[1].set_ylabel(f"$z_1${unit(units.y)}")
    panels[2].step(traj.t, traj.u, where="post", color=COLORS[0], linewidth=1.0, label="u")
    panels[2].set_ylabel(f"u{unit(units.u)}")
    adaptive = np.asarray(traj.adaptive, dtype=float).reshape(len(traj.t), -1)
    for i, name in enumerate(adaptive_labels(traj, adaptive.shape[1])):
        panels[3].plot(traj.t, adaptive[:, i], color=COLORS[i % len(COLORS)], linewidth=1.3, label=name)
    panels[3].set_ylabel(f"adaptive state{unit(units.adaptive)}")
    t_env, envelope = _lemma2_envelope(traj)
    panels[4].step(t_env, envelope, where="post", color=COLORS[1], linewidth=1.0,
                   label=r"max$_i$ |$e_{zi}$| / $L_{zi}$ (max per window)")
    panels[4].axhline(1.0, color="red", linestyle="--", linewidth=1.0, label="Lemma 2 bound")
    panels[4].set_ylim(0.0, 1.25)
    panels[4].set_ylabel("Lemma 2 ratio [-]")
    for ax in panels[:5]:
        mark_divergence(ax, traj)
        time_axis(ax, [traj], units)
        legend(ax, fontsize=7, loc="best")
    panels[5].axis("off")
    panels[5].text(0.0, 1.0, "\n".join(notes), va="top", ha="left", family="monospace", fontsize=7,
                   transform=panels[5].transAxes)
    fig.suptitle(title)
    return save(fig, path)


def _lemma2_envelope(traj: Trajectory, windows: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """``max_i |e_zi| / L_zi`` as its maximum over ``windows`` equal windows of rows (the ratio
    changes every step: drawn row by row it is a solid band)."""
    with np.errstate(all="ignore"):
        ratio = np.max(np.asarray(traj.e_z, dtype=float) / traj.L_z, axis=1) if len(traj.t) else np.array([])
    size = max(1, -(-len(ratio) // windows))
    starts = np.arange(0, len(ratio), size)
    if not len(starts):
        return starts.astype(float), ratio
    with np.errstate(all="ignore"):
        return traj.t[starts], np.fmax.reduceat(ratio, starts)
