"""``qcontrol sweep``: validate every variant, run them (batched), write the table, the record and
the figure; Ctrl-C keeps the finished rows.

Exit status: 0 when every run finished (diverged runs are results, in the table, not failures); 1
when a worker process was killed from outside (one line says so); 2 for bad input (every variant is
validated before anything runs, and the output folder is made only when the results are written: bad
input creates nothing); 130 when interrupted (the finished rows are written).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..errors import QcontrolInputError, Terminated
from ..outputs import (
    check_output_dir,
    check_output_file,
    partial_path,
    prepare_output_dir,
    staged,
    write_json,
    write_text,
)
from ..progress import ProgressLine
from ..provenance import command_line
from ..scenario import Scenario, load_scenario
from ..scenario.resolve import scenario_provenance
from ..sweep.grid import check_size, grid_points, parse_grid
from ..sweep.runs import SweepInterrupted, planned, sweep_summaries
from ..sweep.table import csv_text, metric_columns, sweep_record, sweep_rows
from .arguments import EXIT_OK, add_parallel_options, add_scenario_options, backend_names, options_named
from .printing import law_failed

OUTPUTS = ("sweep.csv", "sweep.json", "sweep.png")


def add_sweep_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``qcontrol sweep`` (its handler is :func:`cmd_sweep`)."""
    p = subparsers.add_parser(
        "sweep",
        help="run a grid of scenario variants (batched) and tabulate them",
        description="Run the product of --grid values (times --random-initial initial states) as "
        "batched closed loops and write DIR/sweep.csv (one row per run), DIR/sweep.json (what was swept, "
        "with provenance) and DIR/sweep.png (a line per metric for one key, heatmaps for two, small "
        "multiples for more). Diverged runs are rows with diverged=True. With no --grid, --random-initial N "
        "runs N initial states of the scenario (one of them is needed). Ctrl-C writes the finished rows to "
        "DIR/sweep.partial.csv and sweep.partial.json, leaving a complete sweep's files as they were. "
        "Exit status: 0 ok, 1 a worker process was killed from outside, 2 bad input, "
        "3 an output could not be written, 130 interrupted, 143 terminated.",
    )
    add_scenario_options(p, timing=False, scenario_help="scenario file (TOML) or a shipped scenario's name",
                         set_help="a fixed override for every run, e.g. simulation.duration=2.0",
                         unset_help="remove a key of the scenario file for every run, e.g. --unset "
                         "reference.amplitude (repeatable; applied before --set and --grid)")
    p.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a scenario key and its values, e.g. controller.kappa_margin=0.1,0.5,1.1 "
                   "(repeatable: the product of all grids is run); values are split at the commas "
                   "outside brackets and quotes: plant.x0=[0.1,0.2],[0.3,0.4] or "
                   "plant.psi='\"min(x1, x2)\"','\"x1\"'")
    p.add_argument("--random-initial", type=int, default=0, metavar="N",
                   help="N random initial states x0 ~ U[-1, 1]^n per grid point (at most 1000000 runs "
                   "in all)")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="seed of --random-initial, 0 to 2**63 - 1 (default 0)")
    p.add_argument("--backend", metavar=backend_names(),
                   help="plant backend (default: the scenario's; --backend ode runs batched and is faster)")
    add_parallel_options(p)
    p.add_argument("--out", type=Path, default=Path("sweep"), metavar="DIR",
                   help="output folder (default: ./sweep)")
    p.set_defaults(command_line=None)  # the command line's main() names the command it runs


def _checked_request(args: argparse.Namespace) -> tuple[list[tuple[str, list[str]]], Scenario]:
    """The sweep's grid and base scenario, once the options and the output folder are checked."""
    if args.workers < 1:
        raise QcontrolInputError(f"--workers {args.workers}: must be >= 1; e.g. --workers 2")
    grid = parse_grid(args.grid)
    check_size(grid, args.random_initial, args.seed)
    check_output_dir(args.out)
    for name in OUTPUTS:
        check_output_file(args.out / name, "--out", fix="remove it or choose another --out folder")
    base = load_scenario(args.scenario, args.overrides, args.unset)
    if args.random_initial and any(k == "plant.x0" for k, _ in grid):
        raise QcontrolInputError("--random-initial and --grid plant.x0=...: give one of them")
    return grid, base


def cmd_sweep(args: argparse.Namespace) -> int:
    """Every variant is loaded (so checked) before the output folder is made."""
    grid, base = _checked_request(args)
    backend = args.backend or base.simulation.backend
    points = grid_points(grid, args.random_initial, args.seed, order=base.order)
    keys = list(points[0]) if points else []
    sets = [list(args.overrides) + [f"{k}={v}" for k, v in p.items()] for p in points]
    with options_named({f"{k}={v}": f"--grid {k}={v}" for k, values in grid for v in values}):
        chunks, variants = planned(base.source, sets, backend, args.unset)
    if backend != "ode" and not args.quiet:
        print(f"sweep on {backend}: one process per chunk of runs; --backend ode steps the runs together "
              "as arrays and is much faster")
    started = time.perf_counter()
    try:
        summaries = sweep_summaries(base.source, sets, backend, args.workers, args.scheduler,
                                    ProgressLine("sweep", not args.quiet, "runs"), chunks,
                                    args.unset, variants)
        interrupted: KeyboardInterrupt | None = None
    except SweepInterrupted as stop:
        summaries, interrupted = stop.summaries, Terminated() if stop.terminated else KeyboardInterrupt()
    out = prepare_output_dir(args.out)  # only now: bad input and failures before here create nothing
    settings = {"scenario": base.name, "backend": backend, "fixed_overrides": list(args.overrides),
                "unset": list(args.unset),
                "random_initial": args.random_initial, "seed": args.seed}
    rows = sweep_rows(points, summaries)
    finished = [s for s in summaries if s is not None]
    metrics = metric_columns(finished)
    # the three files are one result: written together; an interrupted sweep's under the partial
    # names (sweep.partial.csv, ...), never over a complete sweep's
    named = (out / name for name in OUTPUTS)
    csv_path, json_path, png_path = (partial_path(p) if interrupted is not None else p for p in named)
    provenance = scenario_provenance(base, args.command_line or command_line())
    record = sweep_record(rows, len(points), grid, settings, time.perf_counter() - started,
                          provenance) | {"csv": csv_path.name}
    with staged():
        write_text(csv_path, csv_text(rows, keys, metrics))
        write_json(json_path, record)
        if rows:
            from ..plots.sweeps import fig_sweep  # matplotlib: imported only when a figure is drawn

            fig_sweep(rows, [k for k, _ in grid], [m for m in metrics if m.startswith("error_rate_")],
                      png_path, f"{base.name}: {len(rows)} runs on {backend}")
    worst = record["lemma2_max_ratio"]
    print(f"sweep {base.name} on {backend}: {len(rows)} of {len(points)} runs in "
          f"{record['wall_time_s']:.2f} s; {record['diverged']} diverged; "
          f"max Lemma 2 ratio {float('nan') if worst is None else worst:.6f}")
    if interrupted is not None:
        print(f"  interrupted: wrote the {len(rows)} finished runs to {csv_path} and {json_path.name} "
              f"({out / OUTPUTS[0]} and the others are unchanged)")
        raise interrupted
    print(f"  wrote {csv_path}, {json_path} and {png_path}")
    return law_failed(finished) or EXIT_OK
