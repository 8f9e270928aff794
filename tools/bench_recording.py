"""Cost of writing a rerun recording: Example 2, 10 s at dt = 1 ms, with and without a .rrd file.

    python tools/bench_recording.py [--repeat 3] [--duration 10] [--keep FILE]

Prints the median wall time of the bare run and of the recorded run (the recorder streams every
5000 rows, draws a hinge pendulum posed from x1 and a target marker at y_d), the overhead fraction
(target: <= 0.25), the file size and the rows logged per entity. The one-off ``import rerun`` is
timed separately: it is paid once per process, not per run.

tools/bench.py takes its recording figure (:func:`recording_overhead`: ``qcontrol run`` of
Example 2 on MuJoCo, the command's own path) and the peak memory of a 10 kHz run
(:func:`peak_memory_mb`) from here.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import tracemalloc
from collections import Counter
from pathlib import Path

import mujoco
import numpy as np
from bench_limits import scenario

import qcontrol
from qcontrol.assembly import run_scenario
from qcontrol.controller import PaperLaw
from qcontrol.engine import Observer, RunSpec, Trajectory, simulate
from qcontrol.expr import compile_expression as C
from qcontrol.plants.ode import ChainPlant
from qcontrol.quantizer import UniformQuantizer
from qcontrol.reference import Sine
from qcontrol.timegrid import TimeGrid

PENDULUM = """
<mujoco>
  <worldbody>
    <body name="arm" pos="0 0 1">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom name="rod" type="capsule" fromto="0 0 0 0 0 -0.5" size="0.02"/>
      <geom name="bob" type="sphere" pos="0 0 -0.5" size="0.05"/>
    </body>
  </worldbody>
</mujoco>
"""
X, Q = ["x1", "x2"], ["q1", "q2"]
CONSTANTS = {"c": [4.0, 3.0], "delta": 0.01, "kappa": 1.125, "gamma": 1.0, "sigma": 1.0}


def example2(duration: float, observer: Observer | None = None) -> Trajectory:
    """Example 2 of the paper (ODE backend), the closed loop the recording is measured on."""
    plant = ChainPlant(2, None, [C("x2", X), C("x2**2*cos(x1)", X), C("sin(x1)", X)], [-1, -3.5, -34.3])
    q = UniformQuantizer(0.01)
    r = [C("1+q2**2", Q), C("1+2*q2**2", Q), C("1", Q)]
    ctrl = PaperLaw([4, 3], q.max_error, 1.125, 1, 1, r)
    (run,) = simulate(RunSpec(plant=plant, law=ctrl, quantizer=q, reference=Sine(1, 1.5), x0=[0.3, 0.3],
                              grid=TimeGrid.of(duration, 1e-3), observer=observer))
    return run


def timed_bare(duration: float) -> float:
    started = time.perf_counter()
    example2(duration)
    return time.perf_counter() - started


def timed_recorded(duration: float, path: Path, model: mujoco.MjModel) -> tuple[float, float]:
    """Wall time of one run with the recorder, from opening the file to its final rename, and the
    part of it spent in the recorder (opening, observer calls, closing)."""
    from qcontrol.recording import Recording

    inside = 0.0
    started = time.perf_counter()
    with Recording(path) as rec:
        rec.log_static("# Example 2 (benchmark)\n", CONSTANTS, qcontrol.__version__)
        observer = rec.observer("ode", model, "hinge")

        def timed_observer(start: int, stop: int, runs: list[Trajectory]) -> None:
            nonlocal inside
            entered = time.perf_counter()
            observer(start, stop, runs)
            inside += time.perf_counter() - entered

        simulating = time.perf_counter()
        example2(duration, timed_observer)
        simulated = time.perf_counter()
    total = time.perf_counter() - started
    return total, inside + (simulating - started) + (total - (simulated - started))


def rows_per_entity(path: Path) -> Counter[str]:
    from rerun.chunk import RrdReader

    rows: Counter[str] = Counter()
    for chunk in RrdReader(path).stream():
        rows[chunk.entity_path] += chunk.num_rows
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs of each kind; the median is reported")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds (dt = 1 ms)")
    parser.add_argument("--keep", type=Path, help="also keep the last recording at this path")
    args = parser.parse_args(argv)

    started = time.perf_counter()
    import rerun  # noqa: F401  (timed: a one-off cost per process)

    import_s = time.perf_counter() - started
    model = mujoco.MjModel.from_xml_string(PENDULUM)
    example2(0.1)  # warm up numpy and the expression compiler

    with tempfile.TemporaryDirectory(prefix="qcontrol-bench-") as tmp:
        path = Path(tmp) / "bench.rrd"
        bare, recorded, inside = [], [], []
        for _ in range(args.repeat):  # interleaved, so drifts in machine load hit both alike
            bare.append(timed_bare(args.duration))
            total, spent = timed_recorded(args.duration, path, model)
            recorded.append(total)
            inside.append(spent)
        size = path.stat().st_size
        rows = rows_per_entity(path)
        if args.keep is not None:
            args.keep.write_bytes(path.read_bytes())

    bare_s, recorded_s = statistics.median(bare), statistics.median(recorded)
    overhead = (recorded_s - bare_s) / bare_s
    steps = round(args.duration / 1e-3)
    print(f"Example 2, {args.duration:g} s at dt = 1 ms ({steps} steps), median of {args.repeat}")
    print(f"  bare run:          {bare_s:.3f} s  {np.round(bare, 3).tolist()}")
    print(f"  recorded run:      {recorded_s:.3f} s  {np.round(recorded, 3).tolist()}")
    print(f"  overhead fraction: {overhead:.3f}  (target <= 0.25)")
    print(
        f"  in the recorder:   {statistics.median(inside):.3f} s = "
        f"{statistics.median(inside) / bare_s:.3f} of the bare run (less noisy than the difference)"
    )
    print(f"  file size:         {size} bytes ({size / 2**20:.2f} MiB)")
    print(f"  import rerun:      {import_s:.3f} s (once per process, not included above)")
    print("  rows per entity:")
    for entity, count in sorted(rows.items()):
        print(f"    {entity:40s} {count}")
    return 0 if overhead <= 0.25 else 1


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

if __name__ == "__main__":
    sys.exit(main())
