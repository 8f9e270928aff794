"""``qcontrol region SCENARIO``: the region of attraction of one or more laws on a grid of initial
states, written as DIR/region.csv, DIR/region.json (with provenance) and DIR/region.png.

Exit status: 0 when every run finished (diverged points are results, not failures); 1 when a worker
process was killed from outside (one line says so); 2 for bad input (everything is checked before
any run, and the output folder is made only when the results are written); 130 when interrupted, 143
when terminated (SIGTERM) (nothing is written either way).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import QcontrolInputError
from ..outputs import check_output_dir, check_output_file
from ..progress import ProgressLine
from ..provenance import command_line
from ..region import BOX, check_region_size, default_laws, measure_region, parse_grid, parse_law, write_region
from ..scenario import load_scenario
from ..scenario.resolve import scenario_provenance
from .arguments import (
    EXIT_OK,
    add_parallel_options,
    add_scenario_options,
    backend_names,
    options_named,
    timing_overrides,
)
from .printing import report_law_failures


def add_region_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``qcontrol region`` (its handler is :func:`cmd_region`)."""
    p = subparsers.add_parser(
        "region",
        help="map the region of attraction of laws on a grid of initial states",
        description="Run the closed loop from every point of a grid over two state axes (the other "
        "components of x(0) as in the scenario), for each --law, and classify each start: bounded, "
        "diverged (and when) or Lemma 2 violated, with the largest K T of the run. Writes DIR/region.csv "
        "(one row per run), DIR/region.json (counts per law, the points failing in the box |x_i| <= "
        f"{BOX:g}, the largest working scale per direction, provenance) and DIR/region.png (a map per law). "
        "Exit status: 0 ok, 1 a worker process was killed from outside, 2 bad input, "
        "3 a write error, 130 interrupted, 143 terminated.",
    )
    add_scenario_options(p, scenario_help="scenario file (TOML) or a shipped scenario's name",
                         set_help="a fixed override for every run, e.g. simulation.control_period=0.005",
                         unset_help="remove a key of the scenario file for every run")
    p.add_argument("--law", dest="laws", action="append", default=[], metavar="KIND[:KEY=VALUE,...]",
                   help="a law to map, e.g. proposed, proposed:hold=exact, comparison, or a registered kind "
                   "(repeatable; default: the scenario's law, and for the paper's law also hold=exact)")
    p.add_argument("--axes", default="1,2", metavar="I,J",
                   help="the two state axes of the grid (default 1,2)")
    p.add_argument("--box", default="10", metavar="H | LO,HI | LO1,HI1,LO2,HI2",
                   help="the grid's extent: [-H, H] on both axes (default 10), or the bounds given")
    p.add_argument("--resolution", type=int, default=21, metavar="N", help="points per axis (default 21)")
    p.add_argument("--backend", metavar=backend_names(), default="ode",
                   help="plant backend (default ode: batched; mujoco on request)")
    add_parallel_options(p)
    p.add_argument("--out", type=Path, default=Path("region"), metavar="DIR",
                   help="output folder (default ./region)")
    p.set_defaults(command_line=None)


def cmd_region(args: argparse.Namespace) -> int:
    """Every run is checked before the output folder is made."""
    if args.workers < 1:
        raise QcontrolInputError(f"--workers {args.workers}: must be >= 1")
    check_output_dir(args.out)
    for name in ("region.csv", "region.json", "region.png"):
        check_output_file(args.out / name, "--out", fix="remove it or choose another --out folder")
    timing = timing_overrides(args)
    overrides = [*args.overrides, *timing]
    with options_named(timing):
        base = load_scenario(args.scenario, overrides, args.unset)
    grid = parse_grid(base, args.axes, args.box, args.resolution)
    laws = [parse_law(text) for text in args.laws] or default_laws(base)
    check_region_size(grid, len(laws))
    progress = ProgressLine("region", not args.quiet, "runs")
    region = measure_region(base.source, grid, laws, args.backend, overrides, args.unset, args.workers,
                            args.scheduler, progress)  # (interrupted: nothing written, as the module says)
    region.settings = {"fixed_overrides": overrides, "unset": list(args.unset)}
    write_region(region, args.out, scenario_provenance(base, args.command_line or command_line()))
    for law in region.laws:
        s = region.law_summary(law)
        kt = "n/a" if s["max_gain_period"] is None else f"{s['max_gain_period']:.3g}"
        print(f"region {base.name} on {region.backend}, {law.label}: {s['failing_in_box']} of "
              f"{s['points_in_box']} points fail in |x_i| <= {BOX:g} ({s['diverged']} diverged, "
              f"{s['lemma2']} Lemma 2 violated of {s['points']}); max K T {kt}")
    print(f"  wrote {args.out / 'region.csv'}, {args.out / 'region.json'} and {args.out / 'region.png'} "
          f"({region.wall_time_s:.1f} s)")
    return report_law_failures([p.law_failure for p in region.points if p.law_failure]) or EXIT_OK
