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
  bare steps' CPU time measured before and after (slow); each sweep or region timed again while
  its timings take less than 2 s in all (the ODE region, about 0.2 s, some ten times): the figure
  is the shortest, the median beside it. ``--only-sweeps``: these figures alone.

Timings are best-of-N (the machine may be shared); ``--quick`` shortens every horizon.

The parts, by what they measure: ``bench_limits`` (the bare ``mj_step`` and RK4 loops every figure
is against), ``bench_loops`` (single runs), ``bench_batches``, ``bench_recording``, ``bench_laws``
(user laws) and ``bench_sweeps`` (sweeps, regions, reproduce); this file runs them and prints
the table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
from pathlib import Path

import bench_batches
import bench_laws
import bench_loops
import mujoco
import numpy as np
from bench_limits import SCENARIOS, scenario
from bench_recording import peak_memory_mb, recording_overhead
from bench_sweeps import report_sweeps, reproduce_wall, sweep_limits


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
        details["mujoco"][name] = bench_loops.mujoco_ratio(sc, repeat)
        result["mujoco_step_ratio"][name] = details["mujoco"][name]["ratio"]
        details["ode"][name] = bench_loops.ode_speedup(sc, repeat)
        result["ode_speedup_vs_solve_ivp"][name] = details["ode"][name]["speedup"]
    details["compile"] = {backend: bench_loops.compile_times(backend) for backend in ("ode", "mujoco")}
    details["batch"] = bench_batches.batch_times(duration, sizes, repeat)
    per_copy_step = details["batch"]["per_copy_step_ratio_to_rk4"]
    result["batch_per_copy_step_ratio_to_rk4"] = per_copy_step[str(sizes[-1])]
    # 1000 MuJoCo copies of 10 s are 1e7 copy-steps (about a minute): 1 s runs unless --quick (100)
    details["mujoco_batch"] = bench_batches.mujoco_batch(1.0 if not args.quick else 0.2,
                                                         1000 if not args.quick else 100,
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
    bench_loops.report(details)
    bench_batches.report(details)
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
