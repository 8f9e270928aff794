"""The ideal plant of eq. (1): a chain of integrators with unknown nonlinearities.

    x_i' = x_{i+1} (i < n),    x_n' = u + psi(x) + theta^T phi(x)

integrated with classical fixed-step RK4, the input held over each step. A fixed step is
deliberate: an adaptive-step solver either steps over the quantizer's jumps or crawls at them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..expr import Expression


class ChainPlant:
    """Batch of chain-of-integrator plants, eq. (1); the reference model for MuJoCo."""

    def __init__(
        self,
        n: int,
        psi: Expression | None,
        phi: Sequence[Expression],
        theta: Sequence[float],
        batch: int = 1,
    ) -> None:
        theta = np.asarray(theta, dtype=float)
        if len(phi) != theta.size:
            raise ValueError(f"phi has {len(phi)} terms but theta has {theta.size} entries")
        self.n = int(n)
        self.batch = int(batch)
        self.psi = psi
        self.phi = tuple(phi)
        self.theta = theta
        self._x = np.zeros((self.batch, self.n))

    def __enter__(self) -> ChainPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def uncertainty(self, x: np.ndarray) -> np.ndarray:
        """``psi(x) + theta^T phi(x)``, shape ``(batch,)``."""
        columns = x.T
        total = self.psi.on_columns(columns) if self.psi is not None else 0.0
        for coefficient, term in zip(self.theta, self.phi, strict=True):
            total = total + coefficient * term.on_columns(columns)
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
        self._x = np.array(np.broadcast_to(x0, (self.batch, self.n)), dtype=float)

    def state(self) -> np.ndarray:
        return self._x.copy()

    def read_sensors(self) -> np.ndarray:
        return self._x.copy()

    def step(self, u: np.ndarray, h: float) -> None:
        x = self._x
        half = 0.5 * h
        k1 = self.rhs(x, u)
        k2 = self.rhs(x + half * k1, u)
        k3 = self.rhs(x + half * k2, u)
        k4 = self.rhs(x + h * k3, u)
        self._x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
