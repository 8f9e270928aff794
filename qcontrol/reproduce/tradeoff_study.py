"""The reproduction's trade-off study: tracking against the region of attraction, law by law.

On both examples, at 1 kHz, side by side on the same quantized readings: the paper's law (44)-(45)
as printed, its exact hold, the comparison law (46), the tuning-function law of adaptive
backstepping (the chain of eq. (1) is a strict-feedback plant whose regressors all sit in the
last row) and the plain linear law u = alphabar_n (:mod:`qcontrol.controller.linear`), at the
scenario's gains and at high gains. Each law gets Table 1's error rates E(0.100) .. E(0.200) from
the scenario's x(0) over the reproduction's horizon (the paper's 10 s unless shortened) and the
number of starts of the region study's grid it fails from (docs/paper.md, 'The trade-off').

Nothing is measured twice: the region study (:mod:`.region_study`) has mapped the first three
laws at 1 kHz on the same grid already, and its rows and maps are taken as they are; this study
runs the other laws through the same :func:`~.region_study.measure_at`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..paper import OMEGA_KEYS, PAPER_HORIZON
from ..region import OUTCOMES, LawSpec, parse_law
from ..region.study import Region
from ..scenario import load_scenario
from .region_study import BOX, EXAMPLES, LAWS, RATES, measure_at, region_record, region_study, study_grid

CONTROL_PERIOD, GRID_DURATION = RATES[0]  # 1 kHz, the paper's sampling of its examples
HIGH_GAINS = "[20.0, 20.0]"  # c1 = c2 = 20: for n = 2 the PD gains kp = c1 c2 = 400, kd = c1 + c2 = 40
ADDED = (LawSpec("tuning"), LawSpec("linear"), LawSpec("linear", (("c", HIGH_GAINS),)))
NAMES = {  # short enough for a map's title
    "proposed": "paper's law (44)",
    "proposed:hold=exact": "(44) exact hold",
    "comparison": "comparison (46)",
    "tuning": "tuning function",
    "linear": "linear, paper's c",
    f"linear:c={HIGH_GAINS}": "linear, kp 400, kd 40",
}
EQUATIONS = {
    "proposed": "(44)-(45): u = alphabar_n - K zbar_n, K = s eps_hat^T r(x_q) / (kappa (kappa - L))",
    "proposed:hold=exact": "(44) with K replaced by (1 - exp(-K T)) / T; (45)",
    "comparison": "(46): u = alphabar_n - psi(x_q) - theta_hat^T phi(x_q), "
                  "theta_hat' = Gamma phi(x_q) zbar_n",
    "tuning": "tuning functions: u = alpha_n + y_d^(n), theta_hat' = Gamma tau_n (psi and phi as regressors)",
    "linear": "u = alphabar_n of (31)-(34) with the scenario's c (for n = 2: kp = c1 c2, kd = c1 + c2)",
    f"linear:c={HIGH_GAINS}": "u = alphabar_n of (31)-(34) with c = [20, 20]: kp = 400, kd = 40",
}
TRADEOFF_HEADING = "## The trade-off: tracking against the region of attraction (ODE; beyond the paper)"
# The tuning law adapts to regressors: Example 1's psi = 0.1 x2^2 is given to it as theta^T phi in
# the last row (the same plant); Example 2's terms are regressors already.
REGRESSOR_FORM = {"example1": (('plant.phi=["x2**2"]', "plant.theta=[0.1]"), ("plant.psi",))}


def _changes(name: str, kind: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The scenario changes a law of ``kind`` runs with on example ``name`` (overrides, keys unset)."""
    return REGRESSOR_FORM.get(name, ((), ())) if kind == "tuning" else ((), ())


def check_tradeoff(scenarios: Path) -> None:
    """Load every scenario the study adds to the region study's (bad input creates nothing)."""
    for name in EXAMPLES:
        for law in ADDED:
            overrides, unset = _changes(name, law.kind)
            load_scenario(scenarios / f"{name}.toml", [*overrides, *law.overrides()], list(unset))


def tradeoff_study(scenarios: Path, duration: float | None, log: Callable[[str], None],
                   region: Mapping[str, Any] | None = None, resolution: int | None = None,
                   grid_duration: float = GRID_DURATION) -> dict[str, Any]:
    """Every law of the study on both examples at 1 kHz (module docstring). ``region``: the region
    study's result (:func:`~.region_study.region_study`), whose 1 kHz rows and maps are reused (its
    grid and grid duration then apply); without it every law is measured here, on a grid of
    ``resolution`` (default the region study's) with runs of ``grid_duration``. Returns what
    tradeoff.json holds (without provenance) and the maps (``maps``, a list per example)."""
    if region is not None:
        resolution, grid_duration = region["resolution"], region["rates"][0]["grid_duration"]
    grid = study_grid(resolution) if resolution is not None else study_grid()
    rows: list[dict[str, Any]] = []
    maps: list[list] = []
    for name in EXAMPLES:
        path = scenarios / f"{name}.toml"
        measured = _reused(region, name) if region is not None else [
            measure_at(path, grid, [parse_law(t) for t in LAWS], CONTROL_PERIOD, grid_duration, duration)]
        done = {row["law"] for _, found in measured for row in found}
        groups: dict[tuple, list[LawSpec]] = {}  # the laws that run on the same scenario, together
        for law in ADDED:
            if law.label not in done:
                groups.setdefault(_changes(name, law.kind), []).append(law)
        for (overrides, unset), laws in groups.items():
            measured.append(measure_at(path, grid, laws, CONTROL_PERIOD, grid_duration, duration, overrides,
                                       unset))
        example_rows = [_named(row, _changes(name, row["law"].partition(":")[0])) for _, found in measured
                        for row in found]
        rows += example_rows
        example_maps = [m for reg, _ in measured for m in reg.maps()]  # a map per law, the rows' order
        maps.append([_titled(m, row) for m, row in zip(example_maps, example_rows, strict=True)])
        added = sum(len(laws) for laws in groups.values())
        log(f"study: trade-off on {name} at T = {CONTROL_PERIOD * 1e3:g} ms: {len(example_rows)} laws "
            f"({added} mapped here{'' if region is None else ', the others by the region study'})")
    return {"examples": list(EXAMPLES), "control_period": CONTROL_PERIOD, "grid_duration": grid_duration,
            "resolution": grid.resolution, "box": BOX, "omegas": list(OMEGA_KEYS),
            "horizon": PAPER_HORIZON if duration is None else duration,
            "laws": [{"law": r["law"], "name": r["name"], "equation": r["equation"]}
                     for r in rows if r["example"] == EXAMPLES[0]],
            "rows": rows, "maps": maps}


def maps_runs(scenarios: Path, duration: float | None, law_texts: Sequence[str]) -> dict[str, Any]:
    """The region study (``law_texts``: its laws) and this study after it, as plain data a worker
    process sends back: ``region`` (what region.json holds, without provenance), ``region_maps``
    (each region's maps), ``tradeoff`` (:func:`tradeoff_study`'s result) and ``log`` (the lines
    both studies logged, in order)."""
    lines: list[str] = []
    region = region_study(scenarios, duration, lines.append, law_texts)
    study = tradeoff_study(scenarios, duration, lines.append, region)
    return {"region": region_record(region), "region_maps": [r.maps() for r in region["regions"]],
            "tradeoff": study, "log": lines}


def _reused(region: Mapping[str, Any], name: str) -> list[tuple[Region, list[dict[str, Any]]]]:
    """The region study's 1 kHz map of example ``name`` and its rows."""
    found = [r for r in region["regions"]
             if r.scenario.name == name and r.scenario.simulation.period == CONTROL_PERIOD]
    rows = [r for r in region["rows"] if r["example"] == name and r["control_period"] == CONTROL_PERIOD]
    return [(found[0], rows)]


def _named(row: Mapping[str, Any], changes: tuple[Sequence[str], Sequence[str]]) -> dict[str, Any]:
    """A row of the study: the region study's row with the law's name, equation and scenario changes."""
    law = row["law"]
    overrides, unset = changes
    return {"example": row["example"], "law": law, "name": NAMES.get(law, law),
            "equation": EQUATIONS.get(law, "a law given with --law"),
            "scenario_changes": [*overrides, *(f"unset {key}" for key in unset)]} | {
        k: v for k, v in row.items() if k not in ("example", "law")}


def _titled(m: Any, row: Mapping[str, Any]) -> Any:
    """A map titled with its law's name and the starts it fails from."""
    return replace(m, title=f"{row['name']}: {row['failing_in_box']} of {row['points_in_box']} fail")


def tradeoff_record(study: Mapping[str, Any]) -> dict[str, Any]:
    """What tradeoff.json holds: everything but the maps' objects."""
    return {key: value for key, value in study.items() if key != "maps"}


def write_tradeoff_figure(study: Mapping[str, Any], path: Path) -> Path:
    """study_tradeoff.png: a row of region maps per example, a map per law, and the error rates."""
    from ..plots.tradeoff import fig_tradeoff  # matplotlib: imported only when a figure is drawn

    title = (f"Trade-off at T = {CONTROL_PERIOD * 1e3:g} ms: where each law holds ({study['resolution']} x "
             f"{study['resolution']} starts, |x_i(0)| <= {BOX:g}, {study['grid_duration']:g} s runs) and how "
             "well it tracks from x(0) (ODE)")
    return fig_tradeoff(study["maps"], study["rows"], OUTCOMES, path, title)


def tradeoff_section(study: Mapping[str, Any]) -> list[str]:
    """REPORT.md's section: the table, the figure, and what the numbers say."""
    horizon = (f"the paper's {PAPER_HORIZON:g} s" if study["horizon"] == PAPER_HORIZON else
               f"{study['horizon']:g} s (not the paper's {PAPER_HORIZON:g} s: not comparable with Table 1)")
    lines = [
        TRADEOFF_HEADING,
        "",
        f"Every law on the same quantized readings at T = {study['control_period'] * 1e3:g} ms: Table 1's "
        f"E(omega) from the scenario's x(0) over {horizon}, and the starts of the region study's "
        f"{study['resolution']} x {study['resolution']} grid over |x_i(0)| <= {study['box']:g} "
        f"({study['grid_duration']:g} s runs) from which it fails (diverges, or breaks a Lemma 2 bound). "
        "The linear law u = alphabar_n is law (44) without its robust term and adaptation; with "
        "c = [20, 20] it is the PD law kp = 400, kd = 40 with the reference's feedforward. The "
        "tuning-function law is given Example 1's psi as a regressor of its last row (the same plant).",
        "",
        "| example | law | " + " | ".join(f"E({w})" for w in study["omegas"])
        + " | fail in box | max abs(u) from x(0) |",
        "|---|---|" + "---|" * (len(study["omegas"]) + 2),
    ]
    for r in study["rows"]:
        e = r["error_rate"]
        u = r["max_abs_u_from_x0"]
        lines.append(f"| {r['example']} | {r['name']} | " + " | ".join(f"{e[w]:.4f}" for w in study["omegas"])
                     + f" | {r['failing_in_box']} of {r['points_in_box']} | "
                     + ("diverged" if r["diverged_from_x0"] else f"{u:.3g}") + " |")
    lines += ["", "![trade-off](study_tradeoff.png)", "", *_reading(study), ""]
    return lines


def _reading(study: Mapping[str, Any]) -> list[str]:
    """What the table says, in the numbers measured: Example 2's paper's law against the high-gain
    linear law and the exact hold, Example 1's price of high gains, the linear law at the paper's c."""
    rows = {(r["example"], r["law"]): r for r in study["rows"]}
    high_label = f"linear:c={HIGH_GAINS}"
    wanted = [(example, law) for example in EXAMPLES
              for law in ("proposed", "proposed:hold=exact", "linear", high_label)]
    if not all(key in rows for key in wanted):
        return []
    paper, exact = rows[("example2", "proposed")], rows[("example2", "proposed:hold=exact")]
    same, high = rows[("example2", "linear")], rows[("example2", high_label)]
    paper1, high1 = rows[("example1", "proposed")], rows[("example1", high_label)]
    n = paper["points_in_box"]

    def e(row: Mapping[str, Any]) -> str:
        return f"{row['error_rate']['0.100']:.4f}"

    return [
        f"* **Tracking is cheap, holding is not.** On Example 2 the high-gain linear law reaches "
        f"E(0.100) = {e(high)} where the paper's law as printed gives {e(paper)}, with an input of up to "
        f"{high['max_abs_u_from_x0']:.3g} against {paper['max_abs_u_from_x0']:.3g}; it fails from "
        f"{high['failing_in_box']} of {n} starts, the paper's law from {paper['failing_in_box']}, its "
        f"exact hold from {exact['failing_in_box']}.",
        f"* **Where the terms are mild, the price is the input.** On Example 1 (psi = 0.1 x2^2) the "
        f"high-gain linear law fails from {high1['failing_in_box']} of {high1['points_in_box']} starts "
        f"(the paper's law from {paper1['failing_in_box']}) and reaches E(0.100) = {e(high1)} against "
        f"{e(paper1)}, with an input of up to {high1['max_abs_u_from_x0']:.3g} against "
        f"{paper1['max_abs_u_from_x0']:.3g}.",
        f"* **What the paper's law buys.** At the paper's gains c the linear law gives E(0.100) = "
        f"{e(same)} on Example 2 and fails from {same['failing_in_box']} of {n} starts: the error rates "
        "follow the gains c and kappa (the kappa - L study above), while the robust term, held exactly, "
        "is what holds every start of the box, the sampled counterpart of Theorem 1's bound for every "
        "initial state.",
    ]
