"""The figure of a law comparison: y and y_d, the tracking error z1 and the input u of every law on
the same scenario and backend, overlaid (one colour and one dash pattern per law, so that two laws
whose curves coincide both stay visible)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from ..engine import Trajectory
from .common import COLORS, REF_STYLE, Units, column, legend, new_figure, reference, save, unit

DASHES = ("-", "--", (0, (1, 1.5)), "-.")  # solid, dashed, dotted, dash-dot: law i's pattern


def fig_law_overlay(runs: Mapping[str, Trajectory], path: str | os.PathLike, title: str,
                    units: Units) -> Path:
    """Three panels, each law a colour and a dash pattern: y (with y_d), z1 = y - y_d, and u
    (held: steps), labelled in ``units``."""
    fig, grid = new_figure(3, 1)
    axes = grid.ravel()
    first = next(iter(runs.values()))
    t_ref, yd = reference(first)
    axes[0].plot(t_ref, yd, label="$y_d$", **REF_STYLE)
    for i, (kind, traj) in enumerate(runs.items()):
        style = {"color": COLORS[i % len(COLORS)], "linestyle": DASHES[i % len(DASHES)], "label": kind}
        axes[0].plot(traj.t, traj.y, linewidth=1.2, **style)
        axes[1].plot(traj.t, column(traj.z, 0), linewidth=1.2, **style)
        axes[2].step(traj.t, traj.signals["u"], where="post", linewidth=1.0, **style)
    labels = (f"y, $y_d${unit(units.y)}", f"$z_1 = y - y_d${unit(units.y)}", f"u{unit(units.u)}")
    for ax, label in zip(axes, labels, strict=True):
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        legend(ax, fontsize=7)
    axes[-1].set_xlabel(f"t{unit(units.t)}")
    fig.suptitle(title)
    return save(fig, path)
