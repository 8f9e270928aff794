"""Metrics of a run: the paper's error rate (Table 1), the Lemma 2 check, boundedness figures."""

from __future__ import annotations

import numpy as np

from .error_rate import TABLE1_OMEGAS, TABLE1_SAMPLES, error_rate, omega_key  # noqa: F401 (API)
from .sim import RunMetrics, Trajectory


def lemma2_max_ratio(e_z: np.ndarray, L_z: np.ndarray) -> float:
    """``max_{k,i} |e_zi(t_k)| / L_zi`` over finite rows; Lemma 2 promises <= 1."""
    ratio = e_z / L_z
    ratio = ratio[np.isfinite(ratio)]
    return float(ratio.max()) if ratio.size else float("nan")


def finite_max_abs(values: np.ndarray) -> float:
    """Largest finite absolute value (NaN when there is none)."""
    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v)]
    return float(v.max()) if v.size else float("nan")


def summary(traj: Trajectory | RunMetrics, scenario: str, backend: str) -> dict:
    """The ``summary.json`` object of DESIGN's output contract (plus diverged_time/reason).

    The Lemma 2 check covers every instant before a divergence: the row that stopped a diverged
    run holds an out-of-range state (NaN, Inf, or beyond ``state_bound``, possibly so large that
    ``x / delta`` has no fractional digits left), where quantization error is meaningless.
    """
    if isinstance(traj, RunMetrics):  # reduced while the run went on
        rates, z1_late = traj.error_rate, traj.max_abs_z1_last_half
        max_u, final = finite_max_abs(np.array([traj.max_abs_u])), traj.final_adaptive
    else:
        last_half = traj.t >= traj.duration / 2.0
        z1_late = finite_max_abs(traj.z[last_half, 0] if last_half.any() else np.array([np.nan]))
        rates = error_rate(traj.t, traj.z[:, 0], traj.duration)
        max_u, final = finite_max_abs(traj.u), traj.adaptive[-1]
    return {
        "scenario": scenario,
        "backend": backend,
        "duration": traj.duration,
        "dt": traj.dt,
        "steps": traj.steps,
        "wall_time_s": traj.wall_time_s,
        "diverged": bool(traj.diverged),
        "diverged_time": traj.diverged_time,
        "divergence_reason": traj.divergence_reason,
        "error_rate": rates,
        "max_abs_z1_last_half": z1_late,
        "max_abs_u": max_u,
        "final_eps_hat": [float(v) for v in final],
        "adaptive_state": traj.adaptive_name,
        "lemma2_max_ratio": lemma2_max_ratio(traj.lemma2_e_z, traj.L_z),
        "L_z": [float(v) for v in traj.L_z],
    }


def backend_deviation(physics: Trajectory, ideal: Trajectory) -> dict:
    """Largest differences between two runs of the same loop over their common rows.

    ``max_abs_dx`` (one entry per state), ``max_abs_dy``, ``max_abs_du`` and ``max_abs_deps``
    (the adaptive estimates). NaN where the runs share no finite rows.
    """
    rows = min(len(physics.t), len(ideal.t))
    if rows == 0 or not np.array_equal(physics.t[:rows], ideal.t[:rows]):
        raise ValueError("the two runs must share the same time grid")
    dx = np.abs(physics.x[:rows] - ideal.x[:rows])
    return {
        "rows_compared": rows,
        "max_abs_dx": [finite_max_abs(dx[:, i]) for i in range(dx.shape[1])],
        "max_abs_dy": finite_max_abs(dx[:, 0]),
        "max_abs_du": finite_max_abs(physics.u[:rows] - ideal.u[:rows]),
        "max_abs_deps": finite_max_abs(physics.adaptive[:rows] - ideal.adaptive[:rows]),
    }
