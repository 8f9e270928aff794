"""The rest of the command line as functions: :func:`region` (``qcontrol region``),
:func:`reproduce` (``qcontrol reproduce``) and :func:`check` (``qcontrol check``), beside
:func:`qcontrol.run`, :func:`qcontrol.compare`, :func:`qcontrol.compare_laws` and
:func:`qcontrol.sweep`. Each returns a typed result and writes files only when asked to (``out``).

    import qcontrol
    sc = qcontrol.load_scenario("example2", {"simulation.duration": 1.0})
    qcontrol.check(sc).backends["mujoco"]["max_abs_mismatch"]   # MuJoCo against eq. (1)
    reg = qcontrol.region(sc, ["proposed", "proposed:hold=exact"], resolution=9)
    reg.law_summary(reg.laws[0])["failing_in_box"]
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from . import compiled as compiled_paths
from . import reproduce as _reproduce_package  # noqa: F401  (bound before the function of its name)
from .api import _call, _check_arguments, check_scenario
from .assembly import assemble
from .errors import QcontrolInputError
from .outputs import check_output_dir, check_output_file
from .region import Region, default_laws, measure_region, parse_grid, parse_law, write_region
from .scenario import Scenario
from .scenario.resolve import scenario_provenance

__all__ = ["CheckReport", "Reproduction", "check", "region", "reproduce"]

# s of simulated time per run of a reproduction: each run keeps its rows for the figures
MAX_DURATION = 3600.0


# --------------------------------------------------------------------------------------------
# check
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CheckReport:
    """What :func:`check` validated: the scenario, the backend a run would use, its time grid, the
    controller kind whose constants were checked (kappa > L for the paper's law), and per backend
    section the plant's consistency report (for MuJoCo: ``samples``, ``max_abs_mismatch`` and the
    ``realism`` options that make the model differ from eq. (1); empty for the ODE)."""

    scenario: str
    source: str
    backend: str
    steps: int
    dt: float
    law: str
    backends: dict[str, dict[str, Any]]
    compiled_form: str | None = None  # a user law's: "compiled", or why it runs in Python

    def line(self) -> str:
        """The line ``qcontrol check`` prints."""
        notes = "; ".join(_plant_note(name, report) for name, report in self.backends.items())
        law = "" if self.compiled_form is None else f"; the law's compiled form: {self.compiled_form}"
        return (f"ok: {self.source} ({self.scenario}): keys, expressions and the {self.law} law's constants "
                f"valid; {self.steps} steps of {self.dt:g} s on {self.backend}; {notes}{law}")


def check(scenario: Scenario, backend: str | None = None) -> CheckReport:
    """Validate ``scenario`` as a run would, without running it: its law is built (its constants
    checked: Theorem 1's kappa > L for the paper's law) and every backend section's plant built
    (a MuJoCo model is compiled and its acceleration compared with eq. (1) at sampled states).
    ``backend``: the one a run would use (None: the scenario's). Raises
    :class:`~qcontrol.QcontrolInputError` with the one line a run would give; nothing is written."""
    check_scenario(scenario, "check")
    _check_arguments("check", backend=(backend, str, True))
    with compiled_paths.not_needed():  # nothing runs: the Python form of MuJoCo's callback serves
        chosen = assemble(scenario, backend)
        runs = [chosen] + [assemble(scenario, name) for name in scenario.backends if name != chosen.backend]
    reports = {run.backend: dict(run.report.consistency_report or {}) for run in runs}
    steps = round(scenario.simulation.duration / scenario.simulation.dt)
    return CheckReport(scenario.name, str(scenario.source), chosen.backend, steps, scenario.simulation.dt,
                       scenario.controller.kind, reports, user_compiled_form(chosen.law, scenario))


def user_compiled_form(law: Any, scenario: Scenario) -> str | None:
    """For a law of the ``qcontrol.Law`` protocol: "compiled" when its code has a compiled form
    (traced and checked: docs/laws.md, 'Speed'), else why it runs in Python; None for other laws."""
    from .controller.user import UserLaw
    from .engine.user_trace import explain

    if not isinstance(law, UserLaw):
        return None
    return explain(law, law.n, scenario.simulation.dt) or "compiled"


def _plant_note(backend: str, report: Mapping[str, Any]) -> str:
    """What building one backend's plant found, as ``qcontrol check`` says it."""
    if not report:
        return f"{backend}: the plant of eq. (1) built"
    agreement = (f"agrees with eq. (1) at {report['samples']} sampled states (max |mismatch| "
                 f"{report['max_abs_mismatch']:.2g})")
    if report.get("realism"):
        agreement = (f"differs from eq. (1) by up to {report['max_abs_mismatch']:.3g} at {report['samples']} "
                     f"sampled states, as its realism options ({', '.join(report['realism'])}) make it")
    return f"{backend}: the model compiled and {agreement}"


# --------------------------------------------------------------------------------------------
# region
# --------------------------------------------------------------------------------------------


def region(scenario: Scenario, laws: Sequence[str] | None = None, *, axes: tuple[int, int] = (1, 2),
           box: float | Sequence[float] = 10.0, resolution: int = 21, backend: str = "ode", workers: int = 1,
           scheduler: str | None = None, out: str | Path | None = None) -> Region:
    """Map the region of attraction of ``laws`` (``"proposed"``, ``"proposed:hold=exact"``,
    ``"comparison"``, a registered kind, with ``KIND:KEY=VALUE,...`` settings of its ``[controller]``
    table; None: the scenario's law and, for the paper's law, its exact hold): the closed loop from
    every point of a ``resolution`` x ``resolution`` grid over the two state ``axes`` (1-based) in
    ``box`` (a half-width H for [-H, H]^2, ``(lo, hi)``, or ``(lo1, hi1, lo2, hi2)``), each start
    classified as bounded, diverged or Lemma 2 violated, with its largest K T (the sampled gain of
    law (44), docs/math.md, 'Sampling the law'). The other components of x(0) are the scenario's.
    Batched on the ODE (``backend="mujoco"`` on request), in this process or on ``workers`` /
    a Dask ``scheduler``, with the same numbers (too little work for workers stays in this
    process: ``qcontrol.sweep.runs.SPREAD_MIN_WORK``). With ``out`` writes region.csv, region.json and
    region.png there, as ``qcontrol region`` does.

    Returns a :class:`~qcontrol.region.Region`: ``points`` (one
    :class:`~qcontrol.region.RegionPoint` per run), ``laws``, ``law_summary(law)`` (the counts,
    ``failing_in_box``, the largest K T and |u|, the largest working scale per direction) and
    ``outcomes(law)``, the grid of outcomes."""
    check_scenario(scenario, "region")
    _check_arguments("region", backend=(backend, str, False), resolution=(resolution, int, False),
                     workers=(workers, int, False), scheduler=(scheduler, str, True),
                     out=(out, (str, Path), True))
    if laws is not None and (isinstance(laws, str) or not all(isinstance(law, str) for law in laws)):
        raise QcontrolInputError(f"region: laws must be a list of kinds such as [\"proposed\", "
                                 f"\"proposed:hold=exact\"], got {laws!r}")
    if out is not None:
        out = check_output_dir(Path(out))
        for name in ("region.csv", "region.json", "region.png"):
            check_output_file(out / name, "out", fix="remove it or choose another out folder")
    specs = [parse_law(text) for text in laws] if laws else default_laws(scenario)
    grid = parse_grid(scenario, ",".join(str(a) for a in axes), _box_text(box), resolution)
    overrides = [_override_text(item) for item in scenario.overrides]
    found = measure_region(scenario.source, grid, specs, backend, overrides, scenario.unset, workers,
                           scheduler)
    found.settings = {"fixed_overrides": overrides, "unset": list(scenario.unset)}
    if out is not None:
        command = _call("region", scenario, laws=[s.label for s in specs], resolution=resolution)
        write_region(found, out, scenario_provenance(scenario, command))
    return found


def _box_text(box: float | Sequence[float]) -> str:
    """``box`` as ``qcontrol region --box`` reads it."""
    if isinstance(box, int | float) and not isinstance(box, bool):
        return repr(float(box))
    if isinstance(box, Sequence) and not isinstance(box, str) and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in box):
        return ",".join(repr(float(v)) for v in box)
    raise QcontrolInputError(f"region: box must be a half-width H or a list (lo, hi) or (lo1, hi1, lo2, "
                             f"hi2), got {box!r}")


def _override_text(item: str | tuple[str, Any]) -> str:
    """An override as the ``"key=value"`` text the runs reload the scenario with (a dict's
    ``(key, value)`` pair written as TOML)."""
    return item if isinstance(item, str) else f"{item[0]}={_toml(item[1])}"


def _toml(value: Any) -> str:
    """A value as an inline TOML value (JSON's form of strings, numbers, booleans and arrays is
    TOML's; a table is written inline)."""
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return json.dumps(value)


# --------------------------------------------------------------------------------------------
# reproduce
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reproduction:
    """What :func:`reproduce` wrote: the folder ``out``, its ``files`` (names, sorted), Table 1 as
    written to table1.json (``table1``: the paper's rows, ours per backend, and for a full
    reproduction the differences), and whether it was the ``quick`` first look (1 s horizons, no
    region or robustness study, nothing compared with the paper's numbers)."""

    out: Path
    files: tuple[str, ...]
    table1: dict[str, Any]
    quick: bool

    @property
    def report(self) -> str:
        """REPORT.md's text."""
        return (self.out / "REPORT.md").read_text(encoding="utf-8")


def reproduce(out: str | Path, quick: bool = False, *, backend: str = "mujoco", duration: float | None = None,
              scenarios: str | Path | None = None, workers: int | None = None, laws: Sequence[str] = (),
              log: Callable[[str], None] | None = None) -> Reproduction:
    """Reproduce the paper into ``out``, as ``qcontrol reproduce`` does: Figs. 1-8, Table 1 beside
    the paper's (table1.md/.json/.png), the sensitivity studies, the region and robustness studies,
    REPORT.md and a recording per example. ``quick``: a first look (1 s horizons unless
    ``duration`` is given, no region or robustness study; Table 1 then holds our numbers only).
    ``backend``: the examples' plant (MuJoCo with its ODE twin, or the ODE); ``scenarios``: a folder
    holding the five scenario files (default: the shipped ones); ``workers``: processes for the
    robustness study; ``laws``: registered kinds studied beside the paper's two laws; ``log``: a
    callable given each progress line (None: silent). Every input is checked before ``out`` is
    made; the files are put in place together at the end."""
    from .reproduce.reproduction import SCENARIO_DIR
    from .reproduce.reproduction import reproduce as run_reproduction

    _check_arguments("reproduce", out=(out, (str, Path), False), quick=(quick, bool, False),
                     backend=(backend, str, False), scenarios=(scenarios, (str, Path), True),
                     workers=(workers, int, True))
    if duration is not None and not (isinstance(duration, int | float) and 0 < duration <= MAX_DURATION):
        raise QcontrolInputError(f"reproduce: duration must be a number of seconds > 0 and at most "
                                 f"{MAX_DURATION:g}, got {duration!r}")
    if workers is not None and workers < 1:
        raise QcontrolInputError(f"reproduce: workers must be >= 1, got {workers}")
    if isinstance(laws, str) or not all(isinstance(k, str) for k in laws):
        raise QcontrolInputError(f"reproduce: laws must be a list of controller kinds, got {laws!r}")
    folder = Path(scenarios) if scenarios is not None else SCENARIO_DIR
    if not folder.is_dir():
        raise QcontrolInputError(f"reproduce: scenarios {str(folder)!r} is not a folder; give the folder "
                                 "holding example1.toml, example2.toml, ... (or leave it out)")
    table = run_reproduction(out, backend, duration, folder, log or _silent, workers=workers, quick=quick,
                             laws=list(laws))
    folder_out = Path(out)
    files = tuple(sorted(p.name for p in folder_out.iterdir() if p.is_file() and not p.name.startswith(".")))
    return Reproduction(folder_out, files, table, quick)


def _silent(line: str) -> None:
    """A log that drops its lines."""
