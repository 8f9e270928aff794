"""The interface every plant offers to the closed-loop engine (:mod:`qcontrol.sim`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

ScalarObserve = Callable[[], tuple[list[float], list[float]]]  # () -> (true state, sensor reading)
ScalarStep = Callable[[float], None]  # u -> None: hold u over one engine step
ScalarIO = tuple[ScalarObserve, ScalarStep]


class Plant(Protocol):
    """A batch of ``batch`` independent copies of an n-th order plant, eq. (1).

    The engine uses a plant as a context manager (``with plant: ...``) so that backends with
    process-global resources (MuJoCo's passive callback) install and remove them safely.
    All arrays are ``float64``; states have shape ``(batch, n)``, inputs ``(batch,)``.

    A plant may also offer ``scalar_io(h) -> (observe, step)`` for a batch of one: ``observe()``
    returns the true state and the sensor reading as lists of floats, ``step(u)`` holds the float
    ``u`` over ``h`` seconds. The engine then runs a single copy without making arrays; it is
    called once per run, inside the ``with`` block, after :meth:`reset`.
    """

    n: int
    batch: int

    def __enter__(self) -> Plant: ...

    def __exit__(self, *exc: object) -> None: ...

    def reset(self, x0: np.ndarray) -> None:
        """Set the state of every copy; ``x0`` has shape ``(batch, n)``."""

    def state(self) -> np.ndarray:
        """The true state ``x`` (for recording and metrics only; never given to a controller)."""

    def read_sensors(self) -> np.ndarray:
        """What the sensors report for ``x``; the engine quantizes this before control."""

    def step(self, u: np.ndarray, h: float) -> None:
        """Advance every copy by ``h`` seconds with the input ``u`` held (zero-order hold)."""
