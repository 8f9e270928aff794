"""A plain linear law on the quantized readings: the certainty-equivalence backstepping law without
robust term or adaptation, and its scenario keys (docs/math.md, 'The linear law').

    u = alphabar_n(x_q, y_d, .., y_d^(n))                                          (L)

with alphabar_n of eqs. (31)-(34) for the scenario's gains c_i: the paper's law (44) with its
robust term left out, or law (46) with psi and theta^T phi left out. It is linear in x_q and the
reference (for n = 2, ``u = y_d'' - c_1 c_2 (q_1 - y_d) - (c_1 + c_2) (q_2 - y_d')``, a PD law with
``kp = c_1 c_2``, ``kd = c_1 + c_2`` and the reference's feedforward), knows nothing of psi or phi,
and has no state. It is the yardstick of the reproduction's trade-off study: what a law without
any of the paper's machinery does on the same quantized readings.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass

from ..quantizer import QuantizedReading
from ..schema import KindKeys, Table, read_keys
from .backstepping import Advance, BacksteppingLaw, Columns, ControlOutput, output
from .law import LawContext, LawKeys


class LinearLaw(BacksteppingLaw, compiled=True):
    """``u = alphabar_n`` (module docstring), computed by the recursion (31)-(34) every law shares
    (:meth:`~.backstepping.Backstepping.recursion`); no adaptive state. Supports the chain of
    eq. (1) only, like the paper's law: its alphabar_n is that chain's."""

    state_name = "none"
    copies = None

    @classmethod
    def from_context(cls, context: LawContext) -> LinearLaw:
        """The law for the scenario's gains ``c`` and quantizer."""
        return cls(context.c, context.max_error)

    def control(self, reading: QuantizedReading, yd: Sequence[float], state: Columns,
                t: float = 0.0) -> ControlOutput:
        """Law (L) at the quantized reading, in the reading's column form."""
        if not isinstance(reading, QuantizedReading) or reading.max_error != self.max_error:
            self.check_reading(reading)
        zbar, alphabar = self.recursion(reading.columns, yd)  # eqs. (31)-(34)
        return output((alphabar[-1], tuple(zbar), (), 0.0))

    def advancer(self, h: float) -> Advance:
        """No state to advance."""
        return unchanged


def unchanged(state: Columns, out: ControlOutput) -> Columns:
    """The (empty) state of a law without one, one step on."""
    return state


# --------------------------------------------------------------------------------------------
# Scenario keys: [controller] with kind = "linear" (no keys of its own: the gains are controller.c)

KEYS = KindKeys(
    "linear", (),
    meaning="the linear law u = alphabar_n of eqs. (31)-(34) with the gains c: law (44) without its robust "
            "term and adaptation (for n = 2 a PD law, kp = c1 c2, kd = c1 + c2, with feedforward)",
)


@dataclass(frozen=True)
class LinearSettings:
    """The linear law has no keys of its own."""


def parse(table: Table, ctx: LawContext) -> LinearSettings:
    """Refuse any key (the law has none; its gains are ``controller.c``)."""
    read_keys(table, KEYS.keys, {"n": ctx.order})
    return LinearSettings()


def structure(settings: LinearSettings, ctx: LawContext) -> Hashable:
    """Every variant shares a batch (c and delta are common to a batch already)."""
    return settings


LAW_KEYS = LawKeys(
    KEYS, parse, structure,
    divergence_hint="the linear law does not know psi or theta^T phi; a term that grows faster than "
    "linearly (x2^2) outgrows its gains at a large state, and high gains make the held input overshoot "
    "within a control period (docs/math.md, 'The linear law')",
)
