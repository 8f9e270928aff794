"""The built-in laws as numba source for the engine's compiled loop (:mod:`.compiled_loop`).

Each law's column formulas (:class:`~qcontrol.controller.proposed.PaperLaw`, law (44)
with the adaptive law (45), either hold; :class:`~qcontrol.controller.comparison.ComparisonLaw`,
law (46)) written out as the same floating-point operations in the same order, over the locals
``q1 .. qn`` and the reference block ``yd[r, j]``: the recursion (31)-(34), the bounding functions
or the plant's terms (generated from their expression trees,
:func:`qcontrol.expr.source.float_source`), u, and the held targets of the advance. The constants
are read from the law and kept in the array ``lp`` (one compiled text serves every kappa, gamma,
...); ``held`` keeps u, the targets and zbar between samples. Where ``math`` would refuse an
evaluation (the Python form then takes numpy's answer), the lines ``return 1, k``: the row is not
written, and the Python loop runs from it.

A law is compiled only when its built-in class's ``has_compiled_equivalent`` says the compiled form
may stand in for it (:func:`law_source`); anything else keeps the Python loop.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..controller.backstepping import ControlOutput, output
from ..controller.comparison import ComparisonLaw
from ..controller.law import BatchLaw
from ..controller.proposed import PaperLaw
from ..expr.source import FLAG, Statements, float_source

REFUSED = "    return 1, k"


@dataclass(frozen=True)
class LawSource:
    """A law as lines of the generated loop: ``control`` (at a sample: sets ``held``), ``advance``
    (every step), the constants ``lp``, and how ``held`` becomes the Python loop's output."""

    key: str
    control: list[str]
    advance: list[str]
    constants: np.ndarray
    held_output: Callable[[np.ndarray], ControlOutput]


class Constants:
    """The array ``lp`` being filled: :meth:`add` a float, get the source that reads it."""

    def __init__(self) -> None:
        self.values: list[float] = []

    def add(self, value: float) -> str:
        self.values.append(float(value))
        return f"lp[{len(self.values) - 1}]"


def recursion_lines(law: BatchLaw, lp: Constants) -> list[str]:
    """Eqs. (31)-(34) as :meth:`~qcontrol.controller.backstepping.Backstepping.recursion`
    computes them: ``z{i}`` (zbar_i) and ``ab{i}`` (alphabar_i)."""
    lines = ["prev = yd[r, 0]"]
    for i, (minus_c, yd_terms, q_terms) in enumerate(law.coordinates.recursion_steps, start=1):
        lines += [f"z{i} = q{i} - prev", "dd = 0.0"]
        lines += [f"dd = dd + {lp.add(b)} * yd[r, {j}]" for j, b in yd_terms]
        lines += [f"dd = dd + {lp.add(a)} * q{k + 1}" for k, a in q_terms]
        lines += [f"prev = {lp.add(minus_c)} * z{i} + dd", f"ab{i} = prev"]
    return lines


def _evaluations(expressions: list, n: int, prefix: str) -> tuple[list[str], list[str]]:
    """Lines evaluating ``expressions`` on ``q1 .. qn`` (refusing where ``math`` would), and
    the names of their values."""
    body = Statements(prefix)
    names = [f"q{i + 1}" for i in range(n)]
    values = [float_source(e._tree, names, body) for e in expressions]
    return [f"{FLAG} = False", *body.lines, f"if {FLAG}:", REFUSED], values


def _held(n: int, m: int) -> list[str]:
    return [f"held[{1 + m + i}] = z{i + 1}" for i in range(n)]


def copy_value(value: float | np.ndarray) -> float:
    """A parameter of a batch of one (a number, or one per-copy value) as the float the text holds."""
    return float(np.ravel(value)[0])


def _folded(state: str, values: list[str]) -> str:
    """``reduce(add, map(mul, state, values))``: left to right."""
    return " + ".join(f"{state}[{i}] * {v}" for i, v in enumerate(values))


def proposed_source(law: PaperLaw, h: float) -> LawSource:
    """Law (44) with the adaptive law (45), as :meth:`PaperLaw.control` and
    :class:`~qcontrol.controller.proposed.DecayAdvance` compute them on floats."""
    n, m = law.n, law.state_size
    lp = Constants()
    kappa, gain = lp.add(copy_value(law.kappa)), lp.add(copy_value(1.0 / (law.kappa * (law.kappa - law.L))))
    sigma, L = lp.add(copy_value(law.sigma)), lp.add(law.L)
    rate = copy_value(law.gamma * law.sigma)
    decay = lp.add(float(np.exp(-np.asarray(rate) * h)))
    lines = recursion_lines(law, lp)
    evaluate, r = _evaluations(list(law.r), n, "t")
    lines += evaluate + [f"rv{i} = {v}" for i, v in enumerate(r)]
    scaled = not np.all(np.asarray(law.r_scale) == 1.0)
    if scaled:
        scale = lp.add(copy_value(law.r_scale))
        lines += [f"rv{i} = rv{i} * {scale}" for i in range(m)]
    rv = [f"rv{i}" for i in range(m)]
    lines += [f"zn = z{n}", f"s = zn * zn / {kappa} + {L}", f"robust = {_folded('adaptive', rv)}"]
    if law.hold == "paper":
        lines.append(f"held[0] = ab{n} - zn * s * robust * {gain}")
    else:
        period = lp.add(law.period)
        lines += [f"arg = -(s * robust * {gain}) * {period}", "e1 = math.expm1(arg)",
                  "if math.isinf(e1) and math.isfinite(arg):", REFUSED,  # math.expm1 raises there
                  f"held[0] = ab{n} - zn * (-e1 / {period})"]
    lines += [f"held[{1 + i}] = s * rv{i} / {sigma}" for i in range(m)] + _held(n, m)
    advance = [f"adaptive[{i}] = held[{1 + i}] + (adaptive[{i}] - held[{1 + i}]) * {decay}" for i in range(m)]
    key = f"proposed hold={law.hold} scaled={scaled} r={[e.source for e in law.r]}"
    return LawSource(key, lines, advance, np.array(lp.values), HeldOutput(n, m, rate).output)


def comparison_source(law: ComparisonLaw, h: float) -> LawSource:
    """Law (46) and its adaptive law, as :meth:`ComparisonLaw.control` and
    :class:`~qcontrol.controller.comparison.RateAdvance` compute them on floats."""
    n, m = law.n, law.state_size
    lp = Constants()
    gain, step = lp.add(law.adaptation_gain), lp.add(h)
    lines = recursion_lines(law, lp) + [f"uu = ab{n}"]
    if law.psi is not None:
        evaluate, (psi,) = _evaluations([law.psi], n, "s")
        lines += evaluate + [f"uu = uu - {psi}"]
    if law.phi:
        evaluate, phi = _evaluations(list(law.phi), n, "p")
        lines += evaluate + [f"pv{i} = {v}" for i, v in enumerate(phi)]
        lines.append(f"uu = uu - ({_folded('adaptive', [f'pv{i}' for i in range(m)])})")
        if law.known_theta is None:
            lines += [f"zn = z{n}"] + [f"held[{1 + i}] = {gain} * pv{i} * zn" for i in range(m)]
        else:
            lines += [f"held[{1 + i}] = 0.0" for i in range(m)]
    lines += ["held[0] = uu", *_held(n, m)]
    advance = [f"adaptive[{i}] = adaptive[{i}] + {step} * held[{1 + i}]" for i in range(m)]
    key = (f"comparison psi={None if law.psi is None else law.psi.source} "
           f"phi={[e.source for e in law.phi]} known={law.known_theta is not None}")
    return LawSource(key, lines, advance, np.array(lp.values), HeldOutput(n, m, 0.0).output)


class HeldOutput:
    """``held`` (u, targets, zbar) as the :class:`ControlOutput` the Python loop continues with."""

    def __init__(self, n: int, m: int, rate: float) -> None:
        self.n, self.m, self.rate = n, m, rate

    def output(self, held: np.ndarray) -> ControlOutput:
        values = held.tolist()
        m = self.m
        return output((values[0], tuple(values[1 + m:]), tuple(values[1:1 + m]), self.rate))


SOURCES: dict[type, Callable[..., LawSource]] = {
    PaperLaw: proposed_source,
    ComparisonLaw: comparison_source,
}


def law_source(law: BatchLaw, h: float) -> LawSource | None:
    """The law's compiled form, or None: a law of another class, one whose built-in class's
    ``has_compiled_equivalent`` is False (a subclass that defines anything of its own, an instance
    attribute the built-in class does not set: it may change the numbers), or per-copy
    parameters for more than one copy."""
    for base, make in SOURCES.items():
        if isinstance(law, base):
            # the built-in class's definition: a subclass's own property is itself a change
            if not base.has_compiled_equivalent.fget(law) or law.copies not in (None, 1):
                return None
            return make(law, h)
    return None
