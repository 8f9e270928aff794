"""The reference ``[y_d, y_d', ..., y_d^(n)]`` at the instants of a run's rows."""

from __future__ import annotations

import numpy as np

from ..reference import Reference
from ..timegrid import TimeGrid

BLOCK_ROWS = 1000  # rows of the reference the loop holds as Python floats at a time


class ReferenceRows:
    """``y_d .. y_d^(n)`` at the rows of ``grid``: as arrays for blocks of rows (:meth:`block`), and
    as a list of floats one row at a time for the loop (:meth:`at`, a block at a time). With
    ``whole`` the whole table is computed once (a full record); otherwise per block, so memory
    stays flat however long the run. The instants are ``k dt`` whichever way: the same floats."""

    def __init__(self, reference: Reference, n: int, grid: TimeGrid, whole: bool) -> None:
        self.reference, self.n, self.grid = reference, n, grid
        self.table = self._compute(0, grid.rows) if whole else None
        self._rows: list[list[float]] = []
        self._first = self._stop = 0

    def _compute(self, first: int, stop: int) -> np.ndarray:
        return np.asarray(self.reference.derivatives(self.grid.instants(first, stop), self.n), dtype=float)

    def block(self, first: int, stop: int) -> np.ndarray:
        """Rows ``[first, stop)``, shape ``(stop - first, n + 1)``."""
        return self._compute(first, stop) if self.table is None else self.table[first:stop]

    def at(self, k: int) -> list[float]:
        """Row ``k`` as floats (the same for every copy)."""
        if k >= self._stop:
            self._first, self._stop = k, k + BLOCK_ROWS
            self._rows = self.block(k, k + BLOCK_ROWS).tolist()
        return self._rows[k - self._first]
