"""The error rate of the paper's Table 1, computed from a run's rows as they arrive.

``E(omega) = #{i : |z_1(t_i)| > omega} / M`` with ``t_i = i T / (M - 1)``, ``i = 0..M-1`` (SPEC 9).
``z_1`` between recorded instants is interpolated linearly (it is continuous); instants after the
last finite row of a diverged run count as exceeding every omega. Feeding the rows in chunks gives
bit-identical results to feeding them at once: every instant is interpolated on the same pair of
rows, so a long run needs only ``M`` numbers, not its whole ``z_1``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

TABLE1_OMEGAS = (0.100, 0.125, 0.150, 0.175, 0.200)
TABLE1_SAMPLES = 1302
END_TOLERANCE = 1e-12  # an instant this close after the last row takes the last row's value


def omega_key(omega: float) -> str:
    """Key of an error-rate entry in JSON outputs: ``0.1 -> "0.100"``."""
    return f"{omega:.3f}"


class ErrorRateStream:
    """Accumulates ``|z_1|`` at the sample instants from rows given in time order."""

    def __init__(self, horizon: float, samples: int = TABLE1_SAMPLES) -> None:
        if samples < 2:
            raise ValueError("the error rate needs at least 2 samples")
        self.instants = np.arange(samples) * (horizon / (samples - 1))
        self.values = np.full(samples, np.inf)  # inf: not covered (yet): counts as exceeding
        self.done = 0  # instants [0, done) have their value
        self.last: tuple[float, float] | None = None  # (t, |z_1|) of the last finite row so far

    def add(self, t: np.ndarray, z1: np.ndarray) -> None:
        """The next rows (instants ``t``, errors ``z1``); non-finite rows are skipped."""
        finite = np.isfinite(z1)
        t, z = t[finite], np.abs(z1[finite])
        if not t.size:
            return
        if self.last is not None:  # the interval from the previous chunk's last row
            t, z = np.r_[self.last[0], t], np.r_[self.last[1], z]
        stop = int(np.searchsorted(self.instants, t[-1], side="right"))
        if stop > self.done:
            self.values[self.done : stop] = np.interp(self.instants[self.done : stop], t, z)
            self.done = stop
        self.last = (float(t[-1]), float(z[-1]))

    def rates(self, omegas: Sequence[float] = TABLE1_OMEGAS) -> dict[str, float]:
        """``E(omega)`` for each omega, keyed by :func:`omega_key`."""
        values = self.values.copy()
        if self.last is not None:  # as np.interp does just past the last row: its value
            stop = int(np.searchsorted(self.instants, self.last[0] + END_TOLERANCE, side="right"))
            values[self.done : stop] = self.last[1]
        samples = len(values)
        return {omega_key(w): float(np.count_nonzero(values > w)) / samples for w in omegas}


def error_rate(
    t: np.ndarray,
    z1: np.ndarray,
    horizon: float,
    omegas: Sequence[float] = TABLE1_OMEGAS,
    samples: int = TABLE1_SAMPLES,
) -> dict[str, float]:
    """Error rate of Table 1 from a whole run's ``t`` and ``z_1`` (see the module docstring)."""
    stream = ErrorRateStream(horizon, samples)
    stream.add(np.asarray(t, dtype=float), np.asarray(z1, dtype=float))
    return stream.rates(omegas)
