"""Metrics of a run: the paper's error rate (Table 1), the Lemma 2 check, boundedness figures."""

from __future__ import annotations

import numpy as np

from .engine import RunRecord, Trajectory
from .engine.velocity import lemma2_applies
from .error_rate import TABLE1_OMEGAS, error_rate, omega_key
from .summary import Summary

LEMMA2_TOLERANCE = 1e-9  # rounding slack on |e_zi| / L_zi <= 1

__all__ = ["LEMMA2_TOLERANCE", "TABLE1_OMEGAS", "backend_deviation", "error_rate", "finite_max_abs",
           "lemma2_max_ratio", "omega_key", "run_summary", "summary"]


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


def summary(run: RunRecord, scenario: str, backend: str) -> dict:
    """The ``summary.json`` object of a run: :func:`run_summary`'s :meth:`Summary.to_json`."""
    return run_summary(run, scenario, backend).to_json()


def run_summary(run: RunRecord, scenario: str, backend: str) -> Summary:
    """The :class:`~qcontrol.summary.Summary` of a run (docs/commands.md, `qcontrol run`, lists its keys).

    The metrics are the reductions of the signal table, the same whether the run kept every row
    or only its metrics. The Lemma 2 check covers every instant before a divergence: the row that
    stopped a diverged run holds an out-of-range state (NaN, Inf, or beyond ``state_bound``,
    possibly so large that ``x / delta`` has no fractional digits left), where quantization error
    is meaningless. With the velocity differenced from the encoder (``velocity_source =
    "difference"``) the controller's x2 is no quantized reading and Lemma 2 does not apply: the
    ratio is still reported, with ``lemma2_applies`` false; likewise with a logarithmic quantizer
    (no constant bounds its error), when a reading saturated at its channel's range, and on a plant
    outside the chain of eq. (1) (a strict-feedback plant with regressors before its last
    equation), for which Lemma 2's bounds were not derived.
    """
    values = run.reduced()
    final = tuple(float(v) for v in values["final_adaptive"])
    sensors = sensor_figures(run, values)
    bounds = bound_constants(run.bound_names, values["bound_constants"], values["smallest_r"])
    bounds["warnings"] = bounds["warnings"] + sensors.pop("warnings")
    return Summary(
        scenario=scenario, backend=backend, duration=run.duration, dt=run.dt, steps=run.steps,
        wall_time_s=run.wall_time_s, diverged=bool(run.diverged), diverged_time=run.diverged_time,
        divergence_reason=run.divergence_reason, error_rate=values["error_rate"],
        max_abs_z1_last_half=values["max_abs_z1_last_half"], max_abs_u=values["max_abs_u"],
        max_abs_u_applied=values["max_abs_u_applied"], saturated_fraction=values["saturated_fraction"],
        final_eps_hat=final, adaptive_state=run.adaptive_name,  # final_eps_hat: alias of final_state
        lemma2_max_ratio=lemma2_max_ratio(values["e_z_max"][None, :], run.L_z),
        velocity_source=run.velocity_source,
        lemma2_applies=(lemma2_applies(run.velocity_source) and run.quantizer_sector is None
                        and not sensors.get("reading_saturated_fraction") and run.chain),
        L_z=tuple(float(v) for v in run.L_z), L=float(run.L_z[-1]),
        **bounds, law_diagnostics=law_diagnostics(run.law_diagnostics, values["diagnostics"]),
        final_state=final, **sensors, law_failure=run.law_failure,
    )


def sensor_figures(run: RunRecord, values: dict) -> dict:
    """What the sensors of a ``[quantizer]`` table add to the summary, each only where it applies:
    the share of readings that saturated at a channel's range (with a warning when there were
    any: Lemma 2's bounds do not hold at those instants), a logarithmic quantizer's sector bound,
    and the input quantizer's largest error and share of changed samples."""
    out: dict = {"warnings": ()}
    if run.reading_range:
        share = values["reading_saturated_fraction"]
        out["reading_saturated_fraction"] = share
        if share > 0:
            out["warnings"] = (f"readings saturated at their channel's range at {share:.3%} of the "
                               "samples: there the quantization error exceeds delta_i / 2 and Lemma 2's "
                               "bounds no longer hold",)
    if run.quantizer_sector is not None:
        out["quantizer_sector"] = run.quantizer_sector
    if run.quantized_input:
        out["max_abs_input_quantization_error"] = values["max_abs_input_quantization_error"]
        out["input_quantized_fraction"] = values["input_quantized_fraction"]
    return out


def law_diagnostics(diagnostics: tuple, reduced: dict[str, np.ndarray]) -> dict:
    """The law's declared diagnostics as the summary reports them: ``<reduce>_<name>`` (e.g.
    ``max_gain_period``), a number for a diagnostic of width 1, else a list; None where the run
    had no finite value."""
    out, first = {}, 0
    for d in diagnostics:
        values = [float(v) if np.isfinite(v) else None for v in reduced[d.reduce][first : first + d.width]]
        out[d.summary_key] = values[0] if d.width == 1 else values
        first += d.width
    return out


def bound_constants(names: tuple[str, ...], largest: np.ndarray, smallest_r: np.ndarray) -> dict:
    """The separation (37)-(43) as the run measured it: ``bound_constants`` maps each term to the
    largest ``|term| / r(x_q)`` seen (None where it was infinite or undefined: the term is not
    bounded by its r on the run), and ``warnings`` says so in words. Both None/empty
    (``bound_constants`` absent from ``summary.json``) when the separation was not checked (a law
    without r, or terms in t). Where a bounding function went below 1 at some row
    (``smallest_r``: each r_i's smallest value), ``r_below_one`` maps its term to that value and a
    warning says so; the key is there only then."""
    if not names:
        return {"bound_constants": None, "warnings": ()}
    constants = {name: float(v) if np.isfinite(v) else None for name, v in zip(names, largest, strict=True)}
    warnings = [f"{name} is not bounded by its r on this run: |{name}| / r(x_q) was infinite or undefined "
                "(eqs. (37)-(43) need |term(x)| <= constant * r(x_q) wherever |x - x_q| <= delta/2)"
                for name, value in constants.items() if value is None]
    below = {name: float(v) for name, v in zip(names, smallest_r, strict=True) if v < 1}
    warnings += [f"the bounding function r of {name} went below 1 on this run (down to {value:.4g}): eqs. "
                 "(37)-(43) need r_i(x_q) >= 1 wherever the run goes; make r larger there, e.g. 1 + ..."
                 for name, value in below.items()]
    return {"bound_constants": constants, "warnings": tuple(warnings), "r_below_one": below or None}


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
