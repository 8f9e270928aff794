"""The sensor study of ``qcontrol reproduce``: the paper's Example 2 with realistic sensors.

The paper quantizes both states with one uniform step of 0.01 and infinitely many levels. A real
arm reads its angle with an encoder (12 bits over a turn: a step of 2 pi / 4096 = 0.00153 rad)
and its velocity with a coarser signal (here 0.05 rad/s), each over a finite range. The study
runs Example 2's proposed law (ODE backend, like the other studies) with the paper's quantizer
beside such sensor sets, one change at a time, and states per row whether the theory's Lemma 2
covers the run: it does with any finite steps (L then follows each channel's bound), not where a
reading saturated at its range, not with a logarithmic quantizer (no constant bounds its error),
and the input's quantization is outside it altogether. Writes ``sensors.json``,
``study_sensors.png`` and a section of REPORT.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..assembly import run_scenario
from ..engine import Trajectory
from ..metrics import LEMMA2_TOLERANCE, run_summary
from ..plots.common import COLORS, new_figure, save
from ..scenario import load_scenario
from ..summary import Summary

ENCODER = 2 * math.pi / 4096  # rad: a 12-bit angle encoder over one turn
VELOCITY_STEP = 0.05  # rad/s: a coarser velocity channel
RANGE = (math.pi, 20.0)  # rad, rad/s: what the sensors can read
STEPS = f"[{ENCODER!r}, {VELOCITY_STEP!r}]"
# (label, the [quantizer] keys as overrides); every row but the first leaves controller.delta out
ROWS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("paper: uniform, delta = 0.01 on both, no range", ()),
    ("12-bit angle, 0.05 rad/s velocity", (f"quantizer.delta={STEPS}",)),
    ("... with the sensors' range (pi rad, 20 rad/s)",
     (f"quantizer.delta={STEPS}", f"quantizer.range=[{RANGE[0]!r}, {RANGE[1]!r}]")),
    ("... with a range the arm leaves (0.5 rad)",
     (f"quantizer.delta={STEPS}", f"quantizer.range=[0.5, {RANGE[1]!r}]")),
    ("hysteresis, the same steps", ('quantizer.kind="hysteresis"', f"quantizer.delta={STEPS}")),
    ("logarithmic, rho = 0.9, u_min = 0.001",
     ('quantizer.kind="logarithmic"', "quantizer.rho=0.9", "quantizer.u_min=0.001")),
    ("12-bit sensors and a 12-bit input (200 N m / 4096)",
     (f"quantizer.delta={STEPS}", f"quantizer.range=[{RANGE[0]!r}, {RANGE[1]!r}]",
      f"quantizer.input.delta={200.0 / 4096!r}")),
)
OMEGA = "0.100"


def applicability(s: Summary) -> str:
    """What the theory says of a run, in words: whether Lemma 2 covers it and held."""
    if s.quantizer_sector is not None:
        return f"Lemma 2 does not apply (logarithmic: sector bound xi = {s.quantizer_sector:.4g})"
    if s.reading_saturated_fraction:
        share = 100 * s.reading_saturated_fraction
        return f"Lemma 2 does not hold where readings saturated ({share:.3g}% of the samples)"
    held = "held" if s.lemma2_max_ratio <= 1 + LEMMA2_TOLERANCE else "VIOLATED"
    quantized = s.max_abs_input_quantization_error is not None
    extra = "; the input's quantization is outside the theory" if quantized else ""
    return f"Lemma 2 applies, L = {s.L:.4g}: {held}{extra}"


@dataclass(frozen=True)
class Traces:
    """What the study's figure draws of a run (plain arrays: a worker process may send them):
    its instants, z1 and the angle channel's quantization error x1 - q(x1)."""

    t: np.ndarray
    z1: np.ndarray
    angle_error: np.ndarray

    @classmethod
    def of(cls, traj: Trajectory) -> Traces:
        return cls(traj.t, traj.z[:, 0], traj.x_meas[:, 0] - traj.x_q[:, 0])


def sensor_study(scenarios: Path, duration: float | None, log: Callable[[str], None]) -> dict:
    """Every row of :data:`ROWS` on the ODE backend: ``{"rows": [...], "traces": [...]}`` (a
    :class:`Traces` per row)."""
    study = sensor_runs(scenarios, duration)
    log_rows(study, log)
    return study


def sensor_runs(scenarios: Path, duration: float | None) -> dict:
    """:func:`sensor_study` without its log (a worker process's entry point)."""
    rows, traces = [], []
    extra = [f"simulation.duration={duration!r}"] if duration is not None else []
    for label, keys in ROWS:
        unset = ["controller.delta"] if keys else []
        sc = load_scenario(scenarios / "example2.toml", [*keys, *extra], unset=unset)
        traj = run_scenario(sc, "ode")
        s = run_summary(traj, sc.name, "ode")
        rows.append({"label": label, "overrides": list(keys), "unset": unset, "summary": s,
                     "theory": applicability(s)})
        traces.append(Traces.of(traj))
    return {"rows": rows, "traces": traces}


def log_rows(study: Mapping, log: Callable[[str], None]) -> None:
    """A line per row: its E(0.100) and Lemma 2 ratio."""
    for row in study["rows"]:
        s = row["summary"]
        log(f"  sensors: {row['label']}: E({OMEGA}) = {s.error_rate[OMEGA]:.4f}, Lemma 2 ratio "
            f"{s.lemma2_max_ratio:.4g}")


def sensor_record(study: Mapping) -> dict:
    """sensors.json: each row's label, overrides, statement and summary."""
    return {"rows": [{k: (v.to_json() if k == "summary" else v) for k, v in row.items()}
                     for row in study["rows"]]}


def _number(value: float | None, digits: int = 4) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}g}"


def sensor_markdown(study: Mapping) -> list[str]:
    """The study's section of REPORT.md: one row per sensor set."""
    lines = [
        "## Realistic sensors (Example 2, proposed law, ODE backend; beyond the paper)", "",
        "The paper's quantizer beside the sensors a real arm has: a 12-bit angle encoder "
        f"({ENCODER:.4g} rad), a coarser velocity channel ({VELOCITY_STEP} rad/s), finite ranges, "
        "hysteresis, a logarithmic quantizer, a quantized input. L follows each channel's "
        "worst-case error (docs/math.md, 'Sensors beyond the paper: a quantizer per channel').", "",
        f"| sensors | L | E({OMEGA}) | E(0.200) | max \\|z1\\| last half | max \\|u\\| | Lemma 2 ratio | "
        "readings saturated | max \\|q_u(u) - u\\| | what the theory says |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in study["rows"]:
        s: Summary = row["summary"]
        share = s.reading_saturated_fraction
        saturated = "-" if share is None else f"{100 * share:.3g}%"
        lines.append(
            f"| {row['label']} | {_number(s.L)} | {s.error_rate[OMEGA]:.4f} | {s.error_rate['0.200']:.4f} | "
            f"{_number(s.max_abs_z1_last_half, 3)} | {_number(s.max_abs_u, 3)} | "
            f"{_number(s.lemma2_max_ratio)} | {saturated} | "
            f"{_number(s.max_abs_input_quantization_error, 3)} | {row['theory']} |")
    return [*lines, "", "![sensor study](study_sensors.png)", ""]


def fig_sensors(study: Mapping, path: str | Path) -> Path:
    """z1(t) of every row (top) and the quantization error of the angle channel (bottom)."""
    fig, axes = new_figure(2, 1, sharex=True)
    top, bottom = axes[0, 0], axes[1, 0]
    for i, (row, traces) in enumerate(zip(study["rows"], study["traces"], strict=True)):
        color = COLORS[i % len(COLORS)]
        _trace(top, traces, traces.z1, row["label"], color)
        _trace(bottom, traces, traces.angle_error, None, color)
    top.set_ylabel("z1 = y - y_d")
    top.legend(fontsize=7, loc="upper right")
    top.set_title("Example 2 with realistic sensors (proposed law, ODE)")
    bottom.set_ylabel("x1 - q(x1) [rad]")
    bottom.set_xlabel("t [s]")
    bottom.set_ylim(-0.03, 0.03)
    return save(fig, path)


def _trace(ax, traces: Traces, values: np.ndarray, label: str | None, color: str) -> None:
    ax.plot(traces.t, values, color=color, linewidth=0.8, label=label)
