"""User laws against the built-in law of the same mathematics: the paper's law (44)-(45) written
by hand in each documented form (tools/laws_by_hand.py) against the built-in kind ``proposed``,
Example 2 on the ODE backend (the plant costs the same for every law, so the ratio is the law's).

    python tools/bench_laws.py [--quick] [--repeat N]

* single run (10 s, 10,000 steps): every law on the engine's Python loop (QCONTROL_COMPILE=0),
  and the built-in law as it runs by default (compiled where numba is there and it pays);
* batch (``--batch`` copies from different initial states, 2 s, metrics record): one simulate
  call per law; a ``qcontrol.Law`` (``state_rate`` or ``advance``) is called copy by copy, a column-form class
  once per step for the whole batch; the built-in law also as its batch runs by default.

The target: a user law within 2x of the built-in law, single run and batch. Timings are best of N.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import laws_by_hand  # noqa: E402
from bench_timing import best_of, python_loop  # noqa: E402

from qcontrol.assembly import build_law, build_plant, build_quantizer, build_reference  # noqa: E402
from qcontrol.engine import RunSpec, simulate  # noqa: E402
from qcontrol.scenario import Scenario, load_scenario  # noqa: E402
from qcontrol.timegrid import TimeGrid

FORMS = laws_by_hand.FORMS


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


def measure(duration: float, batch_duration: float, copies: int, repeat: int) -> dict:
    laws_by_hand.register()
    single, batched = scenarios(duration, 1), scenarios(batch_duration, copies)
    result: dict = {"single_s": {}, "batch_s": {}}
    run_batch(single["built-in"])  # numba's start and the compiled loop's cache, outside the timing
    result["builtin_default_s"] = best_of(repeat, lambda: run_batch(single["built-in"]))
    with python_loop():
        for name, scs in single.items():
            result["single_s"][name] = best_of(repeat, lambda scs=scs: run_batch(scs))
        for name, scs in batched.items():
            result["batch_s"][name] = best_of(max(1, repeat - 1), lambda scs=scs: run_batch(scs))
    result["single_ratio"] = {f: result["single_s"][f] / result["single_s"]["built-in"] for f in FORMS}
    default = result["builtin_default_s"]
    result["single_ratio_to_default"] = {f: result["single_s"][f] / default for f in FORMS}
    result["batch_ratio"] = {f: result["batch_s"][f] / result["batch_s"]["built-in"] for f in FORMS}
    run_batch(batched["built-in"])  # a compiled batch's start, outside the timing
    batch_default = best_of(max(1, repeat - 1), lambda: run_batch(batched["built-in"]))
    result["builtin_batch_default_s"] = batch_default
    result["batch_ratio_to_default"] = {f: result["batch_s"][f] / batch_default for f in FORMS}
    result.update(duration_s=duration, batch_duration_s=batch_duration, copies=copies, repeat=repeat)
    return result


NAMES = {"rk4": "qcontrol.Law, RK4 of state_rate", "stepped": "qcontrol.Law, its own advance",
         "floats": "qcontrol.Law, its own advance on floats",
         "columns": "BacksteppingLaw subclass, column form"}


def report(result: dict) -> None:
    print(f"{'user law (44)-(45) by hand / built-in proposed':60s} {'ratio':>7s}  target")
    for form in FORMS:
        print(f"{'single run, ' + NAMES[form]:60s} {result['single_ratio'][form]:7.2f}  <= 2    "
              f"({result['single_s'][form]:.3f} s vs {result['single_s']['built-in']:.3f} s, Python loop; "
              f"{result['single_ratio_to_default'][form]:.1f}x the built-in's default run, "
              f"{result['builtin_default_s']:.3f} s)")
    copies = result["copies"]
    for form in FORMS:
        print(f"{f'batch of {copies}, ' + NAMES[form]:60s} {result['batch_ratio'][form]:7.2f}  "
              f"{'<= 2' if form == 'columns' else '':7s}({result['batch_s'][form]:.3f} s vs "
              f"{result['batch_s']['built-in']:.3f} s, {result['batch_duration_s']:g} s runs; "
              f"{result['batch_ratio_to_default'][form]:.1f}x the built-in's default batch, "
              f"{result['builtin_batch_default_s']:.3f} s)")


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
