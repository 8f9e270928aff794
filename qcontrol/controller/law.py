"""What the closed-loop engine uses of a control law, and the registry of controller kinds.

A scenario's ``[controller] kind`` names an entry of :data:`LAW_KINDS`. Every entry, the
built-in laws' and users', is made by :func:`qcontrol.register_law` (:mod:`.kinds`) from a law
and its declared keys (:class:`LawKeys` for a law whose settings need more than their types
checked); the entry parses and checks the keys (the schema the scenario loader validates with
and the documentation is made from) and builds a :class:`BatchLaw` for a batch of variants.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..columns import ColumnForm
from ..errors import QcontrolInputError
from ..expr import Expression
from ..expr.rows import first_nonzero_row, regressor_rows
from ..quantizer import QuantizedReading
from ..schema import KindKeys, Table
from .backstepping import Advance, Backstepping, Columns, ControlOutput, lemma2_bounds

DIAGNOSTIC_REDUCTIONS = ("max", "last")
# The plant classes a law declares it supports: the chain of eq. (1) (terms in the last equation
# only: the paper's law (44)-(45) and law (46)), or the parametric strict-feedback plants, with a
# regressor row in every equation (docs/math.md).
CHAIN, STRICT_FEEDBACK = "chain", "strict-feedback"
PLANT_CLASSES = (CHAIN, STRICT_FEEDBACK)

# (x_q, yd, state) -> values: x_q a tuple of n columns, yd a tuple of n + 1 columns and state a
# tuple of m columns, each ``(rows, batch)``; returns ``(rows, batch)`` for a width of 1, else
# ``(rows, batch, width)``
Evaluate = Callable[[Columns, Columns, Columns], np.ndarray]


@dataclass(frozen=True)
class Diagnostic:
    """A signal a law declares beside the recorded ones: ``name``, ``width`` (columns), ``unit``,
    how a run's summary reduces it over the control samples (``reduce``: ``"max"``, the largest
    finite value, or ``"last"``, the value at the last sample kept; the summary key is
    ``<reduce>_<name>``), what it means, and how it is computed from what the engine records at a
    control sample (the quantized reading, the reference row and the law's state there:
    ``evaluate(x_q, yd, state)``, for many rows at once after the loop recorded them).

    Computing it from the record keeps the law's hot path untouched: a run gives the same
    numbers with or without its diagnostics. ``label`` is how a recording's panel title names it
    (default: its name, with its unit unless that is ``"-"``).

    A law written against the :class:`~.user.Law` protocol declares its diagnostics the same way
    (:class:`~.user_diagnostics.LawDiagnostics`), its ``evaluate`` then taking one copy's arrays.
    """

    name: str
    width: int
    unit: str
    reduce: str
    meaning: str
    evaluate: Evaluate = field(repr=False, compare=False)
    label: str = ""

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise QcontrolInputError(f"diagnostic name {self.name!r} must be letters, digits and _ only")
        if not (isinstance(self.width, int) and self.width >= 1):
            raise QcontrolInputError(f"diagnostic {self.name}: width must be a whole number >= 1")
        if self.reduce not in DIAGNOSTIC_REDUCTIONS:
            raise QcontrolInputError(f"diagnostic {self.name}: reduce must be one of "
                                     f"{', '.join(DIAGNOSTIC_REDUCTIONS)}, got {self.reduce!r}")

    @property
    def caption(self) -> str:
        """How a recording's panel title names it: ``label``, else its name (and unit)."""
        if self.label:
            return self.label
        return self.name if self.unit in ("", "-") else f"{self.name} [{self.unit}]"

    @property
    def summary_key(self) -> str:
        """Its key in summary.json: ``max_gain_period`` for ``gain_period`` reduced by max."""
        return f"{self.reduce}_{self.name}"


class BatchLaw(Protocol):
    """A control law for a batch of copies, as the engine drives it.

    The engine calls :meth:`control` at every control sample with the quantized reading (the only
    state the law may see), ``[y_d .. y_d^(n)]`` and the adaptive state as a tuple of columns
    (``(batch,)`` arrays: the array form, which every law implements and which serves every batch
    size), holds the output's ``u`` over the control period, and advances the adaptive state
    every step with the function :meth:`advancer` made once per run. ``coordinates`` defines the
    errors z, zbar and the Lemma 2 bounds the engine records and checks. A law whose formulas
    serve columns of any form (:mod:`qcontrol.columns`) says so with :class:`AnyColumnForm`.
    """

    state_name: str  # names the adaptive state in outputs: "eps_hat", "theta_hat", ...
    state_size: int  # m >= 0 adaptive states
    copies: int | None  # the batch size that per-copy parameters fix, or None
    diagnostics: tuple[Diagnostic, ...]  # the law's own signals (see :class:`Diagnostic`); may be ()

    @property
    def coordinates(self) -> Backstepping: ...

    def initial_state(self, batch: int) -> np.ndarray:
        """The adaptive state at t = 0, shape ``(batch, m)``."""

    def control(self, reading: QuantizedReading, yd: Sequence[float], state: Columns,
                t: float = 0.0) -> ControlOutput:
        """``u`` and the held terms that drive the adaptive state until the next sample."""

    def advancer(self, h: float) -> Advance:
        """``(state, output) -> state`` over a step ``h`` with the output held (array columns)."""

    def constants(self) -> dict[str, Any]:
        """The law's own constants as a recording shows them (kappa, gamma, ...)."""


@runtime_checkable
class AnyColumnForm(Protocol):
    """A capability: the law's formulas serve columns of any :class:`~qcontrol.columns.ColumnForm`.
    Its :meth:`~BatchLaw.control` works in the form of the reading it is given (``reading.form``:
    the reading's columns, the state and ``u`` all in that form), and :meth:`advancer_in` advances
    a state in a given form. The engine then runs a single run in the form it chooses
    (:mod:`qcontrol.engine.fastpath`); a law without it runs there through its array form."""

    def advancer_in(self, form: ColumnForm, h: float) -> Advance:
        """:meth:`~BatchLaw.advancer` for a state in ``form``."""


_MEMBERS: dict[type, tuple[tuple[str, bool], ...]] = {}  # a protocol's (member, is a method), by protocol
_MISSING = object()


def conforms(obj: object, protocol: type) -> bool:
    """``isinstance(obj, protocol)`` for a runtime-checkable protocol of this package, its members
    listed once: typing lists them again at every check (about 10 us; a batch of user laws checks
    each copy's law several times). ``obj`` conforms when it has every member, a method not None
    (typing's test); else only if its class derives from the protocol and typing says so (a class
    registered with the protocol, without the members, does not conform)."""
    members = _MEMBERS.get(protocol)
    if members is None:
        own = vars(protocol)
        methods = [name for name, value in own.items() if callable(value) and not name.startswith("_")]
        members = _MEMBERS[protocol] = (*((name, True) for name in methods),
                                        *((name, False) for name in own.get("__annotations__", {})))
    for name, method in members:
        value = getattr(obj, name, _MISSING)
        if value is _MISSING or (method and value is None):
            return protocol in type(obj).__mro__ and isinstance(obj, protocol)
    return True


def first_of(settings: Sequence[Any]) -> Any:
    """The settings of a batch whose variants share all of them: the first variant's."""
    return settings[0]


def no_settings() -> Mapping[str, Any]:
    """The settings of a context without a law's own table: an empty, read-only mapping."""
    return MappingProxyType({})


@dataclass(frozen=True)
class LawContext:
    """What a law is built from (public: a law class's ``from_context(context)`` reads it).

    * ``n`` (``order``): the plant order; ``delta`` and ``c``: the common controller keys
      (``max_error = delta / 2``, property (4)); with a ``[quantizer]`` table, ``quantizer_error``
      holds its bound per channel, which ``max_error`` then is (``delta`` is then twice the largest);
    * ``dt``: the simulation step; ``control_period`` (``T``): the time u is held, a whole number
      of steps (``dt`` when the scenario gives none);
    * ``psi``, ``phi``, ``theta``: the plant's terms (the comparison law (46) evaluates them at the
      quantized state; the paper's law counts them); ``rows``: the regressor rows phi_1 ..
      phi_{n-1} of a strict-feedback plant, when the scenario gives them (else ``()``), and
      :attr:`regressor_rows` all n rows;
    * ``settings``: the law's own keys, from ``[controller.<kind>]`` and ``[controller]``, as a
      read-only mapping (empty for the built-in kinds, whose keys are parsed into ``base``);
    * ``base``: the parsed, checked settings of the built-in kind the law is or extends
      (``[controller.proposed]`` for :class:`~.proposed.PaperLaw` and its subclasses, as a
      :class:`~.proposed.ProposedSettings`; ``[controller.comparison]`` for
      :class:`~.comparison.ComparisonLaw`), else None.

    ``input_gain`` is the plant's known input gain b (``x_n' = b u + ...``): the built-in laws
    compute their input for b = 1 and the package divides it by b; a law of your own divides
    its input by it itself.

    ``source`` names the scenario in messages; ``controller`` is the whole ``[controller]`` table
    while a scenario is read (None afterwards).
    """

    source: str
    order: int
    delta: float
    c: tuple[float, ...]
    psi: Expression | None
    phi: tuple[Expression, ...]
    theta: tuple[float, ...]
    dt: float = 1e-3
    control_period: float = 1e-3
    settings: Mapping[str, Any] = field(default_factory=no_settings)
    base: Any = None
    controller: Table | None = field(default=None, repr=False, compare=False)
    input_gain: float = 1.0
    quantizer_error: tuple[float, ...] | None = None  # per channel, from [quantizer] (None: delta / 2)
    rows: tuple[tuple[Expression, ...], ...] = ()

    @property
    def regressor_rows(self) -> tuple[tuple[Expression, ...], ...]:
        """The n regressor rows phi_1 .. phi_n of the plant (rows not given: "0" entries)."""
        return regressor_rows(self.order, self.phi, self.rows)

    @property
    def first_nonzero_row(self) -> int | None:
        """The first equation i < n whose regressor row is not 0, or None (the chain of eq. (1))."""
        return first_nonzero_row(self.rows)

    @property
    def n(self) -> int:
        """The plant order (``order``)."""
        return self.order

    @property
    def uncertain_terms(self) -> int:
        """Entries of eps, eqs. (37)-(43): one per phi_i, plus one for psi."""
        return len(self.phi) + (self.psi is not None)

    @property
    def max_error(self) -> float | tuple[float, ...]:
        """The quantizer's bound delta / 2, property (4); with a ``[quantizer]`` table, one bound
        m_i per channel (what Lemma 2's bounds and the law's L are computed from)."""
        return self.delta / 2.0 if self.quantizer_error is None else self.quantizer_error

    @property
    def L(self) -> float:
        """Lemma 2's ``L = L_zn`` for the gains c and the quantizer's bounds."""
        with np.errstate(all="ignore"):
            return float(lemma2_bounds(self.c, self.max_error)[0][-1])


@dataclass(frozen=True)
class LawKeys:
    """A law's declared keys when their types are not all it takes to read them (the built-in
    laws): ``keys``, the :class:`~qcontrol.schema.KindKeys` (name, type, default, unit, meaning of
    each, which docs/scenarios.md lists); ``parse(table, context) -> settings``, read and checked
    (Theorem 1's kappa > L, ...), handed to the law as ``context.base``; ``structure(settings,
    context)``, what the variants of one batch must share (the rest of their settings goes per
    copy); ``combine(settings list) -> settings``, the variants of a batch as one settings object
    (per-copy values as arrays); ``bounds(settings)``, the bounding functions r of eqs.
    (37)-(43) the law uses, whose separation is checked along single runs; ``divergence_hint``,
    what usually makes this law diverge, for the message of a diverged run; ``also_measure(settings)``,
    settings of the same kind that a study of the law measures beside it by default (``(key,
    value)`` pairs each, e.g. the paper's law held as printed: also its exact hold); ``plants``,
    the plant class it supports (:data:`PLANT_CLASSES`: a chain law is refused at load on a plant
    with a regressor before its last equation)."""

    keys: KindKeys
    parse: Callable[[Table, LawContext], Any]
    structure: Callable[[Any, LawContext], Hashable]
    combine: Callable[[Sequence[Any]], Any] = first_of
    bounds: Callable[[Any], tuple[Expression, ...]] | None = None
    divergence_hint: str = ""
    also_measure: Callable[[Any], tuple[tuple[tuple[str, str], ...], ...]] | None = None
    plants: str = CHAIN


@dataclass(frozen=True)
class LawKind:
    """One controller kind, an entry of :data:`LAW_KINDS`, as :func:`qcontrol.register_law`
    makes it.

    ``keys`` declares the keys of the kind for the scenario's schema (None: checked by the law's
    own code or by the names it declared); ``parse`` reads and checks them from the merged
    controller table into the kind's settings; ``build`` makes one law for a batch of variants
    that share ``structure(settings, context)`` (the settings that may differ within a batch
    become per-copy parameters); the first variant's context is passed. ``bounds`` and
    ``divergence_hint``, ``also_measure``, ``plants``: as :class:`LawKeys` says (a per-copy law
    sees the regressor rows in its context: ``plants`` is the strict-feedback class).
    ``extends``: the kind whose ``[controller.<kind>]`` settings it reads, if any.
    """

    name: str
    keys: KindKeys | None
    parse: Callable[[Table, LawContext], Any]
    build: Callable[[Sequence[Any], LawContext], BatchLaw]
    structure: Callable[[Any, LawContext], Hashable]
    bounds: Callable[[Any], tuple[Expression, ...]] | None = None  # its bounding functions r, if any
    divergence_hint: str = ""
    extends: str | None = None  # the built-in kind whose [controller.<kind>] settings it reads, if any
    declared: LawKeys | None = None  # its keys declared with their types and parsing, if so
    also_measure: Callable[[Any], tuple[tuple[tuple[str, str], ...], ...]] | None = None
    plants: str = STRICT_FEEDBACK  # the plant class the law supports (:data:`PLANT_CLASSES`)


LAW_KINDS: dict[str, LawKind] = {}
BUILT_IN_KINDS: set[str] = set()  # the package's own kinds (:func:`seal_built_in_kinds`): never replaced

KIND_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*\Z")  # a TOML bare key that starts like a name
KIND_NAME_RULE = "letters, digits, _ and -, starting with a letter or _"


def check_kind_name(name: object, what: str) -> str:
    """``name`` if it can name a controller kind (and its ``[controller.<kind>]`` table), else a
    one-line refusal saying which characters are allowed."""
    if not isinstance(name, str) or not KIND_NAME.match(name):
        raise QcontrolInputError(f"{what}: kind {name!r} must be {KIND_NAME_RULE} (e.g. \"ce\" or "
                                 "\"heldout-nominal\"); choose another")
    return name


def add_kind(kind: LawKind, *, replace: bool = False) -> None:
    """Add a controller kind (only :func:`qcontrol.register_law` calls this); its name must be
    new, unless ``replace`` is true and the kind it replaces is not built in."""
    if kind.name in KIND_ALIASES:
        raise QcontrolInputError(f"controller kind {kind.name!r} is a built-in name (of kind "
                                 f"{KIND_ALIASES[kind.name]!r}) and cannot be registered; choose another "
                                 "name")
    taken = LAW_KINDS.get(kind.name)
    if taken is not None and kind.name in BUILT_IN_KINDS:
        raise QcontrolInputError(f"controller kind {kind.name!r} is built in and cannot be replaced; "
                                 "choose another name")
    if taken is not None and not replace:
        raise QcontrolInputError(f"controller kind {kind.name!r} is already registered; choose another name "
                                 "or pass replace=True")
    LAW_KINDS[kind.name] = kind


def seal_built_in_kinds() -> None:
    """Mark every kind registered so far (the package's, at import) as built in."""
    BUILT_IN_KINDS.update(LAW_KINDS)


# Former names of kinds: a scenario written with one still loads, as the kind it now names.
KIND_ALIASES: dict[str, str] = {"baseline": "comparison"}


def check_plant_class(kind: str, ctx: LawContext, where: str) -> None:
    """Refuse a law that supports the chain of eq. (1) only on a plant with a regressor before its
    last equation: one line naming the first such row and the laws that apply."""
    row = ctx.first_nonzero_row
    if row is None or LAW_KINDS[kind].plants != CHAIN:
        return
    apply = [name for name, entry in LAW_KINDS.items() if entry.plants == STRICT_FEEDBACK]
    raise QcontrolInputError(
        f"{ctx.source}: {where}: law {kind!r} needs a chain x1' = x2, .., terms in the last equation only, "
        f"but plant.phi[{row - 1}] (the regressors of x{row}') is not 0; use a law for strict-feedback "
        f"plants: {', '.join(apply)}")


def law_kind(name: str) -> LawKind:
    """The registered kind ``name`` (the scenario loader has checked that it exists)."""
    return LAW_KINDS[name]
