"""``qcontrol reproduce``: the paper's figures and Table 1, the studies and REPORT.md
(:mod:`qcontrol.reproduce`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import QcontrolInputError
from ..plants import BACKENDS
from .arguments import EXIT_OK


def add_reproduce_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol reproduce`` (its handler is :func:`cmd_reproduce`)."""
    rep = sub.add_parser(
        "reproduce",
        help="reproduce the paper's Figures 1-8 and Table 1 with an honest report",
        description="Run both examples of the paper (proposed law and the comparison method of [20]) "
        "and the sensitivity studies; write figures, table1.md/.json, REPORT.md and recordings.",
    )
    rep.add_argument("--out", type=Path, default=Path("results"), metavar="DIR",
                     help="output folder (default: results)")
    rep.add_argument("--backend", choices=tuple(BACKENDS), default="mujoco",
                     help="plant for the examples (default: mujoco, with the ODE twin beside it)")
    rep.add_argument("--duration", type=float, metavar="S",
                     help="shorter horizon for a quick look (default: the paper's 10 s)")
    rep.add_argument("--scenarios", type=Path, default=None, metavar="DIR",
                     help="folder holding example1.toml, example2.toml, example2-rigid.toml, "
                     "example2-arm.toml, example1-cart.toml")
    rep.add_argument("--workers", type=int, default=None, metavar="N",
                     help="worker processes for the robustness study (default: the cores, at most 4)")
    rep.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def cmd_reproduce(args: argparse.Namespace) -> int:
    from ..reproduce import SCENARIO_DIR, reproduce  # matplotlib and the studies: only for this command

    if args.duration is not None and not (args.duration > 0):
        raise QcontrolInputError(f"--duration must be > 0, got {args.duration!r}")
    if args.workers is not None and args.workers < 1:
        raise QcontrolInputError(f"--workers must be >= 1, got {args.workers}")
    scenarios = args.scenarios or SCENARIO_DIR
    log = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    reproduce(args.out, args.backend, args.duration, scenarios, log, command=args.command_line,
              workers=args.workers)
    return EXIT_OK
