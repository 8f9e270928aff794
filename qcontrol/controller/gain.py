"""A known input gain b, ``x_n' = b u + psi + theta^T phi``: the built-in laws divided by it.

The paper's law (44), the comparison law (46) and every law of a kind that extends them compute
the input a plant of unit gain needs, ``u_1``; with a known gain b the plant needs
``u = u_1 / b`` to receive the same ``b u = u_1``. :func:`divided_by_gain` wraps such a law so that
its output is divided by b and nothing else changes (its coordinates, adaptive state and
diagnostics are the law's own). With b = 1 no wrapper is made: the law runs as it always did.

A law of your own (``qcontrol.register_law``, or a class that extends no built-in kind) is not
wrapped: it reads b as ``context.input_gain`` and divides its input itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..columns import ColumnForm
from ..quantizer import QuantizedReading
from .backstepping import Advance, Backstepping, Columns, ControlOutput
from .law import AnyColumnForm, BatchLaw


class DividedByGain:
    """``law`` with its input divided by the known gain ``b`` (a :class:`~.law.BatchLaw`)."""

    def __init__(self, law: BatchLaw, b: float) -> None:
        self.law, self.b = law, float(b)
        self.state_name, self.state_size = law.state_name, law.state_size
        self.copies, self.diagnostics = law.copies, law.diagnostics

    @property
    def coordinates(self) -> Backstepping:
        return self.law.coordinates

    def initial_state(self, batch: int) -> np.ndarray:
        return self.law.initial_state(batch)

    def control(self, reading: QuantizedReading, yd: Sequence[float], state: Columns,
                t: float = 0.0) -> ControlOutput:
        """The law's output with ``u`` replaced by ``u / b``."""
        out = self.law.control(reading, yd, state, t)
        return out._replace(u=out.u / self.b)

    def advancer(self, h: float) -> Advance:
        return self.law.advancer(h)

    def constants(self) -> dict[str, Any]:
        return self.law.constants() | {"input_gain": self.b}


class DividedByGainAnyForm(DividedByGain):
    """:class:`DividedByGain` of a law whose formulas serve any column form (it keeps that
    capability, :class:`~.law.AnyColumnForm`)."""

    def advancer_in(self, form: ColumnForm, h: float) -> Advance:
        return self.law.advancer_in(form, h)


def divided_by_gain(law: BatchLaw, b: float) -> BatchLaw:
    """``law`` whose input is divided by ``b`` (``law`` itself for b = 1)."""
    if b == 1.0:
        return law
    return DividedByGainAnyForm(law, b) if isinstance(law, AnyColumnForm) else DividedByGain(law, b)
