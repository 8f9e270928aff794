"""``qcontrol reproduce``: the paper's Figures 1-8 and Table 1, side by side with ours.

Runs Example 1 and Example 2 (proposed law and the comparison law of reference [20]) on the
chosen backend, with the ideal ODE twin beside MuJoCo, then the sensitivity studies (kappa - L,
a constant scale of r, plant variants) on the ODE backend, and the robustness study on realistic
hardware (:mod:`.robustness_study`, MuJoCo, in worker processes, started first so that it runs
while this process does the rest; the region, trade-off and sensor studies' runs go to the same
workers, first, and the examples' and studies' figures are drawn by forked workers,
:mod:`.drawing`). Writes PNG figures, ``table1.md``, ``table1.json``, ``studies.json``,
``region.json`` (the sampled loop's region study, :mod:`.region_study`), ``tradeoff.json``
(tracking against the region, law by law, :mod:`.tradeoff_study`), ``robustness.json``,
``sensors.json`` (Example 2 with realistic sensors, :mod:`.sensor_study`), ``REPORT.md`` and one
rerun recording per example into the output folder, all put in place together at the end
(:func:`qcontrol.outputs.staged`): an interrupted or failed reproduction leaves the folder's
previous files as they were, never a mix of old and new. Parameters come from the paper's Section 4
(docs/math.md, 'The paper's examples'); nothing is fitted to Table 1. Laws of one's own (``laws``,
``--law KIND``) join Table 1's json as entries not from the paper, and the region and robustness
studies, beside the two built-in laws.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from .. import plots
from ..api import observer_for, recording_for
from ..assembly import Assembly, assemble, runnable_backend
from ..controller import lemma2_L
from ..controller.law import KIND_ALIASES, LAW_KINDS
from ..engine import Trajectory
from ..errors import QcontrolInputError, QcontrolLawFailure
from ..metrics import backend_deviation, run_summary
from ..outputs import check_output_dir, output_dir, staged, write_json, write_text
from ..plants import BACKENDS
from ..resources import shipped_dir
from ..scenario import Scenario, load_scenario
from ..scenario.resolve import scenario_provenance, scenarios_provenance
from ..summary import Summary
from ..sweep import sweep_summaries
from ..sweep.runs import planned
from .drawing import Apart
from .region_study import LAWS as REGION_LAWS
from .region_study import write_region_study
from .report import (
    PAPER_HORIZON,
    PAPER_TABLE1,
    ReportFacts,
    beyond_the_paper,
    report_markdown,
    table1,
    table1_markdown,
)
from .robustness_figures import fig_margins, fig_robustness
from .robustness_study import EXAMPLES, LAWS, Running, default_workers, runs_alone, study_law
from .robustness_study import started as robustness_started
from .sensor_study import fig_sensors, log_rows, sensor_markdown, sensor_record, sensor_runs, sensor_study
from .tradeoff_study import check_tradeoff, maps_runs, tradeoff_record, write_tradeoff_figure

SCENARIO_DIR = shipped_dir("scenarios")
KAPPA_MARGINS = (0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.1, 1.5, 2.0)
R_SCALES = (1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 50.0, 100.0)
PLANT_VARIANTS = (
    ("canonical", "example2", ()),
    ("theta2 = +3.5", "example2", ("plant.theta=[-1.0, 3.5, -34.3]",)),
    ("rigid pendulum", "example2-rigid", ()),
)
COMPARISON = ("controller.kind=comparison",)
BUILT_IN_LAWS = ("proposed", "comparison")  # in every study; --law adds others beside them
ROBUSTNESS_SCENARIOS = tuple(name for pair in EXAMPLES for name in pair)


@dataclass
class Run:
    """One closed-loop run of the reproduction."""

    label: str
    scenario: Scenario
    backend: str
    traj: Trajectory
    summary: Summary
    assembly: Assembly


@dataclass
class Reproduction:
    """Runs and bookkeeping of one ``qcontrol reproduce``."""

    out: Path
    backend: str = "mujoco"
    duration: float | None = None
    scenarios: Path = SCENARIO_DIR
    log: Callable[[str], None] = print
    command: str = ""
    laws: tuple[str, ...] = ()  # controller kinds studied beside the built-in laws (--law)
    runs: list[Run] = field(default_factory=list)
    started: float = field(default_factory=time.perf_counter)
    study_runs: int = 0
    lemma2_ratios: list[float] = field(default_factory=list)
    diverged: list[str] = field(default_factory=list)
    law_failures: list[str] = field(default_factory=list)  # a law written in Python failed in these runs

    def scenario(self, name: str, overrides: Sequence[str] = ()) -> Scenario:
        extra = [f"simulation.duration={self.duration!r}"] if self.duration is not None else []
        return load_scenario(self.scenarios / f"{name}.toml", [*overrides, *extra])

    def run(self, label: str, sc: Scenario, backend: str) -> Run:
        asm = assemble(sc, backend)
        traj = asm.run()[0]
        run = Run(label, sc, backend, traj, run_summary(traj, sc.name, backend), asm)
        self.runs.append(run)
        self.lemma2_ratios.append(run.summary.lemma2_max_ratio)
        if run.summary.diverged:
            self.diverged.append(f"{label} on {backend}")
        if run.summary.law_failure:
            self.law_failures.append(run.summary.law_failure)
        self.log(f"  {label} on {backend}: E(0.100) = {run.summary.error_rate['0.100']:.4f}, "
                 f"Lemma 2 ratio {run.summary.lemma2_max_ratio:.5f} "
                 f"({time.perf_counter() - self.started:.1f} s elapsed)")
        return run

    def twins(self, label: str, sc: Scenario) -> tuple[Run, Run | None]:
        """The run on the chosen backend and, for MuJoCo, its ODE twin."""
        main = self.run(label, sc, self.backend)
        twin = self.run(label, sc, "ode") if self.backend == "mujoco" else None
        return main, twin

    def study(self, label: str, name: str, override_sets: Sequence[Sequence[str]]) -> list[Summary]:
        """Summaries of one sensitivity study: ODE runs by the sweep engine, one by one where each
        takes the compiled loop (:func:`~.robustness_study.runs_alone`), else batched."""
        extra = [f"simulation.duration={self.duration!r}"] if self.duration is not None else []
        path, sets = self.scenarios / f"{name}.toml", [[*o, *extra] for o in override_sets]
        chunks, variants = planned(path, sets, "ode")
        if runs_alone(variants[0]):  # (the same numbers, batched or not)
            chunks = [[i] for i in range(len(sets))]
        summaries = sweep_summaries(path, sets, "ode", chunks=chunks, variants=variants)
        self.study_runs += len(summaries)
        self.lemma2_ratios += [s.lemma2_max_ratio for s in summaries]
        self.diverged += [f"{label} {' '.join(o)}" for o, s in zip(override_sets, summaries, strict=True)
                          if s.diverged]
        self.law_failures += [s.law_failure for s in summaries if s.law_failure]
        self.log(f"study: {label}: {len(summaries)} runs on the ODE "
                 f"({time.perf_counter() - self.started:.1f} s elapsed)")
        return summaries


QUICK_DURATION = 1.0  # s: the horizon of `reproduce --quick`


def reproduce(
    out: str | Path,
    backend: str = "mujoco",
    duration: float | None = None,
    scenarios: str | Path = SCENARIO_DIR,
    log: Callable[[str], None] = print,
    command: str | None = None,
    workers: int | None = None,
    quick: bool = False,
    laws: Sequence[str] = (),
) -> dict:
    """Run the whole reproduction into ``out``; returns Table 1 as written to ``table1.json``.
    ``command`` is what the outputs' provenance names as the command (default: this call);
    ``workers``: processes for the robustness study (default: the machine's cores, at most 4);
    ``quick``: a first look: ``QUICK_DURATION`` unless ``duration`` is given, and no robustness study
    (its 248 MuJoCo runs are most of the time). ``laws``: registered controller kinds (from a law
    module, ``--law KIND``) that join the studies beside the paper's law and the comparison law:
    Example 2's Table 1 runs (as entries marked as not from the paper), the region study and the
    robustness study. Every scenario it uses is validated before the folder is made: bad input
    creates nothing."""
    laws = study_kinds(laws)
    if quick and duration is None:
        duration = QUICK_DURATION
    command = command or (f"qcontrol.reproduce.reproduce({str(out)!r}, backend={backend!r}, "
                          f"duration={duration!r})")
    rep = Reproduction(check_output_dir(out), backend, duration, Path(scenarios), log, command=command,
                       laws=laws)
    _validate(rep)
    with output_dir(out) as o, staged():  # every file put in place at the end, together: never mixed
        table = _write_all(rep, o, command, workers, quick)
    extra = "" if quick else "region.json, tradeoff.json, robustness.json, "
    study = "no region or robustness study (--quick)" if quick else "then the region and robustness studies"
    log(f"wrote {o}: REPORT.md, table1.md, table1.json, studies.json, {extra}figures, recordings "
        f"({len(rep.lemma2_ratios)} example and study runs, {study}; "
        f"{time.perf_counter() - rep.started:.1f} s)")
    if rep.law_failures:  # the files are written; the runs it stopped say so in them
        raise QcontrolLawFailure(f"{rep.law_failures[0]} (it stopped {len(rep.law_failures)} run(s))")
    return table


def _write_all(rep: Reproduction, o: Path, command: str, workers: int | None, quick: bool) -> dict:
    """The runs and their files, in order; Table 1 as written to table1.json. The robustness
    study starts first, on its workers, and runs while this process does the rest; the region and
    trade-off studies' runs (together: the trade-off study reuses the region study's maps) and the
    sensor study's go to the same workers, first."""
    laws = (*LAWS, *map(study_law, rep.laws))
    side = [(maps_runs, (rep.scenarios, rep.duration, (*REGION_LAWS, *rep.laws))),
            (sensor_runs, (rep.scenarios, rep.duration))]
    hardware = (nullcontext(None) if quick else
                robustness_started(rep.scenarios, rep.duration, workers or default_workers(), rep.log, laws,
                                   side))
    forked = (workers or default_workers()) > 1  # (figures drawn apart too, by forked workers)
    with hardware as running, Apart(o, forked) as apart:
        table = _write_runs(rep, o, command, running, apart)
        apart.wait()
        return table


def _write_runs(rep: Reproduction, o: Path, command: str, running: Running | None, apart: Apart) -> dict:
    """:func:`_write_all` with the robustness study started (``running``; None: no robustness
    study, and the sensor study runs here); the examples' and the studies' figures drawn by
    ``apart``."""
    robustness = None if running is None else running.result
    backend = rep.backend
    rep.log(f"Example 1 on {backend}")
    ex1, ex1_twin = rep.twins("example 1", rep.scenario("example1"))
    _record(o / "example1.rrd", ex1, {"ode": ex1_twin}, command)

    rep.log(f"Example 2 on {backend}: proposed and comparison law [20]")
    ex2, ex2_twin = rep.twins("example 2 proposed", rep.scenario("example2"))
    base, base_twin = rep.twins("example 2 comparison", rep.scenario("example2", COMPARISON))
    apart.draw(partial(_example_figures, ex1=(ex1, ex1_twin), ex2=(ex2, ex2_twin, base)))
    _record(o / "example2.rrd", ex2, {"ode": ex2_twin, "comparison": base}, command)
    others = {kind: rep.twins(f"example 2 {kind}", rep.scenario("example2", study_law(kind)[1]))
              for kind in rep.laws}

    table = _table1(o, backend, ex2, ex2_twin, base, base_twin, command, others, rep.duration)

    studies = _studies(rep, apart)
    deviations = {
        name: backend_deviation(a.traj, b.traj)
        for name, a, b in (("example1", ex1, ex1_twin), ("example2", ex2, ex2_twin),
                           ("example2 comparison", base, base_twin),
                           *((f"example2 {kind}", *runs) for kind, runs in others.items()))
        if b is not None
    }
    studied = {name: rep.scenario(name) for name in ("example2", "example2-rigid")}
    provenance = scenarios_provenance(studied, command)
    write_json(o / "studies.json", _studies_json(studies) | {"provenance": provenance})
    region, tradeoff = (None, None) if running is None else _maps(o, rep, running.side[0](), command)
    rep.log("study: Example 2 with realistic sensors (ODE)")
    if running is None:
        sensors = sensor_study(rep.scenarios, rep.duration, rep.log)
    else:
        sensors = running.side[1]()
        log_rows(sensors, rep.log)
    fig_sensors(sensors, o / "study_sensors.png")
    write_json(o / "sensors.json", sensor_record(sensors) | {"provenance": provenance})
    hardware = None if robustness is None else _robustness(o, rep, robustness, apart)
    report = _report(rep, table, studies, deviations, ex1, ex2, hardware, region, tradeoff)
    write_text(o / "REPORT.md", report + "\n".join(sensor_markdown(sensors)))
    return table


def _table1(o: Path, backend: str, ex2: Run, ex2_twin: Run | None, base: Run, base_twin: Run | None,
            command: str, others: Mapping[str, tuple[Run, Run | None]], duration: float | None) -> dict:
    """Table 1 from Example 2's runs (both methods, both backends): table1.json, .md and .png.
    ``others``: the runs of the laws given with ``--law``, by kind, added to the json and the
    Markdown as entries not from the paper (:func:`~.report.beyond_the_paper`); table1.png stays
    the paper's two methods. Runs of another horizon than the paper's (``duration``) are not
    compared with it: no difference in the json and the Markdown, no paper bars in the figure."""
    ours = {backend: {"proposed": ex2.summary.error_rate, "comparison": base.summary.error_rate}}
    if ex2_twin is not None and base_twin is not None:
        ours["ode"] = {"proposed": ex2_twin.summary.error_rate, "comparison": base_twin.summary.error_rate}
    table = table1(ours, duration)
    if others:
        extra = {backend: {kind: main.summary.error_rate for kind, (main, _) in others.items()}}
        if "ode" in ours and backend != "ode":  # the ODE twins
            extra["ode"] = {kind: twin.summary.error_rate for kind, (_, twin) in others.items()}
        table |= beyond_the_paper(extra)
    table |= {"provenance": scenarios_provenance(
        {"proposed": ex2.scenario, "comparison": base.scenario,
         **{kind: runs[0].scenario for kind, runs in others.items()}}, command)}
    write_json(o / "table1.json", table)
    write_text(o / "table1.md", table1_markdown(table))
    names = {"ode": "ODE", "mujoco": "MuJoCo"}
    paper = {"paper": PAPER_TABLE1} if "difference" in table else {}
    title = {} if paper else {"title": rf"Table 1's E($\omega$) (Example 2) on {duration:g} s runs: ours "
                                       f"only, not comparable with the paper's {PAPER_HORIZON:g} s"}
    sources = {method: {**{k: v[method] for k, v in paper.items()},
                        **{names.get(b, b): r[method] for b, r in ours.items()}}
               for method in ("proposed", "comparison")}
    plots.fig_table1(sources, o / "table1.png", **title)
    return table


def _maps(o: Path, rep: Reproduction, mapped: dict, command: str) -> tuple[dict, dict]:
    """The region study and the trade-off study on its 1 kHz maps (``mapped``: their runs, made by
    a worker, :func:`~.tradeoff_study.maps_runs`): region.json, tradeoff.json and their figures;
    returns both studies as REPORT.md reads them."""
    for line in mapped["log"]:
        rep.log(line)
    region, study = mapped["region"], mapped["tradeoff"]
    examples = {name: rep.scenario(name) for name in ("example1", "example2")}
    provenance = scenarios_provenance(examples, command)
    write_region_study(mapped["region_maps"], o / "study_region.png")
    write_json(o / "region.json", region | {"provenance": provenance})
    write_tradeoff_figure(study, o / "study_tradeoff.png")
    write_json(o / "tradeoff.json", tradeoff_record(study) | {"provenance": provenance})
    return region, study


def _robustness(o: Path, rep: Reproduction, result: Callable[[], dict], apart: Apart) -> dict:
    """The robustness study on realistic hardware (``result`` waits for the started study):
    robustness.json and its two figures (the margins' drawn by ``apart`` meanwhile: the study's
    workers are done, a core is free)."""
    robustness = result()
    rep.log(f"study: robustness done ({time.perf_counter() - rep.started:.1f} s elapsed)")
    apart.draw(partial(_margins_figure, robustness=robustness))
    hardware = {name: rep.scenario(name) for name in ROBUSTNESS_SCENARIOS}
    provenance = scenarios_provenance(hardware, rep.command)
    write_json(o / "robustness.json", robustness | {"provenance": provenance})
    fig_robustness(robustness, o / "study_robustness.png")
    return robustness


def _margins_figure(o: Path, robustness: dict) -> None:
    """The robustness study's margins figure into ``o``."""
    fig_margins(robustness, o / "study_margins.png")


def _validate(rep: Reproduction) -> None:
    """Load every scenario variant the reproduction runs; the examples must have the backend's
    section (e.g. [plant.mujoco])."""
    for name in ("example1", "example2"):
        runnable_backend(rep.scenario(name), rep.backend)
    for _, name, overrides in PLANT_VARIANTS:
        rep.scenario(name, overrides)
        rep.scenario(name, (*overrides, *COMPARISON))
    for name in ROBUSTNESS_SCENARIOS:  # the robustness study's plants, with their MuJoCo models
        sc = rep.scenario(name)
        BACKENDS["mujoco"].require(sc.backends.get("mujoco"), sc.source)
    for kind in rep.laws:  # each law given with --law on every scenario it runs on
        for name in ("example1", "example2", *ROBUSTNESS_SCENARIOS):
            rep.scenario(name, study_law(kind)[1])
    check_tradeoff(rep.scenarios)


def study_kinds(kinds: Sequence[str]) -> tuple[str, ...]:
    """``--law`` kinds checked: registered, distinct, and not one of the built-in laws every study
    has already."""
    if isinstance(kinds, str):
        raise QcontrolInputError(f"reproduce: laws must be a list of controller kinds, got {kinds!r}")
    known = ", ".join(LAW_KINDS)
    for i, kind in enumerate(kinds):
        if kind not in LAW_KINDS and kind not in KIND_ALIASES:
            raise QcontrolInputError(f"--law {kind!r}: unknown controller kind; known kinds: {known} "
                                     "(a kind of your own: load its file with --law-module FILE)")
        if KIND_ALIASES.get(kind, kind) in BUILT_IN_LAWS:
            raise QcontrolInputError(f"--law {kind}: the paper's law and the comparison law are in every "
                                     f"study already; give another kind (known kinds: {known})")
        if kind in kinds[:i]:
            raise QcontrolInputError(f"--law {kind}: given twice; give each kind once")
    return tuple(kinds)


def _example_figures(o: Path, ex1: tuple[Run, Run | None], ex2: tuple[Run, Run | None, Run]) -> None:
    """Figures 1-8 and the backends' overlays into ``o``."""
    _example1_figures(o, *ex1)
    _example2_figures(o, *ex2)


def _example1_figures(o: Path, run: Run, twin: Run | None) -> None:
    u = plots.EXAMPLE1_UNITS
    t = plots.PAPER_TITLES
    plots.fig_output(run.traj, o / "fig1_output.png", t[1], u)
    plots.fig_tracking_error(run.traj, o / "fig2_tracking_error.png", t[2], u)
    plots.fig_adaptive(run.traj, o / "fig3_xi_hat.png", t[3], u, labels=[r"$\hat{\xi}$"])
    plots.fig_input(run.traj, o / "fig4_input.png", t[4], u)
    if twin is not None:
        plots.fig_backend_overlay(run.traj, twin.traj, o / "fig_example1_mujoco_vs_ode.png",
                                  "Example 1: MuJoCo slider vs ideal ODE, same controller", u)


def _example2_figures(o: Path, run: Run, twin: Run | None, base: Run) -> None:
    u = plots.EXAMPLE2_UNITS
    t = plots.PAPER_TITLES
    plots.fig_compare_output(run.traj, base.traj, o / "fig5_outputs.png", t[5], u)
    plots.fig_compare_error(run.traj, base.traj, o / "fig6_tracking_errors.png", t[6], u)
    plots.fig_adaptive(run.traj, o / "fig7_eps_hat.png", t[7], u)
    plots.fig_input(run.traj, o / "fig8_input.png", t[8], u)
    if twin is not None:
        plots.fig_backend_overlay(run.traj, twin.traj, o / "fig_example2_mujoco_vs_ode.png",
                                  "Example 2: MuJoCo pendulum vs ideal ODE, same controller", u)


def _record(path: Path, main: Run, ghosts: dict[str, Run | None], command: str) -> None:
    """A rerun recording of the main run with its ghosts: its twin "ode" (the same closed loop on
    the ODE) and the others (the comparison law)."""
    sc, drawn = main.scenario, main.assembly.scene
    with recording_for(path, False, main.assembly, scenario_provenance(sc, command)) as rec:
        observer_for(rec, drawn, main.backend)(0, len(main.traj.t), [main.traj])
        for label, ghost in ghosts.items():
            if ghost is not None:
                twin_of = main.traj if label == "ode" else None
                observer_for(rec, drawn, label, twin_of, ghost=True)(0, len(ghost.traj.t), [ghost.traj])


def _rates(summaries: Sequence[Summary]) -> dict[str, list[float]]:
    keys = summaries[0].error_rate.keys()
    return {w: [s.error_rate[w] for s in summaries] for w in keys}


def _studies_json(studies: dict) -> dict:
    """studies.json: each study's values and its runs' summaries as ``summary.json`` writes them."""
    return {name: study | {"summaries": [s.to_json() for s in study["summaries"]]}
            for name, study in studies.items()}


def _studies(rep: Reproduction, apart: Apart) -> dict:
    """Sensitivity studies next to the canonical result (never replacing it), ODE backend; their
    figures drawn by ``apart``."""
    kappa = rep.study("kappa - L", "example2", [[f"controller.kappa_margin={m!r}"] for m in KAPPA_MARGINS])
    scale = rep.study("r scale", "example2", [[f"controller.r_scale={s!r}"] for s in R_SCALES])
    variants: dict[str, list] = {"labels": [], "summaries": []}  # labels, and one Summary each
    for label, name, overrides in PLANT_VARIANTS:
        for method, extra in (("proposed", ()), ("comparison law (46)", COMPARISON)):
            variants["labels"].append(f"{label}\n{method}")
            variants["summaries"].append(rep.study(f"{label} {method}", name, [[*overrides, *extra]])[0])
    apart.draw(partial(_study_figures, kappa=kappa, scale=scale, variants=variants))
    return {
        "kappa_margin": {"values": list(KAPPA_MARGINS), "summaries": kappa},
        "r_scale": {"values": list(R_SCALES), "summaries": scale},
        "plant_variants": {"values": [v.replace("\n", " ") for v in variants["labels"]],
                           "summaries": variants["summaries"]},
    }


def _study_figures(o: Path, kappa: list[Summary], scale: list[Summary], variants: dict[str, list]) -> None:
    """The sensitivity studies' figures into ``o``."""
    plots.fig_sensitivity(
        KAPPA_MARGINS, _rates(kappa), r"$\kappa - L$", o / "study_kappa.png",
        "Study: Example 2 error rate vs kappa - L (proposed law, ODE)",
        paper_rates=PAPER_TABLE1["proposed"], markers={"paper: 1.1": 1.1, "0.1": 0.1}, xscale="log",
    )
    plots.fig_sensitivity(
        R_SCALES, _rates(scale), "constant scale s of r (r -> s r)", o / "study_r_scale.png",
        "Study: Example 2 error rate vs a constant scale of r (kappa = 1.1 + L, ODE)",
        paper_rates=PAPER_TABLE1["proposed"], xscale="log",
    )
    plots.fig_sensitivity(
        variants["labels"], _rates(variants["summaries"]), "plant reading and method",
        o / "study_plant_variants.png", "Study: Example 2 plant readings (ODE)",
        paper_rates=PAPER_TABLE1["proposed"],
    )


def _report(rep: Reproduction, table: dict, studies: dict, deviations: dict, ex1: Run, ex2: Run,
            robustness: dict | None, region: dict | None, tradeoff: dict | None) -> str:
    """REPORT.md from the runs' facts (see :func:`qcontrol.report.report_markdown`)."""
    traj, c = ex2.traj, ex2.scenario.controller
    facts = ReportFacts(
        backend=rep.backend, duration=rep.duration, study_runs=rep.study_runs,
        seconds=time.perf_counter() - rep.started, lemma2_ratios=rep.lemma2_ratios, diverged=rep.diverged,
        table=table, studies=studies, deviations=deviations, example1=ex1.summary, example2=ex2.summary,
        z2_last_half=float(np.nanmax(np.abs(traj.z[traj.t >= traj.duration / 2, -1]))),
        kappa_plus_L=c.settings.kappa + lemma2_L(c.c, c.delta), robustness=robustness, region=region,
        tradeoff=tradeoff,
    )
    return report_markdown(facts)
