"""Backstepping controllers with quantized states: SPEC sections 3-8.

* :func:`backstepping_coefficients` - the constant coefficients of the virtual controls,
  recursion after eq. (27): ``alpha_i = sum_k a[i][k] x_k + sum_j b[i][j] y_d^(j)``.
* :func:`lemma2_bounds` - Lemma 2 (Appendix A): ``|z_i - zbar_i| <= L_zi``.
* :class:`Backstepping` - true errors z, eqs. (7), (8), (12), (20), (27), and quantized errors
  zbar, alphabar, eqs. (31)-(34).
* :class:`ProposedController` - control law (44) and adaptive law (45).
* :class:`BaselineController` - the comparison law of reference [20], eq. (46), with our
  reconstructed adaptive law (SPEC 8).

Everything is vectorized over a leading batch axis: readings have shape ``(batch, n)``. The
proposed law's scalar parameters (kappa, gamma, sigma, r_scale) may also be given per copy, as
arrays of shape ``(batch,)``: a parameter sweep then runs as one batch, through the same formulas
(a single run is a batch of one with scalar parameters).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from .errors import QcontrolInputError
from .expr import Expression
from .quantizer import QuantizedReading

Parameter = float | np.ndarray  # a scalar, or one value per copy of the batch (shape (batch,))


def _parameter(name: str, value: float | Sequence[float] | np.ndarray) -> Parameter:
    """A controller constant as a float, or as a ``(batch,)`` array of per-copy values."""
    array = np.asarray(value, dtype=float)
    if array.ndim > 1 or array.size == 0:
        raise QcontrolInputError(f"controller {name} must be a number or a list of per-copy numbers")
    if not (np.all(np.isfinite(array)) and np.all(array > 0)):
        raise QcontrolInputError(f"controller {name} must be a finite number > 0, got {value!r}")
    return float(array) if array.ndim == 0 else array


def _column(value: Parameter) -> Parameter:
    """Per-copy values as a column ``(batch, 1)``, to scale rows of ``(batch, m)`` arrays."""
    return value[:, None] if isinstance(value, np.ndarray) else value


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
        # alphabar_i = -c_i zbar_i + D_i with D = q @ Dq.T + yd @ Dy.T, eq. (34):
        # D_1 = y_d',  D_i = sum_{k<i} a[i-1][k] q_{k+1} + sum_{j<i} b[i-1][j] y_d^(j+1).
        n = self.n
        self._Dq = np.zeros((n, n))
        self._Dy = np.zeros((n, n + 1))
        self._Dy[0, 1] = 1.0
        for i in range(1, n):
            self._Dq[i, 1 : i + 1] = self.A[i - 1, :i]
            self._Dy[i, 1 : i + 2] = self.B[i - 1, : i + 1]
        # [zbar | alphabar] = q @ Wq + yd @ Wy: the recursion applied to unit vectors
        eye_q, eye_y = np.eye(n), np.eye(n + 1)
        self._Wq = np.hstack(self._recursion(eye_q, np.zeros((n, n + 1))))
        self._Wy = np.hstack(self._recursion(np.zeros((n + 1, n)), eye_y))

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

    def _recursion(self, q: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (31)-(34) as written: ``zbar_1 = q_1 - y_d``, ``alphabar_i = -c_i zbar_i + D_i``,
        ``zbar_{i+1} = q_{i+1} - alphabar_i``. Evaluated once, on unit vectors, in ``__init__``."""
        D = q @ self._Dq.T + yd @ self._Dy.T
        zbar = np.empty(D.shape)
        alphabar = np.empty(D.shape)
        zbar[..., 0] = q[..., 0] - yd[..., 0]
        alphabar[..., 0] = -self.c[0] * zbar[..., 0] + D[..., 0]
        for i in range(1, self.n):
            zbar[..., i] = q[..., i] - alphabar[..., i - 1]
            alphabar[..., i] = -self.c[i] * zbar[..., i] + D[..., i]
        return zbar, alphabar

    def _values(self, reading: QuantizedReading) -> np.ndarray:
        if not isinstance(reading, QuantizedReading):
            raise TypeError(
                "controllers accept only QuantizedReading (use qcontrol.quantizer.quantize); "
                f"got {type(reading).__name__}"
            )
        if reading.max_error != self.max_error:
            raise ValueError(
                f"reading quantized with bound {reading.max_error}, but the controller's Lemma 2 "
                f"bounds assume {self.max_error}"
            )
        return reading.values


class ControlOutput(NamedTuple):
    """One controller evaluation: input ``u`` (batch,), ``zbar`` (batch, n), and the held
    quantities that drive the adaptive state until the next sample."""

    u: np.ndarray
    zbar: np.ndarray
    target: np.ndarray  # proposed: s r / sigma; baseline: Gamma phi zbar_n (a rate)
    rate: float | np.ndarray  # proposed: gamma sigma, a float or a (batch, 1) column; baseline: 0


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
        # precomputed once: per-copy values as columns, and eq. (45)'s decay rate gamma sigma
        self._sigma_column = _column(sigma)
        self._r_scale_column = None if np.all(np.asarray(r_scale) == 1.0) else _column(r_scale)
        self._rate = _column(gamma * sigma)
        self._gain = 1.0 / (kappa * (kappa - self.L))  # (44): u = -zbar_n s eps^T r / (kappa (kappa - L))

    def initial_state(self, batch: int) -> np.ndarray:
        """``eps_hat(0) = 0``."""
        return np.zeros((batch, self.state_size))

    def bounding_functions(self, q: np.ndarray) -> np.ndarray:
        """``r(x_q)`` with shape ``(..., len(r))``."""
        r = np.empty(q.shape[:-1] + (self.state_size,))
        columns = q.T if q.ndim == 2 else np.moveaxis(q, -1, 0)
        for i, ri in enumerate(self.r):
            r[..., i] = ri.on_columns(columns)
        if self._r_scale_column is not None:
            r *= self._r_scale_column
        return r

    def control(self, reading: QuantizedReading, yd: np.ndarray, eps_hat: np.ndarray) -> ControlOutput:
        """Eq. (44) for the current quantized reading; eq. (45)'s held terms for :meth:`advance`."""
        q = self._values(reading)
        zbar, alphabar = self.quantized_errors(q, yd)
        r = self.bounding_functions(q)
        zn = zbar[:, -1]
        s = zn * zn / self.kappa + self.L
        robust = np.vecdot(eps_hat, r)  # eps_hat^T r(x_q), per copy
        u = alphabar[:, -1] - zn * s * robust * self._gain
        return ControlOutput(u, zbar, s[:, None] * r / self._sigma_column, self._rate)

    @staticmethod
    def advance(state: np.ndarray, out: ControlOutput, h: float) -> np.ndarray:
        """Integrate eq. (45) over ``h`` with ``x_q`` held: exact for the linear ODE
        ``eps_hat' = gamma sigma (target - eps_hat)``."""
        return out.target + (state - out.target) * np.exp(-out.rate * h)


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

    def initial_state(self, batch: int) -> np.ndarray:
        """``theta_hat(0) = 0``, or the true theta in the known-parameter case."""
        if self.known_theta is not None:
            return np.tile(self.known_theta, (batch, 1))
        return np.zeros((batch, self.state_size))

    def control(self, reading: QuantizedReading, yd: np.ndarray, theta_hat: np.ndarray) -> ControlOutput:
        """Eq. (46) with the plant's own psi, phi evaluated at the quantized state."""
        q = self._values(reading)
        zbar, alphabar = self.quantized_errors(q, yd)
        u = alphabar[:, -1].copy()
        if self.psi is not None:
            u -= self.psi(q)
        if self.phi:
            phi_q = np.empty(q.shape[:-1] + (len(self.phi),))
            for i, p in enumerate(self.phi):
                phi_q[..., i] = p(q)
            u -= (theta_hat * phi_q).sum(axis=-1)
            rate = self.adaptation_gain * phi_q * zbar[:, -1:]
        else:
            rate = np.zeros_like(theta_hat)
        if self.known_theta is not None:
            rate = np.zeros_like(theta_hat)
        return ControlOutput(u, zbar, rate, 0.0)

    @staticmethod
    def advance(state: np.ndarray, out: ControlOutput, h: float) -> np.ndarray:
        """``theta_hat`` grows at the held rate (exact for ``x_q`` held over ``h``)."""
        return state + h * out.target


Controller = ProposedController | BaselineController
