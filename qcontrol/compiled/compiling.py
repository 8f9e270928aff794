"""Ctrl-C and SIGTERM held while numba compiles (:class:`~qcontrol.interrupts.Held`), and
raised as the compile returns.

numba does all of its LLVM work under its compiler lock: compiling a function, loading one from
the disk cache, starting its compiler. :class:`HeldWhileCompiling` listens to the lock's events
(``"numba:compiler_lock"``, numba's event API) and makes the main thread's outermost hold of the
lock one :class:`~qcontrol.interrupts.Held` block: a signal that arrives meanwhile is noted, and
its ``KeyboardInterrupt`` (or ``Terminated``) is raised as the lock is released, once numba has
finished and stored what it compiled. Importing this module imports numba.
"""

from __future__ import annotations

import threading

from numba.core import event

from ..interrupts import Held


class HeldWhileCompiling(event.Listener):
    """From the main thread's outermost acquisition of numba's compiler lock to its release, a
    :class:`~qcontrol.interrupts.Held` block (acquisitions in other threads hold nothing: the
    main thread takes the signal there)."""

    def __init__(self) -> None:
        self.depth = 0
        self.block: Held | None = None

    def on_start(self, occurrence: event.Event) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        self.depth += 1
        if self.depth == 1:
            self.block = Held().__enter__()

    def on_end(self, occurrence: event.Event) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        self.depth -= 1
        if self.depth == 0 and self.block is not None:
            block, self.block = self.block, None
            block.__exit__(None, None, None)  # (the held signal's exception is raised here)


_LISTENING: list[HeldWhileCompiling] = []


def hold_while_compiling() -> None:
    """Once per process (worker processes forked later inherit it): numba's compiles hold
    Ctrl-C and SIGTERM (module docstring)."""
    if not _LISTENING:
        _LISTENING.append(HeldWhileCompiling())
        event.register("numba:compiler_lock", _LISTENING[0])
