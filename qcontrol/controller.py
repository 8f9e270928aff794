"""Backstepping controllers with quantized states: SPEC sections 3-8.

* :func:`backstepping_coefficients` - the constant coefficients of the virtual controls,
  recursion after eq. (27): ``alpha_i = sum_k a[i][k] x_k + sum_j b[i][j] y_d^(j)``.
* :func:`lemma2_bounds` - Lemma 2 (Appendix A): ``|z_i - zbar_i| <= L_zi``.
* :class:`Backstepping` - true errors z, eqs. (7), (8), (12), (20), (27), and quantized errors
  zbar, alphabar, eqs. (31)-(34).
* :class:`ProposedController` - control law (44) and adaptive law (45).
* :class:`BaselineController` - the comparison law of reference [20], eq. (46), with our
  reconstructed adaptive law (SPEC 8).

The formulas are written once, over *columns*: one value per state (``q_1 .. q_n``) or per
adaptive estimate, each either a ``(batch,)`` array or, for a batch of one, a plain Python float.
They use only elementwise arithmetic, coefficients precomputed as Python floats, and the compiled
expressions (numpy on arrays, ``math`` on floats: :meth:`Expression.on_floats`), so the same lines
step a batch of 1000 copies on numpy arrays and a single run on floats, where a numpy call on a
one-element array would cost a microsecond each. The engine (:mod:`qcontrol.sim`) passes columns;
:meth:`ProposedController.control` and friends also accept and return the arrays of shape
``(batch, n)`` / ``(batch, m)`` of the public interface, converting around the same formulas.

The proposed law's scalar parameters (kappa, gamma, sigma, r_scale) may also be given per copy, as
arrays of shape ``(batch,)``: a parameter sweep then runs as one batch, through the same formulas
(a single run is a batch of one with scalar parameters).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial, reduce
from operator import add, mul
from typing import NamedTuple

import numpy as np

from .errors import QcontrolInputError
from .expr import Expression, scalar_function
from .quantizer import QuantizedReading

Parameter = float | np.ndarray  # a scalar, or one value per copy of the batch (shape (batch,))
Column = float | np.ndarray  # one value per copy: a (batch,) array, or a float for a batch of one
Columns = tuple  # of Column: q_1 .. q_n, or the adaptive estimates
Evaluator = Callable[[Columns], Column]  # an expression evaluated on the reading's columns


def _parameter(name: str, value: float | Sequence[float] | np.ndarray) -> Parameter:
    """A controller constant as a float, or as a ``(batch,)`` array of per-copy values."""
    array = np.asarray(value, dtype=float)
    if array.ndim > 1 or array.size == 0:
        raise QcontrolInputError(f"controller {name} must be a number or a list of per-copy numbers")
    if not (np.all(np.isfinite(array)) and np.all(array > 0)):
        raise QcontrolInputError(f"controller {name} must be a finite number > 0, got {value!r}")
    return float(array) if array.ndim == 0 else array


def _as_float(value: Parameter) -> float:
    """A parameter of a batch of one as a plain float."""
    return float(np.ravel(value)[0])


def _stack(columns: Sequence[Column], batch: int) -> np.ndarray:
    """Columns (arrays or floats) side by side: shape ``(batch, len(columns))``, or more rows if
    the columns are longer (a state of one copy advanced with a batch's targets)."""
    if not columns:
        return np.empty((batch, 0))
    shape = np.broadcast_shapes((batch,), *(np.shape(c) for c in columns))
    return np.stack([np.broadcast_to(c, shape) for c in columns], axis=1)


def backstepping_coefficients(c: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of ``alpha_i`` in x and in the reference derivatives (SPEC 3).

    Returns ``A`` of shape ``(n, n)`` with ``A[i-1, k-1] = a[i][k]`` (zero for k > i) and ``B`` of
    shape ``(n, n+1)`` with ``B[i-1, j] = b[i][j]`` (coefficient of ``y_d^(j)``).
    """
    c = np.asarray(c, dtype=float)
    n = c.size
    A = np.zeros((n, n))
    B = np.zeros((n, n + 1))
    A[0, 0] = -c[0]
    B[0, 0], B[0, 1] = c[0], 1.0
    for i in range(1, n):  # row i holds alpha_{i+1}
        ci = c[i]
        A[i, 0] = ci * A[i - 1, 0]
        A[i, 1:i] = ci * A[i - 1, 1:i] + A[i - 1, 0 : i - 1]
        A[i, i] = -ci + A[i - 1, i - 1]
        B[i, 0] = ci * B[i - 1, 0]
        B[i, 1 : i + 2] = ci * B[i - 1, 1 : i + 2] + B[i - 1, 0 : i + 1]
    return A, B


def lemma2_bounds(c: Sequence[float], max_error: float) -> tuple[np.ndarray, np.ndarray]:
    """Lemma 2 (Appendix A): bounds ``L_z`` and ``L_alpha`` (both shape ``(n,)``).

    ``max_error`` is the quantizer's bound ``delta/2`` of property (4).
    ``L_z1 = delta/2``, ``L_alpha1 = c_1 delta/2``; ``L_zi = delta/2 + L_alpha(i-1)``,
    ``L_alphai = c_i L_zi + (delta/2) sum_{k<i} |a[i-1][k]|``. The paper's ``L`` is ``L_z[-1]``.
    """
    c = np.asarray(c, dtype=float)
    A, _ = backstepping_coefficients(c)
    n = c.size
    L_z = np.empty(n)
    L_alpha = np.empty(n)
    L_z[0] = max_error
    L_alpha[0] = c[0] * max_error
    for i in range(1, n):
        L_z[i] = max_error + L_alpha[i - 1]
        L_alpha[i] = c[i] * L_z[i] + max_error * np.abs(A[i - 1, :i]).sum()
    return L_z, L_alpha


class Backstepping:
    """Backstepping coordinates for gains ``c`` and a quantizer with bound ``max_error``."""

    def __init__(self, c: Sequence[float], max_error: float) -> None:
        c = np.asarray(c, dtype=float)
        if c.ndim != 1 or c.size < 2:
            raise QcontrolInputError(
                f"the plant order n must be >= 2 (one gain c_i per state), got {c.size} gain(s)"
            )
        if not np.all(np.isfinite(c)) or np.any(c <= 0):
            raise QcontrolInputError(f"every design gain c_i must be a finite number > 0, got {c.tolist()}")
        if not (np.isfinite(max_error) and max_error > 0):
            raise QcontrolInputError(f"quantizer step delta must be > 0, got bound {max_error!r}")
        self.c = c
        self.n = c.size
        self.max_error = float(max_error)
        self.A, self.B = backstepping_coefficients(c)
        self.L_z, self.L_alpha = lemma2_bounds(c, max_error)
        self.L = float(self.L_z[-1])
        # alphabar_i = -c_i zbar_i + D_i, eq. (34), with
        # D_1 = y_d',  D_i = sum_{k<i} a[i-1][k] q_{k+1} + sum_{j<i} b[i-1][j] y_d^(j+1),
        # kept as (index, coefficient) lists of plain floats, zero terms left out.
        n = self.n
        Dq = np.zeros((n, n))
        Dy = np.zeros((n, n + 1))
        Dy[0, 1] = 1.0
        for i in range(1, n):
            Dq[i, 1 : i + 1] = self.A[i - 1, :i]
            Dy[i, 1 : i + 2] = self.B[i - 1, : i + 1]
        # one (-c_i, D_i's y_d terms, D_i's q terms) per i, zipped once (the recursion's hot loop)
        self._steps = tuple(zip(
            [-ci for ci in c.tolist()],
            [tuple((j, b) for j, b in enumerate(row) if b != 0.0) for row in Dy.tolist()],
            [tuple((k, a) for k, a in enumerate(row) if a != 0.0) for row in Dq.tolist()],
            strict=True,
        ))
        # [zbar | alphabar] = q @ Wq + yd @ Wy (for many instants at once, when recording): the
        # recursion applied to unit vectors, as columns of a batch of n (or n + 1) copies
        zbar, alphabar = self._recursion(tuple(np.eye(n)), tuple(np.zeros((n + 1, n))))
        self._Wq = np.column_stack(zbar + alphabar)
        zbar, alphabar = self._recursion(tuple(np.zeros((n, n + 1))), tuple(np.eye(n + 1)))
        self._Wy = np.column_stack(zbar + alphabar)

    def errors(self, x: np.ndarray, yd: np.ndarray) -> np.ndarray:
        """True errors ``z`` (eqs. (7), (8)): ``z_1 = x_1 - y_d``, ``z_i = x_i - alpha_{i-1}``.

        ``x`` has shape ``(..., n)``; ``yd`` holds ``[y_d, ..., y_d^(n)]`` in its last axis and
        broadcasts against ``x`` (e.g. ``(n+1,)`` for one instant, ``(rows, 1, n+1)`` for many).
        """
        alpha = x @ self.A.T + yd @ self.B.T
        z = np.empty(np.broadcast_shapes(x.shape, alpha.shape))
        z[..., 0] = x[..., 0] - yd[..., 0]
        z[..., 1:] = x[..., 1:] - alpha[..., :-1]
        return z

    def quantized_errors(self, q: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Quantized errors ``zbar`` and virtual controls ``alphabar``, eqs. (31)-(34).

        Shapes as in :meth:`errors`, with the quantized state ``q`` in place of ``x``. Both are
        linear in ``(q, y_d)``: one product with the coefficients :meth:`_recursion` gives.
        """
        both = q @ self._Wq + yd @ self._Wy
        return both[..., : self.n], both[..., self.n :]

    def _recursion(self, q: Columns, yd: Sequence[Column]) -> tuple[list[Column], list[Column]]:
        """Eqs. (31)-(34) as written, over columns: ``zbar_1 = q_1 - y_d``,
        ``alphabar_i = -c_i zbar_i + D_i``, ``zbar_{i+1} = q_{i+1} - alphabar_i``.

        ``q`` holds the columns ``q_1 .. q_n``, ``yd`` the values ``y_d .. y_d^(n)`` (floats, the
        same for every copy). The control laws call this every sample; ``__init__`` evaluates it
        once on unit vectors for :meth:`quantized_errors`.
        """
        zbar: list[Column] = []
        alphabar: list[Column] = []
        previous = yd[0]  # zbar_1 = q_1 - y_d
        for qi, (minus_c, yd_terms, q_terms) in zip(q, self._steps):  # noqa: B905 (n of each)
            z = qi - previous
            d = 0.0
            for j, b in yd_terms:
                d = d + b * yd[j]
            for k, a in q_terms:
                d = d + a * q[k]
            previous = minus_c * z + d
            zbar.append(z)
            alphabar.append(previous)
        return zbar, alphabar

    def _refuse(self, reading: object) -> None:
        """Raise for anything but a :class:`QuantizedReading` made with this controller's bound."""
        if not isinstance(reading, QuantizedReading):
            raise TypeError(
                "controllers accept only QuantizedReading (use qcontrol.quantizer.quantize); "
                f"got {type(reading).__name__}"
            )
        raise ValueError(
            f"reading quantized with bound {reading.max_error}, but the controller's Lemma 2 "
            f"bounds assume {self.max_error}"
        )


class ControlOutput(NamedTuple):
    """One controller evaluation: input ``u``, ``zbar``, and the held quantities that drive the
    adaptive state until the next sample.

    Array form (``control`` given a ``(batch, m)`` state): ``u`` (batch,), ``zbar`` (batch, n),
    ``target`` (batch, m). Column form (given a tuple of m columns, as the engine does): ``u`` a
    column, ``zbar`` and ``target`` tuples of columns, ``rate`` a float or a ``(batch,)`` array.
    """

    u: np.ndarray
    zbar: np.ndarray
    target: np.ndarray  # proposed: s r / sigma; baseline: Gamma phi zbar_n (a rate)
    rate: float | np.ndarray  # proposed: gamma sigma, a float or per copy; baseline: 0


# ControlOutput((u, zbar, target, rate)) without NamedTuple's Python-level __new__ (hot loop)
_output = partial(tuple.__new__, ControlOutput)


class _Law(NamedTuple):
    """The constants the column formulas read, for one kind of column (arrays, or floats)."""

    kappa: Parameter
    gain: Parameter  # 1 / (kappa (kappa - L))
    sigma: Parameter
    r_scale: Parameter | None  # None when r_scale == 1 everywhere
    rate: Parameter  # gamma sigma
    terms: tuple  # evaluators of the expressions (r, or psi and phi) on the reading's columns


class ProposedController(Backstepping):
    """The paper's quantized adaptive controller, control law (44) and adaptive law (45).

    ``s = zbar_n^2 / kappa + L``,
    ``u = -(zbar_n / kappa) / (kappa - L) * s * eps_hat^T r(x_q) + alphabar_n``,
    ``eps_hat' = gamma (s r(x_q) - sigma eps_hat)``, ``eps_hat(0) = 0``.

    ``r`` are the bounding functions of eqs. (37)-(43), expressions over ``q1..qn``; each is
    multiplied by ``r_scale`` (any constant >= 1 keeps the bounds valid, SPEC 6).
    """

    state_name = "eps_hat"

    def __init__(
        self,
        c: Sequence[float],
        max_error: float,
        kappa: float,
        gamma: float,
        sigma: float,
        r: Sequence[Expression],
        r_scale: float = 1.0,
        expected_terms: int | None = None,
    ) -> None:
        super().__init__(c, max_error)
        gamma, sigma, r_scale = (_parameter(k, v) for k, v in (("gamma", gamma), ("sigma", sigma),
                                                                 ("r_scale", r_scale)))
        kappa_array = np.asarray(kappa, dtype=float)
        if not (np.all(np.isfinite(kappa_array)) and np.all(kappa_array > self.L)):
            raise QcontrolInputError(
                f"controller kappa must exceed L = L_z{self.n} = {self.L:g} (Theorem 1), got {kappa!r}"
            )
        kappa = _parameter("kappa", kappa)
        if len(r) == 0:
            raise QcontrolInputError("controller r must list at least one bounding function")
        if expected_terms is not None and len(r) != expected_terms:
            raise QcontrolInputError(
                f"controller r has {len(r)} bounding function(s) but the plant has "
                f"{expected_terms} uncertain term(s) (one per phi_i, plus one for psi)"
            )
        sizes = {v.size for v in (kappa, gamma, sigma, r_scale) if isinstance(v, np.ndarray)}
        if len(sizes) > 1:
            raise QcontrolInputError(f"controller per-copy parameters have different lengths {sorted(sizes)}")
        self.copies: int | None = sizes.pop() if sizes else None  # batch size the parameters fix
        self.kappa = kappa
        self.gamma = gamma
        self.sigma = sigma
        self.r = tuple(r)
        self.r_scale = r_scale
        self.state_size = len(self.r)
        # precomputed once: eq. (45)'s decay rate gamma sigma, and (44)'s gain
        rate = gamma * sigma
        self._rate = rate[:, None] if isinstance(rate, np.ndarray) else rate  # array form of ControlOutput
        gain = 1.0 / (kappa * (kappa - self.L))  # (44): u = -zbar_n s eps^T r / (kappa (kappa - L))
        scaled = not np.all(np.asarray(r_scale) == 1.0)
        self._on_arrays = _Law(kappa, gain, sigma, r_scale if scaled else None, rate,
                               tuple(e.on_columns for e in self.r))
        # on floats: math's evaluation (scalar_function); where it raises, control() falls back to
        # Expression.on_floats, which gives numpy's answer (NaN, Inf) there
        self._on_floats = None if self.copies not in (None, 1) else _Law(
            _as_float(kappa), _as_float(gain), _as_float(sigma), _as_float(r_scale) if scaled else None,
            _as_float(rate), tuple(scalar_function(e) for e in self.r))

    def initial_state(self, batch: int) -> np.ndarray:
        """``eps_hat(0) = 0``."""
        return np.zeros((batch, self.state_size))

    def bounding_functions(self, q: np.ndarray) -> np.ndarray:
        """``r(x_q)`` with shape ``(..., len(r))``."""
        columns = q.T if q.ndim == 2 else np.moveaxis(q, -1, 0)
        r = [term(columns) for term in self._on_arrays.terms]
        if self._on_arrays.r_scale is not None:
            r = [ri * self._on_arrays.r_scale for ri in r]
        return np.stack([np.broadcast_to(ri, q.shape[:-1]) for ri in r], axis=-1)

    def control(self, reading: QuantizedReading, yd: Sequence[float],
                eps_hat: np.ndarray | Columns) -> ControlOutput:
        """Eq. (44) for the current quantized reading; eq. (45)'s held terms for :meth:`advance`.

        ``eps_hat`` is a tuple of m columns (column form, as the engine passes it; floats when
        ``reading.floats``), or a ``(batch, m)`` array: the same formulas then run on the array's
        columns and the output is in array form. ``yd`` holds ``y_d .. y_d^(n)``.
        """
        if not isinstance(reading, QuantizedReading) or reading.max_error != self.max_error:
            self._refuse(reading)
        if isinstance(eps_hat, np.ndarray):
            out = self.control(QuantizedReading(reading.values, reading.max_error), yd, tuple(eps_hat.T))
            batch = len(eps_hat)
            return ControlOutput(out.u, _stack(out.zbar, batch), _stack(out.target, batch), self._rate)
        law = self._on_floats if reading.floats else self._on_arrays
        if law is None:
            raise ValueError(f"the controller has per-copy parameters for {self.copies} copies, not one")
        q = reading.columns
        zbar, alphabar = self._recursion(q, yd)  # eqs. (31)-(34)
        try:
            r = [term(q) for term in law.terms]  # r(x_q)
        except (ValueError, ArithmeticError):  # math's domain error or overflow (floats only)
            r = [e.on_floats(q) for e in self.r]
        if law.r_scale is not None:
            r = [ri * law.r_scale for ri in r]
        zn = zbar[-1]
        s = zn * zn / law.kappa + self.L
        robust = reduce(add, map(mul, eps_hat, r))  # eps_hat^T r(x_q), per copy, summed in order
        u = alphabar[-1] - zn * s * robust * law.gain  # eq. (44)
        sigma = law.sigma
        return _output((u, zbar, [s * ri / sigma for ri in r], law.rate))

    def advance(self, state: np.ndarray | Columns, out: ControlOutput, h: float) -> np.ndarray | Columns:
        """Integrate eq. (45) over ``h`` with ``x_q`` held: exact for the linear ODE
        ``eps_hat' = gamma sigma (target - eps_hat)``. ``state`` and ``out`` in the same form
        (array or columns) as :meth:`control` took and gave them."""
        if isinstance(state, np.ndarray):
            eps = self.advance(tuple(state.T), out._replace(target=tuple(out.target.T)), h)
            return _stack(eps, len(state))
        return self.advancer(h, floats=not isinstance(out.u, np.ndarray))(state, out)

    def advancer(self, h: float, floats: bool) -> Callable[[Columns, ControlOutput], Columns]:
        """:meth:`advance` over a fixed ``h`` in column form, as a function ``(state, out) ->
        state`` made once per run: ``exp(-gamma sigma h)`` is computed here, not every step."""
        law = self._on_floats if floats else self._on_arrays
        if law is None:
            raise ValueError(f"the controller has per-copy parameters for {self.copies} copies, not one")
        decay = np.exp(-np.asarray(law.rate) * h)
        decay = decay if decay.ndim else float(decay)

        def advance(state: Columns, out: ControlOutput) -> Columns:
            # zip without strict=: the lengths are equal by construction (strict= costs ~0.3 us)
            return tuple([t + (e - t) * decay for e, t in zip(state, out.target)])  # noqa: B905

        return advance


class BaselineController(Backstepping):
    """Comparison law of reference [20], eq. (46), as SPEC 8 reconstructs it.

    ``u = alphabar_n - psi(x_q) - theta_hat^T phi(x_q)`` with
    ``theta_hat' = Gamma phi(x_q) zbar_n`` (our reconstruction; the paper does not print it), or
    ``theta_hat = theta`` held fixed when ``known_theta`` is given.
    """

    state_name = "theta_hat"

    def __init__(
        self,
        c: Sequence[float],
        max_error: float,
        psi: Expression | None,
        phi: Sequence[Expression],
        adaptation_gain: float = 1.0,
        known_theta: Sequence[float] | None = None,
    ) -> None:
        super().__init__(c, max_error)
        if not (np.isfinite(adaptation_gain) and adaptation_gain > 0):
            raise QcontrolInputError(
                f"baseline adaptation gain Gamma must be a finite number > 0, got {adaptation_gain!r}"
            )
        self.psi = psi
        self.phi = tuple(phi)
        self.adaptation_gain = float(adaptation_gain)
        self.known_theta = None if known_theta is None else np.asarray(known_theta, dtype=float)
        self.state_size = len(self.phi)
        # (psi or None, phi...) evaluated on the reading's columns: numpy, or math on floats
        exprs = (self.psi, *self.phi)
        self._on_arrays = tuple(None if e is None else e.on_columns for e in exprs)
        self._on_floats = tuple(None if e is None else e.on_floats for e in exprs)

    def initial_state(self, batch: int) -> np.ndarray:
        """``theta_hat(0) = 0``, or the true theta in the known-parameter case."""
        if self.known_theta is not None:
            return np.tile(self.known_theta, (batch, 1))
        return np.zeros((batch, self.state_size))

    def control(self, reading: QuantizedReading, yd: Sequence[float],
                theta_hat: np.ndarray | Columns) -> ControlOutput:
        """Eq. (46) with the plant's own psi, phi evaluated at the quantized state. Array or
        column form as in :meth:`ProposedController.control`."""
        if not isinstance(reading, QuantizedReading) or reading.max_error != self.max_error:
            self._refuse(reading)
        if isinstance(theta_hat, np.ndarray):
            out = self.control(QuantizedReading(reading.values, reading.max_error), yd, tuple(theta_hat.T))
            batch = len(theta_hat)
            return ControlOutput(out.u, _stack(out.zbar, batch), _stack(out.target, batch), 0.0)
        q = reading.columns
        psi, *phi = self._on_floats if reading.floats else self._on_arrays
        zbar, alphabar = self._recursion(q, yd)  # eqs. (31)-(34)
        u = alphabar[-1]
        if psi is not None:
            u = u - psi(q)
        rate: tuple = (0.0,) * len(phi)
        if phi:
            phi_q = [p(q) for p in phi]
            u = u - reduce(add, map(mul, theta_hat, phi_q))  # eq. (46): theta_hat^T phi(x_q)
            if self.known_theta is None:
                zn = zbar[-1]
                rate = tuple([self.adaptation_gain * p * zn for p in phi_q])
        return _output((u, tuple(zbar), rate, 0.0))

    def advance(self, state: np.ndarray | Columns, out: ControlOutput, h: float) -> np.ndarray | Columns:
        """``theta_hat`` grows at the held rate (exact for ``x_q`` held over ``h``)."""
        if isinstance(state, np.ndarray):
            grown = self.advance(tuple(state.T), out._replace(target=tuple(out.target.T)), h)
            return _stack(grown, len(state))
        return self.advancer(h, floats=not isinstance(out.u, np.ndarray))(state, out)

    @staticmethod
    def advancer(h: float, floats: bool) -> Callable[[Columns, ControlOutput], Columns]:
        """:meth:`advance` over a fixed ``h`` in column form, as a function made once per run."""

        def advance(state: Columns, out: ControlOutput) -> Columns:
            return tuple([e + h * t for e, t in zip(state, out.target)])  # noqa: B905 (equal lengths)

        return advance


Controller = ProposedController | BaselineController
