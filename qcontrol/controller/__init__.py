"""Control laws with quantized states: the shared backstepping mathematics, the paper's law
(44)-(45), the comparison law (46), and the registry of controller kinds a scenario selects.

* :mod:`.backstepping`: coefficients, Lemma 2 bounds, the coordinates z / zbar / alphabar.
* :mod:`.law`: the :class:`BatchLaw` protocol the engine drives, and the kind registry.
* :mod:`.proposed`: law (44)-(45), :class:`PaperLaw`; :mod:`.comparison`: law (46) of reference
  [20], :class:`ComparisonLaw`: public classes to subclass (:mod:`.classes` registers them).
"""

from . import comparison, proposed
from .backstepping import (
    Backstepping,
    ControlOutput,
    backstepping_coefficients,
    lemma2_bounds,
    lemma2_L,
)
from .comparison import ComparisonController, ComparisonLaw
from .law import LAW_KINDS, AnyColumnForm, BatchLaw, LawContext, LawKind, law_kind, register_kind
from .proposed import PaperLaw, ProposedController

for _kind in (proposed.KIND, comparison.KIND):
    register_kind(_kind)

__all__ = [
    "LAW_KINDS",
    "Backstepping",
    "ComparisonController",
    "ComparisonLaw",
    "BatchLaw",
    "ControlOutput",
    "AnyColumnForm",
    "LawContext",
    "LawKind",
    "PaperLaw",
    "ProposedController",
    "backstepping_coefficients",
    "law_kind",
    "lemma2_L",
    "lemma2_bounds",
    "register_kind",
]
