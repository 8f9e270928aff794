"""The error rate of the paper's Table 1, computed from a run's rows as they arrive.

``E(omega) = #{i : |z_1(t_i)| > omega} / M`` with ``t_i = i T / (M - 1)``, ``i = 0..M-1`` (the
paper's Table 1, Section 4; docs/math.md, 'Choices the paper leaves open', says how the instants
are sampled).
``z_1`` between recorded instants is interpolated linearly (it is continuous); instants after the
last finite row of a diverged run count as exceeding every omega. Feeding the rows in chunks gives
bit-identical results to feeding them at once: every instant is interpolated on the same pair of
rows, so a long run needs only ``M`` numbers, not its whole ``z_1``.

One :class:`ErrorRateStream` serves a whole batch of runs that share their time axis (a sweep
steps 1000 copies together): the interpolation is done for every copy at once, with the formula
of ``np.interp`` (and its values, bit for bit, which the tests check).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

TABLE1_OMEGAS = (0.100, 0.125, 0.150, 0.175, 0.200)
TABLE1_SAMPLES = 1302
END_TOLERANCE = 1e-12  # an instant this close after the last row takes the last row's value


def omega_key(omega: float) -> str:
    """Key of an error-rate entry in JSON outputs: ``0.1 -> "0.100"`` (three decimals when they
    hold the value exactly, otherwise the shortest form: ``0.0005 -> "0.0005"``)."""
    fixed = f"{omega:.3f}"
    return fixed if float(fixed) == omega else repr(float(omega))


def interpolated(ta, za, tc, zc, x):  # noqa: ANN001, ANN201 (floats or arrays; also compiled)
    """``np.interp``'s formula: the value at ``x`` on the line through ``(ta, za)`` and ``(tc, zc)``."""
    slope = (zc - za) / (tc - ta)
    return slope * (x - ta) + za


def follow_row(t, z, instants, values, b, ta, za, i):  # noqa: ANN001, ANN201 (numba's subset of Python)
    """The next row ``(t, |z_1|)`` of run ``b``, rows given one at a time in time order: the
    compiled batch's form of :meth:`ErrorRateStream.add`, the same numbers (every instant up to
    ``t`` takes its value on the same pair of rows, by :func:`interpolated`). ``(ta, za)``: the
    run's last finite row so far (NaN: none), ``i``: its instants with their value; returns them
    after this row (kept in the compiled loop's locals between rows, written back when it returns:
    stores every row would keep the compiler from holding anything in registers). A non-finite
    ``z`` is skipped, as there."""
    if not (z - z == 0.0):
        return ta, za, i
    while i < instants.shape[0] and instants[i] <= t:
        x = instants[i]
        if not (ta == ta) or t <= x:  # no row before (np.interp's left), or the row is at x
            values[i, b] = z
        else:
            values[i, b] = interpolated(ta, za, t, z, x)
        i += 1
    return t, z, i


class ErrorRateStream:
    """Accumulates ``|z_1|`` at the sample instants from rows given in time order, for ``batch``
    runs at once (column ``b`` of every array is run ``b``)."""

    def __init__(self, horizon: float, samples: int = TABLE1_SAMPLES, batch: int = 1) -> None:
        if samples < 2:
            raise ValueError("the error rate needs at least 2 samples")
        self.instants = np.arange(samples) * (horizon / (samples - 1))
        # inf: not covered (yet): counts as exceeding; stored run after run (the compiled batch
        # fills one run's instants after another: their values stay on a few memory pages)
        self.values = np.full((batch, samples), np.inf).T
        self.done = np.zeros(batch, dtype=np.intp)  # run b's instants [0, done[b]) have their value
        self.last_t = np.full(batch, np.nan)  # (t, |z_1|) of each run's last finite row so far
        self.last_z = np.full(batch, np.nan)

    def add(self, t: np.ndarray, z1: np.ndarray) -> None:
        """The next rows: instants ``t`` (rows,) and errors ``z1`` (rows, batch), or (rows,) for a
        single copy. Non-finite entries are skipped (a run's rows after it stopped are NaN)."""
        t = np.asarray(t, dtype=float)
        z = np.abs(np.asarray(z1, dtype=float).reshape(len(t), -1))
        # row 0: each run's last finite row before this chunk (NaN if none), rows 1..: the chunk
        z = np.vstack([self.last_z, z])
        t_rows = np.concatenate([[np.nan], t])

        def time_of(row: np.ndarray) -> np.ndarray:
            return np.where(row == 0, self.last_t, t_rows[row])

        finite = np.isfinite(z)
        rows, runs = np.arange(len(z))[:, None], np.arange(z.shape[1])
        # the finite row at or before each row, and the one at or after it (-1 / len(z): none)
        if finite.all():  # the usual chunk: every row itself
            before = after = np.broadcast_to(rows, z.shape)
        else:
            before = np.maximum.accumulate(np.where(finite, rows, -1), axis=0)
            after = np.minimum.accumulate(np.where(finite, rows, len(z))[::-1], axis=0)[::-1]
        last = before[-1]  # each run's last finite row in the chunk, or -1
        reach = np.where(last >= 0, time_of(np.maximum(last, 0)), -np.inf)
        stop = np.searchsorted(self.instants, reach, side="right")  # run b covers [0, stop[b])
        todo = self.done < stop
        if todo.any():
            first = int(self.done[todo].min())
            x = self.instants[first : int(stop.max()), None]  # (instants, 1)
            at = np.searchsorted(t, x[:, 0], side="right")[:, None]  # the last row with t <= x
            a = before[at, runs]  # the finite rows that bracket x: a (t <= x), c (after a)
            c = after[np.minimum(at + 1, len(z) - 1), runs]
            a = np.where(a < 0, c, a)  # before the first finite row: its value (np.interp's left)
            a, c = np.minimum(a, len(z) - 1), np.minimum(c, len(z) - 1)  # (none: not filled below)
            ta, za, tc, zc = time_of(a), z[a, runs], time_of(c), z[c, runs]
            with np.errstate(all="ignore"):  # the slope of a degenerate pair is not used
                # a row at x (or, before the first row, the first) gives its value
                value = np.where(ta >= x, za, interpolated(ta, za, tc, zc, x))
            index = np.arange(first, first + len(x))[:, None]
            fill = (index >= self.done) & (index < stop)
            self.values[first : first + len(x)] = np.where(fill, value, self.values[first : first + len(x)])
            self.done = np.maximum(self.done, stop)
        found = last >= 0
        self.last_t[found], self.last_z[found] = reach[found], z[last[found], runs[found]]

    def rates(self, omegas: Sequence[float] = TABLE1_OMEGAS, run: int = 0) -> dict[str, float]:
        """``E(omega)`` of run ``run`` for each omega, keyed by :func:`omega_key`."""
        return self.every_rate(omegas, np.array([run]))[0]

    def every_rate(self, omegas: Sequence[float] = TABLE1_OMEGAS, runs: np.ndarray | None = None
                   ) -> list[dict[str, float]]:
        """:meth:`rates` of each run of ``runs`` (default: all), counted for all of them at once."""
        # (runs, samples): a run's instants together, as stored (every run: a view, no copy)
        values = self.values.T if runs is None else self.values.T[runs]
        runs = np.arange(self.values.shape[1]) if runs is None else runs
        ended = np.isfinite(self.last_t[runs])  # as np.interp does just past the last row: its value
        stop = np.searchsorted(self.instants, self.last_t[runs] + END_TOLERANCE, side="right")
        tailed = np.flatnonzero(ended & (self.done[runs] < stop))  # (the runs with instants to fill)
        if len(tailed):
            values = values.copy()
            for r in tailed.tolist():
                values[r, self.done[runs[r]]:stop[r]] = self.last_z[runs[r]]
        samples = values.shape[1]
        counts = [np.count_nonzero(values > w, axis=1).tolist() for w in omegas]
        keys = [omega_key(w) for w in omegas]
        return [{key: float(count[b]) / samples for key, count in zip(keys, counts, strict=True)}
                for b in range(len(runs))]


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
