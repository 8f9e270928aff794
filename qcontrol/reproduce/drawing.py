"""Figures drawn in a forked process while the reproduction goes on.

Drawing a figure (matplotlib's layout and PNG rendering) costs as much CPU time as many of the
reproduction's runs, and it needs nothing but runs already made. :class:`Apart` forks a worker
(:class:`qcontrol.workers.Forks`, which dies with this process) when a set of figures' data
exist, so the worker finds the data in its memory and nothing is sent to it; the worker draws
into a scratch folder this process made (and removes, however the worker ends), and
:meth:`Apart.wait` writes the files' bytes into the output folder, staged with the reproduction's
other files (:func:`qcontrol.outputs.staged`). The figures are the very ones drawn here: the same
code on the same data, byte for byte.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from ..outputs import unstaged, write_file
from ..workers import Forks

Figures = Callable[[Path], object]  # draws its figures into the folder given


def _drawn(figures: Figures, scratch: Path) -> None:
    """Worker entry point: ``figures`` drawn into ``scratch``, each file put in place at once."""
    with unstaged():
        figures(scratch)


class Apart:
    """Sets of figures drawn by forked workers into ``out`` (``forked`` False: here, at once).
    A context manager: the workers end with the block, at once on an error."""

    def __init__(self, out: Path, forked: bool) -> None:
        self.out, self.forked = out, forked
        self.pending: list[tuple[Forks, Path]] = []

    def draw(self, figures: Figures) -> None:
        """Draw ``figures`` (into the folder it is given) apart, or here."""
        if not self.forked:
            figures(self.out)
            return
        scratch = Path(tempfile.mkdtemp(prefix="qcontrol-figures-"))
        try:  # (forked now: the worker holds the figures' data)
            self.pending.append((Forks(1, 1, lambda _: _drawn(figures, scratch)), scratch))
        except BaseException:
            shutil.rmtree(scratch, ignore_errors=True)
            raise

    def wait(self) -> None:
        """Wait for every set of figures drawn apart and write its files into ``out``."""
        while self.pending:
            forks, scratch = self.pending[0]
            forks.result(0)
            for path in sorted(scratch.iterdir()):
                data = path.read_bytes()
                write_file(self.out / path.name, lambda handle, data=data: handle.write(data))
            self._end_first()

    def _end_first(self) -> None:
        """The first set's worker ended and its scratch folder removed."""
        forks, scratch = self.pending.pop(0)
        try:
            forks.close()
        finally:
            shutil.rmtree(scratch, ignore_errors=True)

    def __enter__(self) -> Apart:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        while self.pending:
            self._end_first()
