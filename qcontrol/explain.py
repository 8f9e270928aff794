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
from .paper import OMEGA_KEYS, PAPER_TABLE1, PAPER_TABLE1_ROWS
from .scenario import Scenario

README_SECTION = "README.md, section 'Reproducing the paper'"
# The initial states from which the proposed law stayed bounded (and Lemma 2 held) in every one of
# eight directions, the axes and the diagonals, on the ODE at dt = 1 ms over 10 s, as measured by
# tools/global_claim.py: max_i |x_i(0)| up to this value. Keyed by scenario name and controller
# kind; they hold for the files as shipped.
MEASURED_REGION = {("example1", "proposed"): 9.6, ("example2", "proposed"): 2.0}
MEASURED_DT = 1e-3


def divergence_lines(s: Mapping, sc: Scenario) -> list[str]:
    """Two lines for a diverged run: when and why it stopped, and what usually helps."""
    lines = [f"  DIVERGED: stopped at t = {s['diverged_time']:g} s of {sc.simulation.duration:g} s: "
             f"{s['divergence_reason']}"]
    helps = ["a smaller --dt or simulation.control_period"]
    hint = law_kind(sc.controller.kind).divergence_hint
    if hint:
        helps[0] += f": {hint}"
    region = _region_note(sc)
    if region:
        helps.append(region)
    lines.append("  what usually helps: " + "; ".join(helps))
    return lines


def _region_note(sc: Scenario) -> str:
    """How far x(0) lies outside the region tools/global_claim.py measured for this scenario."""
    limit = MEASURED_REGION.get((sc.name, sc.controller.kind))
    period = sc.simulation.control_period or sc.simulation.dt
    if limit is None or not math.isclose(period, MEASURED_DT):
        return ""
    size = max(abs(v) for v in sc.x0)
    if size <= limit:
        return (f"x(0) = {list(sc.x0)} lies within max |x_i(0)| <= {limit:g}, where tools/global_claim.py "
                f"measured {sc.name} as shipped to stay bounded at dt = 1 ms: a changed setting made the "
                "difference")
    return (f"x(0) = {list(sc.x0)} has max |x_i(0)| = {size:g}, {size / limit:.3g} times the {limit:g} up "
            f"to which tools/global_claim.py measured {sc.name} to stay bounded at dt = 1 ms in every "
            "direction: start closer to the origin")


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
