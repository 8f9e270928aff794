"""``qcontrol run``: one closed loop, its printed summary, and summary.json, the trajectory file,
the figure and the recording it was asked for."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import api
from ..assembly import assemble
from ..errors import QcontrolInputError
from ..outputs import output_dir, write_json
from .arguments import (
    add_recording_options,
    add_scenario_options,
    backend_names,
    check_outputs,
    progress_line,
    scenario_from_args,
)
from .printing import format_summary, print_paper_line, print_warnings, status
from .rendering import add_rendering_options, check_rendering, write_video


def add_run_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol run`` (its handler is :func:`cmd_run`)."""
    run = sub.add_parser(
        "run",
        help="run one scenario and print a summary",
        description="Run one closed loop: plant -> sensors -> quantizer -> controller -> actuator. "
        "Prints a summary; with --out writes DIR/summary.json.",
    )
    add_scenario_options(run)
    run.add_argument("--backend", metavar=backend_names(), help="plant backend (default: the scenario's)")
    run.add_argument("--out", type=Path, metavar="DIR", help="write DIR/summary.json")
    run.add_argument("--save", type=Path, metavar="FILE",
                     help="write the run's signals to FILE.npz (an array per signal) or FILE.csv (a column "
                     "per component); keeps every row in memory, unlike a plain run")
    run.add_argument("--plot", type=Path, metavar="FILE",
                     help="draw the run (y and y_d, z1, u, the adaptive estimates, the Lemma 2 ratio) to "
                     "FILE.png, .pdf or .svg; keeps every row in memory, unlike a plain run")
    add_recording_options(run)
    add_rendering_options(run)


def cmd_run(args: argparse.Namespace) -> int:
    sc = scenario_from_args(args)
    run = assemble(sc, args.backend)  # the run put together once: what follows reads its parts
    if args.save is not None and args.save.suffix not in api.SAVE_FORMATS:
        raise QcontrolInputError(f"--save {args.save}: unknown format {args.save.suffix!r}; "
                                 "give a .npz or .csv file")
    outputs = {"--rrd": args.rrd, "--save": args.save, "--plot": args.plot, "--video": args.video}
    check_outputs(args, sc, outputs, ("summary.json",))
    check_rendering(args, run)
    # a plain run keeps only its metrics (memory stays flat however long the run); --save, --plot
    # and --video need every row
    record = "metrics" if args.save is None and args.plot is None and args.video is None else "full"
    progress = progress_line(sc, run.backend, args)
    result = api.run(run, rrd=args.rrd, spawn=args.spawn, record=record, progress=progress,
                     command=args.command_line, camera_view=args.camera_view)
    progress.finish()
    s = result.typed_summary
    print(format_summary(s, sc))
    print_paper_line(sc)
    print_warnings(s.warnings, s.physics_warnings or ())
    if args.out is not None:
        with output_dir(args.out) as out:
            write_json(out / "summary.json", result.summary)
        print(f"  wrote {out / 'summary.json'}")
    if args.save is not None:
        print(f"  wrote {result.save(args.save)}")
    if args.plot is not None:
        print(f"  wrote {result.plot(args.plot)}")
    if args.rrd is not None:
        print(f"  wrote {args.rrd} (open it with: rerun {args.rrd})")
    write_video(args, result)
    return status(s)
