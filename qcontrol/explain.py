"""What a run's summary says beyond its numbers: why a diverged run stopped and what usually helps,
and, for a scenario of the paper, what the paper reports for it and where the difference is
explained.

A scenario says which of the paper's examples it reproduces (``[scenario] paper_example``); the
paper's numbers live in :mod:`qcontrol.paper`. Nothing here branches on a file name.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .controller import law_kind
from .engine.divergence import DOMAIN_ERROR
from .paper import OMEGA_KEYS, PAPER_TABLE1, PAPER_TABLE1_ROWS
from .resources import resolve_file, shipped_scenarios
from .scenario import Scenario
from .scenario.load import plain_data
from .summary import Summary

README_SECTION = "README.md, section 'Reproducing the paper'"
GAIN_PERIOD_DIAGNOSTIC = "max_gain_period"  # the summary's key of the paper's law's K T monitor
MONITORED_DIAGNOSTICS = (GAIN_PERIOD_DIAGNOSTIC,)  # the law diagnostics with lines of their own (below)
GAIN_PERIOD_LIMIT = 1.0  # K T above this: the held input overshoots the continuous-time decay
SAMPLED_WARNING = ("the sampled loop is outside the range where it behaves like the paper's "
                   "continuous-time law")


def gain_period_lines(s: Summary) -> list[str]:
    """The gain-period monitor of a law that declares one (its diagnostic ``max_gain_period``): its
    value, and a warning once K T > 1. Nothing for a law without it."""
    if GAIN_PERIOD_DIAGNOSTIC not in s.law_diagnostics:
        return []
    value = s.law_diagnostics[GAIN_PERIOD_DIAGNOSTIC]
    shown = "n/a" if value is None else f"{value:.4g}"
    lines = [f"  sampled loop: max K T = {shown} (the robust gain K of law (44) times the control period T)"]
    if value is not None and value > GAIN_PERIOD_LIMIT:
        lines.append(f"  warning: K T reached {value:.4g} > {GAIN_PERIOD_LIMIT:g}: {SAMPLED_WARNING}")
    return lines


def divergence_lines(s: Summary, sc: Scenario) -> list[str]:
    """Two lines for a diverged run: when and why it stopped, and what usually helps."""
    what = "THE LAW FAILED" if s.law_failure else "DIVERGED"
    lines = [f"  {what}: stopped at t = {s.diverged_time:g} s of {sc.simulation.duration:g} s: "
             f"{s.divergence_reason}"]
    if s.divergence_reason.endswith(DOMAIN_ERROR) or s.law_failure:  # no step size fixes these
        return lines
    helps = ["a smaller --dt or simulation.control_period"]
    hint = law_kind(sc.controller.kind).divergence_hint
    if hint:
        helps[0] += f": {hint}"
    helps.append(_region_note(sc))
    lines.append("  what usually helps: " + "; ".join(helps))
    return lines


def _region_note(sc: Scenario) -> str:
    """The command that measures the region of initial states this law holds at this period."""
    size = max(abs(v) for v in sc.x0)
    period = sc.simulation.period
    return (f"x(0) = {list(sc.x0)} (max |x_i(0)| = {size:g}) may lie outside the region this law holds at "
            f"T = {period:g} s: measure it with 'qcontrol region {sc.source}'")


def _leaves(table: Mapping, prefix: str = "") -> dict[str, Any]:
    """A scenario's values by dotted key (``controller.delta``); lists and arrays of tables are values."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, Mapping):
            out |= _leaves(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def _setting(data: Mapping, base_dir: Path, kind: str) -> dict[str, Any]:
    """What decides the numbers of a run of controller ``kind``: every value but the scenario's
    texts, the backend (both run the paper's model), the kind (it picks the row of Table 1) and the
    sections of the other kinds; file paths resolved. The kind's settings are named as the law
    reads them, ``controller.<key>``: from ``[controller.<kind>]``, unless ``[controller]`` gives
    the key directly (which overrides the sub-table)."""
    setting = {}
    leaves = _leaves(data)
    for key, value in leaves.items():
        parts = key.split(".")
        if parts[0] == "scenario" or key in ("simulation.backend", "controller.kind"):
            continue
        if parts[0] == "controller" and len(parts) > 2 and parts[1] != kind:
            continue
        if parts[0] == "controller" and len(parts) > 2:  # the chosen kind's sub-table
            key = f"controller.{'.'.join(parts[2:])}"
            if key in leaves:
                continue
        if parts[-1] == "model" and isinstance(value, str):
            value = resolve_file(value, base_dir)
        setting[key] = value
    return setting


def paper_setting_differences(sc: Scenario) -> list[str]:
    """How a run of a paper scenario leaves the paper's setting, as ``key = value (file: value)``:
    against the shipped file of the same name (the paper's setting as qcontrol reads it), else the
    shipped ``example<n>``. Empty when the run is in the paper's setting."""
    shipped = shipped_scenarios()
    path = shipped.get(sc.name)
    reference = tomllib.loads(path.read_text()) if path is not None else {}
    if reference.get("scenario", {}).get("paper_example") != sc.paper_example:
        path = shipped[f"example{sc.paper_example}"]
        reference = tomllib.loads(path.read_text())
    kind = sc.controller.kind
    paper, run = _setting(reference, path.parent, kind), _setting(plain_data(sc.data), sc.base_dir, kind)
    differences = []
    for key in sorted(set(paper) | set(run)):
        if paper.get(key) != run.get(key):
            ours = "unset" if key not in run else _shown(run[key])
            theirs = "unset" if key not in paper else _shown(paper[key])
            differences.append(f"{key} = {ours} ({path.name}: {theirs})")
    return differences


def _shown(value: Any) -> str:
    return value.name if isinstance(value, Path) else repr(value)


def paper_line(sc: Scenario) -> str | None:
    """One line with what the paper reports for this scenario, or None for a scenario that does
    not reproduce one of the paper's examples. A run that leaves the paper's setting (another
    delta, reference, horizon, sign of psi, ...) gets no paper numbers but what differs."""
    if sc.paper_example is None:
        return None
    differences = paper_setting_differences(sc)
    if differences:
        shown = "; ".join(differences[:4]) + (f"; and {len(differences) - 4} more" if len(differences) > 4
                                               else "")
        return (f"  paper: no numbers to compare: this run leaves the setting of the paper's Example "
                f"{sc.paper_example} in {shown}")
    if sc.paper_example == 1:
        return ("  paper: Example 1 is shown in Figs. 1-4 without numbers (qcontrol reproduce draws ours "
                f"beside them); see {README_SECTION}")
    row = PAPER_TABLE1_ROWS.get(sc.controller.kind)
    if row is None:
        return f"  paper: Table 1 has no row for controller kind {sc.controller.kind!r}; see {README_SECTION}"
    rates = "  ".join(f"E({w})={PAPER_TABLE1[row][w]:.4f}" for w in OMEGA_KEYS)
    return f"  paper, Table 1, {row} law: {rates}; why ours differs: {README_SECTION}"
