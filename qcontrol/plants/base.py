"""What the closed-loop engine uses of a plant, and the terms of eq. (1) every plant is built from.

A plant implements the core :class:`Plant` in array form, ``(batch, n)`` states and ``(batch,)``
inputs, and declares what else it can do as separate capabilities, each a protocol of its own:
:class:`Disturbable` (an external load), :class:`Actuated` (an actuator that may clip u),
:class:`PhysicsReport` (what the physics engine warned about, its agreement with eq. (1)),
:class:`ColumnStepping` (a step written over columns of any form, :mod:`qcontrol.columns`, in
which the engine may step a run) and :class:`NativeStepping` (source text for the engine's
compiled loop). A plant with only the core works at every batch size, and everywhere: each
optional part it lacks has its default here, in one place (:func:`actuator_of`,
:func:`physics_report`; a plant that is not :class:`Disturbable` takes no ``[[disturbance]]``, which
a run refuses before it starts; the scene and the inertia are the backend's,
:class:`~qcontrol.plants.backends.Backend`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..columns import Column, ColumnForm
from ..expr import Expression
from ..expr.rows import first_nonzero_row, regressor_rows

TIME = "t"  # the name of time in the plant's terms, their last variable when they use it


def timed(expression: Expression | None) -> bool:
    """Whether a term of eq. (1) depends on time: its variables are ``x1..xn, t``."""
    return expression is not None and expression.variables[-1:] == (TIME,)


def time_column(columns: Sequence[Column], expression: Expression, t: float) -> Sequence[Column]:
    """The columns a term is evaluated on: the state's, and ``t`` after them for a term in t."""
    return [*columns, t] if timed(expression) else columns


@dataclass(frozen=True)
class PlantTerms:
    """The right-hand side of eq. (1): ``x_i' = x_{i+1}``, ``x_n' = b u + psi(x) + theta^T phi(x)``,
    or of the wider parametric strict-feedback class (docs/math.md): ``x_i' = x_{i+1} +
    phi_i(x_1..x_i)^T theta`` for i < n.

    ``psi`` is unknown to the controller, ``phi`` (the last row, phi_n) known in form with
    ``theta`` unknown; ``b`` is the known input gain (``input_gain`` as the scenario states it;
    None when it does not, which means b = 1 and, on MuJoCo, a command scaled by the joint's
    inertia). ``rows`` holds the regressor rows phi_1 .. phi_{n-1} of the earlier equations when
    the scenario gives them (each of length l), else ``()``: the chain of eq. (1).
    """

    order: int
    psi: Expression | None
    phi: tuple[Expression, ...]
    theta: tuple[float, ...]
    input_gain: float | None = None
    rows: tuple[tuple[Expression, ...], ...] = ()

    @property
    def timed(self) -> bool:
        """Whether a term depends on time t (eq. (1)'s ``psi(x, t)``, ``phi(x, t)``)."""
        return any(timed(e) for e in self.expressions)

    @property
    def b(self) -> float:
        """The input gain b of ``x_n' = b u + ...`` (1 unless the scenario states another)."""
        return 1.0 if self.input_gain is None else float(self.input_gain)

    @property
    def first_nonzero_row(self) -> int | None:
        """The first equation i < n (1-based) whose regressor row has a term that is not 0, or
        None: the plant is then the chain of eq. (1), the paper's class."""
        return first_nonzero_row(self.rows)

    @property
    def regressor_rows(self) -> tuple[tuple[Expression, ...], ...]:
        """All n regressor rows phi_1 .. phi_n (rows not given: every entry the expression 0)."""
        return regressor_rows(self.order, self.phi, self.rows)

    # Two orders, each defined here once: eq. (1)'s sum ``psi + theta^T phi`` (psi first; the plants
    # add the terms in this order), and eqs. (37)-(43)'s, the order of eps and of a law's bounding
    # functions r (phi_1 .. phi_l, then psi; :attr:`bounded`).

    @property
    def bounded(self) -> list[tuple[str, Expression]]:
        """``(name, expression)`` of the terms in the order of eqs. (37)-(43): ``phi1`` .. ``phil``,
        then ``psi`` (if present); the order of eps and of the bounding functions r."""
        return [(f"phi{i + 1}", e) for i, e in enumerate(self.phi)] + (
            [("psi", self.psi)] if self.psi is not None else [])

    @property
    def names(self) -> list[str]:
        """Names of the terms of ``psi + theta^T phi`` in eq. (1)'s order: ``psi`` (if present),
        ``phi1`` .. ``phil``."""
        return (["psi"] if self.psi is not None else []) + [f"phi{i + 1}" for i in range(len(self.phi))]

    @property
    def expressions(self) -> list[Expression]:
        """The terms in the order of :attr:`names`: ``psi`` (if present), then ``phi``."""
        return ([self.psi] if self.psi is not None else []) + list(self.phi)

    @property
    def coefficients(self) -> list[float]:
        """Each term's coefficient in the order of :attr:`names`: 1 for ``psi``, theta_i for ``phi_i``."""
        return ([1.0] if self.psi is not None else []) + list(self.theta)


@runtime_checkable
class Plant(Protocol):
    """A batch of ``batch`` independent copies of an n-th order plant, eq. (1): the core every
    plant implements, in array form (``float64``; states ``(batch, n)``, inputs ``(batch,)``).

    The engine uses a plant as a context manager (``with plant: ...``; leaving the block calls
    :meth:`close`), so that backends with process-global resources (MuJoCo's passive callback)
    install and remove them safely; inside it, :meth:`reset`, then :meth:`observe` and
    :meth:`step` once per row.
    """

    n: int
    batch: int

    def __enter__(self) -> Plant: ...

    def __exit__(self, *exc: object) -> None: ...

    def reset(self, x0: np.ndarray) -> None:
        """Set the state of every copy; ``x0`` has shape ``(batch, n)``."""

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, reading)``: the true state (for the record and the metrics only; never given to a
        controller) and what the sensors report, which the engine quantizes before control; both
        ``(batch, n)``."""

    def step(self, u: np.ndarray, h: float) -> None:
        """Advance every copy by ``h`` seconds with the input ``u`` held (zero-order hold)."""

    def close(self) -> None:
        """Release what the run held (called when the ``with`` block ends)."""


@runtime_checkable
class Disturbable(Protocol):
    """A plant that takes an external load (``[[disturbance]]``)."""

    def disturb(self, d: float) -> None:
        """Apply the external load ``d`` to every copy from the next step on, until changed: a
        matched term ``x_n' = u + d + psi + theta^T phi`` in u's units (a generalized force ``F``
        on the joint is ``d = F / I``; see :mod:`qcontrol.disturbance`). :meth:`Plant.reset` sets
        it to 0."""


@runtime_checkable
class Actuated(Protocol):
    """A plant whose actuator may apply something else than the command (a torque limit)."""

    actuator_limited: bool  # whether the actuator can clip a command (False: actuator() is u)

    def actuator(self, u: np.ndarray) -> np.ndarray:
        """The input the plant applies for the commanded ``u`` (same units, same shape): ``u``
        clipped at the actuator's limit; where it does not clip, ``u`` exactly."""


@runtime_checkable
class PhysicsReport(Protocol):
    """A plant whose physics engine has something to tell users."""

    warnings: list[str]  # what the physics engine warned about during the last run
    consistency_report: dict[str, Any]  # how the model agrees with eq. (1)


# ---- the defaults of the optional capabilities, for a plant that lacks them

def applied_as_commanded(u: np.ndarray) -> np.ndarray:
    """The actuator of a plant that is not :class:`Actuated`: u is applied as commanded."""
    return u


def actuator_of(plant: Plant) -> tuple[Callable[[np.ndarray], np.ndarray], bool]:
    """The plant's actuator and whether it can clip a command (:class:`Actuated`); without the
    capability, u applied as commanded, never clipped."""
    if isinstance(plant, Actuated):
        return plant.actuator, plant.actuator_limited
    return applied_as_commanded, False


@dataclass(frozen=True)
class NoReport:
    """The :class:`PhysicsReport` of a plant without one: no physics engine to warn, nothing measured
    against eq. (1) (the plant is taken to be eq. (1))."""

    warnings: list[str] = field(default_factory=list)
    consistency_report: dict[str, Any] = field(default_factory=dict)


def physics_report(plant: Plant) -> PhysicsReport:
    """What the plant has to tell users (:class:`PhysicsReport`), or, without the capability, the
    default: no warnings and an empty consistency report."""
    return plant if isinstance(plant, PhysicsReport) else NoReport()


class ColumnIO(Protocol):
    """:meth:`Plant.observe` and :meth:`Plant.step` for one run in a column form: ``observe() ->
    (x, reading)``, each n columns of the form, ``step(u)`` with u a column of the form held over
    the run's step."""

    def observe(self) -> tuple[Sequence[Column], Sequence[Column]]: ...

    def step(self, u: Column) -> None: ...


@runtime_checkable
class ColumnStepping(Protocol):
    """A plant whose step is written over columns of any :class:`~qcontrol.columns.ColumnForm`."""

    def column_io(self, form: ColumnForm, h: float) -> ColumnIO:
        """The plant's :class:`ColumnIO` in ``form`` for steps of ``h``, made once per run inside
        the ``with`` block after :meth:`Plant.reset`; its numbers are the array form's, each
        column's operations the same."""


@dataclass
class NativeStepper:
    """One copy's observe and step as source text for the engine's compiled loop
    (:mod:`qcontrol.engine.compiled_loop`), with the numbers that text reads.

    The lines run inside the generated loop function: ``setup`` once per call, ``observe`` to set
    the locals ``x1 .. xn`` (true state) and ``m1 .. mn`` (reading), ``step`` to hold the local
    ``u`` over one step; ``step`` may ``return 2, k`` where it cannot give the Python form's
    numbers (the Python step then runs instead). They read the arrays ``pf`` (floats), ``pi``
    (integers) and ``xs`` (a state the compiled code keeps); ``helpers`` is module-level text
    (functions the lines call). ``key`` names what the text depends on besides itself.
    ``sync_in`` runs before each call (what Python may have changed: a load), ``sync_out``
    after it (what the plant's Python form reads: its state)."""

    key: str
    helpers: str
    setup: list[str]
    observe: list[str]
    step: list[str]
    floats: np.ndarray
    ints: np.ndarray
    state: np.ndarray
    sync_in: Any
    sync_out: Any


@runtime_checkable
class NativeStepping(Protocol):
    """A plant whose batch of one (and, if it says so, of copies) can run inside the engine's
    compiled loop."""

    def native_stepper(self, h: float, readings: int = 0, form: Any = None) -> NativeStepper | None:
        """The one copy's :class:`NativeStepper` for steps of ``h`` (inside the ``with`` block,
        after :meth:`Plant.reset`), or None where this run cannot be compiled (then the Python
        loop runs); it must give, bit for bit, the numbers of the Python loop. ``readings``: how
        many readings the run takes at most (its rows; what a plant drawing noise ahead needs).
        ``form``: a batch of copies asks with its ``TracedForm(batch)`` (the engine's compiled
        batch), and the stepper's numbers then have a row per copy; a plant without that form
        returns None for it."""
