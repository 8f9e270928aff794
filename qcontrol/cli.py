"""The ``qcontrol`` command line: run, compare, reproduce.

Exit status: 0 success; 1 the run diverged or a theory check failed; 2 bad input; 130 interrupted.
Bad input is reported as one line on stderr, never as a traceback.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path

from . import __version__
from .assembly import build_plant, controller_constants, run_scenario, scene
from .attribution import attribution_lines, realism_attribution
from .controller import lemma2_L
from .engine import Observer
from .errors import QcontrolInputError
from .metrics import backend_deviation, summary
from .outputs import check_output_file, prepare_output_dir, write_json
from .plants import BACKENDS, Plant
from .progress import ProgressLine
from .scenario import Scenario, load_scenario
from .sweep import add_sweep_parser, cmd_sweep

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
LEMMA2_TOLERANCE = 1e-9  # rounding slack on |e_zi| / L_zi <= 1


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _add_scenario_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path, help="scenario file (TOML), e.g. scenarios/example2.toml")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scenario key, e.g. --set controller.kappa_margin=0.1 (repeatable; the value is "
        "read as TOML, otherwise as a string)",
    )
    p.add_argument("--duration", type=float, metavar="S", help="simulated time in seconds")
    p.add_argument("--dt", type=float, metavar="S", help="integration step in seconds")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")


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
        epilog="Exit status: 0 ok, 1 diverged or a theory check failed, 2 bad input, 130 interrupted.",
    )
    parser.add_argument("--version", action="version", version=f"qcontrol {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    run = sub.add_parser(
        "run",
        help="run one scenario and print a summary",
        description="Run one closed loop: plant -> sensors -> quantizer -> controller -> actuator. "
        "Prints a summary; with --out writes DIR/summary.json.",
    )
    _add_scenario_options(run)
    run.add_argument("--backend", choices=tuple(BACKENDS), help="plant backend (default: the scenario's)")
    run.add_argument("--out", type=Path, metavar="DIR", help="write DIR/summary.json")
    _add_recording_options(run)

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

    add_sweep_parser(sub)
    return parser


def _scenario_from_args(args: argparse.Namespace) -> Scenario:
    overrides = list(args.overrides)
    if args.duration is not None:
        overrides.append(f"simulation.duration={args.duration!r}")
    if args.dt is not None:
        overrides.append(f"simulation.dt={args.dt!r}")
    return load_scenario(args.scenario, overrides)


def _recording(args: argparse.Namespace) -> AbstractContextManager:
    """A rerun Recording when --rrd or --spawn is given; otherwise nothing is imported or logged."""
    if args.rrd is None and not args.spawn:
        return nullcontext(None)
    from .recording import Recording  # imports rerun (~0.5 s) when it opens: only when asked for

    return Recording(args.rrd, spawn=args.spawn)


def _log_disturbances(rec: object, sc: Scenario) -> None:
    """Arrows and time markers of the scenario's disturbances (see qcontrol.recording.disturbances)."""
    from .recording.disturbances import log_disturbances

    log_disturbances(rec, sc)


def _progress(sc: Scenario, backend: str, args: argparse.Namespace) -> ProgressLine:
    return ProgressLine(f"{sc.name} [{backend}]", not args.quiet)


def _observer(rec: object, sc: Scenario, backend: str, ghost: bool = False) -> Observer | None:
    """The recording's observer of a run on ``backend`` (None without a recording)."""
    if rec is None:
        return None
    drawn = scene(sc)
    if drawn is None:
        return rec.observer(backend, ghost=ghost)
    return rec.observer(backend, drawn.model, drawn.joint, ghost=ghost)


def _print_warnings(plant: Plant) -> None:
    for message in plant.warnings[:3]:
        print(f"  MuJoCo warned: {message}")
    if len(plant.warnings) > 3:
        print(f"  ... and {len(plant.warnings) - 3} more MuJoCo warnings")


def format_summary(s: dict) -> str:
    rates = "  ".join(f"E({k})={v:.4f}" for k, v in s["error_rate"].items())
    lines = [
        f"scenario {s['scenario']} on {s['backend']}: {s['steps']} steps of {s['dt']:g} s "
        f"({s['duration']:g} s simulated) in {s['wall_time_s']:.2f} s",
        f"  error rate: {rates}",
        f"  max |z1| over the last half: {s['max_abs_z1_last_half']:.4g}    max |u|: {s['max_abs_u']:.4g}",
        f"  actuator: max |u applied|: {s['max_abs_u_applied']:.4g}    saturated at "
        f"{100 * s['saturated_fraction']:.1f}% of the control samples",
        f"  final {s['adaptive_state']}: [{', '.join(f'{v:.4g}' for v in s['final_eps_hat'])}]",
        _lemma2_line(s),
    ]
    if s["diverged"]:
        lines.append(f"  DIVERGED at t = {s['diverged_time']:g} s: {s['divergence_reason']}")
    return "\n".join(lines)


def _lemma2_line(s: dict) -> str:
    ratio = f"  Lemma 2: max |e_zi|/L_zi = {s['lemma2_max_ratio']:.6f}"
    if not s["lemma2_applies"]:
        return (f"{ratio} (not checked: x2 is differenced from the encoder, outside the paper's "
                "assumptions)")
    return f"{ratio} (<= 1 holds: {'yes' if s['lemma2_max_ratio'] <= 1 + LEMMA2_TOLERANCE else 'NO'})"


def cmd_run(args: argparse.Namespace) -> int:
    sc = _scenario_from_args(args)
    backend = args.backend or sc.simulation.backend
    BACKENDS[backend].require(sc.backends.get(backend), sc.source)
    out = prepare_output_dir(args.out) if args.out else None
    if args.rrd is not None:
        check_output_file(args.rrd, "--rrd")
    plant = build_plant(sc, backend)
    progress = _progress(sc, backend, args)
    with _recording(args) as rec:
        if rec is not None:
            rec.log_static(sc.text, controller_constants(sc), __version__)
            _log_disturbances(rec, sc)
        # metrics record: memory stays bounded however long the run; the recording streams
        run = run_scenario(sc, backend, plant=plant, observer=_observer(rec, sc, backend), record="metrics",
                           progress=progress)
    progress.finish()
    s = summary(run, sc.name, backend)
    s["L"] = lemma2_L(sc.controller.c, sc.controller.delta)
    print(format_summary(s))
    _print_warnings(plant)
    if out is not None:
        write_json(out / "summary.json", s)
        print(f"  wrote {out / 'summary.json'}")
    if args.rrd is not None:
        print(f"  wrote {args.rrd} (open it with: rerun {args.rrd})")
    return _status(s)


def cmd_compare(args: argparse.Namespace) -> int:
    sc = _scenario_from_args(args)
    if "mujoco" not in sc.backends:
        raise QcontrolInputError(
            f"{sc.source}: compare needs a [plant.mujoco] table (the MuJoCo twin of the ODE); add one"
        )
    out = prepare_output_dir(args.out) if args.out else None
    if args.rrd is not None:
        check_output_file(args.rrd, "--rrd")
    plant = build_plant(sc, "mujoco")
    report = plant.consistency_report
    if report.get("realism"):
        print(f"realism options on ({', '.join(report['realism'])}): MuJoCo differs from the ODE model "
              f"by up to {report['max_abs_mismatch']:.3g} in acceleration at sampled states")
    runs = {}
    with _recording(args) as rec:
        if rec is not None:
            rec.log_static(sc.text, controller_constants(sc), __version__)
            _log_disturbances(rec, sc)
        for backend in ("mujoco", "ode"):  # the ODE twin is drawn as a translucent ghost
            progress = _progress(sc, backend, args)
            traj = run_scenario(sc, backend, plant=plant if backend == "mujoco" else None,
                                observer=_observer(rec, sc, backend, ghost=backend == "ode"),
                                progress=progress)
            progress.finish()
            runs[backend] = (traj, summary(traj, sc.name, backend))
    deviation = backend_deviation(runs["mujoco"][0], runs["ode"][0])
    parts = realism_attribution(sc, runs["ode"][0]) if report.get("realism") else {}
    result = {
        "scenario": sc.name,
        "integrator": sc.backends["mujoco"].integrator,
        "dt": sc.simulation.dt,
        **deviation,
        "consistency": report,
        "realism_alone": parts,
        "mujoco": runs["mujoco"][1],
        "ode": runs["ode"][1],
    }
    for backend in ("mujoco", "ode"):
        print(format_summary(runs[backend][1]))
    _print_warnings(plant)
    print(
        f"MuJoCo vs ODE over {deviation['rows_compared']} instants: "
        f"max |dy| = {deviation['max_abs_dy']:.3g}, "
        f"max |dx| = [{', '.join(f'{v:.3g}' for v in deviation['max_abs_dx'])}], "
        f"max |du| = {deviation['max_abs_du']:.3g}"
    )
    if parts:
        print("\n".join(attribution_lines(parts, deviation)))
    if out is not None:
        write_json(out / "compare.json", result)
        print(f"  wrote {out / 'compare.json'}")
    if args.rrd is not None:
        print(f"  wrote {args.rrd} (open it with: rerun {args.rrd})")
    return max(_status(runs["mujoco"][1]), _status(runs["ode"][1]))


def _status(s: dict) -> int:
    if s["diverged"]:
        return EXIT_FAILED
    if s["lemma2_applies"] and not s["lemma2_max_ratio"] <= 1 + LEMMA2_TOLERANCE:
        print("qcontrol: check failed: a Lemma 2 bound was exceeded", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def cmd_reproduce(args: argparse.Namespace) -> int:
    from .reproduce import SCENARIO_DIR, reproduce

    if args.duration is not None and not (args.duration > 0):
        raise QcontrolInputError(f"--duration must be > 0, got {args.duration!r}")
    if args.workers is not None and args.workers < 1:
        raise QcontrolInputError(f"--workers must be >= 1, got {args.workers}")
    scenarios = args.scenarios or SCENARIO_DIR
    log = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    reproduce(args.out, args.backend, args.duration, scenarios, log, args.workers)
    return EXIT_OK


COMMANDS = {"run": cmd_run, "compare": cmd_compare, "reproduce": cmd_reproduce, "sweep": cmd_sweep}


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    started = time.perf_counter()
    try:
        return COMMANDS[args.command](args)
    except QcontrolInputError as exc:
        print(f"qcontrol: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"\nqcontrol: interrupted after {time.perf_counter() - started:.1f} s", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
