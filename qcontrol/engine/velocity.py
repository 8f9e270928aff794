"""Where the controller's velocity x2 comes from: the velocity sensor, or the encoder's position
differenced over the control period (``simulation.velocity_source``).

``"sensor"`` (the paper's setting): every state is measured and quantized, x_q = q(x_meas).

``"difference"``, as on a joint with only an encoder: the controller's x2 is

    x2_q(t_k) = (q(x1_meas)(t_k) - q(x1_meas)(t_k - T)) / T,    T = the control period,

with q(x1_meas) taken as q(x1_meas)(0) before the run starts (so the first differences are 0).
The other states are quantized readings as before. This is outside the paper's assumptions: the
controller's x2 is not a quantized reading of x2, its error is not bounded by delta / 2 (it is
up to about delta / T plus the lag of the difference), and Lemma 2's bounds need not hold for
z_2 .. z_n. Runs report the Lemma 2 ratio anyway and say that the check does not apply.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from ..quantizer import QuantizedReading

VELOCITY_SOURCES = ("sensor", "difference")
Quantize = Callable[[Any], QuantizedReading]


def differenced(position: Any, past: Any, period: float) -> Any:
    """The differenced velocity: ``(q(x1)(t_k) - q(x1)(t_k - T)) / T`` with ``position`` the
    quantized position now and ``past`` the one ``period`` = T seconds before (floats, columns,
    or the compiled loop's traced symbols)."""
    return (position - past) / period


def lemma2_applies(velocity_source: str) -> bool:
    """Whether Lemma 2's premise (every state the controller sees is q of its reading) holds."""
    return velocity_source == "sensor"


class ArrayDifferencing:
    """``quantize`` with x2 replaced by the quantized position differenced over ``hold`` rows
    (``period`` seconds), for a batch in array form (a single run's: :mod:`.fastpath`). Called
    once per row, in order; one per run."""

    def __init__(self, quantize: Quantize, hold: int, period: float) -> None:
        self.inner, self.hold, self.period = quantize, hold, period
        self.past: deque[np.ndarray] = deque(maxlen=hold)  # q(x1) of the last `hold` rows, oldest first

    def quantize(self, values: np.ndarray) -> QuantizedReading:
        q = self.inner(values)
        out = np.array(q.values, dtype=float)
        q1 = out[:, 0].copy()
        if not self.past:
            self.past.extend([q1] * self.hold)
        out[:, 1] = differenced(q1, self.past[0], self.period)
        self.past.append(q1)
        return QuantizedReading(out, q.max_error, form=q.form)
