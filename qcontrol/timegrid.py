"""The fixed time grid of a run: ``t_k = k dt``, and the one check that a time is a whole number
of steps (the duration, the control period, MuJoCo's sensor delay and period, a plant step)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import QcontrolInputError

RELATIVE_SLACK = 1e-9  # a time within this fraction of a whole number of steps counts as whole


def whole_steps(value: float, step: float, what: str, step_name: str = "dt") -> int:
    """How many steps of ``step`` make ``value`` (at least one); otherwise one
    :class:`QcontrolInputError` line naming ``what``, with the nearest times that would work."""
    count = round(value / step)
    if count >= 1 and abs(count * step - value) <= RELATIVE_SLACK * max(value, step):
        return count
    below = max(1, math.floor(value / step)) * step
    above = max(1, math.ceil(value / step)) * step
    nearest = f"{_show(below)} s" if math.isclose(below, above) else f"{_show(below)} s or {_show(above)} s"
    raise QcontrolInputError(
        f"{what} = {value!r} s is not a whole number of steps {step_name} = {step!r} s; "
        f"use a multiple of {step_name}, e.g. {nearest}"
    )


def _show(t: float) -> str:
    """A time rounded to 12 significant digits, so 3 * 0.001 shows as 0.003."""
    return f"{t:.12g}"


@dataclass(frozen=True)
class TimeGrid:
    """``steps`` steps of ``dt`` (``rows = steps + 1`` instants, row k at ``t_k = k dt``); the
    controller samples every ``hold`` steps (the control period) and holds u in between."""

    dt: float
    steps: int
    hold: int = 1

    @classmethod
    def of(cls, duration: float, dt: float, control_period: float | None = None) -> TimeGrid:
        """The grid of a run; refuses a duration or a control period that is not whole steps."""
        if not (np.isfinite(dt) and dt > 0):
            raise QcontrolInputError(f"simulation.dt must be a finite number > 0, got {dt!r}")
        if not (np.isfinite(duration) and duration > 0):
            raise QcontrolInputError(f"simulation.duration must be a finite number > 0, got {duration!r}")
        steps = step_count(duration, dt)
        hold = 1 if control_period is None else whole_steps(control_period, dt, "simulation.control_period")
        return cls(dt, steps, hold)

    @property
    def rows(self) -> int:
        return self.steps + 1

    @property
    def duration(self) -> float:
        return self.steps * self.dt

    def instants(self, first: int, stop: int) -> np.ndarray:
        """``t_k = k dt`` for rows ``[first, stop)`` (the same floats however they are sliced)."""
        return np.arange(first, stop) * self.dt


def step_count(duration: float, dt: float) -> int:
    """Number of ``dt`` steps in ``duration``; a duration that is not a multiple of dt is refused
    with the nearest steps and durations that would work."""
    steps = round(duration / dt)
    if steps >= 1 and abs(steps * dt - duration) <= RELATIVE_SLACK * max(1.0, duration):
        return steps
    below = max(1, math.floor(duration / dt)) * dt
    above = max(1, math.ceil(duration / dt)) * dt
    durations = _either(below, above)
    steps_that_work = _either(*_round_steps(duration, dt)) or f"{_show(duration / max(1, steps))} s"
    raise QcontrolInputError(
        f"simulation.duration = {duration!r} s is not a whole number of steps dt = {dt!r} s; "
        f"the nearest that work are dt = {steps_that_work} for this duration, or duration = {durations} "
        "for this dt"
    )


def _either(below: float | None, above: float | None) -> str:
    shown = [f"{_show(t)} s" for t in (below, above) if t is not None]
    if len(shown) == 2 and shown[0] == shown[1]:
        shown = shown[:1]
    return " or ".join(shown)


def _round_steps(duration: float, dt: float, digits: int = 3) -> tuple[float | None, float | None]:
    """The steps nearest ``dt`` from below and from above (within a factor of 2) that have at most
    ``digits`` significant digits and make ``duration`` a whole number of steps."""
    exponent = math.floor(math.log10(dt)) - (digits - 1)
    below = above = None
    for shift in (-1, 0, 1):  # mantissas 10^(digits-1) .. 10^digits - 1 around dt's decade
        for mantissa in range(10 ** (digits - 1), 10**digits):
            step = float(f"{mantissa}e{exponent + shift}")
            if not dt / 2 <= step <= 2 * dt:
                continue
            count = round(duration / step)
            if count < 1 or abs(count * step - duration) > RELATIVE_SLACK * max(1.0, duration):
                continue
            if step < dt and (below is None or step > below):
                below = step
            if step > dt and (above is None or step < above):
                above = step
    return below, above
