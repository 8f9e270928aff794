"""Which copies of a batch are still running, and where and why the others stopped."""

from __future__ import annotations

import numpy as np

from .row_buffer import RowBuffer


class Divergence:
    """Stops a copy at the first row whose state or adaptive estimate is NaN/Inf, or whose
    ``|x_i|`` exceeds ``state_bound``: the copy keeps the rows up to and including that one."""

    def __init__(self, batch: int, rows: int, dt: float, state_bound: float,
                 adaptive_name: str = "adaptive state") -> None:
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
        for b in np.flatnonzero(bad.any(axis=0)):
            row = int(np.argmax(bad[:, b]))
            self.kept[b] = first + row + 1
            self.times[b] = (first + row) * self.dt
            self.reasons[b] = self._reason(x[row, b], adaptive[row, b])
            self.alive[b] = False

    def _reason(self, x: np.ndarray, adaptive: np.ndarray) -> str:
        """Which value stopped the copy, e.g. ``x2 = 1.2e+06 left the bound |x_i| <= 1e+06``."""
        for i, value in enumerate(x):
            if not np.isfinite(value):
                return f"x{i + 1} became NaN/Inf"
        for i, value in enumerate(adaptive):
            if not np.isfinite(value):
                return f"{self.adaptive_name}[{i + 1}] became NaN/Inf"
        i = int(np.argmax(np.abs(x)))
        return f"x{i + 1} = {x[i]:.3g} left the bound |x_i| <= {self.state_bound:g}"

    @property
    def all_stopped(self) -> bool:
        return not self.alive.any()

    @property
    def last_row(self) -> int:
        """The last row any copy keeps."""
        return int(self.kept.max()) - 1
