"""How recordings draw the signals of the signal table (:data:`qcontrol.engine.signals.SIGNALS`):
:data:`PLOTS` maps a signal's name to its :class:`Plot` rows (entity path, legend label, colour,
twin styling, a bound drawn as a :class:`Guide`). A signal without an entry is recorded but not
drawn. The engine's table says what a signal is; this map says how it looks."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Guide:
    """Constant lines a recording draws in a plot's panel, the bound the plotted signal respects:
    one entity ``name`` in the panel, one line per legend label, at ``levels``, a function of the
    run's Lemma 2 bounds ``L_z`` (``L_z[0] = delta/2``, the quantizer's largest error)."""

    name: str
    labels: tuple[str, ...]
    levels: Callable[[np.ndarray], tuple[float, ...]]


def _lemma2_bound(L_z: np.ndarray) -> tuple[float, ...]:
    return (1.0,)


def _half_step(L_z: np.ndarray) -> tuple[float, ...]:
    return float(L_z[0]), -float(L_z[0])


LEMMA2_BOUND = Guide("bound", ("bound 1",), _lemma2_bound)
HALF_STEP = Guide("band", ("+delta/2", "-delta/2"), _half_step)


def law_panel_title(run: Any) -> str:
    """The title of the law's panel: the diagnostics the run's law declared, each by its caption
    (the paper's law: ``gain_period = K T of (44) ...``; a user's law: its own names)."""
    return "law diagnostics: " + "; ".join(d.caption for d in run.law_diagnostics)


@dataclass(frozen=True)
class Plot:
    """Where recordings draw a signal: one series per shown component, at ``path`` with the legend
    ``label`` (``{i}`` is the component's number from 1, ``{a}`` the adaptive state's name, ``{d}``
    the name of the law's diagnostic column; a path without ``{i}`` or ``{d}`` holds all components
    as instances of one entity). The path's parent is the
    series' panel (one plot of the layout: ``signals/input`` holds ``u`` and
    whatever else is drawn there); a panel the layout does not know becomes a tab of its own.
    ``components``: the ones shown (None: all); ``per_bound``: divided by the Lemma 2 bound L_zi;
    ``twin``: also drawn for a twin run (the ODE beside MuJoCo: MuJoCo wide, the twin thin on
    top); ``difference``: the panel where a twin's ``|main - twin|`` of it is drawn; ``guide``: the
    bound drawn as constant lines in the panel; ``color``: "main", "reference", "quantized",
    "applied" or "palette" (one colour per component); ``only_if_clipping``: drawn only for runs
    whose actuator could clip u (else ``u applied`` is u and is not drawn twice); ``title``: the
    title of the series' panel, made from the run (None: the layout's own title for the panel)."""

    path: str
    label: str
    components: tuple[int, ...] | None = None
    per_bound: bool = False
    twin: bool = False
    difference: str | None = None
    guide: Guide | None = None
    color: str = "main"
    only_if_clipping: bool = False
    only_if_input_quantized: bool = False  # drawn only for runs with an input quantizer ([quantizer.input])
    title: Callable[[Any], str] | None = None


PLOTS: Mapping[str, tuple[Plot, ...]] = {
    "x": (Plot("signals/tracking/y", "y", (0,), twin=True, difference="signals/difference/y"),
          Plot("signals/state/x{i}/x", "x{i}")),
    "x_q": (Plot("signals/state/x{i}/q", "q(x{i})", color="quantized"),),
    "u": (Plot("signals/input/u", "u", twin=True, difference="signals/difference/u"),),
    "u_applied": (Plot("signals/input/u_applied", "u applied", color="applied", only_if_clipping=True),),
    "u_quantized": (Plot("signals/input/u_quantized", "q_u(u)", color="quantized",
                         only_if_input_quantized=True),),
    "adaptive": (Plot("signals/adaptive/{a}", "{a}_{i}", color="palette"),),
    "yd": (Plot("signals/tracking/y_d", "y_d", (0,), color="reference"),),
    "z": (Plot("signals/error/z1", "z1", (0,), twin=True),),
    "e_z": (Plot("theory/lemma2/ratios", "|e_z{i}| / L_z{i}", per_bound=True, guide=LEMMA2_BOUND,
                 color="palette"),),
    "quantization_error": (Plot("signals/quantization/x{i}/error", "x{i} - q(x{i})", guide=HALF_STEP),),
    "diagnostics": (Plot("theory/law/{d}", "{d}", twin=True, color="palette", title=law_panel_title),),
}
