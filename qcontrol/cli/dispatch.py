"""The ``qcontrol`` command line: run, compare, reproduce, sweep, region, check, model (on
:mod:`qcontrol.api`).

Exit status: 0 success; 1 the run diverged or a theory check failed; 2 bad input (outputs that
cannot be written included: checked before the run); 3 an output could not be written during or
after the run (no space left, an I/O error, no permission: the previous file is intact); 4 a law
written in Python failed during a run (the run stopped there, what was recorded is written);
130 interrupted (Ctrl-C); 143 terminated (SIGTERM). Bad input is reported as one line on stderr, never
as a traceback, and every input is checked before any folder or file is made. Each command is one
module of this package with its parser and its handler; they share the scenario options of
:mod:`.arguments`.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from pathlib import Path

from .._version import __version__
from ..controller.plugins import load_law_module, load_law_plugins
from ..errors import QcontrolInputError, QcontrolLawFailure, QcontrolOutputError, Terminated
from ..interrupts import stops_kept
from ..provenance import command_line
from ..sweep.runs import SweepInterrupted
from ..workers import WorkerDied
from .arguments import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_LAW_FAILED,
    EXIT_STATUS,
    EXIT_TERMINATED,
    EXIT_WRITE_FAILED,
    Parser,
)
from .check_command import add_check_parser, cmd_check
from .compare_command import add_compare_parser, cmd_compare
from .laws_command import add_laws_parser, cmd_laws
from .model_command import add_model_parser, cmd_model
from .region_command import add_region_parser, cmd_region
from .reproduce_command import add_reproduce_parser, cmd_reproduce
from .run_command import add_run_parser, cmd_run
from .sweep_command import add_sweep_parser, cmd_sweep

Register = Callable[[argparse._SubParsersAction], None]
Handler = Callable[[argparse.Namespace], int]

# Each command: the function that registers its parser (and options) and its handler. A new
# command is one module with both, and one entry here.
COMMANDS: dict[str, tuple[Register, Handler]] = {
    "run": (add_run_parser, cmd_run),
    "compare": (add_compare_parser, cmd_compare),
    "laws": (add_laws_parser, cmd_laws),
    "reproduce": (add_reproduce_parser, cmd_reproduce),
    "sweep": (add_sweep_parser, cmd_sweep),
    "region": (add_region_parser, cmd_region),
    "check": (add_check_parser, cmd_check),
    "model": (add_model_parser, cmd_model),
}


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="qcontrol",
        description=(
            "Adaptive backstepping control with quantized states (Sun et al., Electronics 2022, "
            "11, 3160) on an ideal ODE plant or on MuJoCo physics."
        ),
        epilog=EXIT_STATUS,
    )
    parser.add_argument("--version", action="version", version=f"qcontrol {__version__}")
    parser.set_defaults(law_modules=[])  # the commands without scenario options load no law file
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    for register, _ in COMMANDS.values():
        register(sub)
    return parser


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                      line: str | None = None) -> str:
    """A warning as the command line prints it: one line, no source location."""
    return f"qcontrol: warning: {message}\n"


def load_laws(files: Sequence[Path]) -> None:
    """Before any scenario is read: the installed law plugins (entry-point group ``qcontrol.laws``),
    then the ``--law-module`` files in the order given."""
    load_law_plugins()
    for file in files:
        load_law_module(file)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.command_line = command_line(argv)  # what the outputs' provenance names as the command
    warnings.formatwarning = _one_line_warning
    started = time.perf_counter()
    main_thread = threading.current_thread() is threading.main_thread()
    with stops_kept() if main_thread else nullcontext():  # SIGTERM: Terminated, exit status 143
        return _handled(args, started)


def _handled(args: argparse.Namespace, started: float) -> int:
    """The command run; its errors and interruptions as the exit status (module docstring)."""
    try:
        load_laws(args.law_modules)
        return COMMANDS[args.command][1](args)
    except QcontrolInputError as exc:
        print(f"qcontrol: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except QcontrolOutputError as exc:
        print(f"qcontrol: error: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_WRITE_FAILED
    except QcontrolLawFailure as exc:
        print(f"qcontrol: error: the law failed: {exc}", file=sys.stderr)
        return EXIT_LAW_FAILED
    except WorkerDied as exc:
        print(f"qcontrol: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt as exc:  # (a SIGTERM in a sweep: its SweepInterrupted says so)
        terminated = isinstance(exc, Terminated) or (isinstance(exc, SweepInterrupted) and exc.terminated)
        how = "terminated" if terminated else "interrupted"
        print(f"\nqcontrol: {how} after {time.perf_counter() - started:.1f} s", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
