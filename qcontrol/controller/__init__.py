"""Control laws with quantized states: the shared backstepping mathematics, the paper's law
(44)-(45), the comparison law (46), and the registry of controller kinds a scenario selects.

* :mod:`.backstepping`: coefficients, Lemma 2 bounds, the coordinates z / zbar / alphabar.
* :mod:`.law`: the :class:`BatchLaw` protocol the engine drives, and the kind registry.
* :mod:`.kinds`: :func:`register_law`, the one way a law becomes a kind (the built-in laws below
  are registered with it, as users' laws are).
* :mod:`.proposed`: law (44)-(45), :class:`PaperLaw`; :mod:`.comparison`: law (46) of reference
  [20], :class:`ComparisonLaw`: public classes to subclass.
* :mod:`.linear`: the plain linear law u = alphabar_n, the yardstick of the trade-off study.
* :mod:`.user`: the :class:`~.user.Law` protocol of a law written one copy at a time.
"""

from . import comparison, linear, proposed, tuning
from .backstepping import (
    Backstepping,
    ControlOutput,
    backstepping_coefficients,
    lemma2_bounds,
    lemma2_L,
)
from .comparison import ComparisonLaw
from .kinds import register_law, removed_name
from .law import (
    LAW_KINDS,
    AnyColumnForm,
    BatchLaw,
    LawContext,
    LawKeys,
    LawKind,
    law_kind,
    seal_built_in_kinds,
)
from .linear import LinearLaw
from .proposed import PaperLaw
from .tuning import TuningLaw

register_law("proposed", PaperLaw, keys=proposed.LAW_KEYS)
register_law("comparison", ComparisonLaw, keys=comparison.LAW_KEYS)
register_law("tuning", TuningLaw, keys=tuning.LAW_KEYS)
register_law("linear", LinearLaw, keys=linear.LAW_KEYS)
seal_built_in_kinds()


def __getattr__(name: str) -> object:
    """A name this package no longer has: its one-line migration note."""
    note = removed_name(name)
    if note is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    raise AttributeError(note)


__all__ = [
    "LAW_KINDS",
    "Backstepping",
    "ComparisonLaw",
    "BatchLaw",
    "ControlOutput",
    "AnyColumnForm",
    "LawContext",
    "LawKeys",
    "LawKind",
    "LinearLaw",
    "PaperLaw",
    "TuningLaw",
    "backstepping_coefficients",
    "law_kind",
    "lemma2_L",
    "lemma2_bounds",
    "register_law",
]
