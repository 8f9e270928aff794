"""What the commands share on the command line: the exit statuses, the parser whose usage errors
are one line, the scenario options (a scenario file and ``--set``, ``--unset``, ``--duration``,
``--dt``, ``-q``) and the scenario they name, the recording options, where a sweep's or a region's
runs go (``--workers``, ``--scheduler``), and the output checks made before anything runs."""

from __future__ import annotations

import argparse
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

from ..errors import OverrideError, QcontrolInputError
from ..outputs import check_distinct, check_figure_file, check_output_dir, check_output_file
from ..plants import BACKENDS
from ..progress import ProgressLine
from ..resources import shipped_scenarios
from ..scenario import Scenario, load_scenario
from ..sweep.runs import DASK_CONNECT_TIMEOUT

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_WRITE_FAILED, EXIT_LAW_FAILED = 0, 1, 2, 3, 4
EXIT_INTERRUPTED, EXIT_TERMINATED = 130, 143
EXIT_STATUS = ("Exit status: 0 ok, 1 diverged or a theory check failed, 2 bad input (checked before the "
               "run, outputs included; a --law-module that fails or exits at import too), 3 an output "
               "could not be written (disk full, I/O error, no permission; the previous file is kept), "
               "4 a control law written in Python failed during a run (raised, or returned what its "
               "method must not: one line names the method, the error and the line of its file; "
               "QCONTROL_DEBUG=1 prints the traceback), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM).")

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


def add_parallel_options(p: argparse.ArgumentParser) -> None:
    """``--workers`` and ``--scheduler``: where the runs of a sweep or a region go (the same numbers
    wherever they run)."""
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="local worker processes, at most (default 1; runs too few to repay starting "
                   "workers stay in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="send the runs to a running Dask scheduler (needs qcontrol[cluster]); one that "
                   f"does not complete Dask's handshake within {DASK_CONNECT_TIMEOUT:g} s is refused")


def backend_names() -> str:
    """How ``--backend NAME`` shows in a usage line: the backends registered now. The name is not
    checked by the parser but once the command's law modules, which may register a backend, have
    run (an unknown name: one line, exit status 2)."""
    return "{" + ",".join(BACKENDS) + "}"


def add_recording_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rrd", type=Path, metavar="FILE",
                   help="write a rerun recording (open it with `rerun FILE`)")
    p.add_argument("--spawn", action="store_true",
                   help="stream to a rerun viewer started on this machine (needs a display)")


def timing_overrides(args: argparse.Namespace) -> dict[str, str]:
    """``--duration`` and ``--dt`` as the overrides they stand for, each mapped to the option as
    given (so a problem with the value names the option); positive finite seconds, else refused."""
    made = {}
    for option, key, value in (("--duration", "duration", args.duration), ("--dt", "dt", args.dt)):
        if value is None:
            continue
        if not 0 < value < float("inf"):
            raise QcontrolInputError(f"{option} {value!r}: must be a positive number of seconds; "
                                     f"e.g. {option} {'10' if option == '--duration' else '0.001'}")
        made[f"simulation.{key}={value!r}"] = f"{option} {value!r}"
    return made


@contextmanager
def options_named(options: Mapping[str, str]) -> Iterator[None]:
    """A problem with an override the command made from another option (``--duration``, a
    ``--grid`` value; ``options`` maps the override to the option as given) names that option."""
    try:
        yield
    except OverrideError as exc:
        label = options.get(exc.item) if isinstance(exc.item, str) else None
        if label is None:
            raise
        raise exc.named(label) from None


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The scenario of :func:`add_scenario_options`' arguments (with ``timing``): ``--unset``,
    then ``--set``, then ``--duration`` and ``--dt`` applied to the file."""
    timing = timing_overrides(args)
    with options_named(timing):
        return load_scenario(args.scenario, [*args.overrides, *timing], args.unset)


def check_outputs(args: argparse.Namespace, sc: Scenario, files: dict[str, Path | None],
                  in_out: tuple[str, ...] = ()) -> None:
    """Check --out (and the files ``in_out`` it will hold) and the output ``files`` (option ->
    path) without creating anything: each a regular file or a new name, no two the same, none the
    scenario file, none where the folder goes, a --plot with a figure's suffix; with --spawn, make
    sure a viewer runs (one line and exit status 2 when there is no display: before the run
    starts)."""
    given = {option: path for option, path in files.items() if path is not None}
    for option, path in given.items():
        if option == "--plot":
            check_figure_file(path, option)
        else:
            check_output_file(path, option)
    if args.out is not None:
        check_output_dir(args.out)
        for name in in_out:
            fix = "remove it or choose another --out folder"
            given[f"--out (its {name})"] = check_output_file(args.out / name, "--out", fix=fix)
    source = Path(sc.source)
    check_distinct(given, {"scenario file": source} if source.is_file() else {},
                   {"--out": args.out} if args.out is not None else {})
    if args.spawn:
        from ..recording.viewer import start_viewer

        start_viewer()


def progress_line(sc: Scenario, backend: str, args: argparse.Namespace) -> ProgressLine:
    return ProgressLine(f"{sc.name} [{backend}]", not args.quiet)
