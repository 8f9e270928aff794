"""The ideal plant of eq. (1): a chain of integrators with unknown nonlinearities.

    x_i' = x_{i+1} (i < n),    x_n' = b u + psi(x) + theta^T phi(x)

or a parametric strict-feedback plant, ``x_i' = x_{i+1} + theta^T phi_i(x_1..x_i)`` for i < n
(docs/math.md; the equations whose regressor row is 0 are computed exactly as in the chain),
integrated with classical fixed-step RK4, the input held over each step. A fixed step is
deliberate: an adaptive-step solver either steps over the quantizer's jumps or crawls at them.

The state is kept as columns (:mod:`qcontrol.columns`), one value per state ``x_1 .. x_n``, and
:func:`_rk4` and ``psi + theta^T phi`` are written once over them with elementwise arithmetic, the
terms evaluated by the columns' form: ``(batch,)`` arrays and numpy in the array form, or
whatever form the engine steps a run in (:meth:`ChainPlant.column_io`). Same operations in the
same order in every form.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from typing import Any

import numpy as np

from ..columns import ARRAYS, Column, ColumnForm
from ..compiled import CALLED
from ..compiled.traced import TRACED, Symbol, Trace, TracedForm, recording
from ..expr import Expression
from ..expr.rows import is_zero
from .backends import Backend
from .base import NativeStepper, PlantTerms, timed

Rate = Callable[[list[Column]], Column]  # psi + theta^T phi on the state's columns
Lower = tuple[tuple[int, Rate], ...]  # (i - 1, theta^T phi_i) of each earlier equation with terms


class ChainPlant:
    """Batch of chain-of-integrator plants, eq. (1); the reference model for MuJoCo.

    ``theta`` has shape ``(l,)`` (shared by every copy) or ``(batch, l)`` (one row per copy, for
    parameter sweeps).
    """

    def __init__(
        self,
        n: int,
        psi: Expression | None,
        phi: Sequence[Expression],
        theta: Sequence[float] | np.ndarray,
        batch: int = 1,
        input_gain: float = 1.0,
        rows: Sequence[Sequence[Expression]] = (),
    ) -> None:
        theta = np.asarray(theta, dtype=float)
        if theta.shape[-1:] != (len(phi),) and not (theta.size == 0 and not phi):
            raise ValueError(f"phi has {len(phi)} terms but theta has {theta.shape[-1]} entries")
        if theta.ndim == 2 and theta.shape[0] != batch:
            raise ValueError(f"theta has {theta.shape[0]} rows (one per copy) but the batch is {batch}")
        self.n = int(n)
        self.batch = int(batch)
        self.psi = psi
        self.phi = tuple(phi)
        self.theta = theta
        self.input_gain = float(input_gain)  # b of x_n' = b u + ...: RK4 holds b u (u itself for b = 1)
        self.timed = any(timed(e) for e in (psi, *phi))  # terms in t: evaluated at each stage's time
        self._time = 0.0  # t of the state (advanced by h per step, as MuJoCo's data.time)
        # each phi_i's coefficient: a number, or a (batch,) column of per-copy values
        self._coefficients = list(theta.T if theta.ndim == 2 else theta)
        self._rates: dict[ColumnForm, Rate] = {}  # psi + theta^T phi in each form (_rate_in)
        # the earlier equations with a regressor that is not 0: (index i - 1, row), summed as theta^T phi_i
        self._rows = tuple((i, tuple(row)) for i, row in enumerate(rows) if any(not is_zero(e) for e in row))
        self._lower_rates: dict[ColumnForm, Lower] = {}
        self._form: ColumnForm = ARRAYS  # the form the state's columns are in (column_io)
        self._g: Rate = self._rate_in(ARRAYS)
        self._lower: Lower = self._lower_in(ARRAYS)
        self._x: list[Column] = [np.zeros(self.batch)] * self.n
        self._load = 0.0  # the external load d of :meth:`disturb`, held like u
        self.warnings: list[str] = []  # an ODE has nothing to warn about
        self.actuator_limited = False  # eq. (1)'s input is applied as commanded
        self.consistency_report: dict[str, Any] = {}  # it is eq. (1)

    def __enter__(self) -> ChainPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Nothing to release: the ODE holds no resources."""

    def _rate_in(self, form: ColumnForm) -> Rate:
        """``psi + theta^T phi`` on columns of ``form``, the terms summed in eq. (1)'s order (psi,
        then theta_i phi_i), made once per form."""
        rate = self._rates.get(form)
        if rate is None:
            psi = [self.psi] if self.psi is not None else []
            coefficients = [None] * len(psi) + self._coefficients
            rate = self._rates[form] = form.combination(psi + list(self.phi), coefficients)
        return rate

    def _lower_in(self, form: ColumnForm) -> Lower:
        """``(i, theta^T phi_i)`` on columns of ``form`` for each earlier equation whose regressor
        row is not 0 (none for the chain of eq. (1)), made once per form."""
        lower = self._lower_rates.get(form)
        if lower is None:
            lower = self._lower_rates[form] = tuple((i, form.combination(list(row), self._coefficients))
                                                    for i, row in self._rows)
        return lower

    def uncertainty(self, x: np.ndarray) -> np.ndarray:
        """``psi(x) + theta^T phi(x)``, shape ``(batch,)``."""
        total = self._rate_in(ARRAYS)(list(np.asarray(x, dtype=float).T))
        if np.ndim(total) == 0:  # psi and phi absent or constant
            return np.full(x.shape[:-1], float(total))
        return total

    def rhs(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Right-hand side of eq. (1)."""
        dx = np.empty_like(x)
        dx[:, :-1] = x[:, 1:]
        dx[:, -1] = self.input_gain * u + self.uncertainty(x)
        columns = list(np.asarray(x, dtype=float).T)
        for i, rate in self._lower_in(ARRAYS):
            dx[:, i] = dx[:, i] + rate(columns)
        return dx

    def reset(self, x0: np.ndarray) -> None:
        """Set the state (in the form the plant is stepped in) and clear the load."""
        self._x = self._form.columns(np.broadcast_to(np.asarray(x0, dtype=float), (self.batch, self.n)))
        self._load = 0.0
        self._time = 0.0

    def disturb(self, d: float) -> None:
        """The matched load d, held like u: ``x_n' = u + d + psi + theta^T phi``."""
        self._load = float(d)

    def actuator(self, u: np.ndarray) -> np.ndarray:
        """Eq. (1)'s input is applied as commanded."""
        return u

    def state(self) -> np.ndarray:
        return self._form.array(self._x, self.batch)

    def read_sensors(self) -> np.ndarray:
        return self.state()

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """The state and the reading: the ideal plant's sensors read the state exactly."""
        x = self.state()
        return x, x

    def step(self, u: np.ndarray, h: float) -> None:
        """One classical RK4 step of eq. (1) with ``u`` held."""
        if not (isinstance(u, np.ndarray) and u.shape == (self.batch,)):
            u = np.broadcast_to(np.asarray(u, dtype=float).reshape(-1), (self.batch,))
        _advance(self, self._form.column(u), h, self._g)

    def column_io(self, form: ColumnForm, h: float) -> ChainIO:
        """Observe and step in ``form``, steps of ``h`` (:class:`~.base.ColumnStepping`): the
        state is kept in ``form`` from now on, the same RK4 and terms evaluated in it."""
        x = self.state()
        self._form, self._g, self._lower = form, self._rate_in(form), self._lower_in(form)
        self._x = form.columns(x)
        return ChainIO(self, h)

    def native_stepper(self, h: float, readings: int = 0,
                       form: TracedForm = TRACED) -> NativeStepper | None:
        """One copy as source text for the engine's compiled loop: the same RK4 on the same terms
        (:class:`ChainNativeForm`), a batch of one in :data:`TRACED`, a batch of copies in
        ``TracedForm(batch)`` (per-copy theta in per-copy slots); None for an input gain other
        than 1, terms in t or regressors before the last equation (those run in Python).
        (``readings``: unused, the ODE reads its state as it is.)"""
        native = (self.batch == form.batch and self.input_gain == 1.0 and not self.timed
                  and not self._rows)
        return ChainNativeForm(self, h, form).stepper() if native else None


class ChainNativeForm:
    """The batch of one for the engine's compiled loop: :func:`_loaded`, :func:`_rk4` and ``psi +
    theta^T phi`` themselves, run once on the traced form (:mod:`qcontrol.compiled.traced`),
    which records their arithmetic as the source of one numba function ``plant_step(u, xs, pf)``
    (the same operations in the same order), which the loop calls at every step. ``pf`` holds the
    load d (``pf[0]``) and the constants the trace met (h, theta, RK4's own numbers), so one
    compiled text serves every theta; ``xs`` the state. :func:`_loaded` branches on the load, so
    it is recorded for a load and for none. Where ``math`` would refuse a term (the Python form
    then takes numpy's answer), the step returns True before writing the state, the loop returns
    2, and the Python step runs. For a batch of copies (``form`` a ``TracedForm(batch)``) ``pf``
    and ``xs`` have a row per copy (the generated loop hands each copy its own)."""

    def __init__(self, plant: ChainPlant, h: float, form: TracedForm = TRACED) -> None:
        self.plant, self.h, self.form = plant, h, form
        self.trace = Trace("pf", "p")
        self.load = self.trace.constant(plant._load)  # pf[0], kept up to date by sync_in
        self.helpers = self.step_function()
        batched = form.batch != 1
        self.floats = self.trace.table(form.batch if batched else None)
        self.state = plant.state().copy() if batched else plant.state()[0].copy()

    def step_function(self) -> str:
        """``plant_step(u, xs, pf) -> refused``: one step of ``h`` with ``u`` and the load held, as
        :meth:`ChainIO.step` makes it, recorded."""
        n, trace = self.plant.n, self.trace
        lines = []
        with recording(trace):
            for header, load in ((f"if {self.load} != 0.0:", Symbol(self.load, truth=True)), ("else:", 0.0)):
                held = trace.text(_loaded(Symbol("u"), load))
                lines += [header, *[f"    {line}" for line in trace.taken()], f"    uu = {held}"]
            with trace.deferring("return True"):  # (the state written after it)
                stepped = _rk4([Symbol(f"xs[{i}]") for i in range(n)], Symbol("uu"), self.h,
                               self.plant._rate_in(self.form))
                texts = [trace.text(v) for v in stepped]  # written after every refusal
        lines += trace.taken() + [f"xs[{i}] = {text}" for i, text in enumerate(texts)] + ["return False"]
        # called, not inlined by numba (whose IR inlining re-typed it at each of the loop's two
        # steps): compiled once per module, the same IEEE operations
        return (f"{CALLED}\n"
                "def plant_step(u, xs, pf):\n" + "".join(f"    {line}\n" for line in lines))

    def sync_in(self) -> None:
        self.floats[..., 0] = self.plant._load

    def sync_out(self) -> None:
        self.plant._x = self.plant._form.columns(self.state.reshape(self.plant.batch, self.plant.n))

    def stepper(self) -> NativeStepper:
        n = self.plant.n
        observe = [f"x{i} = xs[{i - 1}]" for i in range(1, n + 1)] + [f"m{i} = x{i}" for i in range(1, n + 1)]
        key = f"ode n={n} psi={self.plant.psi is not None} phi={len(self.plant.phi)}"
        step = ["if plant_step(u, xs, pf):", "    return 2, k"]
        return NativeStepper(key, self.helpers, [], observe, step, self.floats, np.zeros(1, dtype=np.int64),
                             self.state, self.sync_in, self.sync_out)


class ChainIO:
    """A :class:`ChainPlant`'s observe and step in the form of its columns
    (:meth:`ChainPlant.column_io`): ``observe()`` gives the state's columns twice (the sensors
    read it exactly; the engine only reads them), ``step(u)`` one RK4 step of ``h`` with u and the
    load d held (RK4 sees their sum)."""

    def __init__(self, plant: ChainPlant, h: float) -> None:
        self.plant, self.h, self.g = plant, h, plant._g

    def observe(self) -> tuple[list[Column], list[Column]]:
        x = self.plant._x
        return x, x

    def step(self, u: Column) -> None:
        _advance(self.plant, u, self.h, self.g)


def _advance(plant: ChainPlant, u: Column, h: float, g: Rate) -> None:
    """One RK4 step of eq. (1) from the plant's state with ``u`` held: ``x_n' = b u + d + ...``
    (the known input gain b, the load d), from the plant's time for terms in t; the rows before
    the last with their terms, if any (a strict-feedback plant)."""
    if plant.input_gain != 1.0:
        u = plant.input_gain * u
    u = _loaded(u, plant._load)
    if plant.timed:
        plant._x = _rk4(plant._x, u, h, g, plant._time, plant._lower)
        plant._time += h
    else:
        plant._x = _rk4(plant._x, u, h, g, None, plant._lower)


def _loaded(u: Column, d: float) -> Column:
    """The input RK4 holds over a step: ``u + d`` with the load d, u itself without one."""
    return u + d if d else u


def _derivative(s: list[Column], u: Column, g: Rate, t: float | None = None, lower: Lower = ()
                ) -> list[Column]:
    """The right-hand side of eq. (1) on columns: ``x_i' = x_{i+1}``, ``x_n' = u + g(x)``
    (``g(x, t)`` for terms in t, given the stage's time ``t``); with ``lower`` (a strict-feedback
    plant), ``x_i' = x_{i+1} + theta^T phi_i(x)`` for its rows."""
    rate = s[1:] + [u + (g(s) if t is None else g([*s, t]))]
    for i, term in lower:
        rate[i] = rate[i] + term(s)
    return rate


def _rk4(x: list[Column], u: Column, h: float, g: Rate, t: float | None = None, lower: Lower = ()
         ) -> list[Column]:
    """One classical RK4 step of eq. (1) on the state's columns (floats or arrays alike); for terms
    in t, from time ``t`` (stages at t, t + h/2, t + h/2, t + h, as MuJoCo's RK4)."""
    half = 0.5 * h
    mid, end = (None, None) if t is None else (t + half, t + h)
    k1 = _derivative(x, u, g, t, lower)
    k2 = _derivative([a + half * b for a, b in zip(x, k1, strict=True)], u, g, mid, lower)
    k3 = _derivative([a + half * b for a, b in zip(x, k2, strict=True)], u, g, mid, lower)
    k4 = _derivative([a + h * b for a, b in zip(x, k3, strict=True)], u, g, end, lower)
    sixth = h / 6.0
    return [a + sixth * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4, strict=True)]


# --------------------------------------------------------------------------------------------
# The "ode" backend: no keys of its own; theta may differ between the copies of a batch


def build(terms: Sequence[PlantTerms], options: Sequence[Any], dt: float) -> ChainPlant:
    """One ChainPlant copy per variant (theta per copy when there is more than one)."""
    first = terms[0]
    theta = first.theta if len(terms) == 1 else np.array([t.theta for t in terms])
    return ChainPlant(first.order, first.psi, first.phi, theta, batch=len(terms), input_gain=first.b,
                      rows=first.rows)


def structure(terms: PlantTerms, options: Any) -> Hashable:
    """Variants sharing a batch share the plant's form and input gain; theta goes per copy."""
    chain = (terms.order, None if terms.psi is None else terms.psi.source, tuple(p.source for p in terms.phi),
             terms.b)
    return chain + (tuple(tuple(p.source for p in row) for row in terms.rows),) if terms.rows else chain


BACKEND = Backend(name="ode", build=build, structure=structure,
                  summary="the ideal ODE of eq. (1), fixed-step RK4 (vectorised over batches)")
