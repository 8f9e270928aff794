"""What the closed-loop engine uses of a plant, and the terms of eq. (1) every plant is built from."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..expr import Expression

Observe = Callable[[], tuple[Any, Any]]  # () -> (true state, sensor reading)
Step = Callable[[Any], None]  # u -> None: hold u over one engine step
IO = tuple[Observe, Step]


@dataclass(frozen=True)
class PlantTerms:
    """The right-hand side of eq. (1): ``x_i' = x_{i+1}``, ``x_n' = u + psi(x) + theta^T phi(x)``.

    ``psi`` is unknown to the controller, ``phi`` known in form with ``theta`` unknown.
    """

    order: int
    psi: Expression | None
    phi: tuple[Expression, ...]
    theta: tuple[float, ...]

    @property
    def names(self) -> list[str]:
        """Names of the terms of ``psi + theta^T phi``: ``psi`` (if present), ``phi1`` .. ``phil``."""
        return (["psi"] if self.psi is not None else []) + [f"phi{i + 1}" for i in range(len(self.phi))]

    @property
    def expressions(self) -> list[Expression]:
        """The terms in the order of :attr:`names`: ``psi`` (if present), then ``phi``."""
        return ([self.psi] if self.psi is not None else []) + list(self.phi)

    @property
    def coefficients(self) -> list[float]:
        """Each term's coefficient in the order of :attr:`names`: 1 for ``psi``, theta_i for ``phi_i``."""
        return ([1.0] if self.psi is not None else []) + list(self.theta)


class Plant(Protocol):
    """A batch of ``batch`` independent copies of an n-th order plant, eq. (1).

    The engine uses a plant as a context manager (``with plant: ...``) so that backends with
    process-global resources (MuJoCo's passive callback) install and remove them safely, calls
    :meth:`reset`, then takes the two functions of :meth:`io` for the run. All arrays are
    ``float64``; states have shape ``(batch, n)``, inputs ``(batch,)``.
    """

    n: int
    batch: int
    warnings: list[str]  # what the physics engine warned about during the last run (shown to users)
    consistency_report: dict[str, Any]  # how the plant agrees with eq. (1) ({} for the ODE, which is eq. (1))

    def __enter__(self) -> Plant: ...

    def __exit__(self, *exc: object) -> None: ...

    def reset(self, x0: np.ndarray) -> None:
        """Set the state of every copy; ``x0`` has shape ``(batch, n)``."""

    def io(self, h: float) -> IO:
        """``observe() -> (x, reading)`` and ``step(u)`` (hold ``u`` over ``h`` seconds) for one run.

        For a batch of one they work on plain floats (lists of n floats, a float ``u``): a numpy
        call on a one-element array costs about a microsecond, float arithmetic tens of
        nanoseconds. Otherwise on ``(batch, n)`` arrays and a ``(batch,)`` array. Called once per
        run, inside the ``with`` block, after :meth:`reset`. ``x`` is the true state (for the
        record and the metrics only; never given to a controller); ``reading`` is what the
        sensors report, which the engine quantizes before control.
        """

    def state(self) -> np.ndarray:
        """The true state ``x``, shape ``(batch, n)``."""

    def read_sensors(self) -> np.ndarray:
        """What the sensors report for ``x``, shape ``(batch, n)``."""

    def step(self, u: np.ndarray, h: float) -> None:
        """Advance every copy by ``h`` seconds with the input ``u`` held (zero-order hold)."""

    def disturb(self, d: float) -> None:
        """Apply the external load ``d`` to every copy from the next step on, until changed: a
        matched term ``x_n' = u + d + psi + theta^T phi`` in u's units (a generalized force ``F``
        on the joint is ``d = F / I``; see :mod:`qcontrol.disturbance`). :meth:`reset` sets it to 0."""

    actuator_limited: bool  # whether the actuator can clip a command (False: actuator() is the identity)

    def actuator(self, u: np.ndarray) -> np.ndarray:
        """The input the plant applies for the commanded ``u`` (same units, same shape): ``u``
        itself for an ideal actuator, ``u`` clipped at the actuator's limit otherwise. Where it
        does not clip, the result is ``u`` exactly."""


def array_io(plant: Plant, h: float) -> IO:
    """:meth:`Plant.io` in array form, from a plant's :meth:`~Plant.state`,
    :meth:`~Plant.read_sensors` and :meth:`~Plant.step`."""

    def observe() -> tuple[np.ndarray, np.ndarray]:
        return plant.state(), plant.read_sensors()

    def step(u: np.ndarray) -> None:
        plant.step(u, h)

    return observe, step
