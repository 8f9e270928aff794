"""``qcontrol compare``: the scenario's controller on MuJoCo and on the ODE of eq. (1), how far
they drift apart, compare.json and the recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import api
from ..assembly import assemble
from ..attribution import attribution_lines
from ..outputs import output_dir, write_json
from ..progress import ProgressLine
from .arguments import (
    add_recording_options,
    add_scenario_options,
    check_outputs,
    progress_line,
    scenario_from_args,
)
from .printing import format_summary, law_failed, print_paper_line, print_warnings, status
from .rendering import add_rendering_options, check_rendering, write_video


def add_compare_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol compare`` (its handler is :func:`cmd_compare`)."""
    compare = sub.add_parser(
        "compare",
        help="run the same controller on MuJoCo physics and on the ideal ODE",
        description="Run the scenario's controller on the MuJoCo model and on the ODE of eq. (1) "
        "with the same step, and report how far they drift apart (max |dx|, |dy|, |du|). "
        "With --out writes DIR/compare.json.",
    )
    add_scenario_options(compare)
    compare.add_argument("--out", type=Path, metavar="DIR", help="write DIR/compare.json")
    add_recording_options(compare)
    add_rendering_options(compare)


def cmd_compare(args: argparse.Namespace) -> int:
    sc = scenario_from_args(args)
    api.require_twin(sc)  # before --spawn starts a viewer
    main = assemble(sc, "mujoco")  # the MuJoCo run put together once (api.compare adds its ODE twin)
    check_outputs(args, sc, {"--rrd": args.rrd, "--video": args.video}, ("compare.json",))
    check_rendering(args, main)
    progress: dict[str, ProgressLine] = {}

    def progress_of(backend: str) -> ProgressLine:
        progress[backend] = progress_line(sc, backend, args)
        return progress[backend]

    cmp = api.compare(main, rrd=args.rrd, spawn=args.spawn, progress=progress_of, command=args.command_line,
                      camera_view=args.camera_view)
    for line in progress.values():
        line.finish()
    result = cmp.summary
    report = result["consistency"]
    if report.get("realism"):
        print(f"realism options on ({', '.join(report['realism'])}): MuJoCo differs from the ODE model "
              f"by up to {report['max_abs_mismatch']:.3g} in acceleration at sampled states")
    runs = (cmp.mujoco.typed_summary, cmp.ode.typed_summary)
    for s in runs:
        print(format_summary(s, sc))
    print_paper_line(sc)
    print_warnings((), result["physics_warnings"])  # compare.json's: the MuJoCo plant's
    print(
        f"MuJoCo vs ODE over {result['rows_compared']} instants: "
        f"max |dy| = {result['max_abs_dy']:.3g}, "
        f"max |dx| = [{', '.join(f'{v:.3g}' for v in result['max_abs_dx'])}], "
        f"max |du| = {result['max_abs_du']:.3g}"
    )
    if result["realism_alone"]:
        print("\n".join(attribution_lines(result["realism_alone"], result)))
    if args.out is not None:
        with output_dir(args.out) as out:
            write_json(out / "compare.json", result)
        print(f"  wrote {out / 'compare.json'}")
    if args.rrd is not None:
        print(f"  wrote {args.rrd} (open it with: rerun {args.rrd})")
    write_video(args, cmp.mujoco, twin=cmp.ode)
    return law_failed(runs) or max(status(s) for s in runs)
