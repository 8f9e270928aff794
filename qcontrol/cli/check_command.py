"""``qcontrol check``: validate a scenario without running it.

    qcontrol check SCENARIO [--set KEY=VALUE ...] [--unset KEY ...] [--backend NAME]

Everything a run would refuse is refused here, with the same one-line message and exit status 2:
the keys (each against its table and kind, docs/scenarios.md), the expressions (parsed, compiled
and evaluated at x(0); the bounding functions r_i >= 1 on sampled quantized states), Theorem 1's
kappa > L, the time grid, and the backend. Each backend section of the file is built: the MuJoCo
model is compiled and its acceleration compared with eq. (1) at sampled states, so an MJCF that
does not describe the scenario's plant is found before any run. Nothing is run and nothing is
written; on success one line says what was checked (exit status 0).
"""

from __future__ import annotations

import argparse

from .. import compiled as compiled_paths
from ..assembly import Assembly, assemble
from ..scenario import Scenario
from .arguments import EXIT_OK, add_scenario_options, backend_names, scenario_from_args


def add_check_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``qcontrol check`` with the scenario options every running command takes."""
    p = subparsers.add_parser(
        "check",
        help="validate a scenario (keys, expressions, MJCF consistency) without running it",
        description="Validate a scenario file as a run would, without running it: every key, every "
        "expression, kappa > L, the time grid, and each backend section (the MuJoCo model is compiled "
        "and compared with eq. (1)). Exit status 0 when it is valid, 2 otherwise (one line on stderr).",
    )
    add_scenario_options(p)
    p.add_argument("--backend", metavar=backend_names(),
                   help="the backend to check for (default: the scenario's)")


def cmd_check(args: argparse.Namespace) -> int:
    """Validate the scenario and put its run together on each backend (its law and plant); print
    one line."""
    sc = scenario_from_args(args)
    runs = _assembled(sc, args.backend)
    built = [_plant_note(run) for run in runs]
    if not args.quiet:
        steps = round(sc.simulation.duration / sc.simulation.dt)
        print(f"ok: {sc.source} ({sc.name}): keys, expressions and the {sc.controller.kind} law's constants "
              f"valid; {steps} steps of {sc.simulation.dt:g} s on {runs[0].backend}; " + "; ".join(built))
    return EXIT_OK


def _assembled(sc: Scenario, backend: str | None) -> list[Assembly]:
    """The run put together as a run would, on the chosen backend and on every backend the file
    has a section for (MuJoCo checks its model against eq. (1) when its plant is built, with the
    Python form of its passive callback, bit-identical to the compiled one: nothing runs, so numba
    is not imported)."""
    with compiled_paths.not_needed():
        chosen = assemble(sc, backend)
        return [chosen] + [assemble(sc, name) for name in sc.backends if name != chosen.backend]


def _plant_note(run: Assembly) -> str:
    """What was found of the run's plant: the consistency of its model with eq. (1), if measured."""
    backend, report = run.backend, run.report.consistency_report
    if not report:
        return f"{backend}: the plant of eq. (1) built"
    agreement = (f"agrees with eq. (1) at {report['samples']} sampled states (max |mismatch| "
                 f"{report['max_abs_mismatch']:.2g})")
    if report.get("realism"):
        agreement = (f"differs from eq. (1) by up to {report['max_abs_mismatch']:.3g} at {report['samples']} "
                     f"sampled states, as its realism options ({', '.join(report['realism'])}) make it")
    return f"{backend}: the model compiled and {agreement}"
