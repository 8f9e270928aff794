"""What every figure shares: the fixed size, the colours, the units of the axes, and the helpers
that make, finish and save a figure atomically."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..engine import Trajectory
from ..outputs import FIGURE_FORMATS, write_file

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
    5: "Fig. 5. Output y of the proposed scheme and the comparison law of [20], and $y_d$ (Example 2)",
    6: "Fig. 6. Tracking error $y - y_d$ of the proposed scheme and the comparison law of [20] (Example 2)",
    7: r"Fig. 7. Estimated parameters $\hat{\varepsilon}_i$, i = 1, 2, 3 (Example 2)",
    8: "Fig. 8. Control input with state quantization (Example 2)",
}
"""The paper's figure captions (numbered as in the paper), usable as ``title`` arguments."""

# Colour-blind-safe palette (Okabe-Ito); the reference is always drawn dashed black.
COLORS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000")
REF_STYLE = {"color": "black", "linestyle": "--", "linewidth": 1.2}


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


def new_figure(rows: int = 1, cols: int = 1, **subplot_kw) -> tuple[Figure, np.ndarray]:
    """A constrained-layout figure of the fixed size on its own Agg canvas, with its axes array."""
    fig = Figure(figsize=(FIG_WIDTH_PX / FIG_DPI, FIG_HEIGHT_PX / FIG_DPI), dpi=FIG_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, **subplot_kw)
    return fig, axes


_NO_LAYOUT = {"figure.autolayout": False, "figure.constrained_layout.use": False}  # settings: no engine


def save(fig: Figure, path: str | os.PathLike) -> Path:
    """Write ``fig`` to ``path`` atomically, as PNG, PDF or SVG by its suffix (PNG for any other
    suffix; the command line refuses those before the run); missing folders are created. The
    figure is laid out once (twice where a title had to be wrapped, :func:`fit_titles`) and drawn
    once, as laid out: while it is written it has no layout engine at all, since matplotlib draws
    a figure that has one (even the "none" placeholder) once more, unseen, before drawing it
    (about a sixth of a figure's CPU time, for the same pixels)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fit_titles(fig)
    suffix = target.suffix.lower()
    kind = suffix[1:] if suffix in FIGURE_FORMATS else "png"
    engine = fig.get_layout_engine()
    if engine is not None:
        with rc_context(_NO_LAYOUT):  # (no engine: not the one the settings would choose)
            fig.set_layout_engine(None)
    try:
        return write_file(target, lambda handle: fig.savefig(handle, format=kind, dpi=FIG_DPI))
    finally:
        if engine is not None:
            fig.set_layout_engine(engine)


def fit_titles(fig: Figure, most_lines: int = 4) -> None:
    """Lay ``fig`` out (its layout engine, if any), then wrap each title (its axes' and its
    suptitle) that runs past the figure's edges onto as few lines as keep it inside (at most
    ``most_lines``) and, if one was wrapped, lay it out again: constrained layout then makes room
    for the extra lines. Only the titles' text changes, never what is drawn."""
    renderer = fig.canvas.get_renderer()
    suptitle = fig._suptitle  # matplotlib keeps the Text of fig.suptitle here (None without one)
    titles = [ax.title for ax in fig.axes if ax.title.get_text()] + ([] if suptitle is None else [suptitle])
    engine = fig.get_layout_engine()
    if engine is not None:
        engine.execute(fig)  # where each title is drawn
    wrapped = False
    for title in titles:
        text = title.get_text()
        for lines in range(2, most_lines + 1):
            box = title.get_window_extent(renderer)
            if box.x0 >= 0 and box.x1 <= fig.bbox.width:
                break
            title.set_text(wrap_title(text, lines))
            wrapped = True
    if wrapped and engine is not None:
        engine.execute(fig)


def wrap_title(text: str, lines: int) -> str:
    """``text`` on about ``lines`` lines of equal length, broken between words, never inside a
    ``$...$`` formula."""
    words: list[str] = []
    for word in text.split(" "):
        if words and words[-1].count("$") % 2:  # inside a formula: keep it one word
            words[-1] += " " + word
        else:
            words.append(word)
    target = len(text) / lines
    out = [words[0]]
    for word in words[1:]:
        longer = len(out[-1]) + 1 + len(word)
        if len(out) < lines and abs(longer - target) > abs(len(out[-1]) - target):  # break nearer target
            out.append(word)
        else:
            out[-1] += " " + word
    return "\n".join(out)


def unit(unit: str) -> str:
    return f" [{unit}]" if unit else ""


def time_axis(ax: Axes, trajs: Sequence[Trajectory], units: Units) -> None:
    """Label the time axis and make it span the longest scheduled duration (truncation stays visible)."""
    ax.set_xlabel(f"t{unit(units.t)}")
    end = max((tr.duration for tr in trajs if np.isfinite(tr.duration) and tr.duration > 0), default=None)
    if end is not None:
        ax.set_xlim(0.0, end)
    ax.grid(True, alpha=0.3)


def mark_divergence(ax: Axes, traj: Trajectory, name: str = "", color: str = "red") -> None:
    """A dotted vertical line at the instant a diverged run stopped, labelled for the legend."""
    if not traj.diverged:
        return
    when = traj.diverged_time
    if when is None or not np.isfinite(when):
        when = float(traj.t[-1]) if len(traj.t) else 0.0
    who = f"{name} " if name else ""
    ax.axvline(when, color=color, linestyle=":", linewidth=1.5, label=f"{who}diverged at t = {when:.3g} s")


def finite_or_note(ax: Axes, *arrays: np.ndarray) -> None:
    """Write a note on axes whose data are all NaN/Inf (otherwise the panel would just be empty)."""
    if not any(np.isfinite(np.asarray(a, dtype=float)).any() for a in arrays):
        ax.text(0.5, 0.5, "no finite samples", transform=ax.transAxes, ha="center", va="center", color="gray")


def legend(ax: Axes, **kw) -> None:
    handles, _ = ax.get_legend_handles_labels()
    if handles:
        ax.legend(loc=kw.pop("loc", "best"), framealpha=0.85, fontsize=kw.pop("fontsize", 9), **kw)


def finish(fig: Figure, ax: Axes, trajs: Sequence[Trajectory], units: Units, title: str,
            path: str | os.PathLike) -> Path:
    """The common end of a time-series figure: time axis, title, legend, atomic save."""
    time_axis(ax, trajs, units)
    ax.set_title(title)
    legend(ax)
    return save(fig, path)


def omega_band(ax: Axes, omega: float | None) -> None:
    if omega is not None and np.isfinite(omega) and omega > 0:
        ax.axhspan(-omega, omega, color="gray", alpha=0.12, label=rf"$|z_1| \leq \omega$ = {omega:g}")


def adaptive_labels(traj: Trajectory, count: int) -> list[str]:
    symbol = {"eps_hat": r"\hat{\varepsilon}", "theta_hat": r"\hat{\theta}", "xi_hat": r"\hat{\xi}"}
    base = symbol.get(traj.adaptive_name)
    if base is None:
        return [traj.adaptive_name if count == 1 else f"{traj.adaptive_name}_{i + 1}" for i in range(count)]
    if count == 1:
        return [f"${base}$"]
    return [f"${base}_{{{i + 1}}}$" for i in range(count)]


def column(values: np.ndarray, index: int) -> np.ndarray:
    """Column ``index`` of a time-major array as float (a 1-D array is its own column 0)."""
    arr = np.asarray(values, dtype=float)
    return arr if arr.ndim == 1 else arr[:, index]


def reference(*trajs: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y_d)`` from the longest of the trajectories (a diverged one may be truncated)."""
    longest = max(trajs, key=lambda tr: len(tr.t))
    return np.asarray(longest.t, dtype=float), column(longest.yd, 0)
