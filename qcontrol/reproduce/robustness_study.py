"""The robustness study of ``qcontrol reproduce``: both examples on realistic hardware.

For Example 2 (the arm, ``example2-arm.toml``) and Example 1 (the cart, ``example1-cart.toml``),
with the proposed law (44)-(45) and the comparison law (46) (and any law given with ``--law``:
``laws``), on MuJoCo with the ODE twin's numbers beside:

* **each imperfection alone** on the paper's ideal scenario, with the realistic scenario's value
  (each number has one source: the realistic file), the x2 differenced from the encoder, and
  **all together** (the realistic scenario as shipped, without its demonstration disturbance);
  rows with sensor noise run :data:`SEEDS` seeds and report the median and the range;
* **margins**: each imperfection alone, pushed beyond the hardware, to find where it breaks;
* **disturbances** on the ideal and the realistic arm: an impulse and a load step at half the
  run, the peak error and the recovery time.

The ODE twin runs the same scenario on the ODE of eq. (1): it shares what is not physics (the
control period, the velocity source, the disturbances) and none of the ``[plant.mujoco]`` realism
options, so the gap between the two columns is the physics. Runs are independent and go to worker
processes; the numbers do not depend on how many.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .. import compiled as compiled_paths
from ..assembly import run_scenario, scene
from ..engine import compiled_loop
from ..metrics import finite_max_abs, run_summary
from ..scenario import Scenario, load_scenario
from ..sharing import sharing
from ..summary import Summary
from ..sweep import run_batch
from ..timegrid import TimeGrid
from ..workers import Forks, worker_count

SEEDS = tuple(range(1, 21))  # sensor-noise seeds of every row with noise on
ALONE_PER_JOB = 8  # runs of one file alone (no noise) in a worker's job: small jobs keep the end balanced
SEED_OVERRIDE = "plant.mujoco.noise_seed="
StudyLaw = tuple[str, tuple[str, ...]]  # a law of the study: its name and the overrides that select it
LAWS: tuple[StudyLaw, ...] = (("proposed", ()), ("comparison", ("controller.kind=comparison",)))
EXAMPLES = (("example2", "example2-arm"), ("example1", "example1-cart"))  # (ideal, realistic)
NUMBERS = ("max_abs_z1_last_half", "max_abs_u_applied", "saturated_fraction", "lemma2_max_ratio")
RECOVERY_BAND = 0.1  # |z1| < 0.1: Table 1's smallest omega
LABELS = {  # realism options of [plant.mujoco] studied alone, in this order
    "torque_limit": "torque limit", "frictionloss": "friction", "armature": "rotor inertia (armature)",
    "rod_mass": "link mass (rod)", "sensor_noise": "sensor noise", "sensor_delay": "sensor delay",
    "sensor_period": "sensor period",
}
# Margins: each imperfection alone on the ideal scenario, beyond the hardware: (label, unit, values,
# overrides with {v} the value). The realistic values are in the scenario files.
MARGINS: dict[str, tuple[tuple[str, str, tuple[float, ...], tuple[str, ...]], ...]] = {
    "example2": (
        ("torque limit", "N m", (20.0, 10.0, 5.0), ("plant.mujoco.torque_limit={v!r}",)),
        ("friction", "N m", (10.0, 30.0), ("plant.mujoco.frictionloss={v!r}",)),
        ("sensor delay", "s", (0.02, 0.05), ("plant.mujoco.sensor_delay={v!r}",)),
        ("control period", "s", (0.02, 0.05), ("simulation.control_period={v!r}",)),
        ("x2 differenced over T", "s", (0.005, 0.02, 0.05),
         ('simulation.velocity_source="difference"', "simulation.control_period={v!r}")),
    ),
    "example1": (
        ("force limit", "N", (2.0, 1.0), ("plant.mujoco.torque_limit={v!r}",)),
        ("friction", "N", (0.1, 0.3, 3.0), ("plant.mujoco.frictionloss={v!r}",)),
        ("sensor delay", "s", (0.05,), ("plant.mujoco.sensor_delay={v!r}",)),
        ("control period", "s", (0.05,), ("simulation.control_period={v!r}",)),
        ("x2 differenced over T", "s", (0.02, 0.1),
         ('simulation.velocity_source="difference"', "simulation.control_period={v!r}")),
    ),
}
# Disturbances on the arm, at half the run: a bump (20 N m for 50 ms: 1 N m s, as in
# example2-arm.toml) and a load that stays (10 N m, about 30 % of the largest gravity torque).
DISTURBANCES = (
    ("impulse", 'disturbance=[{{kind = "impulse", start = {t!r}, duration = 0.05, force = 20.0}}]'),
    ("load step", 'disturbance=[{{kind = "step", start = {t!r}, value = 10.0}}]'),
)


@dataclass(frozen=True)
class StudyJob:
    """One run of the study: a scenario file, its overrides and the backend (picklable)."""

    path: str
    overrides: tuple[str, ...]
    backend: str


def _summaries(tasks: Sequence[StudyJob]) -> list[Summary]:
    """Worker entry point: the summaries (metrics only) of a job's runs (:func:`batches`): each run
    alone where a single run takes the compiled loop (its sensor noise included; a process running
    many pays for numba's start once), else a row's seeds stepped as one batch (short runs, or no
    compiled paths). A run's numbers are its own either way."""
    _compiled_paths()
    with sharing():  # (what the runs' scenarios and plants share is checked once)
        scenarios = [load_scenario(t.path, list(t.overrides)) for t in tasks]
        backend = tasks[0].backend
        if len({_row(t) for t in tasks}) == 1 and len(tasks) > 1 and not runs_alone(scenarios[0]):
            return run_batch(scenarios, backend)
        return [run_batch([sc], backend)[0] for sc in scenarios]


def _row(task: StudyJob) -> tuple:
    """What the runs of one row share: all but the sensor-noise seed."""
    return task.backend, task.path, tuple(o for o in task.overrides if not o.startswith(SEED_OVERRIDE))


def runs_alone(sc: Scenario) -> bool:
    """Whether a study's runs like ``sc`` go faster one by one than as a batch: where a single run
    takes the compiled loop (compiled paths asked for, runs of at least
    :data:`~qcontrol.engine.compiled_loop.MIN_ROWS` rows). One compiled loop serves every run of
    the same structure whatever its numbers."""
    sim = sc.simulation
    return compiled_paths.requested() and TimeGrid.of(sim.duration, sim.dt).rows >= compiled_loop.MIN_ROWS


def _compiled_paths() -> None:
    """Start numba in this process, if compiled paths are asked for (a study's many runs pay
    for its start; :func:`~qcontrol.engine.compiled_loop.numba_pays`)."""
    if compiled_paths.requested():
        compiled_paths.enabled()


def batches(tasks: Sequence[StudyJob]) -> list[list[int]]:
    """The tasks' indices in jobs for the workers: a row's sensor-noise seeds together (runs that
    differ in the seed alone, so they share :func:`~qcontrol.assembly.batch_structure`), the other
    runs by scenario file and backend, at most :data:`ALONE_PER_JOB` a job (loaded and built
    together, :func:`~qcontrol.sharing.sharing`: what they share is checked once, about a tenth of
    their CPU time); the largest first, so that workers start on the longest work."""
    rows: dict[tuple, list[int]] = {}
    for i, task in enumerate(tasks):
        rows.setdefault(_row(task), []).append(i)
    files: dict[tuple, list[int]] = {}
    for row in rows.values():
        if len(row) == 1:
            files.setdefault((tasks[row[0]].backend, tasks[row[0]].path), []).append(row[0])
    alone = [ids[j:j + ALONE_PER_JOB] for ids in files.values() for j in range(0, len(ids), ALONE_PER_JOB)]
    return sorted([row for row in rows.values() if len(row) > 1] + alone, key=len, reverse=True)


@dataclass(frozen=True)
class Errors:
    """What a disturbance case needs of a run: its instants, z1, and whether it diverged."""

    t: np.ndarray
    z1: np.ndarray
    diverged: bool


def _errors(runs: Sequence[tuple[StudyJob, bool]]) -> list[tuple[Errors, Summary | None]]:
    """Worker entry point: for each ``(task, summarized)``, the tracking error of the task's run
    (full record) and, ``summarized``, its summary (a row reads the same run: the full record's
    summary is the metrics record's). The runs' scenarios are loaded and their plants built
    together (:func:`~qcontrol.sharing.sharing`: what they share is checked once)."""
    _compiled_paths()
    out = []
    with sharing():
        for task, summarized in runs:
            sc = load_scenario(task.path, list(task.overrides))
            run = run_scenario(sc, task.backend)
            out.append((Errors(run.t, run.z[:, 0].copy(), bool(run.diverged)),
                        run_summary(run, sc.name, task.backend) if summarized else None))
    return out


def recovery(disturbed: Errors, quiet: Errors, start: float, delta: float) -> dict:
    """What a disturbance at ``start`` did to the tracking error z1 (``quiet``: the same run without it).

    ``peak_abs_z1`` (and ``peak_abs_z1_undisturbed``): max |z1| from ``start`` on;
    ``peak_deviation``: max |z1 - z1_undisturbed| from ``start`` on; ``recovery_time_s``: from
    ``start`` until |z1| < 0.1 holds to the end (None: never); ``recovery_to_undisturbed_s``: from
    ``start`` until z1 is back within delta of the undisturbed run's for good (None: never);
    ``final_deviation``: max |z1 - z1_undisturbed| over the last second."""
    rows = min(len(disturbed.t), len(quiet.t))
    t, z, zq = disturbed.t[:rows], disturbed.z1[:rows], quiet.z1[:rows]
    after = t >= start - 1e-12
    deviation = np.abs(z - zq)
    return {
        "diverged": bool(disturbed.diverged), "peak_abs_z1": finite_max_abs(z[after]),
        "peak_abs_z1_undisturbed": finite_max_abs(zq[after]),
        "peak_deviation": finite_max_abs(deviation[after]),
        "recovery_time_s": _settled(t, np.abs(z), RECOVERY_BAND, after, start, disturbed.diverged),
        "recovery_to_undisturbed_s": _settled(t, deviation, delta, after, start, disturbed.diverged),
        "final_deviation": finite_max_abs(deviation[t >= t[-1] - 1.0]),
    }


def _settled(t: np.ndarray, values: np.ndarray, band: float, after: np.ndarray, start: float,
             diverged: bool) -> float | None:
    """Time from ``start`` to the first row after which ``values < band`` holds to the end (None:
    never; NaN counts as outside)."""
    bad = np.flatnonzero(after & ~(values < band))
    if diverged or (bad.size and bad[-1] == len(t) - 1):
        return None
    return 0.0 if not bad.size else float(t[bad[-1] + 1] - start)


# --------------------------------------------------------------------------------------------
# the cases


def imperfections(realistic: Scenario) -> list[tuple[str, tuple[str, ...]]]:
    """``(label, overrides on the ideal scenario)`` for each imperfection of ``realistic`` alone,
    then the x2 differenced from the encoder."""
    o, sim = realistic.backends["mujoco"], realistic.simulation
    values = {"torque_limit": o.torque_limit, "frictionloss": o.frictionloss, "armature": o.armature,
              "rod_mass": o.rod_mass, "sensor_noise": list(o.sensor_noise), "sensor_delay": o.sensor_delay,
              "sensor_period": o.sensor_period}
    labels = LABELS | {"torque_limit": _limit_label(realistic)}
    rows = [(labels[key], (f"plant.mujoco.{key}={values[key]!r}",)) for key in LABELS if key in o.realism]
    if sim.control_period is not None:
        rows.append(("control period", (f"simulation.control_period={sim.control_period!r}",)))
    rows.append(("x2 differenced", ('simulation.velocity_source="difference"',)))
    return rows


def _limit_label(sc: Scenario) -> str:
    """"torque limit" on a hinge, "force limit" on a slide."""
    return "torque limit" if scene(sc).hinge else "force limit"


def _seeded(overrides: Sequence[str], noisy: bool) -> list[tuple[str, ...]]:
    """The override sets of a row: one per seed when sensor noise is on, else the row itself."""
    if not noisy:
        return [tuple(overrides)]
    return [(*overrides, f"{SEED_OVERRIDE}{s}") for s in SEEDS]


def _physics_free(overrides: Sequence[str]) -> tuple[str, ...]:
    """What the ODE twin shares: every override but the MuJoCo model's."""
    return tuple(o for o in overrides if not o.startswith("plant.mujoco."))


@dataclass
class Plan:
    """Every task of the study, each run once, and how the rows find their summaries.
    ``no_ops``: per scenario file, the overrides that change nothing of it (left out of a task,
    so that the same run asked for twice is one task)."""

    tasks: list[StudyJob]
    index: dict[StudyJob, int]
    no_ops: dict[str, frozenset[str]] = field(default_factory=dict)

    def add(self, task: StudyJob) -> StudyJob:
        kept = self.no_ops.get(task.path, frozenset())
        task = StudyJob(task.path, tuple(o for o in task.overrides if o not in kept), task.backend)
        if task not in self.index:
            self.index[task] = len(self.tasks)
            self.tasks.append(task)
        return task


def study_law(kind: str) -> StudyLaw:
    """A registered controller kind as a law of the study (one given with ``--law``)."""
    return kind, (f"controller.kind={kind!r}",)


@dataclass
class Study:
    """The study's plan: its rows, margins and disturbance cases, and the runs they read
    (``plan``: summaries; ``full``: the disturbance cases' full runs)."""

    rows: list[dict]
    margins: list[dict]
    disturbances: list[dict]
    plan: Plan
    full: Plan


def robustness_study(scenarios: Path, duration: float | None, workers: int,
                     log: Callable[[str], None] = print, laws: Sequence[StudyLaw] = LAWS) -> dict:
    """Run the whole study for each of ``laws`` (default: the paper's law and the comparison law);
    the object written to ``robustness.json``."""
    with started(scenarios, duration, workers, log, laws) as running:
        return running.result()


class Running(NamedTuple):
    """A started study: ``result()`` waits for it and returns the object of
    :func:`robustness_study`; ``side[i]()`` waits for the i-th side job and returns its value."""

    result: Callable[[], dict]
    side: list[Callable[[], Any]]


@contextmanager
def started(scenarios: Path, duration: float | None, workers: int, log: Callable[[str], None] = print,
            laws: Sequence[StudyLaw] = LAWS, side: Sequence[tuple[Callable, tuple]] = ()
            ) -> Iterator[Running]:
    """The study started on ``workers`` worker processes (more than one: they run while the
    caller does other work); yields its :class:`Running`. ``side``: other independent jobs
    ``(function, arguments)`` of the caller's (their values picklable), given to the workers first
    (in this process, when asked for, without workers). The workers end with the block."""
    study = _plan(scenarios, duration, laws)
    workers = worker_count(workers, len(study.plan.tasks))
    log(f"study: robustness: {len(study.plan.tasks)} runs, {len(study.disturbances)} disturbance cases, "
        f"on {workers} worker(s)")
    compiled_paths.started()  # (before the workers fork: they start with numba loaded and started)
    calls, results = _execute(study.plan.tasks, study.full.tasks)
    calls = [*side, *calls]  # (in the order the workers take them)

    def call(k: int) -> Any:
        function, arguments = calls[k]
        return function(*arguments)

    with Forks(workers, len(calls), call) if workers > 1 else nullcontext() as forks:
        answer = call if forks is None else forks.result
        yield Running(lambda: _assembled(study, *results(lambda k: answer(len(side) + k))),
                      [lambda k=k: answer(k) for k in range(len(side))])


def _plan(scenarios: Path, duration: float | None, laws: Sequence[StudyLaw]) -> Study:
    """Every row, margin and disturbance case of the study, and the runs they read (each once)."""
    extra = (f"simulation.duration={duration!r}",) if duration is not None else ()
    no_ops = {str(scenarios / f"{name}.toml"): _no_ops(load_scenario(scenarios / f"{name}.toml", list(extra)))
              for pair in EXAMPLES for name in pair}
    plan = Plan([], {}, no_ops)
    rows, margins, disturbances = [], [], []
    for ideal, realistic in EXAMPLES:
        ideal_path, real_path = str(scenarios / f"{ideal}.toml"), str(scenarios / f"{realistic}.toml")
        real = load_scenario(real_path, list(extra))
        noisy_real = "sensor_noise" in real.backends["mujoco"].realism
        cases = [("ideal", ideal_path, ()), *((label, ideal_path, o) for label, o in imperfections(real)),
                 ("all together", real_path, ("disturbance=[]",))]
        for law, law_overrides in laws:
            for label, path, overrides in cases:
                noisy = label == "sensor noise" or (label == "all together" and noisy_real)
                sets = _seeded((*overrides, *law_overrides, *extra), noisy)
                rows.append({"example": ideal, "imperfection": label, "law": law, "scenario": Path(path).stem,
                             "overrides": list(sets[0][: len(overrides)]),
                             "seeds": list(SEEDS) if noisy else None,
                             "mujoco": [plan.add(StudyJob(path, s, "mujoco")) for s in sets],
                             "ode": [plan.add(StudyJob(path, _physics_free(sets[0]), "ode"))]})
            for label, unit, values, templates in MARGINS[ideal]:
                for v in values:
                    overrides = tuple(t.format(v=v) for t in templates)
                    margins.append({"example": ideal, "imperfection": label, "unit": unit, "value": v,
                                    "law": law, "overrides": list(overrides),
                                    "mujoco": [plan.add(StudyJob(ideal_path,
                                                                 (*overrides, *law_overrides, *extra),
                                                                 "mujoco"))]})
        if ideal == "example2":
            disturbances += _disturbance_cases(ideal_path, real_path, real.simulation.duration, extra, laws)
    full = Plan([], {}, no_ops)
    for case in disturbances:
        case["runs"] = (full.add(case.pop("task")), full.add(case.pop("quiet")))
    return Study(rows, margins, disturbances, plan, full)


def _no_ops(sc: Scenario) -> frozenset[str]:
    """The study's overrides that change nothing of ``sc``: ``disturbance=[]`` where it has no
    ``[[disturbance]]``, its own sensor-noise seed (a row's first seed, the quiet run of a
    disturbance case: the same run as a row's)."""
    mujoco = sc.backends.get("mujoco")
    return frozenset([*([] if sc.disturbances else ["disturbance=[]"]),
                      *([] if mujoco is None else [f"{SEED_OVERRIDE}{mujoco.noise_seed}"])])


def _assembled(study: Study, summaries: list[Summary], errors: list[Errors]) -> dict:
    """The study's object from its runs' summaries and full runs."""
    rows, margins, disturbances, plan, full = (study.rows, study.margins, study.disturbances, study.plan,
                                               study.full)
    for row in rows + margins:
        for backend in ("mujoco", "ode"):
            if backend in row:
                row[backend] = aggregate([summaries[plan.index[task]] for task in row[backend]])
    for case in disturbances:
        disturbed, quiet = (errors[full.index[task]] for task in case.pop("runs"))
        case["result"] = recovery(disturbed, quiet, case["start"], case.pop("delta"))
    return {"seeds": list(SEEDS), "recovery_band": RECOVERY_BAND, "rows": rows, "margins": margins,
            "disturbances": disturbances}


def _disturbance_cases(ideal_path: str, real_path: str, duration: float, extra: tuple[str, ...],
                       laws: Sequence[StudyLaw]) -> list[dict]:
    """An impulse and a load step at half the run on the ideal and the realistic arm, each law,
    on MuJoCo and on the ODE twin."""
    start = duration / 2.0
    cases = []
    for plant, path in (("ideal arm", ideal_path), ("realistic arm", real_path)):
        delta = load_scenario(path, list(extra)).controller.delta
        for kind, template in DISTURBANCES:
            for law, law_overrides in laws:
                for backend in ("mujoco", "ode"):
                    overrides = (template.format(t=start), *law_overrides, *extra)
                    cases.append({"plant": plant, "scenario": Path(path).stem, "disturbance": kind,
                                  "law": law, "backend": backend, "start": start, "overrides": [overrides[0]],
                                  "delta": delta, "task": StudyJob(path, overrides, backend),
                                  "quiet": StudyJob(path, ("disturbance=[]", *law_overrides, *extra),
                                                    backend)})
    return cases


def _execute(tasks: list[StudyJob], full: list[StudyJob]
             ) -> tuple[list[tuple[Callable, tuple]], Callable[[Callable[[int], Any]], tuple[list, list]]]:
    """The calls ``(function, arguments)`` that make every task's summary and every full run's
    tracking error: the summaries in :func:`batches`, the full runs by file and backend (a task
    that is also a full run takes its summary from it), in the order workers take them (the rows'
    seeds first, the longest jobs, then the full runs, then the runs alone); and the function that
    gives the summaries and errors, in order, from ``answer(k)``, the k-th call's value (waited
    for, or made then when there are no workers)."""
    in_full = {task: i for i, task in enumerate(full)}
    own = [i for i, task in enumerate(tasks) if task not in in_full]
    chunks = [[own[j] for j in ids] for ids in batches([tasks[i] for i in own])]
    jobs = [[tasks[i] for i in ids] for ids in chunks]
    summarized = {in_full[task] for task in tasks if task in in_full}
    together: dict[tuple[str, str], list[int]] = {}  # the full runs of one file on one backend
    for i, task in enumerate(full):
        together.setdefault((task.path, task.backend), []).append(i)
    groups = list(together.values())
    fulls = [[(full[i], i in summarized) for i in ids] for ids in groups]
    seeds = [j for j, job in enumerate(jobs) if len(job) > ALONE_PER_JOB]
    alone = [j for j, job in enumerate(jobs) if len(job) <= ALONE_PER_JOB]
    calls = [*((_summaries, (jobs[j],)) for j in seeds), *((_errors, (f,)) for f in fulls),
             *((_summaries, (jobs[j],)) for j in alone)]
    at = {j: k for k, j in enumerate(seeds)} | {j: len(seeds) + len(fulls) + k for k, j in enumerate(alone)}

    def results(answer: Callable[[int], Any]) -> tuple[list[Summary], list[Errors]]:
        summaries: list[Summary] = [None] * len(tasks)  # type: ignore[list-item]
        ran = [answer(at[j]) for j in range(len(jobs))]
        grouped = [answer(len(seeds) + k) for k in range(len(fulls))]
        for ids, job in zip(chunks, ran, strict=True):
            for i, s in zip(ids, job, strict=True):
                summaries[i] = s
        runs: list[tuple[Errors, Summary | None]] = [None] * len(full)  # type: ignore[list-item]
        for ids, group in zip(groups, grouped, strict=True):
            for i, r in zip(ids, group, strict=True):
                runs[i] = r
        for i, task in enumerate(tasks):
            if task in in_full:
                summaries[i] = runs[in_full[task]][1]
        return summaries, [errors for errors, _ in runs]

    return calls, results


def default_workers() -> int:
    """Worker processes for the study: the machine's cores, at most 4."""
    return worker_count(4, 4)


# --------------------------------------------------------------------------------------------
# aggregation


def _spread(values: Sequence[float]) -> dict[str, float]:
    finite = [v for v in values if v is not None and np.isfinite(v)]
    if not finite:
        return {"median": float("nan"), "min": float("nan"), "max": float("nan")}
    return {"median": float(statistics.median(finite)), "min": float(min(finite)), "max": float(max(finite))}


def aggregate(summaries: Sequence[Summary]) -> dict:
    """One row's runs (one, or one per seed): every number as median, min and max over the runs
    (over the finite values: a diverged run has no max |z1| over the last half), and how many
    runs diverged."""
    omegas = list(summaries[0].error_rate)
    return {
        "runs": len(summaries),
        "diverged": sum(bool(s.diverged) for s in summaries),
        "lemma2_applies": all(s.lemma2_applies for s in summaries),
        "error_rate": {w: _spread([s.error_rate[w] for s in summaries]) for w in omegas},
        **{key: _spread([getattr(s, key) for s in summaries]) for key in NUMBERS},  # fields of Summary
    }

