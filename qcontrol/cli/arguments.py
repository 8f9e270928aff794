"""What the commands share on the command line: the exit statuses, the parser whose usage errors
are one line, the scenario options (a scenario file and ``--set``, ``--unset``, ``--duration``,
``--dt``, ``-q``) and the scenario they name, the recording options, and the output checks made
before anything runs."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..outputs import check_output_dir, check_output_file
from ..progress import ProgressLine
from ..resources import shipped_scenarios
from ..scenario import Scenario, load_scenario

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

SET_HELP = ("override a scenario key, e.g. --set controller.kappa_margin=0.1 (repeatable; the value is "
            "read as TOML, otherwise as a string)")
UNSET_HELP = ("remove a key of the scenario file, e.g. --unset reference.amplitude (repeatable; "
              "applied before --set)")

LAW_MODULE_HELP = ("a Python file that registers control laws with qcontrol.register_law, run before the "
                   "scenario is read, e.g. --law-module mylaws.py --set controller.kind=mine (repeatable)")


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def add_scenario_options(p: argparse.ArgumentParser, *, timing: bool = True, scenario_help: str | None = None,
                         set_help: str = SET_HELP, unset_help: str = UNSET_HELP) -> None:
    """The scenario a command works on: the file (or a shipped scenario's name), ``--set``,
    ``--unset``, ``--law-module``, ``-q`` and, with ``timing``, ``--duration`` and ``--dt``
    (:func:`scenario_from_args` reads them)."""
    p.add_argument("scenario", type=Path,
                   help=scenario_help or "scenario file (TOML), e.g. scenarios/example2.toml, or a shipped "
                   f"scenario's name ({', '.join(shipped_scenarios())})")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help=set_help)
    p.add_argument("--unset", dest="unset", action="append", default=[], metavar="KEY", help=unset_help)
    p.add_argument("--law-module", dest="law_modules", action="append", default=[], type=Path,
                   metavar="FILE", help=LAW_MODULE_HELP)
    if timing:
        p.add_argument("--duration", type=float, metavar="S", help="simulated time in seconds")
        p.add_argument("--dt", type=float, metavar="S", help="integration step in seconds")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def add_recording_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rrd", type=Path, metavar="FILE",
                   help="write a rerun recording (open it with `rerun FILE`)")
    p.add_argument("--spawn", action="store_true",
                   help="stream to a rerun viewer started on this machine (needs a display)")


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The scenario of :func:`add_scenario_options`' arguments (with ``timing``): ``--unset``,
    then ``--set``, then ``--duration`` and ``--dt`` applied to the file."""
    overrides = list(args.overrides)
    if args.duration is not None:
        overrides.append(f"simulation.duration={args.duration!r}")
    if args.dt is not None:
        overrides.append(f"simulation.dt={args.dt!r}")
    return load_scenario(args.scenario, overrides, args.unset)


def check_outputs(args: argparse.Namespace, files: dict[str, Path | None]) -> None:
    """Check --out and the output ``files`` (option -> path) without creating anything; with
    --spawn, make sure a viewer runs (one line and exit status 2 when there is no display: before
    the run starts)."""
    if args.out is not None:
        check_output_dir(args.out)
    for option, path in files.items():
        if path is not None:
            check_output_file(path, option)
    if args.spawn:
        from ..recording.viewer import start_viewer

        start_viewer()


def progress_line(sc: Scenario, backend: str, args: argparse.Namespace) -> ProgressLine:
    return ProgressLine(f"{sc.name} [{backend}]", not args.quiet)
