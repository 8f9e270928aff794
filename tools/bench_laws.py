"""User laws against the built-in law of the same mathematics: the paper's law (44)-(45) written
by hand in each documented form (tools/laws_by_hand.py) against the built-in kind ``proposed``,
Example 2 on the ODE backend (the plant costs the same for every law, so the ratio is the law's).

    python tools/bench_laws.py [--quick] [--repeat N]

Each law as it runs by default, the figure user law / built-in (target 2x), in three settings:

* a session (numba started, as in a notebook, a sweep or the bench): a single run (10 s,
  10,000 steps) and a batch (``--batch`` copies from different initial states, 2 s, metrics
  record; one simulate call per law) run compiled where the law has a compiled form (the
  built-in law; a law whose code the engine traced and checked, docs/laws.md 'Speed') and it
  pays (a batch of the built-in law below 5000 rows runs its array form), else on the Python loop;
* a fresh process (``qcontrol run`` of 10 s from the command line): everything on the Python
  loop, a traced law through its traced calls;
* ``QCONTROL_COMPILE=0``: every law's own Python (what a law without a compiled form pays).

Timings are best of N (the batches in a session best of 3N), in rounds that run every law in turn
(wall; the CPU ratio beside it for the session's figures: it spreads less with the load).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import laws_by_hand  # noqa: E402
from bench_timing import best_of_both, python_loop  # noqa: E402

from qcontrol.assembly import build_law, build_plant, build_quantizer, build_reference  # noqa: E402
from qcontrol.controller.user import UserLaw  # noqa: E402
from qcontrol.engine import RunSpec, simulate  # noqa: E402
from qcontrol.engine.compiled_user import column_parts  # noqa: E402
from qcontrol.engine.user_trace import explain  # noqa: E402
from qcontrol.scenario import Scenario, load_scenario  # noqa: E402
from qcontrol.timegrid import TimeGrid

FORMS = laws_by_hand.FORMS
BATCH_ROUNDS = 3  # rounds of the batches per --repeat


def scenarios(duration: float, copies: int) -> dict[str, list[Scenario]]:
    """The built-in law and each hand-written form, ``copies`` variants from initial states
    spread over [-0.5, 0.5]^2 (one variant: the scenario's own x0)."""
    base = load_scenario("example2", {"simulation.duration": duration})
    spread = np.linspace(-0.5, 0.5, 2 * copies).reshape(copies, 2).tolist()
    starts = [list(base.x0)] if copies == 1 else spread
    made = {"built-in": [base.with_overrides({"plant.x0": x0}) for x0 in starts]}
    for form in FORMS:
        chosen = laws_by_hand.overrides(base, form)
        made[form] = [base.with_overrides(chosen | {"plant.x0": x0}) for x0 in starts]
    return made


def run_batch(scs: list[Scenario]) -> None:
    sc = scs[0]
    simulate(RunSpec(plant=build_plant(sc, "ode", batch=len(scs)), law=build_law(scs),
                     quantizer=build_quantizer(sc), reference=build_reference(sc),
                     x0=[s.x0 for s in scs] if len(scs) > 1 else sc.x0,
                     grid=TimeGrid.of(sc.simulation.duration, sc.simulation.dt),
                     record="metrics" if len(scs) > 1 else "full"))


def compiled_form(sc: Scenario) -> str:
    """Whether the form's law has a compiled form ("compiled", or why not)."""
    law = build_law([sc])
    if isinstance(law, UserLaw):
        return explain(law, law.n, sc.simulation.dt) or "compiled"
    parts = column_parts(build_quantizer(sc), law, law.n, sc.simulation.dt)
    return "compiled" if not isinstance(parts, str) else parts


def timed(made: dict[str, list[Scenario]], rounds: int, warm: bool = True
          ) -> tuple[dict[str, float], dict[str, float]]:
    """Best wall and best CPU time of each entry's run over ``rounds`` rounds, each running every
    entry once, in turn (``warm``: a first run of each outside the timing, for numba's start, a
    compiled form's tracing and the compiled-code cache): the entries meet the same load, which
    on a shared machine changes from one second to the next."""
    if warm:
        for scs in made.values():
            run_batch(scs)
    wall, cpu = dict.fromkeys(made, float("inf")), dict.fromkeys(made, float("inf"))
    for _ in range(rounds):
        for name, scs in made.items():
            once = best_of_both(1, lambda scs=scs: run_batch(scs))
            wall[name], cpu[name] = min(wall[name], once[0]), min(cpu[name], once[1])
    return wall, cpu


FRESH = """
import json, sys, time
sys.path.insert(0, {tools!r})
import bench_laws, laws_by_hand
laws_by_hand.register()
made, best = bench_laws.scenarios({duration!r}, 1), {{}}
for name, scs in made.items():
    times = []
    for _ in range({repeat!r}):
        start = time.perf_counter()
        bench_laws.run_batch(scs)
        times.append(time.perf_counter() - start)
    best[name] = min(times)
print(json.dumps(best))
"""


def fresh_process(duration: float, repeat: int) -> dict[str, float]:
    """Best wall time of each law's single run in a process that has not started numba."""
    script = FRESH.format(tools=str(Path(__file__).resolve().parent), duration=duration, repeat=repeat)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure(duration: float, batch_duration: float, copies: int, repeat: int) -> dict:
    laws_by_hand.register()
    result: dict = {"single_fresh_s": fresh_process(duration, repeat)}
    import numba  # noqa: F401  (a session: numba started, as the bench's other figures have it)

    single, batched = scenarios(duration, 1), scenarios(batch_duration, copies)
    result["compiled_form"] = {f: compiled_form(single[f][0]) for f in FORMS}
    result["single_s"], result["single_cpu_s"] = timed(single, repeat)
    # (a batch of 50 takes 20-40 ms: its best of two, at a load of 5-8, spread 1.2-2.0x for the same code)
    result["batch_s"], result["batch_cpu_s"] = timed(batched, BATCH_ROUNDS * repeat)
    with python_loop():
        result["single_python_s"] = timed(single, repeat, warm=False)[0]
        result["batch_python_s"] = timed(batched, max(1, repeat - 1), warm=False)[0]
    for run in ("single", "batch", "single_fresh", "single_python", "batch_python", "single_cpu",
                "batch_cpu"):
        times = result[f"{run}_s"]
        result[f"{run}_ratio"] = {f: times[f] / times["built-in"] for f in FORMS}
    result.update(duration_s=duration, batch_duration_s=batch_duration, copies=copies, repeat=repeat)
    return result


NAMES = {"rk4": "Law, state_rate, numpy", "stepped": "Law, advance, numpy",
         "rate-floats": "Law, state_rate, floats", "floats": "Law, advance, floats",
         "columns": "BacksteppingLaw subclass, column form"}


def report(result: dict) -> None:
    print(f"{'user law (44)-(45) by hand / built-in proposed':52s} {'ratio':>10s}  target")
    copies = result["copies"]
    for run, label in (("single", "single run"), ("batch", f"batch of {copies}")):
        for form in FORMS:
            fresh = (f"fresh process {result['single_fresh_ratio'][form]:.2f}x, "
                     if run == "single" else "")
            times = result[f"{run}_s"]
            print(f"{label + ', ' + NAMES[form]:52s} {result[f'{run}_ratio'][form]:10.2f}  <= 2    "
                  f"({times[form]:.3f} s vs {times['built-in']:.3f} s in a session, CPU "
                  f"{result[f'{run}_cpu_ratio'][form]:.2f}x; "
                  f"{fresh}QCONTROL_COMPILE=0 {result[f'{run}_python_ratio'][form]:.2f}x; "
                  f"compiled form: {result['compiled_form'][form]})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs (smoke run)")
    parser.add_argument("--repeat", type=int, default=3, help="best of N (default 3)")
    parser.add_argument("--batch", type=int, default=50, help="copies in the batch (default 50)")
    args = parser.parse_args(argv)
    duration, batch_duration = (1.0, 0.5) if args.quick else (10.0, 2.0)
    report(measure(duration, batch_duration, args.batch, 1 if args.quick else args.repeat))
    return 0


if __name__ == "__main__":
    sys.exit(main())
