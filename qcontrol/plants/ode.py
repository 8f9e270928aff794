"""The ideal plant of eq. (1): a chain of integrators with unknown nonlinearities.

    x_i' = x_{i+1} (i < n),    x_n' = u + psi(x) + theta^T phi(x)

integrated with classical fixed-step RK4, the input held over each step. A fixed step is
deliberate: an adaptive-step solver either steps over the quantizer's jumps or crawls at them.

The state is kept as columns, one value per state ``x_1 .. x_n``, and :func:`_rk4` is written once
over them with elementwise arithmetic: for a batch of one the columns are plain floats and the
terms are evaluated with ``math`` (a numpy call on a one-element array costs about a microsecond,
the same arithmetic on floats a few tens of nanoseconds), otherwise they are ``(batch,)`` arrays
and numpy evaluates the terms. Same operations in the same order; only ``sin``, ``cos``, ... come
from the C library instead of numpy on floats, which may differ in the last bit.
:meth:`ChainPlant.io` lets the engine's batch-of-one loop use the floats without making arrays.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from typing import Any

import numpy as np

from ..expr import Expression, ScalarFn, scalar_function
from .backends import Backend
from .base import IO, PlantTerms, array_io

Column = float | np.ndarray  # one value per copy: a (batch,) array, or a float for a batch of one
Uncertainty = Callable[[list[Column]], Column]  # psi + theta^T phi on the state's columns


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
        # (coefficient, term): a coefficient is a float, or a (batch,) column of per-copy values
        coefficients = theta.T if theta.ndim == 2 else theta
        self._terms = list(zip(coefficients, self.phi, strict=True))
        self._floats = self.batch == 1
        if self._floats:
            row = theta[0] if theta.ndim == 2 else theta  # the one copy's theta
            self._g: Uncertainty = _scalar_uncertainty(psi, phi, row)
        else:
            self._g = self._uncertainty_columns
        self._x: list[Column] = [0.0] * self.n if self._floats else [np.zeros(self.batch)] * self.n
        self._load = [0.0]  # the external load d of :meth:`disturb` (a cell the step closures read)
        self.warnings: list[str] = []  # an ODE has nothing to warn about
        self.actuator_limited = False  # eq. (1)'s input is applied as commanded
        self.consistency_report: dict[str, Any] = {}  # it is eq. (1)

    def __enter__(self) -> ChainPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def _uncertainty_columns(self, columns: Sequence[np.ndarray]) -> np.ndarray | float:
        """``psi + theta^T phi`` on columns (numpy), the terms summed in order."""
        total = self.psi.on_columns(columns) if self.psi is not None else None
        for coefficient, term in self._terms:
            value = coefficient * term.on_columns(columns)
            total = value if total is None else total + value  # (no 0.0 + value: a numpy call)
        return 0.0 if total is None else total

    def uncertainty(self, x: np.ndarray) -> np.ndarray:
        """``psi(x) + theta^T phi(x)``, shape ``(batch,)``."""
        total = self._uncertainty_columns(x.T)
        if np.ndim(total) == 0:  # psi and phi absent or constant
            return np.full(x.shape[:-1], float(total))
        return total

    def rhs(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Right-hand side of eq. (1)."""
        dx = np.empty_like(x)
        dx[:, :-1] = x[:, 1:]
        dx[:, -1] = u + self.uncertainty(x)
        return dx

    def reset(self, x0: np.ndarray) -> None:
        x0 = np.array(np.broadcast_to(x0, (self.batch, self.n)), dtype=float)
        self._x = x0[0].tolist() if self._floats else list(np.ascontiguousarray(x0.T))
        self._load[0] = 0.0

    def disturb(self, d: float) -> None:
        """The matched load d, held like u: ``x_n' = u + d + psi + theta^T phi``."""
        self._load[0] = float(d)

    def actuator(self, u: np.ndarray) -> np.ndarray:
        """Eq. (1)'s input is applied as commanded."""
        return u

    def state(self) -> np.ndarray:
        return np.array([self._x]) if self._floats else np.array(self._x).T

    def read_sensors(self) -> np.ndarray:
        return self.state()

    def step(self, u: np.ndarray, h: float) -> None:
        """One classical RK4 step of eq. (1) with ``u`` held."""
        if self._floats:
            u = float(np.ravel(u)[0])
        elif not (isinstance(u, np.ndarray) and u.shape == (self.batch,)):
            u = np.broadcast_to(np.asarray(u, dtype=float), (self.batch,))
        self._x = _rk4(self._x, u + self._load[0] if self._load[0] else u, h, self._g)

    def io(self, h: float) -> IO:
        """``observe() -> (x, reading)`` and ``step(u)`` (an RK4 step of ``h``) for one run; for a
        batch of one on plain floats, as closures made once per run. The ideal plant's sensors read
        the state exactly, so both are the state (the engine only reads them)."""
        if not self._floats:
            return array_io(self, h)
        g, load = self._g, self._load

        def observe() -> tuple[list[float], list[float]]:
            x = self._x
            return x, x

        def step(u: float) -> None:  # u and d are both held over the step: RK4 sees their sum
            d = load[0]
            self._x = _rk4(self._x, u + d if d else u, h, g)

        return observe, step


def _scalar_uncertainty(psi: Expression | None, phi: Sequence[Expression], theta: np.ndarray) -> Uncertainty:
    """``psi + theta^T phi`` on plain floats, summed in the order of :meth:`ChainPlant.uncertainty`.
    Where ``math`` refuses (a domain error, an overflow) the terms are evaluated again with
    :meth:`Expression.on_floats`, which gives numpy's answer (NaN, Inf) there."""
    coefficients = [float(c) for c in theta]
    fast = (scalar_function(psi) if psi is not None else None, [scalar_function(p) for p in phi])
    safe = (psi.on_floats if psi is not None else None, [p.on_floats for p in phi])

    def total(x: list[float], first: ScalarFn | None, terms: list[ScalarFn]) -> float:
        value = first(x) if first is not None else 0.0
        for coefficient, term in zip(coefficients, terms):  # noqa: B905 (equal lengths)
            value = value + coefficient * term(x)
        return value

    def uncertainty(x: list[float]) -> float:
        try:
            return total(x, *fast)
        except (ValueError, ZeroDivisionError, OverflowError):
            return total(x, *safe)

    return uncertainty


def _rk4(x: list[Column], u: Column, h: float, g: Uncertainty) -> list[Column]:
    """One classical RK4 step of eq. (1) on the state's columns (floats or arrays alike)."""
    half = 0.5 * h

    def rhs(s: list[Column]) -> list[Column]:
        return s[1:] + [u + g(s)]

    k1 = rhs(x)
    k2 = rhs([a + half * b for a, b in zip(x, k1, strict=True)])
    k3 = rhs([a + half * b for a, b in zip(x, k2, strict=True)])
    k4 = rhs([a + h * b for a, b in zip(x, k3, strict=True)])
    sixth = h / 6.0
    return [a + sixth * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4, strict=True)]


# --------------------------------------------------------------------------------------------
# The "ode" backend: no keys of its own; theta may differ between the copies of a batch


def build(terms: Sequence[PlantTerms], options: Any, dt: float) -> ChainPlant:
    """One ChainPlant copy per variant (theta per copy when there is more than one)."""
    first = terms[0]
    theta = first.theta if len(terms) == 1 else np.array([t.theta for t in terms])
    return ChainPlant(first.order, first.psi, first.phi, theta, batch=len(terms))


def structure(terms: PlantTerms, options: Any) -> Hashable:
    """Variants sharing a batch share the plant's form; theta goes per copy."""
    return terms.order, None if terms.psi is None else terms.psi.source, tuple(p.source for p in terms.phi)


BACKEND = Backend("ode", None, None, build, structure, lambda options, dt: None,
                  "the ideal ODE of eq. (1), fixed-step RK4 (vectorised over batches)")
