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

from ..commands import check
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
    """Validate the scenario and build its law and each backend's plant (:func:`qcontrol.check`);
    print one line."""
    report = check(scenario_from_args(args), args.backend)
    if not args.quiet:
        print(report.line())
    return EXIT_OK
