"""The one progress display of the command line: a line on stderr, redrawn in place, on a terminal
only (a log file or a pipe gets none, for every command)."""

from __future__ import annotations

import sys


class ProgressLine:
    """``progress(done, total)``: on a terminal, ``label: 42% [unit]`` redrawn in place (a newline
    when done); nothing elsewhere (a log file, a pipe), nor unless ``enabled``."""

    def __init__(self, label: str, enabled: bool, unit: str = "") -> None:
        self.label, self.unit = label, unit
        self.enabled = enabled and sys.stderr.isatty()
        self.shown = -1

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        percent = 100 * done // max(total, 1)
        if percent == self.shown:
            return
        self.shown = percent
        count = f" ({done}/{total} {self.unit})" if self.unit else ""
        sys.stderr.write(f"\r{self.label}: {percent:3d}%{count}" + ("\n" if done >= total else ""))
        sys.stderr.flush()

    def finish(self) -> None:
        """End an unfinished line (a run that stopped early) so what follows starts on its own."""
        if self.enabled and self.shown not in (-1, 100):
            sys.stderr.write("\n")
            sys.stderr.flush()
        self.shown = 100
