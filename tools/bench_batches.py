"""tools/bench.py's batches: Example 2 batched on the ODE (N copies, per-copy kappa, metrics record)
per copy-step against a step of the compiled bare RK4 of the right-hand side, and on MuJoCo
against one bare C ``mj_step``."""

from __future__ import annotations

import numpy as np
from bench_limits import ROOT, compiled_rk4, mj_step_loop, scenario
from bench_timing import best_of

from qcontrol.assembly import build_law, build_plant, build_quantizer, build_reference
from qcontrol.engine import RunSpec, simulate
from qcontrol.scenario import Scenario, load_scenario
from qcontrol.timegrid import TimeGrid


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

        if size > 100:  # an untimed run first, as a structure's first batch on a machine
            run()  # compiles it (a large batch runs its own, paired form), which the figure is not
        times[str(size)] = best_of(repeat, run)  # (one timing of the 1 s batch of 1000 read 2.6-4.0)
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
    bare = best_of(repeat, mj_step_loop(build_plant(sc, "mujoco"), 10_000, installed=False)) / 10_000
    per_copy_step = wall / (size * steps)
    return {"size": size, "duration_s": duration, "wall_s": wall, "us_per_copy_step": per_copy_step * 1e6,
            "ratio_to_bare_mj_step": per_copy_step / bare, "on_mujoco_batch": plant._threaded is not None}


def report(details: dict) -> None:
    """The table's lines of the batches."""
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
