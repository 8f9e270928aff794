"""Figures drawn in a forked process while the reproduction goes on.

Drawing a figure (matplotlib's layout and PNG rendering) costs as much CPU time as many of the
reproduction's runs, and it needs nothing but runs already made. :class:`Apart` forks a worker
(:func:`qcontrol.workers.worker_pool`, which dies with this process) when a set of figures' data
exist, so the worker finds the data in its memory and nothing is sent to it; the worker draws
into a scratch folder and sends back the files' bytes, which :meth:`Apart.wait` writes into the
output folder, staged with the reproduction's other files (:func:`qcontrol.outputs.staged`). The
figures are the very ones drawn here: the same code on the same data, byte for byte.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from itertools import count
from multiprocessing.pool import AsyncResult, Pool
from pathlib import Path
from types import TracebackType

from ..outputs import unstaged, write_file
from ..workers import worker_pool

Figures = Callable[[Path], object]  # draws its figures into the folder given
_KEPT: dict[int, Figures] = {}  # the figures a forked worker draws, by key (set before the fork)
_KEYS = count()


def _drawn(key: int) -> dict[str, bytes]:
    """Worker entry point: the files the figures of ``key`` draw, by name."""
    with unstaged(), tempfile.TemporaryDirectory(prefix="qcontrol-figures-") as scratch:
        _KEPT[key](Path(scratch))
        return {path.name: path.read_bytes() for path in sorted(Path(scratch).iterdir())}


class Apart:
    """Sets of figures drawn by forked workers into ``out`` (``forked`` False: here, at once).
    A context manager: the workers end with the block, at once on an error."""

    def __init__(self, out: Path, forked: bool) -> None:
        self.out, self.forked = out, forked
        self.pending: list[tuple[Pool, AsyncResult, int]] = []

    def draw(self, figures: Figures) -> None:
        """Draw ``figures`` (into the folder it is given) apart, or here."""
        if not self.forked:
            figures(self.out)
            return
        key = next(_KEYS)
        _KEPT[key] = figures
        pool = worker_pool(1)  # (forked now: it holds the figures' data)
        self.pending.append((pool, pool.apply_async(_drawn, (key,)), key))

    def wait(self) -> None:
        """Wait for every set of figures drawn apart and write its files into ``out``."""
        while self.pending:
            pool, result, key = self.pending[0]
            for name, data in result.get().items():
                write_file(self.out / name, lambda handle, data=data: handle.write(data))
            pool.close()
            pool.join()
            self.pending.pop(0)
            _KEPT.pop(key, None)

    def __enter__(self) -> Apart:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        for pool, _, key in self.pending:
            pool.terminate()
            pool.join()
            _KEPT.pop(key, None)
        self.pending.clear()
