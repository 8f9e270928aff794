"""Parameter sweeps: many variants of one scenario, batched, on local workers or a Dask cluster.

    qcontrol sweep SCENARIO --grid key=v1,v2,... [--grid ...] [--random-initial N --seed S]
                   [--backend ode|mujoco] [--workers N] [--scheduler ADDRESS] [--out DIR]

How runs are grouped. Variants that share :func:`qcontrol.assembly.batch_structure` (plant
expressions, controller kind, gains c, delta, r, reference, dt, duration, ...) differ only in
numbers the law and the backend take per copy (for the proposed law ``kappa``/``kappa_margin``,
``gamma``, ``sigma``, ``r_scale``; ``x0``; on the ODE ``theta``). Such variants are stepped
together as one batch in one :func:`qcontrol.engine.simulate` call (``record="metrics"``).
Anything else (e.g. a grid over ``controller.c``) splits the runs into groups, each its own batch.

Determinism. Groups are cut into chunks of at most ``CHUNK`` runs in input order, whatever the
executor; a chunk is one batch. So the in-process path, local worker processes and a Dask cluster
run the very same batches and give identical numbers (only ``wall_time_s`` differs).

MuJoCo. Chunks run as :class:`qcontrol.plants.mujoco.plant.MujocoPlant` batches (one ``MjData`` per
copy, the unmodelled term in the passive callback exactly as in a single run), spread over worker
processes. ``mujoco.batch`` threads are not used: they refuse Python physics callbacks, and
holding the term in ``qfrc_applied`` over a step would cost accuracy (see the bench report).

Exit status of ``qcontrol sweep``: 0 when every run finished (diverged runs are results, reported
in the table, not failures); 2 for bad input (every variant is validated before anything runs, and
the output folder is made only when the results are written: bad input creates nothing).
"""

from __future__ import annotations

import argparse
import csv
import io
import itertools
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from .assembly import batch_structure, run_variants
from .controller import lemma2_L
from .errors import QcontrolInputError
from .metrics import TABLE1_OMEGAS, omega_key, summary
from .outputs import atomic_path, check_output_dir, prepare_output_dir, write_text
from .plants import BACKENDS
from .progress import ProgressLine
from .scenario import Scenario, load_scenario

CHUNK = 250  # runs per batch: fixed, so every executor runs the same batches
DASK_CONNECT_TIMEOUT = 10.0  # seconds to reach a --scheduler
Progress = Callable[[int, int], None]  # (runs done, runs in total)
CSV_METRICS = [f"error_rate_{omega_key(w)}" for w in TABLE1_OMEGAS] + [
    "max_abs_z1_last_half", "max_abs_u", "diverged", "lemma2_max_ratio",
]


# --------------------------------------------------------------------------------------------
# grouping and batched runs


def run_batch(scs: Sequence[Scenario], backend: str) -> list[dict]:
    """Run variants that share their batch structure as one batch; one summary dict per variant."""
    started = time.perf_counter()
    runs = run_variants(scs, backend, record="metrics")
    share = (time.perf_counter() - started) / len(scs)
    out = []
    for s, run in zip(scs, runs, strict=True):
        run.wall_time_s = share  # the batch's time, per run
        result = summary(run, s.name, backend)
        result["L"] = lemma2_L(s.controller.c, s.controller.delta)
        out.append(result)
    return out


def _run_chunk(scenario_path: str, override_sets: list[list[str]], backend: str,
               unset: Sequence[str] = ()) -> list[dict]:
    """Worker entry point (picklable arguments only): load the variants and run them as a batch."""
    return run_batch([load_scenario(scenario_path, o, unset) for o in override_sets], backend)


def plan(scenario_path: str | Path, override_sets: Sequence[Sequence[str]], backend: str,
         unset: Sequence[str] = ()) -> list[list[int]]:
    """Load (and so validate) every variant; return chunks of indices, each one batch."""
    groups: dict[tuple, list[int]] = {}
    for i, overrides in enumerate(override_sets):
        sc = load_scenario(scenario_path, list(overrides), unset)
        BACKENDS[backend].require(sc.backends.get(backend), sc.source)
        groups.setdefault(batch_structure(sc, backend), []).append(i)
    return [ids[k : k + CHUNK] for ids in groups.values() for k in range(0, len(ids), CHUNK)]


def sweep_summaries(
    scenario_path: str | Path,
    override_sets: list[list[str]],
    backend: str = "ode",
    workers: int = 1,
    scheduler: str | None = None,
    progress: Progress | None = None,
    unset: Sequence[str] = (),
) -> list[dict]:
    """One :func:`qcontrol.metrics.summary` dict (plus ``L``) per override set, in input order.

    Variants are batched (see the module docstring); ``workers > 1`` spreads the batches over
    local processes, ``scheduler`` (a Dask ``distributed`` address) over a cluster. Every
    executor runs the same batches, so the numbers are identical; ``wall_time_s`` is the batch's
    wall time divided by its size. Bad input raises :class:`QcontrolInputError` before any run.
    ``unset`` keys are removed from the file of every variant before its overrides.
    """
    if backend not in BACKENDS:
        raise QcontrolInputError(f"--backend {backend!r}: use one of {', '.join(BACKENDS)}")
    if workers < 1:
        raise QcontrolInputError(f"--workers {workers}: must be >= 1")
    path = str(scenario_path)
    sets = [list(o) for o in override_sets]
    unset = list(unset)
    chunks = plan(path, sets, backend, unset)
    results: list[dict | None] = [None] * len(sets)
    done = 0

    def store(ids: list[int], summaries: list[dict]) -> None:
        nonlocal done
        for i, s in zip(ids, summaries, strict=True):
            results[i] = s
        done += len(ids)
        if progress is not None:
            progress(done, len(sets))

    tasks = [(path, [sets[i] for i in ids], backend, unset) for ids in chunks]
    if scheduler is not None:
        for ids, summaries in zip(chunks, _on_dask(scheduler, tasks), strict=True):
            store(ids, summaries)
    elif workers > 1 and len(chunks) > 1:
        with ProcessPoolExecutor(max_workers=min(workers, len(chunks))) as pool:
            futures = [pool.submit(_run_chunk, *task) for task in tasks]
            for ids, future in zip(chunks, futures, strict=True):
                store(ids, future.result())
    else:
        for ids, task in zip(chunks, tasks, strict=True):
            store(ids, _run_chunk(*task))
    return results  # type: ignore[return-value]


def _on_dask(address: str, tasks: list[tuple]) -> list[list[dict]]:
    """Run the chunks on an existing Dask cluster (optional extra ``cluster``)."""
    try:
        from distributed import Client
    except ImportError:
        raise QcontrolInputError(
            "--scheduler needs Dask distributed: pip install 'qcontrol[cluster]'"
        ) from None
    try:
        client = Client(address, timeout=DASK_CONNECT_TIMEOUT)
    except (OSError, TimeoutError, ValueError) as exc:
        raise QcontrolInputError(
            f"--scheduler {address}: cannot connect ({exc}); "
            "give the address of a running Dask scheduler, e.g. tcp://host:8786"
        ) from None
    with client:
        futures = [client.submit(_run_chunk, *task, pure=False) for task in tasks]
        return client.gather(futures)


# --------------------------------------------------------------------------------------------
# grids


def parse_grid(items: Sequence[str]) -> list[tuple[str, list[str]]]:
    """``["key=v1,v2", ...]`` -> ``[(key, [v1, v2]), ...]`` (values kept as text, read as TOML
    by the scenario loader). A value that is a list (``plant.x0=[0.1,0.2],[0.3,0.4]``) is split
    at the top level only."""
    grid = []
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise QcontrolInputError(f"--grid {item!r}: expected KEY=V1,V2,... such as "
                                     "controller.kappa_margin=0.1,0.5,1.1")
        values, depth, start = [], 0, 0
        for i, ch in enumerate(raw + ","):
            depth += ch in "[{" and 1 or (-1 if ch in "]}" else 0)
            if ch == "," and depth == 0:
                value = raw[start:i].strip()
                if not value:
                    raise QcontrolInputError(f"--grid {item!r}: empty value; list values as v1,v2,...")
                values.append(value)
                start = i + 1
        if any(k == key for k, _ in grid):
            raise QcontrolInputError(f"--grid {key}: given twice; list all its values in one --grid")
        grid.append((key, values))
    return grid


def grid_points(grid: Sequence[tuple[str, list[str]]], random_initial: int = 0, seed: int | None = None,
                x0_scale: float = 1.0, order: int = 2) -> list[dict[str, str]]:
    """The product of the grids, times ``random_initial`` initial states per point (uniform in
    ``[-x0_scale, x0_scale]^n`` from ``seed``); each point maps key -> value text."""
    keys = [k for k, _ in grid]
    points = [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*(v for _, v in grid))]
    if random_initial <= 0:
        return points
    rng = np.random.default_rng(seed)
    starts = rng.uniform(-x0_scale, x0_scale, size=(random_initial, order))
    texts = ["[" + ", ".join(repr(float(v)) for v in x) + "]" for x in starts]
    return [p | {"plant.x0": text} for p in points for text in texts]


# --------------------------------------------------------------------------------------------
# outputs


def sweep_rows(points: Sequence[dict[str, str]], summaries: Sequence[dict]) -> list[dict]:
    """One CSV row per run: the varied keys, the error rates, and the run's checks."""
    rows = []
    for point, s in zip(points, summaries, strict=True):
        row: dict = dict(point)
        for w in TABLE1_OMEGAS:
            row[f"error_rate_{omega_key(w)}"] = s["error_rate"][omega_key(w)]
        for key in ("max_abs_z1_last_half", "max_abs_u", "diverged", "lemma2_max_ratio"):
            row[key] = s[key]
        rows.append(row)
    return rows


def csv_text(rows: Sequence[dict], keys: Sequence[str]) -> str:
    """The table as CSV: varied keys, then :data:`CSV_METRICS`; floats with repr precision."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(keys) + CSV_METRICS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
    return buffer.getvalue()


def sweep_figure(rows: Sequence[dict], keys: Sequence[str], path: Path, title: str) -> Path:
    """Error rate E(omega) per run (sorted by the first varied key), diverged runs marked."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    index = np.arange(len(rows))
    for w in TABLE1_OMEGAS:
        ax.plot(index, [r[f"error_rate_{omega_key(w)}"] for r in rows], marker=".", lw=0.8,
                label=rf"$E(\omega={w:g})$")
    bad = [i for i, r in enumerate(rows) if r["diverged"]]
    if bad:
        ax.scatter(bad, [1.0] * len(bad), marker="x", color="red", zorder=5, label="diverged")
    if len(rows) <= 30 and keys:
        ax.set_xticks(index, [", ".join(str(r[k]) for k in keys) for r in rows], rotation=60, ha="right",
                      fontsize=7)
        ax.set_xlabel(", ".join(keys))
    else:
        ax.set_xlabel(f"run (grid order over {', '.join(keys) or 'runs'})")
    ax.set_ylabel("error rate E(omega)")
    ax.set_ylim(-0.02, 1.05)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncols=3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    return path


# --------------------------------------------------------------------------------------------
# command line


def add_sweep_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``qcontrol sweep`` (its handler is :func:`cmd_sweep`)."""
    p = subparsers.add_parser(
        "sweep",
        help="run a grid of scenario variants (batched) and tabulate them",
        description="Run the product of --grid values (times --random-initial initial states) as "
        "batched closed loops and write DIR/sweep.csv (one row per run) and DIR/sweep.png. "
        "Diverged runs are rows with diverged=True. Exit status: 0 ok, 2 bad input.",
    )
    p.add_argument("scenario", type=Path, help="scenario file (TOML), e.g. scenarios/example2.toml")
    p.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a scenario key and its values, e.g. controller.kappa_margin=0.1,0.5,1.1 "
                   "(repeatable: the product of all grids is run)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="a fixed override for every run, e.g. simulation.duration=2.0")
    p.add_argument("--unset", dest="unset", action="append", default=[], metavar="KEY",
                   help="remove a key of the scenario file for every run, e.g. --unset reference.amplitude "
                   "(repeatable; applied before --set and --grid)")
    p.add_argument("--random-initial", type=int, default=0, metavar="N",
                   help="N random initial states x0 ~ U[-1, 1]^n per grid point")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of --random-initial (default 0)")
    p.add_argument("--backend", choices=BACKENDS, default="ode", help="plant backend (default: ode)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="send the runs to a running Dask scheduler (needs qcontrol[cluster])")
    p.add_argument("--out", type=Path, default=Path("sweep"), metavar="DIR",
                   help="output folder (default: ./sweep)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")


def cmd_sweep(args: argparse.Namespace) -> int:
    """``qcontrol sweep``: returns 0 when the sweep ran (diverged runs included), 2 is raised as
    :class:`QcontrolInputError` by the callers' handler."""
    if args.random_initial < 0:
        raise QcontrolInputError(f"--random-initial {args.random_initial}: must be >= 0")
    grid = parse_grid(args.grid)
    check_output_dir(args.out)
    base = load_scenario(args.scenario, args.overrides, args.unset)
    if args.random_initial and any(k == "plant.x0" for k, _ in grid):
        raise QcontrolInputError("--random-initial and --grid plant.x0=...: give one of them")
    points = grid_points(grid, args.random_initial, args.seed, order=base.order)
    keys = list(points[0]) if points else []
    sets = [list(args.overrides) + [f"{k}={v}" for k, v in p.items()] for p in points]
    started = time.perf_counter()
    summaries = sweep_summaries(args.scenario, sets, args.backend, args.workers, args.scheduler,
                                ProgressLine("sweep", not args.quiet, "runs", piped_every=10), args.unset)
    wall = time.perf_counter() - started
    out = prepare_output_dir(args.out)
    rows = sweep_rows(points, summaries)
    write_text(out / "sweep.csv", csv_text(rows, keys))
    sweep_figure(rows, keys, out / "sweep.png", f"{base.name}: {len(rows)} runs on {args.backend}")
    diverged = sum(bool(r["diverged"]) for r in rows)
    ratios = [r["lemma2_max_ratio"] for r in rows if math.isfinite(r["lemma2_max_ratio"])]
    worst = max(ratios, default=math.nan)
    print(f"sweep {base.name} on {args.backend}: {len(rows)} runs in {wall:.2f} s, {diverged} diverged, "
          f"max Lemma 2 ratio {worst:.6f}")
    print(f"  wrote {out / 'sweep.csv'} and {out / 'sweep.png'}")
    return 0
