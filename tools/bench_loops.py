"""tools/bench.py's single runs: the MuJoCo closed loop against a bare C ``mj_step`` loop, ``mj_step``
with the plant's passive callback (native and Python) against the same bare loop; one ODE run
against scipy's ``solve_ivp`` and against the compiled bare RK4 of its right-hand side; and the
first run of a structure in a new process (empty cache, compile forced, cached, Python loop)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import numpy as np
from bench_limits import ROOT, SCENARIOS, compiled_rk4, mj_step_loop
from bench_timing import best_of
from bench_timing import python_loop as compiled_off  # QCONTROL_COMPILE=0 inside the block

from qcontrol.assembly import build_controller, build_plant, build_quantizer, build_reference, run_scenario
from qcontrol.quantizer import QuantizedReading
from qcontrol.scenario import Scenario


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
    bare = best_of(repeat, mj_step_loop(plant, steps, installed=False)) / steps
    native = best_of(repeat, mj_step_loop(plant, steps, installed=True)) / steps
    with compiled_off():
        python_plant = build_plant(sc, "mujoco")
        python = best_of(repeat, mj_step_loop(python_plant, steps, installed=True)) / steps
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


def report(details: dict) -> None:
    """The table's lines of the single runs and of the first runs in a new process."""
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
