"""The ``qcontrol`` command line: run, compare, reproduce, sweep, check (built on :mod:`qcontrol.api`).

Exit status: 0 success; 1 the run diverged or a theory check failed; 2 bad input (outputs that
cannot be written included: checked before the run); 3 an output could not be written during or
after the run (no space left, an I/O error, no permission: the previous file is intact); 130
interrupted (Ctrl-C); 143 terminated (SIGTERM). Bad input is reported as one line on stderr, never
as a traceback, and every input is checked before any folder or file is made.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

from . import api
from ._version import __version__
from .assembly import runnable_backend
from .attribution import attribution_lines
from .check import add_check_parser, cmd_check
from .errors import QcontrolInputError, QcontrolOutputError, Terminated, shown
from .explain import divergence_lines, paper_line
from .outputs import (
    check_distinct,
    check_figure_file,
    check_output_dir,
    check_output_file,
    path_kind,
    prepare_output_dir,
    write_json,
)
from .plants import BACKENDS
from .progress import ProgressLine
from .provenance import command_line
from .resources import shipped_scenarios
from .scenario import Scenario, load_scenario
from .sweep import add_sweep_parser, cmd_sweep

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_WRITE_FAILED = 0, 1, 2, 3
EXIT_INTERRUPTED, EXIT_TERMINATED = 130, 143
EXIT_STATUS = ("Exit status: 0 ok, 1 diverged or a theory check failed, 2 bad input (checked before the run, "
               "outputs included), 3 an output could not be written (disk full, I/O error, no permission; "
               "the previous file is kept), 130 interrupted, 143 terminated (SIGTERM).")
MAX_REPRODUCE_DURATION = 3600.0  # s of simulated time per run: every run keeps its rows for the figures
REPRODUCE_SCENARIOS = ("example1.toml", "example2.toml", "example2-rigid.toml", "example2-arm.toml",
                       "example1-cart.toml")
LEMMA2_TOLERANCE = 1e-9  # rounding slack on |e_zi| / L_zi <= 1


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _add_scenario_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path,
                   help="scenario file (TOML), e.g. scenarios/example2.toml, or a shipped scenario's name "
                   f"({', '.join(shipped_scenarios())})")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scenario key, e.g. --set controller.kappa_margin=0.1 (repeatable; the value is "
        "read as TOML, otherwise as a string)",
    )
    add_unset_option(p)
    p.add_argument("--duration", type=float, metavar="S", help="simulated time in seconds")
    p.add_argument("--dt", type=float, metavar="S", help="integration step in seconds")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def add_unset_option(p: argparse.ArgumentParser) -> None:
    """``--unset KEY`` (repeatable): remove a key of the file before the ``--set`` overrides."""
    p.add_argument("--unset", dest="unset", action="append", default=[], metavar="KEY",
                   help="remove a key of the scenario file, e.g. --unset reference.amplitude (repeatable; "
                   "applied before --set)")


def _add_recording_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rrd", type=Path, metavar="FILE",
                   help="write a rerun recording (open it with `rerun FILE`)")
    p.add_argument("--spawn", action="store_true",
                   help="stream to a rerun viewer started on this machine (needs a display)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="qcontrol",
        description=(
            "Adaptive backstepping control with quantized states (Sun et al., Electronics 2022, "
            "11, 3160) on an ideal ODE plant or on MuJoCo physics."
        ),
        epilog=EXIT_STATUS,
    )
    parser.add_argument("--version", action="version", version=f"qcontrol {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    _add_run_parser(sub)
    _add_compare_parser(sub)
    _add_reproduce_parser(sub)
    add_sweep_parser(sub)
    add_check_parser(sub, _add_scenario_options, _scenario_from_args)
    return parser


def _add_run_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol run`` (its handler is :func:`cmd_run`)."""
    run = sub.add_parser(
        "run",
        help="run one scenario and print a summary",
        description="Run one closed loop: plant -> sensors -> quantizer -> controller -> actuator. "
        "Prints a summary; with --out writes DIR/summary.json.",
    )
    _add_scenario_options(run)
    run.add_argument("--backend", choices=tuple(BACKENDS), help="plant backend (default: the scenario's)")
    run.add_argument("--out", type=Path, metavar="DIR", help="write DIR/summary.json")
    run.add_argument("--save", type=Path, metavar="FILE",
                     help="write the run's signals to FILE.npz (an array per signal) or FILE.csv (a column "
                     "per component); keeps every row in memory, unlike a plain run")
    run.add_argument("--plot", type=Path, metavar="FILE",
                     help="draw the run (y and y_d, z1, u, the adaptive estimates, the Lemma 2 ratio) to "
                     "FILE.png, .pdf or .svg; keeps every row in memory, unlike a plain run")
    _add_recording_options(run)


def _add_compare_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol compare`` (its handler is :func:`cmd_compare`)."""
    compare = sub.add_parser(
        "compare",
        help="run the same controller on MuJoCo physics and on the ideal ODE",
        description="Run the scenario's controller on the MuJoCo model and on the ODE of eq. (1) "
        "with the same step, and report how far they drift apart (max |dx|, |dy|, |du|). "
        "With --out writes DIR/compare.json.",
    )
    _add_scenario_options(compare)
    compare.add_argument("--out", type=Path, metavar="DIR", help="write DIR/compare.json")
    _add_recording_options(compare)


def _add_reproduce_parser(sub: argparse._SubParsersAction) -> None:
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
                     help=f"folder holding {', '.join(REPRODUCE_SCENARIOS)} (default: the shipped ones)")
    rep.add_argument("--workers", type=int, default=None, metavar="N",
                     help="worker processes for the robustness study (default: the cores, at most 4)")
    rep.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def _scenario_from_args(args: argparse.Namespace) -> Scenario:
    overrides = list(args.overrides)
    if args.duration is not None:
        overrides.append(f"simulation.duration={args.duration!r}")
    if args.dt is not None:
        overrides.append(f"simulation.dt={args.dt!r}")
    return load_scenario(args.scenario, overrides, args.unset)


def _check_outputs(args: argparse.Namespace, sc: Scenario, files: dict[str, Path | None],
                   in_out: Sequence[str]) -> None:
    """Check --out (and the files ``in_out`` it will hold) and the output ``files`` (option ->
    path) without creating anything: each a regular file or a new name, no two the same, none the
    scenario file, none where the folder goes; with --spawn, make sure a viewer runs (one line and
    exit status 2 when there is no display: before the run starts)."""
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
    check_distinct(given, {"scenario file": Path(sc.source)} if Path(sc.source).is_file() else {},
                   {"--out": args.out} if args.out is not None else {})
    if args.spawn:
        from .recording.viewer import start_viewer

        start_viewer()


def _progress(sc: Scenario, backend: str, args: argparse.Namespace) -> ProgressLine:
    return ProgressLine(f"{sc.name} [{backend}]", not args.quiet)


def _print_warnings(s: dict) -> None:
    for warning in s.get("warnings", []):
        print(f"  warning: {warning}")
    physics = s.get("physics_warnings", [])
    for message in physics[:3]:
        print(f"  MuJoCo warned: {message}")
    if len(physics) > 3:
        print(f"  ... and {len(physics) - 3} more MuJoCo warnings")


def format_summary(s: dict, sc: Scenario) -> str:
    """The printed summary of a run; a diverged run says when and why it stopped and what usually
    helps (:mod:`qcontrol.explain`)."""
    rates = "  ".join(f"E({k})={v:.4f}" for k, v in s["error_rate"].items())
    if s["diverged"]:
        simulated = (f"stopped after {s['steps']} of {round(s['duration'] / s['dt'])} steps of {s['dt']:g} s "
                     f"({s['steps'] * s['dt']:g} s of {s['duration']:g} s simulated)")
    else:
        simulated = f"{s['steps']} steps of {s['dt']:g} s ({s['duration']:g} s simulated)"
    lines = [
        f"scenario {s['scenario']} on {s['backend']}: {simulated} in {s['wall_time_s']:.2f} s",
        f"  error rate: {rates}",
        f"  max |z1| over the last half: {s['max_abs_z1_last_half']:.4g}    max |u|: {s['max_abs_u']:.4g}",
        f"  actuator: max |u applied|: {s['max_abs_u_applied']:.4g}    saturated at "
        f"{100 * s['saturated_fraction']:.1f}% of the control samples",
        f"  final {s['adaptive_state']}: [{', '.join(f'{v:.4g}' for v in s['final_eps_hat'])}]",
        _lemma2_line(s),
    ]
    if s["diverged"]:
        lines += divergence_lines(s, sc)
    return "\n".join(lines)


def _lemma2_line(s: dict) -> str:
    ratio = f"  Lemma 2: max |e_zi|/L_zi = {s['lemma2_max_ratio']:.6f}"
    if not s["lemma2_applies"]:
        return (f"{ratio} (not checked: x2 is differenced from the encoder, outside the paper's "
                "assumptions)")
    return f"{ratio} (<= 1 holds: {'yes' if _lemma2_holds(s) else 'NO'})"


def _lemma2_holds(s: dict) -> bool:
    """Whether the run kept every Lemma 2 error within its bound (up to rounding)."""
    return s["lemma2_max_ratio"] <= 1 + LEMMA2_TOLERANCE


def _print_paper_line(s: dict, sc: Scenario) -> None:
    """For a scenario of the paper, what the paper reports and where the difference is explained."""
    told = paper_line(s, sc)
    if told is not None:
        print(told)


def cmd_run(args: argparse.Namespace) -> int:
    sc = _scenario_from_args(args)
    backend = runnable_backend(sc, args.backend)
    if args.save is not None and args.save.suffix not in api.SAVE_FORMATS:
        raise QcontrolInputError(f"--save {args.save}: unknown format {args.save.suffix!r}; "
                                 "give a .npz or .csv file")
    _check_outputs(args, sc, {"--rrd": args.rrd, "--save": args.save, "--plot": args.plot}, ["summary.json"])
    # a plain run keeps only its metrics (memory stays flat however long the run); --save and
    # --plot need every row
    record = "full" if args.save is not None or args.plot is not None else "metrics"
    progress = _progress(sc, backend, args)
    result = api.run(sc, backend, rrd=args.rrd, spawn=args.spawn, record=record, progress=progress,
                     command=args.command_line)
    progress.finish()
    s = result.summary
    print(format_summary(s, sc))
    _print_paper_line(s, sc)
    _print_warnings(s)
    if args.out is not None:
        out = prepare_output_dir(args.out)
        write_json(out / "summary.json", s)
        print(f"  wrote {out / 'summary.json'}")
    if args.save is not None:
        print(f"  wrote {result.save(args.save)}")
    if args.plot is not None:
        print(f"  wrote {_plot_run(result, args.plot)}")
    if args.rrd is not None:
        print(f"  wrote {args.rrd} (open it with: rerun {args.rrd})")
    return _status(s)


def _plot_run(result: api.Result, path: Path) -> Path:
    from .plots import fig_run

    s = result.summary
    notes = [f"{s['scenario']} on {s['backend']}, {s['duration']:g} s, dt = {s['dt']:g} s"]
    notes += [f"E({k}) = {v:.4f}" for k, v in s["error_rate"].items()]
    notes += [f"max |z1|, last half = {s['max_abs_z1_last_half']:.4g}", f"max |u| = {s['max_abs_u']:.4g}",
              f"Lemma 2 ratio = {s['lemma2_max_ratio']:.6f}"]
    if s["diverged"]:
        notes.append(f"diverged at t = {s['diverged_time']:g} s")
    return fig_run(result.trajectory, path, f"{s['scenario']} ({s['backend']})", notes=notes)


def cmd_compare(args: argparse.Namespace) -> int:
    sc = _scenario_from_args(args)
    api.require_twin(sc)  # before --spawn starts a viewer
    _check_outputs(args, sc, {"--rrd": args.rrd}, ["compare.json"])
    progress: dict[str, ProgressLine] = {}

    def progress_of(backend: str) -> ProgressLine:
        progress[backend] = _progress(sc, backend, args)
        return progress[backend]

    cmp = api.compare(sc, rrd=args.rrd, spawn=args.spawn, progress=progress_of, command=args.command_line)
    for line in progress.values():
        line.finish()
    result = cmp.summary
    report = result["consistency"]
    if report.get("realism"):
        print(f"realism options on ({', '.join(report['realism'])}): MuJoCo differs from the ODE model "
              f"by up to {report['max_abs_mismatch']:.3g} in acceleration at sampled states")
    for backend in ("mujoco", "ode"):
        print(format_summary(result[backend], sc))
    _print_paper_line(result["mujoco"], sc)
    _print_warnings(result)
    print(
        f"MuJoCo vs ODE over {result['rows_compared']} instants: "
        f"max |dy| = {result['max_abs_dy']:.3g}, "
        f"max |dx| = [{', '.join(f'{v:.3g}' for v in result['max_abs_dx'])}], "
        f"max |du| = {result['max_abs_du']:.3g}"
    )
    if result["realism_alone"]:
        print("\n".join(attribution_lines(result["realism_alone"], result)))
    if args.out is not None:
        out = prepare_output_dir(args.out)
        write_json(out / "compare.json", result)
        print(f"  wrote {out / 'compare.json'}")
    if args.rrd is not None:
        print(f"  wrote {args.rrd} (open it with: rerun {args.rrd})")
    return max(_status(result["mujoco"]), _status(result["ode"]))


def _status(s: dict) -> int:
    if s["diverged"]:
        return EXIT_FAILED
    if s["lemma2_applies"] and not _lemma2_holds(s):
        print("qcontrol: check failed: a Lemma 2 bound was exceeded", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def cmd_reproduce(args: argparse.Namespace) -> int:
    """The command-line options are checked before the reproduction (and matplotlib) is imported."""
    if args.duration is not None and not (0 < args.duration <= MAX_REPRODUCE_DURATION):
        raise QcontrolInputError(f"--duration {args.duration!r}: must be a number of seconds > 0 and at most "
                                 f"{MAX_REPRODUCE_DURATION:g}; e.g. --duration 2 for a quick look")
    if args.workers is not None and args.workers < 1:
        raise QcontrolInputError(f"--workers {args.workers}: must be >= 1; e.g. --workers 2 (more than the "
                                 "cores are capped at the cores)")
    if args.scenarios is not None:
        kind = path_kind(args.scenarios)
        if not args.scenarios.exists() or kind != "a folder":
            what = "does not exist" if not args.scenarios.exists() else f"is {kind or 'a file'}"
            raise QcontrolInputError(f"--scenarios {shown(args.scenarios)}: {what}; give the folder holding "
                                     f"{', '.join(REPRODUCE_SCENARIOS)}")
    check_output_dir(args.out)
    from .reproduce import SCENARIO_DIR, reproduce

    scenarios = args.scenarios or SCENARIO_DIR
    log = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    reproduce(args.out, args.backend, args.duration, scenarios, log, command=args.command_line,
              workers=args.workers)
    return EXIT_OK


COMMANDS = {"run": cmd_run, "compare": cmd_compare, "reproduce": cmd_reproduce, "sweep": cmd_sweep,
            "check": cmd_check}


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                      line: str | None = None) -> str:
    """A warning as the command line prints it: one line, no source location."""
    return f"qcontrol: warning: {message}\n"


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM: stop as Ctrl-C does (every output cleans up after itself), exit status 143."""
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.command_line = command_line(argv)  # what the outputs' provenance names as the command
    warnings.formatwarning = _one_line_warning
    started = time.perf_counter()
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    try:
        return COMMANDS[args.command](args)
    except QcontrolInputError as exc:
        print(f"qcontrol: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except QcontrolOutputError as exc:
        print(f"qcontrol: error: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_WRITE_FAILED
    except KeyboardInterrupt as exc:
        how = "terminated" if isinstance(exc, Terminated) else "interrupted"
        print(f"\nqcontrol: {how} after {time.perf_counter() - started:.1f} s", file=sys.stderr)
        return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
