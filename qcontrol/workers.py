"""Local worker processes that never outlive the command that started them.

Each worker is a fork of the command's process. It leaves Ctrl-C to the parent (which stops the
pool), and dies with the parent however the parent ends: on Linux the kernel sends it SIGKILL when
the parent exits (``PR_SET_PDEATHSIG``, also after a ``kill -9`` of the parent); everywhere a
watchdog thread exits it within half a second of the parent's end. The number of workers is
capped at the work there is and at the machine's cores (more only share the cores and memory).
"""

from __future__ import annotations

import ctypes
import gc
import multiprocessing
import multiprocessing.pool
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

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
    with _signals_after_forking() as caught, _frozen_heap():
        pool = context.Pool(workers, initializer=_worker_start, initargs=(os.getpid(),))
    if caught:  # the command was asked to stop while the workers forked: they are not left running
        pool.terminate()
        for signum in caught:
            signal.raise_signal(signum)
    return pool


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


@contextmanager
def _signals_after_forking() -> Iterator[list[int]]:
    """Ctrl-C or SIGTERM arriving while the pool forks its workers is held, and given (the list
    yielded) for :func:`worker_pool` to act on once they are forked. Python runs a signal's handler
    at the next line of Python, which may be one of the hooks run around a fork (logging's lock),
    and it ignores an exception raised there: the command's "stop now" would be printed as
    "Exception ignored" and lost, and the command would run on. A child forked meanwhile ends on
    the signal as it would without a handler. If forking fails, a held signal is acted on here."""
    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    parent, caught = os.getpid(), []

    def hold(signum: int, frame: object) -> None:
        if os.getpid() != parent:  # a worker, before its start: the signal's default action
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        caught.append(signum)

    previous = {signum: signal.signal(signum, hold) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield caught
    except BaseException:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in caught:
            signal.raise_signal(signum)
        raise
    for signum, handler in previous.items():
        signal.signal(signum, handler)
