"""The sensors' Gaussian reading noise: one seeded stream per copy.

Copy ``b`` of a batch draws from ``numpy.random.default_rng(seeds[b])``, two standard normal
values (position, velocity) per reading, scaled by the option's standard deviations. So a copy
reads the very noise a single run with its seed reads, whatever else shares its batch: a study
over seeds runs as one batch and gives each seed's numbers. Copies with the same seed share one
stream's draws.

Draws are made ahead in blocks of :data:`BLOCK` readings: a Generator's normal values are
consumed in order, so ``normal(size=(BLOCK, 2))`` holds the values of ``BLOCK`` successive
``normal(size=2)`` draws (drawing ahead changes none of them). So a run's whole noise can be
drawn before it starts (:meth:`SensorNoise.ahead`, what the compiled loop adds to the readings)
and its readings still get the very values, in the same order.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

BLOCK = 1024  # readings drawn ahead per stream


class SensorNoise:
    """The noise of each copy's readings, ``(batch, 2)`` per :meth:`draw`."""

    def __init__(self, std: Sequence[float], seeds: Sequence[int | None]) -> None:
        self.std = np.asarray(std, dtype=float)
        self.seeds = list(seeds)
        self._distinct = list(dict.fromkeys(self.seeds))
        self._copy_stream = [self._distinct.index(s) for s in self.seeds]
        self.reset()

    def reset(self) -> None:
        """Every stream back at its seed's start (a run's reset; no streams without noise)."""
        self._streams = [np.random.default_rng(seed) for seed in self._distinct] if self.std.any() else []
        self._block = np.empty((0, len(self.seeds), 2))
        self._row = 0

    def draw(self) -> np.ndarray:
        """The noise of one reading of every copy, ``(batch, 2)``."""
        row = self.ahead(1)[0]
        self._row += 1
        return row

    def ahead(self, count: int) -> np.ndarray:
        """The noise of the next ``count`` readings of every copy, ``(count, batch, 2)``: standard
        normals times the deviations, without taking them (:meth:`draw` still gives them, in
        order; :meth:`skip` passes over them). The compiled loop reads a run's noise from here."""
        while len(self._block) - self._row < count:
            ahead = [stream.normal(0.0, 1.0, size=(BLOCK, 2)) for stream in self._streams]
            block = np.stack([ahead[k] for k in self._copy_stream], axis=1)
            self._block = np.concatenate([self._block[self._row:], block])
            self._row = 0
        return self._block[self._row:self._row + count] * self.std

    def skip(self, count: int) -> None:
        """Pass over the next ``count`` readings (read elsewhere from :meth:`ahead`)."""
        self.ahead(count)
        self._row += count
