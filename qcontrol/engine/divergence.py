"""Which copies of a batch are still running, and where and why the others stopped."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..expr import Expression
from .row_buffer import RowBuffer

DOMAIN_ERROR = "not a step-size problem"  # ends the reason of a NaN that a plant term's domain explains


class Divergence:
    """Stops a copy at the first row whose state or adaptive estimate is NaN/Inf, or whose
    ``|x_i|`` exceeds ``state_bound``: the copy keeps the rows up to and including that one."""

    def __init__(self, batch: int, rows: int, dt: float, state_bound: float,
                 adaptive_name: str = "adaptive state", terms: Sequence[tuple[str, Expression]] = (),
                 law_failures: Mapping[int, tuple[float, str, bool]] | None = None) -> None:
        # a law's failures as it records them (copy -> (t, the line, whether control() failed)):
        # the copy stops at that row, the line its reason (see controller/user_failure.py)
        self.law_failures = law_failures if law_failures is not None else {}
        self.law_failed = [False] * batch
        self.terms = tuple(terms)  # the plant's expressions by name, to explain a NaN (see _domain_error)
        self.before: np.ndarray | None = None  # the last row of the rows tested before, (batch, n)
        self.dt = dt
        self.state_bound = state_bound
        self.adaptive_name = adaptive_name
        self.alive = np.ones(batch, dtype=bool)
        self.kept = np.full(batch, rows)  # rows each copy keeps
        self.times: list[float | None] = [None] * batch
        self.reasons = [""] * batch

    def test(self, first: int, stop: int, buffer: RowBuffer) -> None:
        """Test rows ``[first, stop)`` of every copy still running."""
        if first >= stop:
            return
        rows = buffer.rows(first, stop)
        x, adaptive = rows["x"], rows["adaptive"]  # (rows, batch, n), (rows, batch, m)
        bad_state = ~np.isfinite(x).all(axis=2) | ~np.isfinite(adaptive).all(axis=2)
        bad = (bad_state | (np.abs(x) > self.state_bound).any(axis=2)) & self.alive
        failed = self._law_failed(first, stop, bad) if self.law_failures else None
        for b in np.flatnonzero(bad.any(axis=0)):
            row = int(np.argmax(bad[:, b]))
            self.kept[b] = first + row + 1
            self.times[b] = (first + row) * self.dt
            before = x[row - 1, b] if row > 0 else None if self.before is None else self.before[b]
            if failed is not None and b in failed and failed[b] <= first + row:
                self.reasons[b], self.law_failed[b] = self.law_failures[b][1], True
            else:
                self.reasons[b] = self._reason(x[row, b], adaptive[row, b], before)
            self.alive[b] = False
        self.before = np.array(x[-1])

    def _law_failed(self, first: int, stop: int, bad: np.ndarray) -> dict[int, int]:
        """The row at which each running copy's law failed, among rows before ``stop``; a failure in
        ``control()`` marks its row in ``bad`` (its u is NaN), one in the state's update shows as
        the NaN state of the next row. A law failing at the very row where the state had already
        gone bad (fed NaN) is not the reason."""
        rows = {}
        for b, (t, _, in_control) in self.law_failures.items():
            row = int(round(t / self.dt)) + (0 if in_control else 1)
            if row < stop and self.alive[b]:
                natural = bool(bad[row - first, b]) if row >= first else False
                if in_control and not natural and row >= first:
                    bad[row - first, b] = True
                if not natural or not in_control:
                    rows[b] = row
        return rows

    def _reason(self, x: np.ndarray, adaptive: np.ndarray, before: np.ndarray | None = None) -> str:
        """Which value stopped the copy, e.g. ``x2 = 1.2e+06 left the bound |x_i| <= 1e+06``."""
        for i, value in enumerate(x):
            if not np.isfinite(value):
                return self._domain_error(before) or f"x{i + 1} became NaN/Inf"
        for i, value in enumerate(adaptive):
            if not np.isfinite(value):
                return f"{self.adaptive_name}[{i + 1}] became NaN/Inf"
        i = int(np.argmax(np.abs(x)))
        return f"x{i + 1} = {x[i]:.3g} left the bound |x_i| <= {self.state_bound:g}"

    def _domain_error(self, before: np.ndarray | None) -> str | None:
        """A term of the plant that is NaN at the finite state the step started from, or at that
        state with one coordinate's sign flipped (a step's inner stages cross zero first): the
        state went NaN through that expression's domain (e.g. a negative base to a fractional
        power), not through the step size."""
        if before is None or not np.all(np.isfinite(before)):
            return None
        flipped = [np.where(np.arange(len(before)) == i, -before, before) for i in range(len(before))]
        for name, term in self.terms:
            for state in (before, *flipped):
                with np.errstate(all="ignore"):
                    value = float(term(state))
                if np.isnan(value):
                    shown = ", ".join(f"x{i + 1} = {v:.4g}" for i, v in enumerate(state))
                    return (f"{name} = {term.source!r} is NaN at {shown} (beside the last finite state): "
                            "the expression is undefined there (a negative base to a fractional power? "
                            f"write cbrt(x) or spow(x, p) = sign(x) |x|**p), {DOMAIN_ERROR}")
        return None

    @property
    def all_stopped(self) -> bool:
        return not self.alive.any()

    @property
    def last_row(self) -> int:
        """The last row any copy keeps."""
        return int(self.kept.max()) - 1
