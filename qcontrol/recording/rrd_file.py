"""The file behind a recording: written under a temporary name of its own
(:class:`qcontrol.outputs.AtomicFile`), moved to its final name only when the run finished and the
file reads back with its footer; an interrupted or failed recording is kept as
``NAME.partial.rrd`` and never replaces a complete one.

rerun reports its own sink errors (e.g. a full disk) as coloured log lines on stderr; the
process's rerun logging is turned off (unless ``RUST_LOG`` says otherwise) and the file is
checked here instead, so a failure is one line of qcontrol's.
"""

from __future__ import annotations

import errno
import os
import warnings
from pathlib import Path

from ..errors import QcontrolOutputError, shown
from ..outputs import AtomicFile, finish


def quiet_rerun_logging() -> None:
    """rerun's own log lines off (before rerun makes its first stream); a user's RUST_LOG wins."""
    os.environ.setdefault("RUST_LOG", "off")


def rrd_problem(path: Path) -> str | None:
    """Why the recording at ``path`` does not read back (None when it does): no footer, or a
    frame that does not decode."""
    import rerun_bindings
    from rerun.chunk import RrdReader

    try:
        if not rerun_bindings.check_for_rrd_footer(str(path)):
            return "it has no footer: the stream was cut"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if not RrdReader(path).recordings():
                return "it holds no recording"
    except (RuntimeError, OSError, ValueError) as exc:
        return f"it does not read back: {exc}"
    return None


def _space_left(folder: Path) -> bool:
    try:
        return os.statvfs(folder).f_bavail > 0
    except OSError:
        return True


def _folder(path: Path) -> Path:
    return path.parent if str(path.parent) else Path(".")


class RrdFile:
    """One recording's file: ``temporary`` is what rerun writes to."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file = AtomicFile(path)
        self._file.release()  # rerun opens it by name
        self.temporary = self._file.temporary

    def written(self) -> int:
        """The bytes rerun wrote so far (-1 if the file cannot be read): a writer's progress."""
        try:
            return os.stat(self.temporary).st_size
        except OSError:
            return -1

    def space_left(self) -> bool:
        """Whether the file's disk has space left (True when that cannot be told)."""
        return _space_left(_folder(self.path))

    def finish(self, complete: bool, cause: str | None = None) -> Path | None:
        """Once rerun closed the file (or gave up on it): a complete run's verified file replaces
        ``path``; an interrupted one is kept as the partial name (a warning says where) and
        ``path`` is left as it was. A complete run whose file does not read back is a
        :class:`QcontrolOutputError` (what was written is kept as the partial name), its cause a
        full disk, ``cause`` (why the file was given up on), or what is wrong with the file.
        Returns where the data is, if anywhere."""
        problem = rrd_problem(self.temporary)
        if complete and problem is None and cause is None:
            return finish(self._file)
        folder = _folder(self.path)
        kept = self._file.keep_partial()
        where = (f"kept what was recorded as {shown(kept)}" if kept is not None
                 else "nothing was kept")
        if complete:
            full = not _space_left(folder)
            cause = "no space left on the device" if full else cause or problem
            fix = "free some space or write elsewhere" if full else "check the disk or write elsewhere"
            raise QcontrolOutputError(errno.ENOSPC if full else errno.EIO,
                                      f"{shown(self.path)}: cannot write the recording ({cause}); {where}, "
                                      f"{shown(self.path)} is unchanged; {fix}")
        warnings.warn(f"the run did not finish: {where}; {shown(self.path)} is unchanged", stacklevel=3)
        return kept

    def discard(self) -> None:
        self._file.discard()
