"""Metrics of a run: the paper's error rate (Table 1), the Lemma 2 check, boundedness figures."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .sim import Trajectory

TABLE1_OMEGAS = (0.100, 0.125, 0.150, 0.175, 0.200)
TABLE1_SAMPLES = 1302


def omega_key(omega: float) -> str:
    """Key of an error-rate entry in JSON outputs: ``0.1 -> "0.100"``."""
    return f"{omega:.3f}"


def error_rate(
    t: np.ndarray,
    z1: np.ndarray,
    horizon: float,
    omegas: Sequence[float] = TABLE1_OMEGAS,
    samples: int = TABLE1_SAMPLES,
) -> dict[str, float]:
    """Error rate of Table 1: ``E(omega) = #{i : |z_1(t_i)| > omega} / M``.

    ``t_i = i T / (M - 1)``, ``i = 0..M-1`` over ``T = horizon`` (SPEC 9). ``z_1`` between recorded
    instants is interpolated linearly (it is continuous). Sample instants after the end of a
    diverged run count as exceeding every omega.
    """
    if samples < 2:
        raise ValueError("the error rate needs at least 2 samples")
    instants = np.arange(samples) * (horizon / (samples - 1))
    finite = np.isfinite(z1)
    t_ok, z_ok = t[finite], np.abs(z1[finite])
    covered = instants <= (t_ok[-1] + 1e-12 if t_ok.size else -np.inf)
    values = np.full(samples, np.inf)
    if t_ok.size:
        values[covered] = np.interp(instants[covered], t_ok, z_ok)
    return {omega_key(w): float(np.count_nonzero(values > w)) / samples for w in omegas}


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


def summary(traj: Trajectory, scenario: str, backend: str) -> dict:
    """The ``summary.json`` object of DESIGN's output contract (plus diverged_time/reason).

    The Lemma 2 check covers every instant before a divergence: the row that stopped a diverged
    run holds an out-of-range state (NaN, Inf, or beyond ``state_bound``, possibly so large that
    ``x / delta`` has no fractional digits left), where quantization error is meaningless.
    """
    last_half = traj.t >= traj.duration / 2.0
    z1_last_half = traj.z[last_half, 0] if last_half.any() else np.array([np.nan])
    final = traj.adaptive[-1]
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
        "error_rate": error_rate(traj.t, traj.z[:, 0], traj.duration),
        "max_abs_z1_last_half": finite_max_abs(z1_last_half),
        "max_abs_u": finite_max_abs(traj.u),
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
