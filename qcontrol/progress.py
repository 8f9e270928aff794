"""The one progress display of the command line: a line on stderr, redrawn in place on a terminal."""

from __future__ import annotations

import sys


class ProgressLine:
    """``progress(done, total)``: on a terminal, ``label: 42% [unit]`` redrawn in place (a newline
    when done); elsewhere (a log file, a pipe) a line every ``piped_every`` percent, or nothing
    when ``piped_every`` is None. Nothing at all unless ``enabled``."""

    def __init__(self, label: str, enabled: bool, unit: str = "", piped_every: int | None = None) -> None:
        self.label, self.unit, self.piped_every = label, unit, piped_every
        self.tty = sys.stderr.isatty()
        self.enabled = enabled and (self.tty or piped_every is not None)
        self.shown = -1

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        percent = 100 * done // max(total, 1)
        step = percent if self.tty else percent // self.piped_every
        if step == self.shown:
            return
        self.shown = step
        count = f" ({done}/{total} {self.unit})" if self.unit else ""
        if self.tty:
            sys.stderr.write(f"\r{self.label}: {percent:3d}%{count}" + ("\n" if done >= total else ""))
        else:
            sys.stderr.write(f"{self.label}: {percent:3d}%{count}\n")
        sys.stderr.flush()

    def finish(self) -> None:
        """End an unfinished line (a run that stopped early) so what follows starts on its own."""
        if self.enabled and self.tty and self.shown not in (-1, 100):
            sys.stderr.write("\n")
            sys.stderr.flush()
        self.shown = 100
