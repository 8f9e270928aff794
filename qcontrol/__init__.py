"""qcontrol: adaptive backstepping control of uncertain nonlinear systems with quantized states.

Implements Sun et al., "Global Adaptive Control for Uncertain Nonlinear Systems under
Non-Lipschitz Condition with Quantized States", Electronics 2022, 11, 3160. The data flow is
quantizer -> controller -> plant (ODE or MuJoCo) -> closed-loop engine -> recording/plots/metrics.

The Python API (docs/python.md, and the API reference of the documentation site):

* :func:`load_scenario` -> :class:`Scenario` (immutable; ``sc.with_overrides({...})``)
* :func:`run` -> :class:`Result` (``summary``, as JSON; ``typed_summary``, a frozen
  :class:`Summary` whose ``to_json()`` is that summary; the signals ``t, x, x_q, u, y, yd, z, adaptive``,
  ``save``, ``plot``); :func:`compare` -> :class:`Comparison` (``summary``, ``mujoco``, ``ode``);
  :func:`compare_laws` -> :class:`LawComparison` (several laws side by side: ``table``,
  ``runs``, ``plot``); :func:`sweep` -> the sweep's table (a dict per run); :func:`region` ->
  a :class:`~qcontrol.region.Region` (the region of attraction on a grid of initial states);
  :func:`reproduce` -> a :class:`~qcontrol.commands.Reproduction` (the paper's figures, Table 1
  and REPORT.md); :func:`check` -> a :class:`~qcontrol.commands.CheckReport` (a scenario
  validated without running it). ``qcontrol.sweep``, ``qcontrol.region`` and
  ``qcontrol.reproduce`` are these functions; the packages of the same names stay importable
  (``from qcontrol.sweep import ...``).
* :class:`Law` (one copy at a time; its state by RK4 of ``state_rate``, or by its own
  ``advance``) and :func:`register_law`, the one way to make a law a kind selected by
  ``controller.kind``; :func:`check_keys`, :func:`quantized_backstepping` and
  :func:`lemma2_bounds` help write one; a law with :class:`LawDiagnostics` declares
  :class:`Diagnostic` signals of its own (``Result.diagnostic(name)``, the summary, saved
  files); :func:`load_law_module` runs a file that registers laws
  (``--law-module``), :func:`load_law_plugins` the installed plugins (entry points ``qcontrol.laws``);
  :func:`expression` compiles a math expression as scenarios do (for a law's bounding function r).
* :class:`PaperLaw` (law (44)-(45)), :class:`ComparisonLaw` (law (46)) and their base
  :class:`BacksteppingLaw`: the built-in laws as public classes to subclass (the column form),
  registered with :func:`register_law` too and built from a :class:`LawContext`;
  :class:`Diagnostic` declares a law's own recorded signal.
"""

from ._version import __version__
from .api import (
    Comparison,
    Result,
    compare,
    lemma2_bounds,
    model_equation,
    model_scenario,
    quantized_backstepping,
    run,
    sweep,
)
from .commands import CheckReport, Reproduction, check, region, reproduce
from .controller.backstepping import BacksteppingLaw, ControlOutput
from .controller.comparison import ComparisonLaw
from .controller.kinds import register_law, removed_name
from .controller.law import Diagnostic, LawContext
from .controller.plugins import load_law_module, load_law_plugins
from .controller.proposed import PaperLaw
from .controller.user import Law, check_keys
from .controller.user_diagnostics import LawDiagnostics
from .errors import QcontrolInputError
from .expr import expression
from .law_comparison import LawComparison, compare_laws
from .scenario import Scenario, load_scenario
from .summary import Summary

__all__ = [
    "BacksteppingLaw",
    "CheckReport",
    "Comparison",
    "ComparisonLaw",
    "ControlOutput",
    "Diagnostic",
    "Law",
    "LawComparison",
    "LawContext",
    "LawDiagnostics",
    "PaperLaw",
    "QcontrolInputError",
    "Reproduction",
    "Result",
    "Scenario",
    "Summary",
    "__version__",
    "check",
    "check_keys",
    "compare",
    "compare_laws",
    "expression",
    "lemma2_bounds",
    "load_law_module",
    "load_law_plugins",
    "load_scenario",
    "model_equation",
    "model_scenario",
    "quantized_backstepping",
    "region",
    "register_law",
    "reproduce",
    "run",
    "sweep",
]


def __getattr__(name: str) -> object:
    """A public name that no longer exists: its one-line migration note (docs/laws.md, 'Migrating')."""
    note = removed_name(name)
    if note is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    raise AttributeError(note)
