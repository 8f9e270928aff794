"""Which copies of a batch are still running, and where and why the others stopped."""

from __future__ import annotations

import numpy as np

from .rows import RowBuffer


class Divergence:
    """Stops a copy at the first row whose state or adaptive estimate is NaN/Inf, or whose
    ``|x_i|`` exceeds ``state_bound``: the copy keeps the rows up to and including that one."""

    def __init__(self, batch: int, rows: int, dt: float, state_bound: float) -> None:
        self.dt = dt
        self.state_bound = state_bound
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
        for b in np.flatnonzero(bad.any(axis=0)):
            row = int(np.argmax(bad[:, b]))
            self.kept[b] = first + row + 1
            self.times[b] = (first + row) * self.dt
            self.reasons[b] = (
                "state or adaptive estimate became NaN/Inf"
                if bad_state[row, b]
                else f"state left the bound |x_i| <= {self.state_bound:g}"
            )
            self.alive[b] = False

    @property
    def all_stopped(self) -> bool:
        return not self.alive.any()

    @property
    def last_row(self) -> int:
        """The last row any copy keeps."""
        return int(self.kept.max()) - 1
