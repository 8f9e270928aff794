"""Local worker processes that never outlive the command that started them.

Each worker is a fork of the command's process. It leaves Ctrl-C to the parent (which ends the
workers), and dies with the parent however the parent ends: on Linux the kernel sends it SIGKILL
when the parent exits (``PR_SET_PDEATHSIG``, also after a ``kill -9`` of the parent); everywhere a
watchdog thread exits it within half a second of the parent's end. A SIGTERM ends it at once (the
default action: a SIGTERM sent to the command's whole process group, as a job scheduler,
``timeout`` or a closing terminal sends it, ends the workers with the command). The number of
workers is capped at the work there is and at the machine's cores (more only share the cores and
memory).

A worker finds its tasks in its memory (``run(i)``, with what ``run`` reads, set before the fork):
only the index goes to it and the result (or error) comes back pickled, over a pipe of its own that
a helper thread of the parent watches. A worker that dies (killed from outside) closes its pipe:
the task it held is a :class:`WorkerDied` error in the parent, never a wait forever; ending the
workers is a SIGKILL to each and a wait for it, no lock shared with them. Two ways to use them:
:class:`Forks`, workers that run a list of tasks while this process goes on (it waits for each
result when it needs it), and :func:`share`, where this process is one of the workers (a sweep's
chunks). Every wait for a worker acts on a stop asked for whose exception was lost
(:func:`qcontrol.interrupts.stop_if_asked`).
"""

from __future__ import annotations

import ctypes
import gc
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from multiprocessing.connection import Connection, Pipe, wait
from typing import Any

from .interrupts import Held, stop_if_asked

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


class WorkerDied(RuntimeError):
    """A forked worker ended before it sent the result of its task (killed from outside)."""


WORKER_DIED = ("a worker process ended before it finished its runs (killed from outside, e.g. by "
               "the system when memory ran out); run again, with fewer --workers if memory is short")


def share(workers: int, count: int, run: Callable[[int], Any], done: Callable[[int, Any], None]) -> None:
    """``run(i)`` for each ``i`` of ``range(count)`` on ``workers`` workers: this process and
    ``workers - 1`` forks of it (which find ``run`` and what it reads in their memory: nothing is
    pickled but the results), each taking the next ``i`` when it is free. ``done(i, result)`` is
    called in this thread, for a fork's result once this process is between two of its own runs;
    a fork's error is raised here. The forks end with the call, however it ends. A fork costs a
    few ms to start and stop (a ``multiprocessing`` pool of one cost some 15-25 ms)."""
    take, finished = _taker(count), queue.SimpleQueue()
    mine = take()
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
            stop_if_asked()
            _done(done, *finished.get())


def _taker(count: int) -> Callable[[], int | None]:
    """The next index of ``range(count)`` at each call (None: none left), from any thread."""
    following, lock = iter(range(count)), threading.Lock()

    def take() -> int | None:
        with lock:
            return next(following, None)

    return take


def _done(done: Callable[[int, Any], None], i: int, ok: bool, value: Any) -> None:
    if not ok:
        stop_if_asked()  # (a fork ended by the SIGTERM sent to the whole group: the stop, not its end)
        raise value
    done(i, value)


class Forks:
    """``run(i)`` for each ``i`` of ``range(count)`` on ``workers`` forks of this process, started
    now and running while this process goes on; each fork takes the next ``i`` when it is free (the
    first tasks first). :meth:`result` waits for a task's result. A context manager: the forks end
    with the block, however it ends (:meth:`close`)."""

    def __init__(self, workers: int, count: int, run: Callable[[int], Any]) -> None:
        self._finished: queue.SimpleQueue = queue.SimpleQueue()
        self._got: dict[int, tuple[bool, Any]] = {}
        self._stack = ExitStack()
        self._stack.enter_context(_forks(min(max(workers, 1), count), run, _taker(count), self._finished))

    def result(self, i: int) -> Any:
        """Task ``i``'s result, once it is in (its error raised here): :class:`WorkerDied` as soon
        as a fork has ended before it sent its task's result (the results cannot all come),
        ``Terminated`` if this process was asked to stop (:func:`~.interrupts.stop_if_asked`)."""
        while i not in self._got:
            stop_if_asked()
            j, ok, value = self._finished.get()
            if isinstance(value, WorkerDied):
                stop_if_asked()
                raise value
            self._got[j] = (ok, value)
        ok, value = self._got[i]
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """End the forks still running (SIGKILL) and wait for each, and for the helper thread."""
        self._stack.close()

    def __enter__(self) -> Forks:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _feed(forks: list[Connection], firsts: list[int | None], take: Callable[[], int | None],
          finished: queue.SimpleQueue) -> None:
    """The helper thread of :func:`share` and :class:`Forks`: its first task to each fork, then,
    as each sends a result, the result to ``finished`` and the next task (None: none left, the fork
    ends) to that fork."""
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
    """``count`` forks of this process serving :func:`share` or :class:`Forks`, fed by a helper thread
    (:func:`_feed`); on leaving, those still running are ended (SIGKILL), every fork is waited
    for and the helper thread with them (it ends as the last fork's connection closes)."""
    _flush()  # (what this process has buffered is not written again by a fork)
    forks: list[tuple[int, Connection]] = []
    feeder = None
    try:
        with Held(), _frozen_heap():  # (a stop asked for while they fork: acted on once forked)
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
        for pid, _ in forks:  # (SIGKILL: a SIGTERM that reaches a fork before its first act, where
            # it still has this process's handlers, is lost with them; an exited fork is a zombie)
            os.kill(pid, signal.SIGKILL)
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
