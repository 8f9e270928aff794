"""The region of attraction of a law, measured: closed-loop runs from every point of a 2-D grid of
initial states, each classified as bounded, diverged (and when) or Lemma 2 violated.

The runs are a sweep over ``plant.x0`` (one override set per point and law), batched and run in
this process, on local workers or on a Dask scheduler by :func:`qcontrol.sweep.sweep_summaries`:
the same numbers whatever the executor. The scenario is loaded once per law and each start is a
copy of it with its x(0) (:func:`region_variants`); local workers receive those copies as forks
of this process, a Dask cluster's workers load each start from the file. Any
registered controller kind can be measured (a law registered from Python runs in this process
and on local workers).
"""

from __future__ import annotations

import math
import re
import time
import tomllib
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..assembly import batch_structure, runnable_backend
from ..controller import LAW_KINDS
from ..controller.law import KIND_ALIASES
from ..errors import QcontrolInputError
from ..metrics import LEMMA2_TOLERANCE
from ..scenario import Scenario, load_scenario
from ..sharing import sharing
from ..summary import Summary
from ..sweep.grid import MAX_RUNS
from ..sweep.runs import RunsDone, chunks_of, sweep_summaries

if TYPE_CHECKING:
    from ..plots.region import RegionMap

OUTCOMES = ("bounded", "diverged", "lemma2")  # how a run from one point ended (see classify)
BOX = 10.0  # the box |x_i(0)| <= BOX the study reports on (the paper's examples start well inside)
DIRECTIONS = ((1, 0), (0, 1), (1, 1), (1, -1), (-1, 0), (0, -1), (-1, -1), (-1, 1))


def _close(x: float, y: float, atol: float) -> bool:
    """``numpy.isclose(x, y, atol=atol)`` (rtol 1e-5) of two numbers, by the same float operations
    without making arrays of them (the ray test asks it of every grid point, direction and law: as
    numpy calls, a quarter of the reproduction's region and trade-off studies)."""
    x, y = float(x), float(y)
    return (abs(x - y) <= atol + 1e-05 * abs(y) and math.isfinite(y)) or x == y


@dataclass(frozen=True)
class LawSpec:
    """One law to measure: a controller kind and settings of its ``[controller]`` table, as given
    on the command line (``proposed``, ``proposed:hold=exact``, ``comparison``)."""

    kind: str
    settings: tuple[tuple[str, str], ...] = ()

    @property
    def label(self) -> str:
        return self.kind + ("" if not self.settings else ":" + ",".join(f"{k}={v}" for k, v in self.settings))

    def overrides(self) -> list[str]:
        return [f"controller.kind={self.kind!r}"] + [f"controller.{k}={_toml_value(v)}"
                                                     for k, v in self.settings]


def _toml_value(text: str) -> str:
    """A setting's value as TOML: as written when it is one (``0.5``, ``"exact"``, ``[1, 2]``),
    else the bare word as a string (``exact``)."""
    try:
        tomllib.loads(f"v = {text}")
        return text
    except tomllib.TOMLDecodeError:
        return repr(text)


SETTING_SEPARATOR = re.compile(r",(?![^\[]*\])")  # a comma outside a list's brackets


def parse_law(text: str) -> LawSpec:
    """``KIND`` or ``KIND:KEY=VALUE,KEY=VALUE`` -> a :class:`LawSpec` (the kind must be registered);
    a value may be a list, its commas inside its brackets (``linear:c=[20.0, 20.0]``)."""
    kind, _, rest = text.partition(":")
    kind = KIND_ALIASES.get(kind.strip(), kind.strip())
    if kind not in LAW_KINDS:
        raise QcontrolInputError(f"--law {text!r}: unknown controller kind {kind!r}; use one of "
                                 f"{', '.join(LAW_KINDS)}, optionally with settings (proposed:hold=exact)")
    settings = []
    for item in filter(None, (part.strip() for part in SETTING_SEPARATOR.split(rest))):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise QcontrolInputError(f"--law {text!r}: expected KIND:KEY=VALUE,... such as "
                                     "proposed:hold=exact")
        settings.append((key.strip(), value.strip()))
    return LawSpec(kind, tuple(settings))


def default_laws(sc: Scenario) -> list[LawSpec]:
    """The scenario's own law, and the settings its kind says to measure beside it
    (``LawKeys.also_measure``: for the paper's law held as printed, its exact hold)."""
    kind = LAW_KINDS[sc.controller.kind]
    more = () if kind.also_measure is None else kind.also_measure(sc.controller.settings)
    return [LawSpec(sc.controller.kind), *(LawSpec(sc.controller.kind, settings) for settings in more)]


@dataclass(frozen=True)
class RegionGrid:
    """Initial states on a grid over two state axes (0-based ``axes``), ``resolution`` points per
    axis from ``low`` to ``high`` (per axis); the other components of x(0) as in the scenario."""

    axes: tuple[int, int]
    low: tuple[float, float]
    high: tuple[float, float]
    resolution: int

    def values(self, which: int) -> np.ndarray:
        return np.linspace(self.low[which], self.high[which], self.resolution)

    def starts(self, x0: Sequence[float]) -> list[tuple[float, ...]]:
        """Every initial state, the first axis varying slowest."""
        out = []
        for a in self.values(0):
            for b in self.values(1):
                x = list(x0)
                x[self.axes[0]], x[self.axes[1]] = float(a), float(b)
                out.append(tuple(x))
        return out


def parse_grid(sc: Scenario, axes: str, box: str, resolution: int) -> RegionGrid:
    """``--axes 1,2``, ``--box 10`` (or ``LO,HI``, or ``LO1,HI1,LO2,HI2``), ``--resolution N``."""
    try:
        picked = tuple(int(v) - 1 for v in axes.split(","))
    except ValueError:
        picked = ()
    if len(picked) != 2 or picked[0] == picked[1] or not all(0 <= a < sc.order for a in picked):
        raise QcontrolInputError(f"--axes {axes!r}: give two different state numbers from 1 to {sc.order}, "
                                 "e.g. 1,2")
    try:
        bounds = [float(v) for v in box.split(",")]
    except ValueError:
        bounds = []
    if len(bounds) == 1 and not bounds[0] > 0:
        raise QcontrolInputError(f"--box {box!r}: a half-width must be > 0 (the grid is [-H, H]); "
                                 "e.g. --box 10, or give LO,HI")
    if len(bounds) == 1:
        bounds = [-bounds[0], bounds[0]] * 2
    elif len(bounds) == 2:
        bounds = bounds * 2
    if len(bounds) != 4 or not all(math.isfinite(v) for v in bounds) or not (
            bounds[0] < bounds[1] and bounds[2] < bounds[3]):
        raise QcontrolInputError(f"--box {box!r}: give a half-width (10), LO,HI, or LO1,HI1,LO2,HI2 "
                                 "with LO < HI")
    bound = sc.simulation.state_bound
    if not all(abs(v) <= bound for v in bounds):
        raise QcontrolInputError(f"--box {box!r}: the grid's bounds must be within the divergence bound "
                                 f"simulation.state_bound = {bound:g} (a start further out has diverged "
                                 "already); e.g. --box 10")
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 2:
        raise QcontrolInputError(f"--resolution {resolution!r}: need at least 2 points per axis")
    grid = RegionGrid(picked, (bounds[0], bounds[2]), (bounds[1], bounds[3]), resolution)  # type: ignore[arg-type]
    check_region_size(grid, 1)
    return grid


def check_region_size(grid: RegionGrid, laws: int) -> int:
    """The number of runs (every start for every law), refused as one line over the sweep's cap
    :data:`~qcontrol.sweep.grid.MAX_RUNS`, before any is made."""
    runs = grid.resolution ** 2 * max(1, laws)
    if runs > MAX_RUNS:
        largest, side = math.isqrt(MAX_RUNS // max(1, laws)), grid.resolution
        raise QcontrolInputError(
            f"--resolution {side}: {side} x {side} starts for {max(1, laws)} "
            f"law(s) is {runs:,} runs, more than the {MAX_RUNS:,} a region (like a sweep) may make; "
            f"give --resolution {largest} or less")
    return runs


def classify(s: Summary) -> str:
    """``diverged``; ``lemma2`` (bounded, but a Lemma 2 bound was exceeded where it applies); or
    ``bounded``."""
    if s.diverged:
        return "diverged"
    if s.lemma2_applies and not s.lemma2_max_ratio <= 1 + LEMMA2_TOLERANCE:
        return "lemma2"
    return "bounded"


@dataclass(frozen=True)
class RegionPoint:
    """One run: its law, x(0), how it ended and its figures (``max_gain_period`` None for a law
    that declares no gain)."""

    law: str
    x0: tuple[float, ...]
    outcome: str
    diverged_time: float | None
    lemma2_max_ratio: float
    max_gain_period: float | None
    max_abs_u: float
    law_failure: str | None = None  # the line of a law written in Python that failed (and stopped the run)


@dataclass
class Region:
    """What a region study measured: its grid and laws, every point, and the scenario's x(0)."""

    scenario: Scenario
    grid: RegionGrid
    laws: list[LawSpec]
    backend: str
    points: list[RegionPoint]
    wall_time_s: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)

    def of(self, law: LawSpec) -> list[RegionPoint]:
        return [p for p in self.points if p.law == law.label]

    def outcomes(self, law: LawSpec) -> np.ndarray:
        """``(resolution, resolution)`` of outcome indices (OUTCOMES), first axis first."""
        codes = [OUTCOMES.index(p.outcome) for p in self.of(law)]
        return np.array(codes).reshape(self.grid.resolution, self.grid.resolution)

    def law_summary(self, law: LawSpec) -> dict[str, Any]:
        """Counts, the box |x_i| <= BOX, the largest K T and |u|, and per direction the largest
        working scale found on the grid."""
        points = self.of(law)
        in_box = [p for p in points if max(abs(v) for v in p.x0) <= BOX + 1e-12]
        gains = [p.max_gain_period for p in points if p.max_gain_period is not None]
        kept = [p.max_abs_u for p in in_box if p.outcome != "diverged" and math.isfinite(p.max_abs_u)]
        return {
            "law": law.label,
            "overrides": law.overrides(),
            "points": len(points),
            **{outcome: sum(p.outcome == outcome for p in points) for outcome in OUTCOMES},
            "points_in_box": len(in_box),
            "failing_in_box": sum(p.outcome != "bounded" for p in in_box),
            "max_gain_period": max(gains) if gains else None,
            "max_gain_period_bounded": max((p.max_gain_period for p in points if p.outcome == "bounded"
                                            and p.max_gain_period is not None), default=None),
            "max_abs_u_in_box": max(kept, default=None),
            "directions": self.directions(points),
        }

    def directions(self, points: Sequence[RegionPoint]) -> list[dict[str, Any]]:
        """Along each axis and diagonal of the two axes (from the scenario's other components): the
        largest scale s = max(|x_a|, |x_b|) up to which every grid point on the ray is bounded, and
        the first failing scale (None: none failed on the grid)."""
        a, b = self.grid.axes
        span = max(abs(v) for v in (*self.grid.low, *self.grid.high))
        out = []
        for da, db in DIRECTIONS:
            ray = []
            for p in points:
                s = max(abs(p.x0[a]), abs(p.x0[b]))
                if s > 0 and _close(p.x0[a], s * da, 1e-9 * span) and _close(p.x0[b], s * db, 1e-9 * span):
                    ray.append((s, p.outcome))
            largest, first_fail = 0.0, None
            for s, outcome in sorted(ray):
                if outcome != "bounded":
                    first_fail = s
                    break
                largest = s
            out.append({"direction": [da, db], "points": len(ray), "largest_ok": largest if ray else None,
                        "first_fail": first_fail})
        return out

    def maps(self) -> list[RegionMap]:
        """A map per law for :func:`qcontrol.plots.region.fig_region`."""
        from ..plots.region import RegionMap  # matplotlib: imported only when a figure is drawn

        g = self.grid
        a, b = g.axes
        period = self.scenario.simulation.period
        out = []
        for law in self.laws:
            gains = np.array([np.nan if p.max_gain_period is None else p.max_gain_period
                              for p in self.of(law)])
            s = self.law_summary(law)
            out.append(RegionMap(
                g.values(0), g.values(1), self.outcomes(law).T, gains.reshape(g.resolution, g.resolution).T,
                (self.scenario.x0[a], self.scenario.x0[b]), BOX,
                f"{law.label}: {s['failing_in_box']} of {s['points_in_box']} fail in |x_i| <= {BOX:g}",
                f"x{a + 1}(0)", f"{self.scenario.name}\nT = {period * 1e3:g} ms\nx{b + 1}(0)"))
        return out

    def title(self) -> str:
        g = self.grid
        return (f"Region of attraction of {self.scenario.name} on {self.backend}: {g.resolution} x "
                f"{g.resolution} initial states, {self.scenario.simulation.duration:g} s runs")

    def record(self, provenance: dict) -> dict[str, Any]:
        """``region.json``: what was measured and how (the points themselves are in region.csv)."""
        g = self.grid
        return {
            "scenario": self.scenario.name,
            "backend": self.backend,
            "axes": [f"x{a + 1}" for a in g.axes],
            "low": list(g.low),
            "high": list(g.high),
            "resolution": g.resolution,
            "x0": list(self.scenario.x0),
            "dt": self.scenario.simulation.dt,
            "control_period": self.scenario.simulation.period,
            "duration": self.scenario.simulation.duration,
            "box": BOX,
            **self.settings,
            "laws": [self.law_summary(law) for law in self.laws],
            "outcomes": {"bounded": "stayed bounded with every Lemma 2 bound holding",
                         "diverged": "left |x_i| <= state_bound or became NaN/Inf (diverged_time: when)",
                         "lemma2": "stayed bounded but a Lemma 2 bound |e_zi| <= L_zi was exceeded"},
            "wall_time_s": self.wall_time_s,
            "csv": "region.csv",
            "figure": "region.png",
            "provenance": provenance,
        }


def _x0_text(x: Sequence[float]) -> str:
    return "plant.x0=[" + ", ".join(repr(v) for v in x) + "]"


def region_sets(grid: RegionGrid, laws: Sequence[LawSpec], x0: Sequence[float], overrides: Sequence[str] = ()
                ) -> tuple[list[tuple[LawSpec, tuple[float, ...]]], list[list[str]]]:
    """The (law, x(0)) of every run and its override set, laws first."""
    runs = [(law, x) for law in laws for x in grid.starts(x0)]
    return runs, [[*overrides, *law.overrides(), _x0_text(x)] for law, x in runs]


def region_variants(path: str, runs: Sequence[tuple[LawSpec, tuple[float, ...]]], overrides: Sequence[str],
                    unset: Sequence[str], backend: str) -> tuple[list[Scenario], list[list[int]]]:
    """Every run's scenario, and the groups (indices, in input order) that share a batch structure:
    the scenario loaded (and checked) once per law, each start a copy of it with its x(0) (a start
    differs from it only there; a start's file read and checked again costs about as much as its
    1 kHz, 2 s ODE run in a batch), exactly what loading each override set of :func:`region_sets`
    would give."""
    loaded: dict[str, tuple[Scenario, Hashable]] = {}
    groups: dict[Hashable, list[int]] = {}
    variants = []
    for i, (law, x) in enumerate(runs):
        if law.label not in loaded:
            sc = load_scenario(path, [*overrides, *law.overrides()], list(unset))
            runnable_backend(sc, backend)
            loaded[law.label] = sc, batch_structure(sc, backend)  # (x(0) is a copy's own: not in it)
        sc, structure = loaded[law.label]
        variants.append(replace(sc, x0=tuple(x), overrides=(*sc.overrides, _x0_text(x))))
        groups.setdefault(structure, []).append(i)
    return variants, list(groups.values())


def measure_region(scenario: str | Path, grid: RegionGrid, laws: Sequence[LawSpec], backend: str = "ode",
                   overrides: Sequence[str] = (), unset: Sequence[str] = (), workers: int = 1,
                   scheduler: str | None = None, progress: RunsDone | None = None) -> Region:
    """Run every law from every point of ``grid`` (see the module docstring): in this process, or
    (``workers > 1``, ``scheduler``) through the sweep's executors; the same batches either way, so
    the same numbers. Bad input (a law's settings, an override) raises
    :class:`QcontrolInputError` before any run."""
    with sharing():  # (the file's tables read and checked once, for the scenario and every law)
        return _measure(scenario, grid, laws, backend, overrides, unset, workers, scheduler, progress)


def _measure(scenario: str | Path, grid: RegionGrid, laws: Sequence[LawSpec], backend: str,
             overrides: Sequence[str], unset: Sequence[str], workers: int, scheduler: str | None,
             progress: RunsDone | None) -> Region:
    """:func:`measure_region`, loading inside :func:`qcontrol.sharing.sharing`."""
    base = load_scenario(scenario, list(overrides), list(unset))
    if not laws:
        raise QcontrolInputError("no law to measure: give --law KIND at least once")
    labels = [law.label for law in laws]
    if len(set(labels)) != len(labels):
        raise QcontrolInputError(f"--law: a law is given twice ({', '.join(labels)}); give each once")
    if workers < 1:
        raise QcontrolInputError(f"--workers {workers}: must be >= 1")
    if not isinstance(grid, RegionGrid):
        raise QcontrolInputError(f"measure_region: grid must be a RegionGrid (from parse_grid), got "
                                 f"{type(grid).__name__}")
    check_region_size(grid, len(laws))
    runs, sets = region_sets(grid, laws, base.x0, overrides)
    started = time.perf_counter()
    variants, groups = region_variants(base.source, runs, overrides, unset, backend)  # (every law checked)
    summaries = sweep_summaries(base.source, sets, backend, workers, scheduler, progress, chunks_of(groups),
                                unset, variants)
    points = [RegionPoint(law.label, x, classify(s), s.diverged_time, s.lemma2_max_ratio,
                          s.law_diagnostics.get("max_gain_period"), s.max_abs_u, s.law_failure)
              for (law, x), s in zip(runs, summaries, strict=True)]
    return Region(base, grid, list(laws), backend, points, time.perf_counter() - started)


CSV_FIELDS = ("law", "outcome", "diverged_time", "lemma2_max_ratio", "max_gain_period", "max_abs_u")


def csv_text(region: Region) -> str:
    """``region.csv``: one row per run: law, the two axes' x(0), outcome and figures."""
    import csv
    import io

    a, b = (f"x{i + 1}" for i in region.grid.axes)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["law", a, b, *CSV_FIELDS[1:]])
    for p in region.points:
        values = [p.outcome, p.diverged_time, p.lemma2_max_ratio, p.max_gain_period, p.max_abs_u]
        writer.writerow([p.law, repr(p.x0[region.grid.axes[0]]), repr(p.x0[region.grid.axes[1]]),
                         *("" if v is None else repr(v) if isinstance(v, float) else v for v in values)])
    return buffer.getvalue()


def write_region(region: Region, out: Path, provenance: dict) -> None:
    """region.csv, region.json and region.png in ``out`` (made now), put in place together once all
    three are complete (:func:`qcontrol.outputs.staged`): the folder never mixes two regions."""
    from ..outputs import output_dir, staged, write_json, write_text
    from ..plots.region import fig_region  # matplotlib: imported only when a figure is drawn

    with output_dir(out) as out, staged():
        write_text(out / "region.csv", csv_text(region))
        write_json(out / "region.json", region.record(provenance))
        fig_region([region.maps()], OUTCOMES, out / "region.png", region.title())
