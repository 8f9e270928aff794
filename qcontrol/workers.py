"""Local worker processes that never outlive the command that started them.

Each worker is a fork of the command's process. It leaves Ctrl-C to the parent (which stops the
pool), and dies with the parent however the parent ends: on Linux the kernel sends it SIGKILL when
the parent exits (``PR_SET_PDEATHSIG``, also after a ``kill -9`` of the parent); everywhere a
watchdog thread exits it within half a second of the parent's end. The number of workers is
capped at the work there is and at the machine's cores (more only share the cores and memory).

Two ways to use them: :func:`worker_pool`, a ``multiprocessing`` pool (tasks and results
pickled), and :func:`share`, where this process is one of the workers and its forks find their
tasks in their memory (a sweep's chunks: only the results come back pickled).
"""

from __future__ import annotations

import ctypes
import gc
import multiprocessing
import multiprocessing.pool
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing.connection import Connection, Pipe, wait
from typing import Any

from .interrupts import Held

_PR_SET_PDEATHSIG = 1
WATCH_PERIOD = 0.5  # s between a worker's checks that its parent is alive


def worker_count(requested: int, work: int) -> int:
    """``requested`` workers capped at ``work`` (tasks or chunks) and at the machine's cores."""
    return max(1, min(requested, work, os.cpu_count() or 1))


def _watch(parent: int) -> None:
    while True:
        if os.getppid() != parent:
            os._exit(1)
        time.sleep(WATCH_PERIOD)


def _worker_start(parent: int) -> None:
    """A worker's first act: ignore Ctrl-C, ask to be killed with the parent, watch it anyway."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the parent's handler: a SIGTERM ends a worker
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before the request was made
        os._exit(1)
    threading.Thread(target=_watch, args=(parent,), daemon=True, name="qcontrol-parent-watch").start()


def worker_pool(workers: int) -> multiprocessing.pool.Pool:
    """A pool of ``workers`` forked processes that die with this one; its user ends it with
    ``terminate()`` on every exit path (a ``finally``), so an error, Ctrl-C or SIGTERM stops the
    workers at once."""
    context = multiprocessing.get_context("fork")
    pool = None
    try:
        with Held(), _frozen_heap():  # (a stop asked for while the workers fork: acted on once forked)
            pool = context.Pool(workers, initializer=_worker_start, initargs=(os.getpid(),))
    except BaseException:  # the command was asked to stop: the workers are not left running
        if pool is not None:
            pool.terminate()
        raise
    return pool


class WorkerDied(RuntimeError):
    """A forked worker ended before it sent the result of its task (killed from outside)."""


WORKER_DIED = ("a worker process ended before it finished its runs (killed from outside, e.g. by "
               "the system when memory ran out); run again, with fewer --workers if memory is short")


def share(workers: int, count: int, run: Callable[[int], Any], done: Callable[[int, Any], None]) -> None:
    """``run(i)`` for each ``i`` of ``range(count)`` on ``workers`` workers: this process and
    ``workers - 1`` forks of it (which find ``run`` and what it reads in their memory: nothing is
    pickled but the results), each taking the next ``i`` when it is free. ``done(i, result)`` is
    called in this thread, for a fork's result once this process is between two of its own runs;
    a fork's error is raised here. The forks end with the call, however it ends. Leaner than a
    :func:`worker_pool` (no task pickled, one helper thread): a fork costs a few ms to start and
    stop where a pool of one costs some 15-25 ms."""
    following, lock = iter(range(count)), threading.Lock()

    def take() -> int | None:
        with lock:
            return next(following, None)

    mine, finished = take(), queue.SimpleQueue()
    with _forks(max(0, min(workers, count) - 1), run, take, finished):
        stored = 0
        while mine is not None:
            done(mine, run(mine))
            stored += 1
            while not finished.empty():
                _done(done, *finished.get())
                stored += 1
            mine = take()
        for _ in range(stored, count):
            _done(done, *finished.get())


def _done(done: Callable[[int, Any], None], i: int, ok: bool, value: Any) -> None:
    if not ok:
        raise value
    done(i, value)


def _feed(forks: list[Connection], firsts: list[int | None], take: Callable[[], int | None],
          finished: queue.SimpleQueue) -> None:
    """The helper thread of :func:`share`: its first task to each fork, then, as each sends a
    result, the result to ``finished`` and the next task (None: none left, the fork ends) to that
    fork."""
    busy = {}
    for conn, first in zip(forks, firsts, strict=True):
        busy[conn] = _give(conn, first)
    waiting = [conn for conn in forks if busy[conn] is not None]
    while waiting:
        for conn in wait(waiting):
            try:
                finished.put(conn.recv())
            except (EOFError, OSError):  # the fork ended (killed, or this process is stopping it)
                finished.put((busy[conn], False, WorkerDied(WORKER_DIED)))
                waiting.remove(conn)
                continue
            busy[conn] = _give(conn, take())
            if busy[conn] is None:
                waiting.remove(conn)


def _give(conn: Connection, i: int | None) -> int | None:
    try:
        conn.send(i)
    except OSError:  # (the fork is gone: its end is found at the next wait)
        pass
    return i


@contextmanager
def _forks(count: int, run: Callable[[int], Any], take: Callable[[], int | None],
           finished: queue.SimpleQueue) -> Iterator[None]:
    """``count`` forks of this process serving :func:`share`, fed by a helper thread
    (:func:`_feed`); on leaving, those still running are ended (SIGTERM), every fork is waited
    for and the helper thread with them (it ends as the last fork's connection closes)."""
    _flush()  # (what this process has buffered is not written again by a fork)
    forks: list[tuple[int, Connection]] = []
    feeder = None
    try:
        with Held(), _frozen_heap():  # (as worker_pool: the forks are ended below)
            parent = os.getpid()
            for _ in range(count):
                mine, its = Pipe()
                pid = os.fork()
                if pid == 0:
                    _serve(parent, its, run)
                its.close()
                forks.append((pid, mine))
        firsts = [take() for _ in forks]  # (taken here: this thread takes the next only after)
        feeder = threading.Thread(target=_feed, args=([c for _, c in forks], firsts, take, finished),
                                  daemon=True, name="qcontrol-feed-workers")
        feeder.start()
        yield
    finally:
        for pid, _ in forks:
            os.kill(pid, signal.SIGTERM)  # (a fork that has exited is a zombie until waited for)
        for pid, _ in forks:
            os.waitpid(pid, 0)
        if feeder is not None:
            feeder.join()
        for _, conn in forks:
            conn.close()


def _serve(parent: int, conn: Connection, run: Callable[[int], Any]) -> None:
    """A fork's life: ``run`` each index received, send ``(i, True, result)`` or ``(i, False,
    error)``, until None; then exit (never returning into the caller's code)."""
    code = 0
    try:
        _worker_start(parent)
        while (i := conn.recv()) is not None:
            try:
                answer = (i, True, run(i))
            except BaseException as exc:  # (sent to this process's parent, which raises it)
                answer = (i, False, exc)
            try:
                conn.send(answer)
            except Exception as exc:  # a result or an error that cannot be pickled
                conn.send((i, False, RuntimeError(f"a worker could not send its result ({exc})")))
    except BaseException:
        code = 1
    finally:
        _flush()
        os._exit(code)


def _flush() -> None:
    """Write out what standard output and error hold (a closed or missing stream: nothing)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, ValueError, OSError):
            pass


@contextmanager
def _frozen_heap() -> Iterator[None]:
    """The objects of this process frozen while the workers fork: a worker's garbage collections
    then never walk the objects it inherits, so they neither take its time nor copy the pages they
    lie in (a forked process shares its parent's memory until it writes to it). This process
    unfreezes them at once; one that froze objects of its own is left as it is."""
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
