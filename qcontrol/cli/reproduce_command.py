"""``qcontrol reproduce``: the paper's figures and Table 1, the studies and REPORT.md
(:mod:`qcontrol.reproduce`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..commands import MAX_DURATION
from ..errors import QcontrolInputError, shown
from ..outputs import check_output_dir, path_kind
from .arguments import EXIT_OK, backend_names

SCENARIO_FILES = ("example1.toml", "example2.toml", "example2-rigid.toml", "example2-arm.toml",
                  "example1-cart.toml")


def add_reproduce_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol reproduce`` (its handler is :func:`cmd_reproduce`)."""
    rep = sub.add_parser(
        "reproduce",
        help="reproduce the paper's Figures 1-8 and Table 1 with an honest report",
        description="Write the paper's Figures 1-8, Table 1 (table1.md/.json/.png), REPORT.md, the "
        "studies' figures and recordings. It runs, in order (times on an idle 2-core VM): (1) Example 1 "
        "and Example 2 with the proposed law and the comparison law of [20], each on MuJoCo with its ODE "
        "twin (about 5 s with the figures and recordings); (2) the sensitivity studies on the ODE: "
        "kappa - L, the scale of r, the plant variants (21 runs, batched: about 3 s); (2b) the sampled "
        "loop's region of attraction: both examples at 1 and 2 kHz, the paper's law, its exact hold and "
        "the comparison law on a 9 x 9 grid of initial states (compiled ODE batches: about 2 s of CPU with "
        "its figure); (2c) the trade-off: "
        "the tuning-function law and the linear law (paper's gains; kp 400, kd 40) mapped beside them at "
        "1 kHz, every law with Table 1's rates (about 2.5 s of CPU with its figure); (3) the robustness "
        "study: 248 MuJoCo runs of the realistic arm and cart (each imperfection alone, 20 noise seeds, "
        "margins beyond the hardware, disturbances; with (2b) and (2c) on the same two worker processes: "
        "about 24 s of CPU; the whole command took 13.0-13.3 s on 2 idle cores (17 s and 32 s of CPU "
        "before the region maps, the linear law and per-channel sensors were compiled); with an empty "
        "compile cache 17 s, and about 24 s for the later run that compiles what the first ran in "
        "Python; longer on a shared machine). --quick skips (2b), "
        "(2c) and (3) and runs 1 s horizons: about 12 s "
        "on a shared 2-core VM, most of it writing the figures.",
    )
    rep.add_argument("--out", type=Path, default=Path("results"), metavar="DIR",
                     help="output folder (default: results)")
    rep.add_argument("--backend", metavar=backend_names(), default="mujoco",
                     help="plant for the examples (default: mujoco, with the ODE twin beside it)")
    rep.add_argument("--duration", type=float, metavar="S",
                     help="horizon of every run (default: the paper's 10 s); the robustness study keeps its "
                     "248 runs: for a quick look use --quick")
    rep.add_argument("--quick", action="store_true",
                     help="a first look in about 12 s: 1 s horizons (or --duration), no region "
                     "study, trade-off study or robustness study (no region.json, study_region.png, "
                     "tradeoff.json, study_tradeoff.png, robustness.json, study_robustness.png, "
                     "study_margins.png)")
    rep.add_argument("--scenarios", type=Path, default=None, metavar="DIR",
                     help=f"folder holding {', '.join(SCENARIO_FILES)} (default: the shipped ones)")
    rep.add_argument("--workers", type=int, default=None, metavar="N",
                     help="worker processes for the robustness study (default: the cores, at most 4)")
    rep.add_argument("--law-module", dest="law_modules", action="append", default=[], type=Path,
                     metavar="FILE", help="a Python file that registers control laws with "
                     "qcontrol.register_law, run first, e.g. --law-module mylaws.py --law mine (repeatable)")
    rep.add_argument("--law", dest="laws", action="append", default=[], metavar="KIND",
                     help="a controller kind (built in, from --law-module or an installed plugin) studied "
                     "beside the paper's law and the comparison law: its Example 2 runs in table1.json "
                     "(marked as not from the paper), its runs of both examples in the region and "
                     "robustness studies (repeatable; each adds about half of those studies' time)")
    rep.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def cmd_reproduce(args: argparse.Namespace) -> int:
    """The command-line options are checked before the reproduction (and matplotlib) is imported."""
    if args.duration is not None and not (0 < args.duration <= MAX_DURATION):
        raise QcontrolInputError(f"--duration {args.duration!r}: must be a number of seconds > 0 and at most "
                                 f"{MAX_DURATION:g}; e.g. --duration 2 for a quick look")
    if args.workers is not None and args.workers < 1:
        raise QcontrolInputError(f"--workers {args.workers}: must be >= 1; e.g. --workers 2 (more than the "
                                 "cores are capped at the cores)")
    if args.scenarios is not None and path_kind(args.scenarios) != "a folder":
        kind = path_kind(args.scenarios) or "a file"
        what = "does not exist" if not args.scenarios.exists() else f"is {kind}"
        raise QcontrolInputError(f"--scenarios {shown(args.scenarios)}: {what}; give the folder holding "
                                 f"{', '.join(SCENARIO_FILES)}")
    check_output_dir(args.out)
    from ..reproduce import SCENARIO_DIR, reproduce  # matplotlib and the studies: only for this command

    scenarios = args.scenarios or SCENARIO_DIR
    log = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    reproduce(args.out, args.backend, args.duration, scenarios, log, command=args.command_line,
              workers=args.workers, quick=args.quick, laws=args.laws)
    return EXIT_OK
