"""qcontrol's performance figures, as ratios measured in one process against the physical limit
(the targets: docs/performance.md).

    python tools/bench.py [--quick] [--json FILE] [--repeat N] [--sweeps | --only-sweeps] [--reproduce]

* MuJoCo closed loop: us per step, and the ratio to a bare C ``mj_step`` loop on the same model
  and integrator with no passive callback; ``mj_step`` with the plant's native callback, and with
  the Python one, against the same bare loop.
* ODE backend, one run: the speed-up over scipy's ``solve_ivp`` (RK45, max_step = dt) on the same
  closed loop: the controller is evaluated inside the right-hand side from the quantized state and
  eps_hat is part of the ODE state; and the ratio to a compiled (numba) bare RK4 loop of the same
  right-hand side.
* 1000 Example 2 runs batched on MuJoCo (``mujoco.batch``), per copy and step against bare
  ``mj_step``; ``--reproduce``: the wall time of ``qcontrol reproduce``.
* Batched ODE runs of Example 2 (per-copy kappa, ``record="metrics"``): N = 1, 10, 100, 1000,
  the cost per copy and step against one step of the compiled bare RK4 of the right-hand side
  (target: <= 3 at N = 1000).
* Recording: the seconds ``--rrd`` adds to ``qcontrol run`` of Example 2 (MuJoCo), per simulated
  second (target <= 5 ms); the peak traced memory of a 10 s, 10 kHz run (full record).
* User laws: the paper's law (44)-(45) written by hand in each documented form of a user law
  against the built-in kind, single run and batch (tools/bench_laws.py; target <= 2x).
* ``--sweeps``: 200- and 1000-run ``sweep_summaries`` of 10 s Example 2 runs on ``--workers``:
  on MuJoCo the wall time against the runs' bare C ``mj_step`` steps on one core (untimed, as the
  runs step; targets on 2 workers: <= 0.65 and <= 0.6), on the ODE against the runs' compiled bare
  RK4 on one core (target for 1000 runs <= 4); the same for ``qcontrol region`` (121 bounded starts
  of Example 2, both backends; <= 0.65 on MuJoCo, <= 4 on the ODE); on W workers the targets are
  2 / W times those; wall and CPU time (this process and its workers) per simulated second; the
  bare steps' CPU time measured before and after (slow). ``--only-sweeps``: these figures alone.

Timings are best-of-N (the machine may be shared); ``--quick`` shortens every horizon.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import bench_laws
import mujoco
import numpy as np
from bench_timing import best_of, best_of_both
from bench_timing import python_loop as compiled_off  # QCONTROL_COMPILE=0 inside the block

from qcontrol.assembly import (
    build_controller,
    build_law,
    build_plant,
    build_quantizer,
    build_reference,
    run_scenario,
)
from qcontrol.engine import RunSpec, simulate
from qcontrol.plants.mujoco.callbacks import untimed
from qcontrol.quantizer import QuantizedReading
from qcontrol.scenario import Scenario, load_scenario
from qcontrol.sweep import sweep_summaries
from qcontrol.timegrid import TimeGrid

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ("example1", "example2")


def scenario(name: str, duration: float, dt: float | None = None) -> Scenario:
    overrides = [f"simulation.duration={duration!r}"] + ([f"simulation.dt={dt!r}"] if dt else [])
    return load_scenario(ROOT / "scenarios" / f"{name}.toml", overrides)


# --------------------------------------------------------------------------------------------


def _mj_step_loop(plant, steps: int, installed: bool) -> Callable[[], None]:
    """``steps`` calls of ``mj_step`` on the plant's first copy, at rest at x = 0 with no input (an
    equilibrium of both examples), with the plant's passive callback installed or with none."""
    model, data = plant.model, plant._datas[0]

    def loop() -> None:
        if installed:
            with plant:
                plant.reset(np.zeros((plant.batch, 2)))
                for _ in range(steps):
                    mujoco.mj_step(model, data)
        else:  # (without the bindings' profiling timer, as a run steps: the physics alone)
            with untimed():
                plant.reset(np.zeros((plant.batch, 2)))
                for _ in range(steps):
                    mujoco.mj_step(model, data)

    return loop


def compiled_loop_in_use(sc: Scenario, backend: str) -> bool:
    """Whether a single run of ``sc`` on ``backend`` runs the compiled loop to its end."""
    from qcontrol.assembly import build_controller, run_spec
    from qcontrol.engine import ClosedLoop

    loop = ClosedLoop(run_spec(sc, build_plant(sc, backend), build_controller(sc), [sc.x0], None))
    loop.run()
    return loop.handover is None


_FIRST_RUN = """
import sys, time
started = time.perf_counter()
import numba  # a process that has started numba (else a 10 s ODE run stays in Python)
from qcontrol.assembly import run_scenario
from qcontrol.engine import compiled_loop
from qcontrol.scenario import load_scenario
if sys.argv[3] == "compile":  # compiled though the structure was not compiled before (compile_pays)
    compiled_loop.COLD_MIN_ROWS = 0
sc = load_scenario(sys.argv[1], ["simulation.duration=10.0"])
loaded = time.perf_counter()
run_scenario(sc, sys.argv[2])
print(time.perf_counter() - loaded, loaded - started)
"""


def compile_times(backend: str) -> dict:
    """A 10 s Example 2 run in a new process with an empty cache folder (a structure not compiled
    before, 10,001 rows: the Python loop; on MuJoCo the passive callback compiled), again with the
    loop's compile forced (``COLD_MIN_ROWS = 0``), again (loaded from the disk cache), and with
    ``QCONTROL_COMPILE=0`` (the Python loop): seconds of the run call itself, numba imported
    before it (its import, about 0.3 s, not counted; its set-up at the first compiled call is)."""
    times = {}
    with tempfile.TemporaryDirectory() as cache:
        for label, how in (("first_run_s", "1"), ("compile_run_s", "compile"), ("cached_run_s", "1"),
                           ("python_loop_s", "0")):
            env = {**os.environ, "QCONTROL_CACHE_DIR": cache, "QCONTROL_COMPILE": "0" if how == "0" else "1"}
            path = str(ROOT / "scenarios" / "example2.toml")
            out = subprocess.run([sys.executable, "-c", _FIRST_RUN, path, backend, how], env=env,
                                 capture_output=True, text=True, check=True).stdout
            times[label] = float(out.split()[0])
    return times


def mujoco_ratio(sc: Scenario, repeat: int) -> dict:
    """The closed loop on MuJoCo against the physical limit, a bare C ``mj_step`` loop (no passive
    callback); and ``mj_step`` with the plant's passive callback (native, and Python) against it."""
    steps = round(sc.simulation.duration / sc.simulation.dt)
    plant = build_plant(sc, "mujoco")
    plant.native_for_run()  # the native callback compiled (or loaded) before the timing
    closed = best_of(repeat, lambda: run_scenario(sc, "mujoco", plant=plant)) / steps
    bare = best_of(repeat, _mj_step_loop(plant, steps, installed=False)) / steps
    native = best_of(repeat, _mj_step_loop(plant, steps, installed=True)) / steps
    with compiled_off():
        python_plant = build_plant(sc, "mujoco")
        python = best_of(repeat, _mj_step_loop(python_plant, steps, installed=True)) / steps
        python_loop = best_of(repeat, lambda: run_scenario(sc, "mujoco", plant=python_plant)) / steps
    return {"closed_loop_us_per_step": closed * 1e6, "bare_mj_step_us_per_step": bare * 1e6,
            "compiled_loop": compiled_loop_in_use(sc, "mujoco"), "python_loop_us_per_step": python_loop * 1e6,
            "python_loop_ratio": python_loop / bare,
            "native_callback_us_per_step": native * 1e6, "python_callback_us_per_step": python * 1e6,
            "ratio": closed / bare, "native_callback_ratio": native / bare,
            "python_callback_ratio": python / bare, "native_in_use": plant._native is not None,
            "target": "closed loop <= 1.3, native callback <= 1.05 (x bare mj_step)"}


def solve_ivp_closed_loop(sc: Scenario) -> None:
    """The same closed loop through scipy: controller inside the rhs, eps_hat in the state."""
    from scipy.integrate import solve_ivp

    plant, controller = build_plant(sc, "ode"), build_controller(sc)
    quantizer, reference = build_quantizer(sc), build_reference(sc)
    n = sc.order

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        x, eps = y[None, :n], y[None, n:]
        reading = QuantizedReading(quantizer(x), quantizer.max_error)
        out = controller.control(reading, reference.derivatives(t, n), tuple(eps.T))
        deps = (np.column_stack(out.target) - eps) * out.rate  # eq. (45): gamma (s r - sigma eps)
        return np.concatenate([plant.rhs(x, out.u)[0], deps[0]])

    y0 = np.concatenate([sc.x0, np.zeros(controller.state_size)])
    dt, duration = sc.simulation.dt, sc.simulation.duration
    solve_ivp(rhs, (0.0, duration), y0, method="RK45", max_step=dt,
              t_eval=np.arange(round(duration / dt) + 1) * dt)


def compiled_rk4(sc: Scenario) -> Callable[[int], None]:
    """The physical limit of the ODE backend: a numba loop of classical RK4 steps of the same
    right-hand side (eq. (1) with u = 0 held), generated from the plant's expression trees."""
    import numba

    from qcontrol.expr.source import FLAG, Statements, float_source

    terms, n = sc.terms, sc.order
    names = [f"s{i}" for i in range(n)]
    body = Statements("t")
    total = float_source(terms.psi._tree, names, body) if terms.psi is not None else "0.0"
    for theta, phi in zip(terms.theta, terms.phi, strict=True):
        total = body.temporary(f"{total} + {float(theta)!r} * {float_source(phi._tree, names, body)}")
    lines = [f"{FLAG} = False", *body.lines, f"return {total}"]
    xs, args = ", ".join(f"x{i}" for i in range(n)), ", ".join(f"y{i}" for i in range(n))

    def stage(k: str, scale: str) -> list[str]:  # y = x + scale * k, then k' = rhs(y)
        return [f"y{i} = x{i} + {scale} * {k}{i}" for i in range(n)]

    def rhs(k: str, state: str) -> list[str]:
        return [f"{k}{i} = {state}{i + 1}" for i in range(n - 1)] + [f"{k}{n - 1} = g({state})"]

    loop = [*rhs("a", "x").copy(), *stage("a", "half"), *rhs("b", "y"), *stage("b", "half"), *rhs("c", "y"),
            *stage("c", "h"), *rhs("d", "y")]
    loop = [line.replace("g(x)", f"g({xs})").replace("g(y)", f"g({args})") for line in loop]
    loop += [f"x{i} = x{i} + sixth * (a{i} + 2.0 * (b{i} + c{i}) + d{i})" for i in range(n)]
    source = (f"def g({', '.join(names)}):\n" + "".join(f"    {line}\n" for line in lines)
              + f"def rk4({xs}, h, steps):\n    half, sixth = 0.5 * h, h / 6.0\n"
              + "    for _ in range(steps):\n" + "".join(f"        {line}\n" for line in loop)
              + "    return x0\n")
    namespace = {"math": math}
    exec(compile(source, "<bench rk4>", "exec"), namespace)  # our own generated text
    namespace["g"] = numba.njit(error_model="numpy")(namespace["g"])
    rk4 = numba.njit(error_model="numpy")(namespace["rk4"])
    x0, h = [0.0] * n, sc.simulation.dt  # at rest (an equilibrium of the examples), as the mj_step loop
    rk4(*x0, h, 1)  # compiled here, not timed

    return lambda steps: rk4(*x0, h, steps)


def ode_speedup(sc: Scenario, repeat: int) -> dict:
    """One ODE run against scipy's solve_ivp, and against a compiled bare RK4 of the same rhs."""
    engine = best_of(repeat, lambda: run_scenario(sc, "ode"))
    with compiled_off():
        python_loop = best_of(repeat, lambda: run_scenario(sc, "ode"))
    scipy_s = best_of(max(1, repeat // 2), lambda: solve_ivp_closed_loop(sc))
    steps = round(sc.simulation.duration / sc.simulation.dt)
    rk4 = compiled_rk4(sc)
    bare = best_of(repeat, lambda: rk4(steps))
    return {"engine_s": engine, "solve_ivp_s": scipy_s, "speedup": scipy_s / engine,
            "compiled_loop": compiled_loop_in_use(sc, "ode"), "python_loop_s": python_loop,
            "python_loop_speedup": scipy_s / python_loop,
            "compiled_rk4_s": bare, "ratio_to_compiled_rk4": engine / bare, "target": ">= 300 (vs solve_ivp)"}


def batch_times(duration: float, sizes: list[int], repeat: int) -> dict:
    """Example 2 on the ODE, N copies with different kappa in one simulate call (metrics record):
    seconds, and the cost per copy and step against a step of the compiled bare RK4 of the rhs."""
    path = ROOT / "scenarios" / "example2.toml"
    steps = round(duration / scenario("example2", duration).simulation.dt)
    rk4 = compiled_rk4(scenario("example2", duration))
    rk4_step = best_of(repeat, lambda: rk4(steps)) / steps
    times = {}
    for size in sizes:
        margins = np.linspace(0.1, 1.1, size).tolist() if size > 1 else [1.1]
        scs = [load_scenario(path, [f"simulation.duration={duration!r}", f"controller.kappa_margin={m!r}"])
               for m in margins]
        sc = scs[0]

        def run(scs: list[Scenario] = scs, sc: Scenario = sc, size: int = size) -> None:
            simulate(RunSpec(plant=build_plant(sc, "ode", batch=size), law=build_law(scs),
                             quantizer=build_quantizer(sc), reference=build_reference(sc), x0=sc.x0,
                             grid=TimeGrid.of(duration, sc.simulation.dt), record="metrics"))

        if size > 100:  # timed once: an untimed run first, as a structure's first batch on a machine
            run()  # compiles it (a large batch runs its own, paired form), which the figure is not
        times[str(size)] = best_of(repeat if size <= 100 else max(1, repeat // 2), run)
    one = times["1"]
    return {"seconds": times, "ratio_to_one": {k: v / one for k, v in times.items()},
            "rk4_ns_per_step": rk4_step * 1e9,
            "ns_per_copy_step": {k: v / (int(k) * steps) * 1e9 for k, v in times.items()},
            "per_copy_step_ratio_to_rk4": {k: v / (int(k) * steps) / rk4_step for k, v in times.items()},
            "target": "N = 1000: <= 3 (x a compiled bare RK4 step)"}


def mujoco_batch(duration: float, size: int, repeat: int) -> dict:
    """Example 2 on MuJoCo, ``size`` copies with different kappa in one simulate call (metrics
    record): per copy and step, against one bare C ``mj_step``."""
    path = ROOT / "scenarios" / "example2.toml"
    scs = [load_scenario(path, [f"simulation.duration={duration!r}", f"controller.kappa_margin={m!r}"])
           for m in np.linspace(0.1, 1.1, size).tolist()]
    sc, steps = scs[0], round(duration / scs[0].simulation.dt)
    plant = build_plant(sc, "mujoco", batch=size)

    def run() -> None:
        simulate(RunSpec(plant=plant, law=build_law(scs), quantizer=build_quantizer(sc),
                         reference=build_reference(sc), x0=[s.x0 for s in scs],
                         grid=TimeGrid.of(duration, sc.simulation.dt), record="metrics"))

    wall = best_of(repeat, run)
    bare = best_of(repeat, _mj_step_loop(build_plant(sc, "mujoco"), 10_000, installed=False)) / 10_000
    per_copy_step = wall / (size * steps)
    return {"size": size, "duration_s": duration, "wall_s": wall, "us_per_copy_step": per_copy_step * 1e6,
            "ratio_to_bare_mj_step": per_copy_step / bare, "on_mujoco_batch": plant._threaded is not None}


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


def recording_overhead(duration: float, repeat: int) -> dict:
    """What ``--rrd`` adds to ``qcontrol run scenarios/example2.toml`` (MuJoCo, the command's own
    path: ``qcontrol.run`` with and without ``rrd``), interleaved runs, best of ``repeat`` each:
    the seconds the recording adds and their ratio to the run without it (the target is for the
    ratio against the fastest run path there is, so the seconds are what a faster loop will meet)."""
    import qcontrol

    sc = scenario("example2", duration)
    bare, recorded = [], []
    with tempfile.TemporaryDirectory(prefix="qcontrol-bench-") as tmp:
        # untimed: the one-off import of rerun and start of its machinery (about 0.4 s) belongs
        # to the process, not to each run (it made --quick report 19x)
        qcontrol.run(sc, "mujoco", rrd=Path(tmp) / "warm-up.rrd")
        for _ in range(repeat):
            started = time.perf_counter()
            qcontrol.run(sc, "mujoco")
            bare.append(time.perf_counter() - started)
            started = time.perf_counter()
            qcontrol.run(sc, "mujoco", rrd=Path(tmp) / "bench.rrd")
            recorded.append(time.perf_counter() - started)
        size = (Path(tmp) / "bench.rrd").stat().st_size
    extra = min(recorded) - min(bare)
    return {"ratio": extra / min(bare), "recording_s": extra, "run_s": min(bare), "file_mb": size / 2**20,
            "ms_per_simulated_s": extra / duration * 1e3, "target": "<= 5 ms per simulated second",
            "note": f"qcontrol run example2 --rrd, MuJoCo, {duration:g} s, best of {repeat}"}


def peak_memory_mb(duration: float) -> float:
    sc = scenario("example2", duration, dt=1e-4)
    tracemalloc.start()
    run_scenario(sc, "ode")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


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
    mj_step = _mj_step_loop(build_plant(sc, "mujoco"), steps, installed=False)
    return {"mujoco": best_of_both(repeat, mj_step)[1] / steps,
            "ode": best_of_both(repeat, lambda: rk4(steps))[1] / steps}


def sweep_limits(duration: float, workers: int, repeat: int) -> dict:
    """200- and 1000-run sweeps of Example 2 (per-copy kappa) on ``workers`` local workers, and
    ``qcontrol region`` (:func:`region_limits`): wall and CPU time, per simulated second, and
    against the runs' bare steps on one core (:func:`bare_limits`, measured before and after the
    sweeps: the shorter, the load may change meanwhile), with the targets."""
    path = ROOT / "scenarios" / "example2.toml"
    sc = scenario("example2", duration)
    before = bare_limits(sc, max(3, repeat))
    timed: dict = {}
    for backend, runs in (("mujoco", 200), ("mujoco", 1000), ("ode", 1000)):
        sets = [[f"simulation.duration={duration!r}", f"controller.kappa_margin={m!r}"]
                for m in np.linspace(0.1, 1.1, runs).tolist()]
        started, used = time.perf_counter(), cpu_seconds()
        sweep_summaries(path, sets, backend=backend, workers=workers)
        timed[backend, "sweep", runs] = (time.perf_counter() - started, cpu_seconds() - used, {})
    timed.update(region_limits(path, duration, workers))
    after = bare_limits(sc, max(3, repeat))
    limit = {backend: min(before[backend], after[backend]) for backend in before}
    steps = round(duration / sc.simulation.dt)
    out = {}
    for (backend, kind, runs), (wall, cpu, extra) in timed.items():
        bare = runs * steps * limit[backend]
        out[f"{backend}_{'region_' if kind == 'region' else ''}{runs}"] = {
            "wall_s": wall, "cpu_s": cpu, "ratio_to_bare_one_core": wall / bare,
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
        started, used = time.perf_counter(), cpu_seconds()
        region = measure_region(path, grid, [parse_law("proposed")], backend,
                                overrides=[f"simulation.duration={duration!r}"], workers=workers)
        wall, cpu = time.perf_counter() - started, cpu_seconds() - used
        out[backend, "region", len(region.points)] = (
            wall, cpu, {"diverged": sum(p.outcome != "bounded" for p in region.points)})
    return out


# --------------------------------------------------------------------------------------------


def measure(args: argparse.Namespace) -> dict:
    # the figures are those of a process that has started numba, whose single runs of 10 s take
    # the compiled forms (a fresh process leaves a run that short to Python: it would not pay)
    import numba  # noqa: F401
    duration = 1.0 if args.quick else 10.0
    repeat = 1 if args.quick else args.repeat
    sizes = [1, 10, 100] if args.quick else [1, 10, 100, 1000]
    result: dict = {"machine": f"{platform.node()} {platform.machine()} {platform.processor() or ''}".strip(),
                    "python": sys.version.split()[0], "numpy": np.__version__, "mujoco": mujoco.__version__,
                    "quick": args.quick, "duration_s": duration, "repeat": repeat,
                    "compiled": os.environ.get("QCONTROL_COMPILE", "1") != "0"}
    result["mujoco_step_ratio"], result["ode_speedup_vs_solve_ivp"] = {}, {}
    details: dict = {"mujoco": {}, "ode": {}}
    for name in SCENARIOS:
        sc = scenario(name, duration)
        details["mujoco"][name] = mujoco_ratio(sc, repeat)
        result["mujoco_step_ratio"][name] = details["mujoco"][name]["ratio"]
        details["ode"][name] = ode_speedup(sc, repeat)
        result["ode_speedup_vs_solve_ivp"][name] = details["ode"][name]["speedup"]
    details["compile"] = {backend: compile_times(backend) for backend in ("ode", "mujoco")}
    details["batch"] = batch_times(duration, sizes, repeat)
    per_copy_step = details["batch"]["per_copy_step_ratio_to_rk4"]
    result["batch_per_copy_step_ratio_to_rk4"] = per_copy_step[str(sizes[-1])]
    # 1000 MuJoCo copies of 10 s are 1e7 copy-steps (about a minute): 1 s runs unless --quick (100)
    details["mujoco_batch"] = mujoco_batch(1.0 if not args.quick else 0.2, 1000 if not args.quick else 100,
                                           1 if args.quick else max(1, repeat // 2))
    details["recording"] = recording_overhead(duration, repeat)
    if args.quick:  # opening, the static logs and closing cost ~10 ms a file: a 1 s run is no test
        details["recording"]["note"] += "; quick: per-file costs dominate a 1 s run, the target is for 10 s"
    result["recording_ms_per_simulated_s"] = details["recording"]["ms_per_simulated_s"]
    result["recording_s"] = details["recording"]["recording_s"]
    details["user_laws"] = bench_laws.measure(duration, duration / 5, 10 if args.quick else 50, repeat)
    result["user_law_ratio"] = {"single": details["user_laws"]["single_ratio"],
                                "single_fresh_process": details["user_laws"]["single_fresh_ratio"],
                                "batch": details["user_laws"]["batch_ratio"]}
    result["peak_memory_mb"] = peak_memory_mb(duration)
    result["peak_memory_note"] = f"Example 2, ODE, full record, {duration:g} s at dt = 1e-4 (tracemalloc)"
    if args.sweeps:
        result["sweeps"] = sweep_limits(duration, args.workers, repeat)
    if args.reproduce:
        result["reproduce"] = reproduce_wall(args.workers)
    result["details"] = details
    return result


def report(result: dict, args: argparse.Namespace) -> None:
    details = result["details"]
    print(f"qcontrol bench on {result['machine']} (python {result['python']}, numpy {result['numpy']}, "
          f"mujoco {result['mujoco']}){' [quick]' if args.quick else ''}, best of {result['repeat']}, "
          f"compiled paths {'on' if result['compiled'] else 'off (QCONTROL_COMPILE=0)'}")
    print(f"{'figure':52s} {'value':>10s}  target")
    for name in SCENARIOS:
        m, o = details["mujoco"][name], details["ode"][name]
        print(f"{'MuJoCo closed loop / bare C mj_step, ' + name:52s} {m['ratio']:10.2f}  <= 1.3  "
              f"({m['closed_loop_us_per_step']:.2f} vs {m['bare_mj_step_us_per_step']:.2f} us/step)")
        print(f"{'MuJoCo Python loop (QCONTROL_COMPILE=0) / bare, ' + name:52s} "
              f"{m['python_loop_ratio']:10.2f}           ({m['python_loop_us_per_step']:.2f} us/step; "
              f"the line above ran the compiled loop: {m['compiled_loop']})")
        print(f"{'mj_step with native callback / bare, ' + name:52s} {m['native_callback_ratio']:10.3f}  "
              f"<= 1.05 ({m['native_callback_us_per_step']:.2f} us/step; "
              f"native in use: {m['native_in_use']})")
        print(f"{'mj_step with Python callback / bare, ' + name:52s} {m['python_callback_ratio']:10.3f}  "
              f"         ({m['python_callback_us_per_step']:.2f} us/step)")
        print(f"{'ODE speed-up vs solve_ivp RK45, ' + name:52s} {o['speedup']:10.1f}  >= 300  "
              f"({o['engine_s']:.4f} s vs {o['solve_ivp_s']:.3f} s)")
        print(f"{'ODE Python loop (QCONTROL_COMPILE=0) vs solve_ivp, ' + name:52s} "
              f"{o['python_loop_speedup']:10.1f}           ({o['python_loop_s']:.4f} s; "
              f"the line above ran the compiled loop: {o['compiled_loop']})")
        print(f"{'ODE run / compiled bare RK4 of the rhs, ' + name:52s} {o['ratio_to_compiled_rk4']:10.1f}  "
              f"         ({o['engine_s']:.4f} s vs {o['compiled_rk4_s']:.5f} s)")
    for backend, times in details["compile"].items():
        print(f"{'compiled loop, 10 s Example 2 on ' + backend + ': first run [s]':52s} "
              f"{times['first_run_s']:10.3f}           (empty cache: Python; compiled: "
              f"{times['compile_run_s']:.3f} s; cached, new process: {times['cached_run_s']:.3f} s; "
              f"Python loop: {times['python_loop_s']:.3f} s)")
    batches = details["batch"]
    for size, ratio in batches["per_copy_step_ratio_to_rk4"].items():
        target = "<= 3" if size == "1000" else ""
        print(f"{'ODE Example 2 batch of ' + size + ', per copy-step / bare RK4 step':52s} {ratio:10.2f}  "
              f"{target:7s} ({batches['ns_per_copy_step'][size]:.0f} vs {batches['rk4_ns_per_step']:.0f} ns; "
              f"{batches['seconds'][size]:.3f} s)")
    mb = details["mujoco_batch"]
    print(f"{'MuJoCo batch of ' + str(mb['size']) + ' (per copy-step) / bare mj_step':52s} "
          f"{mb['ratio_to_bare_mj_step']:10.2f}           "
          f"({mb['wall_s']:.2f} s for {mb['duration_s']:g} s runs; "
          f"mujoco.batch: {mb['on_mujoco_batch']})")
    rec = details["recording"]
    print(f"{'recording cost per simulated second [ms]':52s} {rec['ms_per_simulated_s']:10.2f}  <= 5    "
          f"({rec['recording_s']:.4f} s of recording on a {rec['run_s']:.3f} s run, "
          f"{rec['file_mb']:.1f} MB; {rec['note']})")
    bench_laws.report(details["user_laws"])
    print(f"{'peak memory, 10 kHz run [MB]':52s} {result['peak_memory_mb']:10.1f}  "
          f"({result['peak_memory_note']})")
    if "sweeps" in result:
        report_sweeps(result["sweeps"])
    if "reproduce" in result:
        print(f"{'qcontrol reproduce wall time [s]':52s} {result['reproduce']['wall_s']:10.1f}  <= 15    "
              f"({args.workers} workers; CPU {result['reproduce']['cpu_s']:.1f} s)")


def report_sweeps(sweeps: dict) -> None:
    """The lines of :func:`sweep_limits`: wall time against the runs' bare steps on one core."""
    for label, r in sweeps["runs"].items():
        backend, *region, runs = label.split("_")
        kind, limit = "region" if region else "sweep", "mj_step" if backend == "mujoco" else "RK4"
        what = f"{backend} {kind} of {runs}, {sweeps['workers']} w. / bare {limit} on 1 core"
        print(f"{what:52s} "
              f"{r['ratio_to_bare_one_core']:10.3f}  {r['target']:7s} ({r['wall_s']:.2f} s wall, "
              f"CPU {r['cpu_s']:.2f} s = {r['cpu_ratio_to_bare']:.3f} x bare; per simulated s "
              f"{r['wall_ms_per_simulated_s']:.2f} ms wall, {r['cpu_ms_per_simulated_s']:.2f} ms CPU)")
    print(f"{'':52s} (bare mj_step {sweeps['bare_mj_step_us']:.3f} us untimed, bare RK4 step "
          f"{sweeps['bare_rk4_ns']:.1f} ns; load {sweeps['load']:.1f}; {sweeps['note']})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short horizons, small batches (smoke run)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="write the figures as JSON")
    parser.add_argument("--repeat", type=int, default=3, help="best of N (default 3)")
    parser.add_argument("--sweeps", "--sweep1000", action="store_true",
                        help="also time 200- and 1000-run sweeps against the bare steps (slow)")
    parser.add_argument("--reproduce", action="store_true", help="also time qcontrol reproduce (slow)")
    parser.add_argument("--workers", type=int, default=2, help="workers for --sweeps, --reproduce (2)")
    parser.add_argument("--only-sweeps", action="store_true", help="the --sweeps figures alone")
    args = parser.parse_args(argv)
    if args.only_sweeps:
        import numba  # noqa: F401  (a process that has started numba, as measure's)
        repeat = 1 if args.quick else args.repeat
        result = {"sweeps": sweep_limits(1.0 if args.quick else 10.0, args.workers, repeat)}
        report_sweeps(result["sweeps"])
    else:
        result = measure(args)
        report(result, args)
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2, default=lambda v: None if v != v else v) + "\n")
        print(f"wrote {args.json}")
    figures = result["mujoco_step_ratio"].values() if "mujoco_step_ratio" in result else [
        r["ratio_to_bare_one_core"] for r in result["sweeps"]["runs"].values()]
    return 0 if all(math.isfinite(v) for v in figures) else 1


if __name__ == "__main__":
    sys.exit(main())
