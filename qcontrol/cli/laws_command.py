"""``qcontrol laws``: several control laws on the same scenario and backend, side by side (a table,
DIR/laws.json with every law's summary, DIR/laws.png overlaying y, z1 and u, and a recording
with every law)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import QcontrolInputError
from ..law_comparison import compare_laws
from ..outputs import check_output_dir, check_output_file, prepare_output_dir, write_json
from ..region import parse_law
from .arguments import EXIT_FAILED, EXIT_OK, add_scenario_options, backend_names, scenario_from_args
from .printing import law_failed


def add_laws_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol laws`` (its handler is :func:`cmd_laws`)."""
    p = sub.add_parser(
        "laws", help="run several control laws on the same scenario and compare them",
        description="Run the scenario once per --law (controller kinds: built in, from --law-module or "
        "an installed plugin) on one backend and print a row per law. With --out writes DIR/laws.json "
        "and DIR/laws.png (y, z1 and u of every law); --rrd records every law (the first as the main run).",
    )
    add_scenario_options(p)
    p.add_argument("--law", dest="laws", action="append", default=[], metavar="KIND[:KEY=VALUE,...]",
                   required=True, help="a law to compare: a controller kind with optional settings of its "
                   "[controller] table (give two or more, e.g. --law proposed --law proposed:hold=exact "
                   "--law comparison)")
    p.add_argument("--backend", metavar=backend_names(), help="default: the scenario's simulation.backend")
    p.add_argument("--out", type=Path, metavar="DIR", help="write DIR/laws.json and DIR/laws.png")
    p.add_argument("--rrd", type=Path, metavar="FILE", help="write a rerun recording with every law")


def cmd_laws(args: argparse.Namespace) -> int:
    """Every --law is checked (as ``qcontrol region --law`` checks it) before any run."""
    sc = scenario_from_args(args)
    labels = [parse_law(text).label for text in args.laws]
    if len(labels) < 2 or len(set(labels)) != len(labels):
        raise QcontrolInputError(f"--law: give two or more different laws, e.g. --law proposed --law "
                                 f"comparison (given: {', '.join(labels)})")
    if args.out is not None:
        check_output_dir(args.out)
    if args.rrd is not None:
        check_output_file(args.rrd, "--rrd")
    cmp = compare_laws(sc, args.laws, backend=args.backend, rrd=args.rrd, command=args.command_line)
    rates = [k for k in cmp.table[0] if k.startswith("error_rate_")]
    print(f"{sc.name} on {next(iter(cmp.runs.values())).backend}: {len(cmp.runs)} laws")
    header = "".join(f"E({k[11:]})  " for k in rates) + "max|z1|,2nd half  max|u|    Lemma 2"
    width = max(16, *(len(row["kind"]) + 2 for row in cmp.table))
    print(f"  {'law':<{width}}{header}")
    for row in cmp.table:
        shown = "DIVERGED" if row["diverged"] else f"{row['lemma2_max_ratio']:.6f}"
        print(f"  {row['kind']:<{width}}" + "".join(f"{row[k]:.4f}    " for k in rates)
              + f"{row['max_abs_z1_last_half']:<17.4g} {row['max_abs_u']:<9.4g} {shown}")
    if args.out is not None:
        out = prepare_output_dir(args.out)
        runs = {k: r.summary for k, r in cmp.runs.items()}
        write_json(out / "laws.json", {"table": cmp.table, "runs": runs, "provenance": cmp.provenance})
        print(f"  wrote {out / 'laws.json'} and {cmp.plot(out / 'laws.png')}")
    if args.rrd is not None:
        print(f"  wrote {args.rrd} (open it with: rerun {args.rrd})")
    failed = law_failed(r.summary for r in cmp.runs.values())
    return failed or (EXIT_FAILED if any(row["diverged"] for row in cmp.table) else EXIT_OK)
