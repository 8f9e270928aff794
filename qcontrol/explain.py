"""What a run's summary says beyond its numbers: why a diverged run stopped and what usually helps,
and, for a scenario of the paper, what the paper reports for it and where the difference is
explained.

A scenario says which of the paper's examples it reproduces (``[scenario] paper_example``); the
paper's numbers live in :mod:`qcontrol.paper`. Nothing here branches on a file name.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from .controller import law_kind
from .engine.divergence import DOMAIN_ERROR
from .paper import OMEGA_KEYS, PAPER_TABLE1, PAPER_TABLE1_ROWS
from .scenario import Scenario

README_SECTION = "README.md, section 'Reproducing the paper'"
GAIN_PERIOD_LIMIT = 1.0  # K T above this: the held input overshoots the continuous-time decay
SAMPLED_WARNING = ("the sampled loop is outside the range where it behaves like the paper's "
                   "continuous-time law")


def gain_period_lines(s: Mapping) -> list[str]:
    """The gain-period monitor of a law that declares one (``max_gain_period``): its value, and a
    warning once K T > 1. Nothing for a law without it."""
    if "max_gain_period" not in s:
        return []
    value = s["max_gain_period"]
    shown = "n/a" if value is None else f"{value:.4g}"
    lines = [f"  sampled loop: max K T = {shown} (the robust gain K of law (44) times the control period T)"]
    if value is not None and value > GAIN_PERIOD_LIMIT:
        lines.append(f"  warning: K T reached {value:.4g} > {GAIN_PERIOD_LIMIT:g}: {SAMPLED_WARNING}")
    return lines


def divergence_lines(s: Mapping, sc: Scenario) -> list[str]:
    """Two lines for a diverged run: when and why it stopped, and what usually helps."""
    lines = [f"  DIVERGED: stopped at t = {s['diverged_time']:g} s of {sc.simulation.duration:g} s: "
             f"{s['divergence_reason']}"]
    if s["divergence_reason"].endswith(DOMAIN_ERROR):  # a term's domain, which no step size fixes
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


def paper_line(s: Mapping, sc: Scenario) -> str | None:
    """One line with what the paper reports for this scenario, or None for a scenario that does
    not reproduce one of the paper's examples."""
    if sc.paper_example is None:
        return None
    if sc.paper_example == 1:
        return ("  paper: Example 1 is shown in Figs. 1-4 without numbers (qcontrol reproduce draws ours "
                f"beside them); see {README_SECTION}")
    row = PAPER_TABLE1_ROWS.get(sc.controller.kind)
    if row is None:
        return f"  paper: Table 1 has no row for controller kind {sc.controller.kind!r}; see {README_SECTION}"
    rates = "  ".join(f"E({w})={PAPER_TABLE1[row][w]:.4f}" for w in OMEGA_KEYS)
    horizon = "" if math.isclose(s["duration"], 10.0) else f" (over T = 10 s; this run: {s['duration']:g} s)"
    return f"  paper, Table 1, {row} law: {rates}{horizon}; why ours differs: {README_SECTION}"
