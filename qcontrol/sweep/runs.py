"""Many variants of one scenario, batched, in this process, on local workers or on a Dask cluster.

How runs are grouped. Variants that share :func:`qcontrol.assembly.batch_structure` (plant
expressions, controller kind, gains c, delta, r, reference, dt, duration, ...) differ only in
numbers the law and the backend take per copy (for the proposed law ``kappa``/``kappa_margin``,
``gamma``, ``sigma``, ``r_scale``; ``x0``; on the ODE ``theta``; on MuJoCo the theta of the
terms the passive callback adds and the sensor noise's seed). Such variants are stepped
together as one batch in one :func:`qcontrol.engine.simulate` call (``record="metrics"``).
Anything else (e.g. a grid over ``controller.c``) splits the runs into groups, each its own batch.

Chunks. Groups are cut into chunks of at most ``CHUNK`` runs in input order, of even sizes; a chunk
is one batch. With several workers (local processes, or a Dask cluster's threads) the chunks are
cut smaller, down to ``MIN_BATCH``, so that each worker gets as many runs: a 200-run sweep on 2
workers runs as two batches of 100, one per worker, a 600-run one as six of 100 (not three of
200); groups of different sizes are cut until no worker would run :data:`BALANCE` times an even
share, and the chunks go out largest first. A group of fewer than ``MIN_BATCH`` runs goes run by
run instead:
a batch's array form costs a fixed amount per step, which a single run (the engine's fast path)
does not pay, so small batches are slower than their runs alone (measured on Example 2, 10 s, both
backends: a batch of 2 costs 2.3-2.8x its two runs, 4 about 1.2x, 8 about 0.6-0.8x).

Determinism. A copy's numbers do not depend on the batch it is stepped in (its size or its
neighbours), so the in-process path, local worker processes and a Dask cluster give identical
numbers however they chunk (only ``wall_time_s`` differs), and a copy's summary is its run
alone's, key for key (the separation (37)-(43) is checked along every copy).

MuJoCo. Chunks run as MuJoCo plant batches, spread over worker processes: on the compiled batch
(each copy's ``MjData`` stepped from compiled code, a thousand rows of one copy at a time:
:mod:`qcontrol.engine.compiled_batch`) where the law and the plant allow it, else on
``mujoco.batch`` (the copies stepped in C, the unmodelled term in the native passive callback),
else one ``MjData`` per copy; the numbers are the same either way
(:mod:`qcontrol.plants.mujoco.threaded`). One batch runs on one thread: the workers are the
parallelism.

The runs take place inside :func:`qcontrol.sharing.sharing`, as the variants' loading does (the
workers are forked inside it): a plant checks its model against eq. (1) once per process, not
once per batch (about 8 ms of each MuJoCo batch of Example 2).

Local workers. With W workers this process is one of them: it forks W - 1 copies of itself, and
each of the W takes the next chunk (largest first) when it is free
(:func:`qcontrol.workers.share`), rather than this process waiting on a pool of W: one process
fewer to start, feed and stop, and no pool (a fork finds its chunks in its memory; only the
summaries come back pickled), for the same chunks.

Small sweeps stay in this process. Workers are forked only when the work is worth it: at least
:data:`SPREAD_MIN_WORK` copy-steps (runs x rows) on the backend (about 0.1 s of work on one core).
Below that, starting the processes costs more than the half of the work they take (and a batch in
the array form, short runs, costs about as much halved as whole: a fixed amount per step).
Before forking, this process starts numba's compiler once (when the batches will run compiled
code), so that the workers inherit it instead of each starting it again (about 0.35 s of CPU
each, 0.6 s under load), and it freezes its objects for the workers' garbage collector
(:mod:`qcontrol.workers`).

Laws registered from Python (:func:`qcontrol.register_law`) run in this process and on local
workers (which start as copies of this process); a Dask cluster's workers do not know them.

Loading. :func:`planned` loads (and so checks) every variant once, before any run. In this process
and on local workers those very scenarios run: a local worker is a fork of this process made
after they were loaded, so it finds them in its memory (:data:`_LOADED`) and receives only its
chunk's indices; nothing is loaded again or pickled. A Dask cluster's workers load their chunk's
variants from the file and the override sets.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from itertools import count, pairwise
from pathlib import Path
from typing import Any

from .. import compiled as compiled_paths
from ..assembly import batch_structure, run_variants
from ..errors import QcontrolInputError, Terminated, shown
from ..metrics import run_summary
from ..plants import BACKENDS
from ..scenario import Scenario
from ..scenario.load import load_variants
from ..sharing import sharing
from ..summary import Summary
from ..timegrid import TimeGrid
from ..workers import share, worker_count

CHUNK = 250  # runs per batch at most (fewer when there are more workers than chunks)
# copy-steps (runs x rows) below which a sweep stays in this process whatever --workers says: about
# 0.1 s of work on one core (a forked worker costs some 30-50 ms to start, feed and stop; measured
# on Example 2, 10 s runs: 5-40 runs were 1.6-2.5x slower on 2 workers than in this process)
SPREAD_MIN_WORK = {"ode": 500_000, "mujoco": 20_000}
MIN_BATCH = 5  # smaller groups run run by run; chunks cut for workers stay at least this long
BALANCE = 1.1  # the busiest worker's runs at most this times an even share, where chunks allow
DASK_CONNECT_TIMEOUT = 10.0  # seconds to reach a --scheduler and complete Dask's handshake
RunsDone = Callable[[int, int], None]  # (runs done, runs in total)
# (path, override sets of a chunk, backend, unset, and where this process or a fork of it holds
# the loaded variants: their key in _LOADED and the chunk's indices; None, None on a cluster)
ChunkJob = tuple[str, list[list[str]], str, list[str], int | None, list[int] | None]
_LOADED: dict[int, Sequence[Scenario]] = {}  # a sweep's loaded variants, by key, while it runs
_KEYS = count()


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C during a sweep: ``summaries`` holds the finished runs' summaries (None elsewhere)."""

    def __init__(self, summaries: list[Summary | None], terminated: bool = False) -> None:
        super().__init__()
        self.summaries = summaries
        self.terminated = terminated  # SIGTERM rather than Ctrl-C


def run_batch(scs: Sequence[Scenario], backend: str) -> list[Summary]:
    """Run variants that share their batch structure as one batch; one :class:`Summary` per variant."""
    started = time.perf_counter()
    runs = run_variants(scs, backend, record="metrics")
    share = (time.perf_counter() - started) / len(scs)
    out = []
    for s, run in zip(scs, runs, strict=True):
        run.wall_time_s = share  # the batch's time, per run
        out.append(run_summary(run, s.name, backend))
    return out


def _even(ids: list[int], size: int) -> list[list[int]]:
    """``ids`` cut in order into even chunks of at most ``size`` runs, as few as that allows, none
    cut below :data:`MIN_BATCH` runs for the workers' sake (never above :data:`CHUNK`)."""
    pieces = max(-(-len(ids) // CHUNK), min(-(-len(ids) // size), len(ids) // MIN_BATCH))
    bounds = [len(ids) * k // pieces for k in range(pieces + 1)]
    return [ids[a:b] for a, b in pairwise(bounds)]


def _chunk_size(runs: int, workers: int) -> int:
    """At most :data:`CHUNK` runs, fewer (down to :data:`MIN_BATCH`) so that ``runs`` make a
    multiple of ``workers`` chunks: each worker gets as many (1000 runs on 2 workers: 250; 600 on
    2: 150, not 200, whose three chunks would leave one worker idle for a third of the sweep)."""
    workers = max(1, workers)
    rounds = -(-runs // (workers * CHUNK))
    return min(CHUNK, max(MIN_BATCH, -(-runs // (workers * rounds))))


def chunks_of(groups: Iterable[list[int]], workers: int = 1) -> list[list[int]]:
    """Each group (indices of runs that share their batch structure, in input order) cut into even
    chunks of at most :data:`CHUNK`, smaller (down to :data:`MIN_BATCH`) where that gives each of
    ``workers`` a chunk; a group smaller than :data:`MIN_BATCH`, one chunk per run."""
    groups = [list(ids) for ids in groups]
    size = _chunk_size(sum(len(ids) for ids in groups), workers)
    return [piece for ids in groups
            for piece in (_even(ids, size) if len(ids) >= MIN_BATCH else [[i] for i in ids])]


def for_workers(chunks: list[list[int]], workers: int) -> list[list[int]]:
    """``chunks`` (a :func:`plan`) cut further, where they are long, to give each of ``workers`` as
    many runs; cut smaller (down to :data:`MIN_BATCH`) while the chunks, handed out largest first
    to whichever worker is free, would keep one worker busy :data:`BALANCE` times longer than an
    even share (groups of different sizes: three of 100 runs on 2 workers run as six of 50, not
    one worker's 200 against the other's 100). Largest first, so that the last are the shortest."""
    total = sum(len(ids) for ids in chunks)
    size = _chunk_size(total, workers)
    if workers <= 1:  # (in this process: the chunks in input order)
        return _cut(chunks, size)
    while True:
        cut = sorted(_cut(chunks, size), key=len, reverse=True)
        if size <= MIN_BATCH or _busiest(cut, workers) <= BALANCE * total / workers:
            return cut
        size = max(MIN_BATCH, size * 9 // 10)


def _cut(chunks: list[list[int]], size: int) -> list[list[int]]:
    """``chunks`` in order, each longer than ``size`` cut into even pieces of at most ``size``."""
    return [piece for ids in chunks for piece in (_even(ids, size) if len(ids) > size else [ids])]


def _busiest(chunks: list[list[int]], workers: int) -> int:
    """The runs of the busiest of ``workers`` when each free worker takes the next chunk."""
    loads = [0] * workers
    for ids in chunks:
        heapq.heapreplace(loads, loads[0] + len(ids))
    return max(loads)


def run_variants_batched(scs: Sequence[Scenario], backend: str) -> list[Summary]:
    """One summary per variant, in input order, in this process: the variants grouped and
    chunked exactly as :func:`plan` groups a sweep's (so the same batches and numbers)."""
    groups: dict[tuple, list[int]] = {}
    for i, sc in enumerate(scs):
        BACKENDS[backend].require(sc.backends.get(backend), sc.source)
        groups.setdefault(batch_structure(sc, backend), []).append(i)
    results: list[Summary] = [None] * len(scs)  # type: ignore[list-item]
    for chunk in chunks_of(groups.values()):
        for i, s in zip(chunk, run_batch([scs[i] for i in chunk], backend), strict=True):
            results[i] = s
    return results


def _run_chunk(scenario_path: str, override_sets: list[list[str]], backend: str,
               unset: Sequence[str] = (), key: int | None = None, ids: list[int] | None = None
               ) -> list[Summary]:
    """Worker entry point (picklable arguments only): the chunk's variants as this process (or
    the process it was forked from) loaded them (``key``, ``ids``), else loaded from the file,
    run as a batch."""
    loaded = _LOADED.get(key) if key is not None else None
    if loaded is not None and ids is not None:
        return run_batch([loaded[i] for i in ids], backend)
    return run_batch(load_variants(scenario_path, override_sets, unset), backend)


def planned(scenario_path: str | Path, override_sets: Sequence[Sequence[str]], backend: str,
            unset: Sequence[str] = ()) -> tuple[list[list[int]], list[Scenario]]:
    """Load (and so validate) every variant; the chunks of indices, each one batch (:func:`plan`),
    and the variants, which :func:`sweep_summaries` runs without loading them again. ``unset``
    keys are removed from the file of every variant before its overrides."""
    if backend not in BACKENDS:
        raise QcontrolInputError(f"--backend {backend!r}: use one of {', '.join(BACKENDS)}")
    groups: dict[tuple, list[int]] = {}
    index = count()

    def check(sc: Scenario) -> None:  # each variant as it loads: a bad one is refused before the next
        BACKENDS[backend].require(sc.backends.get(backend), sc.source)
        groups.setdefault(batch_structure(sc, backend), []).append(next(index))

    variants = load_variants(scenario_path, [list(overrides) for overrides in override_sets], unset, check)
    return chunks_of(groups.values()), variants


def plan(scenario_path: str | Path, override_sets: Sequence[Sequence[str]], backend: str,
         unset: Sequence[str] = ()) -> list[list[int]]:
    """Load (and so validate) every variant; return chunks of indices, each one batch. ``unset``
    keys are removed from the file of every variant before its overrides."""
    return planned(scenario_path, override_sets, backend, unset)[0]


def sweep_summaries(
    scenario_path: str | Path,
    override_sets: list[list[str]],
    backend: str = "ode",
    workers: int = 1,
    scheduler: str | None = None,
    progress: RunsDone | None = None,
    chunks: list[list[int]] | None = None,
    unset: Sequence[str] = (),
    variants: Sequence[Scenario] | None = None,
) -> list[Summary]:
    """One :class:`~qcontrol.summary.Summary` per override set, in input order.

    Variants are batched (see the module docstring); ``workers > 1`` spreads the batches over
    local processes, ``scheduler`` (a Dask ``distributed`` address) over a cluster, the chunks cut
    so that each worker gets one. The numbers are identical on every executor; ``wall_time_s`` is the batch's
    wall time divided by its size. Bad input raises :class:`QcontrolInputError` before any run
    (``chunks``, ``variants``: the :func:`planned` already made; the variants, one per override
    set, are run as they are in this process and on local workers). Ctrl-C raises
    :class:`SweepInterrupted` with the finished runs. ``unset`` keys are removed from the file of
    every variant before its overrides.
    """
    if workers < 1:
        raise QcontrolInputError(f"--workers {workers}: must be >= 1")
    path, sets, unset = str(scenario_path), [list(o) for o in override_sets], list(unset)
    if chunks is None:
        chunks, variants = planned(path, sets, backend, unset)
    key = None if variants is None else next(_KEYS)
    if key is not None:
        _LOADED[key] = variants
    try:
        with sharing():  # (a plant checks its model once per process: see the module docstring)
            return _summaries(path, sets, backend, unset, chunks, key, workers, scheduler, progress)
    finally:
        _LOADED.pop(key, None)


def _summaries(path: str, sets: list[list[str]], backend: str, unset: list[str], chunks: list[list[int]],
               key: int | None, workers: int, scheduler: str | None, progress: RunsDone | None
               ) -> list[Summary]:
    """:func:`sweep_summaries` once the variants are planned (and, with ``key``, loaded)."""
    results: list[Summary | None] = [None] * len(sets)
    done = 0

    def store(ids: list[int], summaries: list[Summary]) -> None:
        nonlocal done
        for i, s in zip(ids, summaries, strict=True):
            results[i] = s
        done += len(ids)
        if progress is not None:
            progress(done, len(sets))

    def jobs(parts: int, here: int | None = key) -> tuple[list[list[int]], list[ChunkJob]]:
        """The chunks cut again for ``parts`` workers (the numbers stay: see the module docstring),
        each with its variants held under ``here`` (None: loaded where the chunk runs)."""
        cut = for_workers(chunks, parts)
        return cut, [(path, [sets[i] for i in ids], backend, unset, here, None if here is None else ids)
                     for ids in cut]

    try:
        if scheduler is not None:
            _on_dask(scheduler, lambda parts: jobs(parts, None), store)
        elif workers > 1 and len(sets) > 1 and worth_spreading(_LOADED.get(key), backend):
            cut, tasks = jobs(worker_count(workers, len(sets)))
            _on_workers(worker_count(workers, len(cut)), cut, tasks, store)
        else:
            for ids, task in zip(*jobs(1), strict=True):
                store(ids, _run_chunk(*task))
    except KeyboardInterrupt as stop:
        raise SweepInterrupted(results, isinstance(stop, Terminated)) from None
    return results  # type: ignore[return-value]


def worth_spreading(variants: Sequence[Scenario] | None, backend: str) -> bool:
    """Whether the runs of ``variants`` are work enough for worker processes: at least
    :data:`SPREAD_MIN_WORK` copy-steps on ``backend`` (a backend it does not name, or variants
    loaded elsewhere: always)."""
    least = SPREAD_MIN_WORK.get(backend)
    if least is None or variants is None:
        return True
    work = 0
    for sc in variants:
        sim = sc.simulation
        work += TimeGrid.of(sim.duration, sim.dt, sim.control_period).rows
        if work >= least:
            return True
    return False


def _start_numba(chunks: list[list[int]]) -> None:
    """numba's compiler started in this process (its typing and target registries loaded) when a
    chunk is a batch (batches run compiled code) and compiled paths are on, so that the workers
    forked next inherit it rather than each paying for it."""
    if any(len(ids) > 1 for ids in chunks):
        compiled_paths.started()


def _on_workers(workers: int, chunks: list[list[int]], tasks: list[ChunkJob],
                store: Callable[[list[int], list[Summary]], None]) -> None:
    """The chunks on ``workers`` local workers: this process and ``workers - 1`` forks of it
    (registered laws included), each taking the next chunk (largest first) when it is free
    (:func:`qcontrol.workers.share`); the same chunks, so the same numbers."""
    if workers > 1:
        _start_numba(chunks)
    share(workers, len(tasks), lambda i: _run_chunk(*tasks[i]),
          lambda i, summaries: store(chunks[i], summaries))


def _connect(client_class: Any, address: str) -> Any:
    """A Dask client of the scheduler at ``address``, connected in a thread of its own while this
    one waits in short steps, so that Ctrl-C stops the wait at once and a scheduler that accepts
    the connection but never completes Dask's handshake is refused after
    :data:`DASK_CONNECT_TIMEOUT` seconds (one line, as any address that does not work)."""
    made: list[Any] = []
    failed: list[BaseException] = []

    def connect() -> None:
        try:
            made.append(client_class(address, timeout=DASK_CONNECT_TIMEOUT))
        except BaseException as exc:  # any failure of the address is reported below, as one line
            failed.append(exc)

    fix = "give the address of a running Dask scheduler, e.g. tcp://host:8786"
    thread = threading.Thread(target=connect, daemon=True, name="qcontrol-dask-connect")
    thread.start()
    deadline = time.monotonic() + DASK_CONNECT_TIMEOUT + 1.0
    while thread.is_alive() and time.monotonic() < deadline:
        thread.join(0.1)
    if thread.is_alive():
        raise QcontrolInputError(f"--scheduler {shown(address)}: no Dask handshake within "
                                 f"{DASK_CONNECT_TIMEOUT:g} s (something answers there, but not a Dask "
                                 f"scheduler); {fix}")
    if failed:
        exc = failed[0]
        why = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
        raise QcontrolInputError(f"--scheduler {shown(address)}: cannot connect ({why}); {fix}")
    return made[0]


def _on_dask(address: str, jobs: Callable[[int], tuple[list[list[int]], list[ChunkJob]]],
             store: Callable[[list[int], list[Summary]], None]) -> None:
    """Run the chunks on an existing Dask cluster (optional extra ``cluster``), cut for its threads."""
    try:
        from distributed import Client
    except ImportError:
        raise QcontrolInputError(
            "--scheduler needs Dask distributed: pip install 'qcontrol[cluster]'"
        ) from None
    client = _connect(Client, address)
    with client:
        threads = sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())
        chunks, tasks = jobs(max(1, threads))
        futures = [client.submit(_run_chunk, *task, pure=False) for task in tasks]
        for ids, summaries in zip(chunks, client.gather(futures), strict=True):
            store(ids, summaries)
