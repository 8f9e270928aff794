"""A sweep's results: one row per run (``sweep.csv``) and what the sweep was (``sweep.json``)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from typing import Any

from ..error_rate import TABLE1_OMEGAS, omega_key
from ..summary import Summary

RUN_METRICS = ["max_abs_z1_last_half", "max_abs_u", "diverged", "diverged_time", "lemma2_max_ratio"]
CSV_METRICS = [f"error_rate_{omega_key(w)}" for w in TABLE1_OMEGAS] + RUN_METRICS  # the paper's omegas


def metric_columns(summaries: Sequence[Summary]) -> list[str]:
    """The metric columns: an error rate per omega of the runs (``[metrics] omega``), then the run's
    figures, then the laws' own diagnostics as their summaries report them (``max_gain_period``;
    every column any run has, in the order first seen: a run whose law lacks one leaves it empty)."""
    if not summaries:
        return list(CSV_METRICS)
    diagnostics = dict.fromkeys(key for s in summaries for key in diagnostic_cells(s))
    return [f"error_rate_{key}" for key in summaries[0].error_rate] + RUN_METRICS + list(diagnostics)


def sweep_rows(points: Sequence[dict[str, str]], summaries: Sequence[Summary | None]) -> list[dict]:
    """One row per finished run: the varied keys, the error rates, and the run's figures."""
    rows = []
    for point, s in zip(points, summaries, strict=True):
        if s is None:  # not run (the sweep was interrupted)
            continue
        rows.append(dict(point) | metric_row(s))
    return rows


def metric_row(s: Summary) -> dict[str, Any]:
    """A run's metric columns: the error rate per omega (``error_rate_0.100``, ...), then
    :data:`RUN_METRICS`, then its law's diagnostics (:func:`diagnostic_cells`)."""
    return {f"error_rate_{key}": rate for key, rate in s.error_rate.items()} | {
        "max_abs_z1_last_half": s.max_abs_z1_last_half, "max_abs_u": s.max_abs_u,  # RUN_METRICS
        "diverged": s.diverged, "diverged_time": s.diverged_time, "lemma2_max_ratio": s.lemma2_max_ratio,
    } | diagnostic_cells(s)


def diagnostic_cells(s: Summary) -> dict[str, Any]:
    """The law's diagnostics of a run, one cell each: ``max_gain_period``, or ``last_<name>_1 ..``
    for a diagnostic of width > 1 (None where the run had no value)."""
    cells: dict[str, Any] = {}
    for key, value in s.law_diagnostics.items():
        if isinstance(value, list):
            cells |= {f"{key}_{i + 1}": v for i, v in enumerate(value)}
        else:
            cells[key] = value
    return cells


def csv_text(rows: Sequence[dict], keys: Sequence[str], metrics: Sequence[str]) -> str:
    """The table as CSV: varied keys, then the metrics; floats with repr precision."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[*keys, *metrics], lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (repr(v) if isinstance(v, float) else "" if v is None else v) for k,
                         v in row.items()})
    return buffer.getvalue()


def sweep_record(rows: Sequence[dict], total: int, grid: Sequence[tuple[str, list[str]]],
                 settings: dict[str, Any], wall_time_s: float, provenance: dict) -> dict:
    """``sweep.json``: what was swept and how it went (the rows themselves are in sweep.csv)."""
    ratios = [r["lemma2_max_ratio"] for r in rows if r["lemma2_max_ratio"] is not None
              and math.isfinite(r["lemma2_max_ratio"])]
    return {
        "grid": {key: values for key, values in grid},
        **settings,
        "runs": total,
        "runs_finished": len(rows),
        "interrupted": len(rows) < total,
        "diverged": sum(bool(r["diverged"]) for r in rows),
        "lemma2_max_ratio": max(ratios, default=None),
        "wall_time_s": wall_time_s,
        "csv": "sweep.csv",
        "provenance": provenance,
    }
