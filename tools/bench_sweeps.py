"""tools/bench.py's sweeps and regions (``--sweeps``, ``--only-sweeps``) against the runs' bare steps
on one core, and ``qcontrol reproduce``'s wall and CPU time (``--reproduce``)."""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from bench_limits import ROOT, compiled_rk4, mj_step_loop, scenario
from bench_timing import best_of_both

from qcontrol.assembly import build_plant
from qcontrol.scenario import Scenario
from qcontrol.sweep import sweep_summaries


def cpu_seconds() -> float:
    """User + system CPU time of this process and of its children that have ended (workers)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def reproduce_wall(workers: int) -> dict:
    """Wall and CPU time of ``qcontrol reproduce`` (the whole command, in a fresh process): on a
    loaded machine the CPU time says what the wall time cannot."""
    with tempfile.TemporaryDirectory(prefix="qcontrol-bench-") as tmp:
        started, cpu = time.perf_counter(), cpu_seconds()
        subprocess.run([sys.executable, "-m", "qcontrol.cli", "reproduce", "--out", tmp, "-q",
                        "--workers", str(workers)], check=True, stdout=subprocess.DEVNULL)
        return {"wall_s": time.perf_counter() - started, "cpu_s": cpu_seconds() - cpu, "workers": workers}


# wall time / the runs' bare steps on one core, on 2 workers; on W workers the target is 2 / W times
# this (the same work per core: the batches cost about one bare step per copy-step)
SWEEP_TARGETS = {("mujoco", "sweep", 200): 0.65, ("mujoco", "sweep", 1000): 0.6, ("ode", "sweep", 1000): 4.0,
                 ("mujoco", "region", 121): 0.65, ("ode", "region", 121): 4.0}


def bare_limits(sc: Scenario, repeat: int) -> dict:
    """Seconds of one bare step on one core: a C ``mj_step`` of the model (no passive callback,
    without the bindings' profiling timer, as the runs step) and a step of the compiled bare RK4
    of the right-hand side (ODE); the shortest CPU time of ``repeat`` loops (a loop's wall time on
    a shared machine counts the waits for a core: at a load of 15 it made mj_step 6.4 us, not 3.4)."""
    steps = round(sc.simulation.duration / sc.simulation.dt)
    rk4 = compiled_rk4(sc)
    mj_step = mj_step_loop(build_plant(sc, "mujoco"), steps, installed=False)
    return {"mujoco": best_of_both(repeat, mj_step)[1] / steps,
            "ode": best_of_both(repeat, lambda: rk4(steps))[1] / steps}


def sweep_limits(duration: float, workers: int, repeat: int) -> dict:
    """200- and 1000-run sweeps of Example 2 (per-copy kappa) on ``workers`` local workers, and
    ``qcontrol region`` (:func:`region_limits`): wall and CPU time, per simulated second, and
    against the runs' bare steps on one core (:func:`bare_limits`, measured before and after the
    sweeps: the shorter, the load may change meanwhile), with the targets. Each is timed as
    :func:`timings` says (a sweep of several seconds once, the ODE region about ten times): the
    figure is the shortest wall time, the median beside it."""
    path = ROOT / "scenarios" / "example2.toml"
    sc = scenario("example2", duration)
    before = bare_limits(sc, max(3, repeat))
    timed: dict = {}
    for backend, runs in (("mujoco", 200), ("mujoco", 1000), ("ode", 1000)):
        sets = [[f"simulation.duration={duration!r}", f"controller.kappa_margin={m!r}"]
                for m in np.linspace(0.1, 1.1, runs).tolist()]
        walls, cpus, _ = timings(lambda sets=sets, backend=backend: sweep_summaries(
            path, sets, backend=backend, workers=workers))
        timed[backend, "sweep", runs] = (walls, cpus, {})
    timed.update(region_limits(path, duration, workers))
    after = bare_limits(sc, max(3, repeat))
    limit = {backend: min(before[backend], after[backend]) for backend in before}
    steps = round(duration / sc.simulation.dt)
    out = {}
    for (backend, kind, runs), (walls, cpus, extra) in timed.items():
        bare = runs * steps * limit[backend]
        wall, cpu, median = min(walls), min(cpus), statistics.median(walls)
        out[f"{backend}_{'region_' if kind == 'region' else ''}{runs}"] = {
            "wall_s": wall, "cpu_s": cpu, "ratio_to_bare_one_core": wall / bare,
            "wall_s_median": median, "ratio_median": median / bare, "walls_s": walls,
            "cpu_ratio_to_bare": cpu / bare,  # (this process and its workers: what the work cost)
            "wall_ms_per_simulated_s": wall / (runs * duration) * 1e3,
            "cpu_ms_per_simulated_s": cpu / (runs * duration) * 1e3,
            "target": f"<= {SWEEP_TARGETS[backend, kind, runs] * 2 / workers:g}", **extra}
    return {"duration_s": duration, "workers": workers, "load": os.getloadavg()[0], "runs": out,
            "bare_mj_step_us": limit["mujoco"] * 1e6, "bare_rk4_ns": limit["ode"] * 1e9,
            "bare_before_after": {k: [before[k], after[k]] for k in before},
            "note": "targets on 2 workers; on W workers 2 / W times those (the same work per core)"}


def region_limits(path: Path, duration: float, workers: int) -> dict:
    """``qcontrol region`` of Example 2 (the paper's law, 11 x 11 starts in |x_i| <= 1.5, all of
    them bounded) on ``workers`` local workers: (backend, "region", runs) -> (wall, CPU, extra)."""
    from qcontrol.region import RegionGrid, measure_region, parse_law

    grid, out = RegionGrid((0, 1), (-1.5, -1.5), (1.5, 1.5), 11), {}
    for backend in ("mujoco", "ode"):
        walls, cpus, region = timings(lambda backend=backend: measure_region(
            path, grid, [parse_law("proposed")], backend, overrides=[f"simulation.duration={duration!r}"],
            workers=workers))
        out[backend, "region", len(region.points)] = (
            walls, cpus, {"diverged": sum(p.outcome != "bounded" for p in region.points)})
    return out


# A sweep or region is timed until these seconds are spent (at most TIMINGS times): the ODE region
# of 121 runs takes 0.15-0.21 s on 2 idle cores, where its work (the longer half and the planning,
# in CPU) is about 0.12 s; a single timing that short is the machine's, not the code's
BUDGET_S, TIMINGS = 2.0, 9


def timings(run: Callable[[], Any]) -> tuple[list[float], list[float], Any]:
    """Wall and CPU times (this process and its workers) of ``run()``, once and again while the
    runs took less than :data:`BUDGET_S` in all (at most :data:`TIMINGS` times), and its last result."""
    walls: list[float] = []
    cpus: list[float] = []
    while not walls or (sum(walls) < BUDGET_S and len(walls) < TIMINGS):
        started, used = time.perf_counter(), cpu_seconds()
        result = run()
        walls.append(time.perf_counter() - started)
        cpus.append(cpu_seconds() - used)
    return walls, cpus, result


def report_sweeps(sweeps: dict) -> None:
    """The lines of :func:`sweep_limits`: wall time against the runs' bare steps on one core."""
    for label, r in sweeps["runs"].items():
        backend, *region, runs = label.split("_")
        kind, limit = "region" if region else "sweep", "mj_step" if backend == "mujoco" else "RK4"
        what = f"{backend} {kind} of {runs}, {sweeps['workers']} w. / bare {limit} on 1 core"
        count = len(r["walls_s"])
        timed = (f"best of {count}: {r['wall_s']:.2f} s wall, median {r['wall_s_median']:.2f} s = "
                 f"{r['ratio_median']:.3f} x bare" if count > 1 else f"{r['wall_s']:.2f} s wall")
        print(f"{what:52s} "
              f"{r['ratio_to_bare_one_core']:10.3f}  {r['target']:7s} ({timed}, "
              f"CPU {r['cpu_s']:.2f} s = {r['cpu_ratio_to_bare']:.3f} x bare; per simulated s "
              f"{r['wall_ms_per_simulated_s']:.2f} ms wall, {r['cpu_ms_per_simulated_s']:.2f} ms CPU)")
    print(f"{'':52s} (bare mj_step {sweeps['bare_mj_step_us']:.3f} us untimed, bare RK4 step "
          f"{sweeps['bare_rk4_ns']:.1f} ns; load {sweeps['load']:.1f}; {sweeps['note']})")
