"""Lemma 2's figure, the largest ``|e_zi|`` of each copy, folded as rows arrive (a
:class:`~.reductions.Reduction`), and in a batch taken over each copy's run alone's values.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .reductions import Chunk, Constant, MetricSettings, Reduction

# A batch's products (a (rows, batch, n) block times a matrix: BLAS's matrix product) round otherwise
# than a run alone's (one row of one copy at a time: a vector-matrix product). The largest Lemma 2
# errors of a batch are therefore taken at the rows that can hold them, recomputed as a run alone
# computes them: every value not recomputed is within SLACK * s of that rows' exact value, with s the
# row's largest |reading|, |q|, |y_d^(j)| times the coordinates' coefficient size (lemma2_slack).
SLACK = 2.0 ** -40  # a bound on the rounding of either evaluation, relative to s (about 2^13 times it)
CANDIDATES = 256  # rows a compiled fold notes per copy and block; past it the block is the array form's


def lemma2_slack(coordinates: Any) -> float:
    """``SLACK`` times the size of the backstepping coordinates' coefficients (after eq. (27)),
    ``(n + 1)(1 + sum |A| + sum |B|)``: what multiplies a row's largest input in the bound above."""
    A, B = coordinates.A, coordinates.B
    return SLACK * (A.shape[0] + 1) * (1.0 + float(np.abs(A).sum()) + float(np.abs(B).sum()))


def row_scale(x_meas: np.ndarray, x_q: np.ndarray, yd: np.ndarray) -> np.ndarray:
    """``(rows, batch)``: the largest |x_meas|, |x_q|, |y_d^(j)| of each row of each copy (NaN
    where one is NaN)."""
    largest = np.maximum(np.abs(x_meas).max(axis=-1), np.abs(x_q).max(axis=-1))
    return np.maximum(largest, np.abs(yd).max(axis=-1))


class Lemma2Largest(Reduction):
    """The largest finite Lemma 2 error ``|e_zi|`` per i, over every row before a divergence (the
    row that stopped a diverged copy holds an out-of-range state, where quantization error is
    meaningless).

    In a batch (``alone`` set by the record: Lemma 2's errors at given rows of given copies,
    derived as each copy's run alone derives them) the largest is taken over the values of a run
    alone: the rows whose batch value is within the slack of the largest are recomputed (the
    comment above :data:`SLACK`), so each copy's figure is its run alone's to the last bit. The
    compiled fold folds the errors of a traced row (derived by the recursion (31)-(34) itself,
    applied to the reading for z (eqs. (7)-(8)) and to q for zbar) and notes the rows to recompute."""

    name, signal, reads = "e_z_max", "e_z", ("e_z", "x_meas", "x_q", "yd")

    def __init__(self, batch: int, width: int, duration: float, settings: MetricSettings) -> None:
        super().__init__(batch, width, duration, settings)
        self.largest = np.full((batch, width), -np.inf)
        self.alone: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
        self.slack = 0.0

    def values(self, block: Mapping[str, Any]) -> Any:
        """e_z; in a batch, beside it what each row's slack is made of (:func:`row_scale`)."""
        if self.alone is None:
            return block["e_z"]
        return block["e_z"], block["x_meas"], block["x_q"], block["yd"]

    def add(self, chunk: Chunk, values: Any) -> None:
        counted = None if chunk.everyone else chunk.before_divergence[..., None]
        if self.alone is not None:
            values, *scaled = values
            values = self._as_alone(chunk, values, (row_scale(*scaled) * self.slack)[..., None], counted)
        checked = np.isfinite(values)
        if counted is not None:
            checked &= counted
        np.maximum(self.largest, np.where(checked, values, -np.inf).max(axis=0), out=self.largest)

    def _as_alone(self, chunk: Chunk, values: np.ndarray, slack: np.ndarray, counted: np.ndarray | None
                  ) -> np.ndarray:
        """``values`` with every row that may hold a copy's largest (or is not finite) recomputed
        as its run alone computes it."""
        low = values - slack  # (its values are at least these)
        kept = np.isfinite(low) if counted is None else np.isfinite(low) & counted
        floor = np.maximum(self.largest, np.where(kept, low, -np.inf).max(axis=0))
        maybe = ~(values + slack < floor)  # (NaN: recomputed)
        if counted is not None:
            maybe &= counted
        rows, copies = np.nonzero(maybe.any(axis=-1))
        if len(rows):
            values = values.copy()
            values[rows, copies] = self.alone(chunk.first + rows, copies)
        return values

    def value(self, b: int) -> np.ndarray:
        return self.largest[b].copy()

    @property
    def partials(self) -> tuple[float, ...]:  # type: ignore[override]
        """Per i a floor of the largest (its exact value, less the slack, over the rows so far),
        the count of rows noted, and the rows."""
        return (-math.inf,) * self.largest.shape[1] + (0.0,) + (math.nan,) * CANDIDATES

    def row_values(self, values: Any) -> list[Any]:
        """A traced row's errors, then the values its slack is made of."""
        if self.alone is None:
            raise TypeError("Lemma 2's errors of a run alone: nothing to recompute")
        return [value for signal in values for value in signal]

    def fold_lines(self, values: list[str], slot: int, t: str, constant: Constant) -> list[str]:
        n = self.largest.shape[1]
        count = f"fp[{slot + n}]"
        lines = [f"l2_s = max({', '.join(f'abs({v})' for v in values[n:])}) * {constant(self.slack)}",
                 "l2_new = False"]
        for i, error in enumerate(values[:n]):
            floor = f"fp[{slot + i}]"
            lines += [f"if {error} - l2_s > {floor}:", f"    {floor} = {error} - l2_s",
                      f"if not {error} + l2_s < {floor}:", "    l2_new = True"]
        return [*lines, "if l2_new:", f"    l2_c = int({count})", f"    if l2_c < {CANDIDATES}:",
                f"        fp[{slot + n + 1} + l2_c] = k", f"        {count} = l2_c + 1.0",
                "    else:  # too many: the block is the array form's", "        odd[b] = True"]

    def restart(self, partials: np.ndarray) -> None:
        partials[:, : self.largest.shape[1]] = self.largest

    def merge(self, copies: np.ndarray, partials: np.ndarray) -> None:
        n = self.largest.shape[1]
        count = partials[:, n].astype(np.intp)
        noted = np.flatnonzero(copies & (count > 0))
        if not len(noted):
            return
        held = np.arange(CANDIDATES)[None, :] < count[noted][:, None]
        rows = partials[noted, n + 1 :][held].astype(np.intp)
        owners = np.broadcast_to(noted[:, None], held.shape)[held]
        values = self.alone(rows, owners)
        np.maximum.at(self.largest, owners, np.where(np.isfinite(values), values, -np.inf))
