"""Ctrl-C and SIGTERM held while work runs that must not stop halfway, and acted on as it ends.

Python runs a signal's handler at the next line of Python the main thread runs, and that line may
lie inside work that cannot be left halfway: a hook run around a fork (logging's lock), where the
exception is ignored and the command's "stop now" is lost; or numba compiling, where llvmlite
runs Python between its calls into LLVM (its callbacks, the lock taken around each call). There a
``KeyboardInterrupt`` is lost ("Exception ignored") or leaves llvmlite's objects half updated:
raised as ``LLVMPY_LinkModules`` returns, it leaves Python owning a module LLVM has already
destroyed, and the process crashes later, when it frees it.

While a :class:`Held` block runs, such a signal is only noted. As the block ends, however it ends,
the handlers are put back and each noted signal is given to them again, so the
``KeyboardInterrupt`` (or :class:`~.errors.Terminated`) is raised where the block ends and the
command stops as it does anywhere else. Blocks nest (an inner block's signal goes to the outer
one's hold).

Only the main thread runs Python's signal handlers and may change them: in another thread a block
holds nothing (a signal then interrupts the main thread, not the block). A signal whose handler
is not Python's is left as it is, for it runs no Python: ignored, or the default action (a worker
process ignores Ctrl-C, and SIGTERM ends it at once).

A handler may also run inside a finalizer (an object's ``__del__``, e.g. rerun's recording stream
collected), and Python ignores what a finalizer raises: the ``Terminated`` is lost there and the
command would go on (and wait for workers the same SIGTERM ended). Inside :func:`stops_kept` (the
command line's SIGTERM handling) such a lost ``Terminated`` is noted as Python reports it ignored
(``sys.unraisablehook``), and the places where the command waits for its workers, forks them (the
end of a :class:`Held` block), finishes an output file or puts a staged set of files in place call
:func:`stop_if_asked`, which raises it again: a lost stop is acted on there.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType, TracebackType
from typing import Any

from .errors import Terminated

HELD = (signal.SIGINT, signal.SIGTERM)
_LOST: list[int] = []  # the process whose Terminated Python ignored (its id: a fork's is not its parent's)


def _terminate(signum: int, frame: FrameType | None) -> None:
    """SIGTERM's handler: stop as Ctrl-C does (every output cleans up after itself), exit status
    143. (A stop lost before is this one now.)"""
    _LOST.clear()
    raise Terminated


@contextmanager
def stops_kept() -> Iterator[None]:
    """The block runs with SIGTERM raising ``Terminated`` and a ``Terminated`` lost in a finalizer
    noted for :func:`stop_if_asked` (module docstring); the previous handler and hook are put back
    as it ends. In the main thread only."""
    previous, hook = signal.signal(signal.SIGTERM, _terminate), sys.unraisablehook

    def noting(unraisable: Any) -> None:
        if unraisable.exc_type is not None and issubclass(unraisable.exc_type, Terminated):
            _LOST[:] = [os.getpid()]
        hook(unraisable)

    sys.unraisablehook = noting
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        sys.unraisablehook = hook
        _LOST.clear()


def stop_if_asked() -> None:
    """Raise again, in the main thread, a ``Terminated`` Python ignored (:func:`stops_kept`);
    elsewhere, or with none lost, nothing."""
    if _LOST == [os.getpid()] and threading.current_thread() is threading.main_thread():
        _LOST.clear()
        raise Terminated


class Held:
    """``with Held():`` the block runs with Ctrl-C and SIGTERM held (module docstring); the
    signals held are in :attr:`caught` until the block ends."""

    def __init__(self) -> None:
        self.caught: list[int] = []
        self._previous: dict[int, object] = {}
        self._process = os.getpid()

    def __enter__(self) -> Held:
        if threading.current_thread() is threading.main_thread():
            for signum in HELD:
                handler = signal.getsignal(signum)
                if callable(handler):
                    self._previous[signum] = signal.signal(signum, self._hold)
        return self

    def _hold(self, signum: int, frame: FrameType | None) -> None:
        if os.getpid() != self._process:  # a fork made in the block, before its own start: the
            signal.signal(signum, signal.SIG_DFL)  # signal's default action, as without a handler
            os.kill(os.getpid(), signum)
            return
        self.caught.append(signum)

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        """The handlers back, then each signal held given to them (the first that raises ends the
        block with its exception, in place of any the block raised); a stop lost before is acted
        on (:func:`stop_if_asked`)."""
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
        caught, self.caught = self.caught, []
        for signum in caught:
            signal.raise_signal(signum)
        stop_if_asked()
