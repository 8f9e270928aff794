"""External disturbances on the joint: the scenario's ``[[disturbance]]`` list and its schedule.

A disturbance is a generalized force on the plant's joint (N m on a hinge, N on a slide), acting
on top of the controller's input: a push (kind ``impulse``: a constant force over a short time)
or a load that stays (kind ``step``). Each kind declares its keys in :data:`DISTURBANCE_KINDS`.

How it enters the plant. MuJoCo receives the force itself, in ``qfrc_applied``. The ODE of
eq. (1) has unit input gain (``x_n' = u + psi + theta^T phi``), so a generalized force ``F`` is
the matched term ``d = F / I`` there, ``I`` being the joint's generalized inertia from the MuJoCo
model (``mj_fullM``, the same ``I`` that turns u into a torque), or 1 when the scenario has no
MuJoCo model. Both plants thus see the same term and ``qcontrol compare`` isolates the other
differences. Inside the engine and the plants the load is carried in u's units (``d``).

Timing. The force is held over each step of the time grid at its average over the step, so an
impulse's integral, ``force * duration``, is exact whatever ``dt`` (a start that falls inside a
step gives that step a fraction of the force). The engine applies a new value only at the rows
where it changes (:meth:`Schedule.changes`): the loop itself pays nothing for disturbances.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import QcontrolInputError
from .schema import Key, KindKeys, Section, Table, number, read_keys, string, type_name
from .timegrid import RELATIVE_SLACK


@dataclass(frozen=True)
class Disturbance:
    """A generalized force ``force`` on the joint over ``[start, end)`` (``end`` infinite for a
    load that stays)."""

    kind: str
    start: float
    end: float
    force: float

    @property
    def lasting(self) -> bool:
        """Whether it stays until the end of the run (a load step)."""
        return math.isinf(self.end)

    def describe(self, unit: str = "") -> str:
        """One line for recordings and reports, e.g. ``impulse 20 N m over [5, 5.05) s``."""
        force = f"{self.force:g}{' ' + unit if unit else ''}"
        if self.lasting:
            return f"{self.kind} {force} from t = {self.start:g} s on"
        return f"{self.kind} {force} over [{self.start:g}, {self.end:g}) s"


MAX_TIME = 1e9  # s: the latest start and the longest push a disturbance may have (far beyond any run)
START = Key("start", number(nonnegative=True, maximum=MAX_TIME), unit="s",
            meaning="when it begins (simulated time)", example="5.0")
IMPULSE_KEYS = (
    START,
    Key("duration", number(positive=True, maximum=MAX_TIME), unit="s", meaning="how long the force acts",
        example="0.05"),
    Key("force", number(), unit="N m or N", example="20.0",
        meaning="the generalized force on the joint while it acts (its integral is force * duration)"),
)
STEP_KEYS = (
    START,
    Key("value", number(), unit="N m or N", example="-5.0",
        meaning="the generalized force on the joint from start to the end of the run"),
)


def _impulse(values: dict[str, Any]) -> Disturbance:
    return Disturbance("impulse", values["start"], values["start"] + values["duration"], values["force"])


def _step(values: dict[str, Any]) -> Disturbance:
    return Disturbance("step", values["start"], math.inf, values["value"])


@dataclass(frozen=True)
class DisturbanceKind:
    """One kind of disturbance: its keys and how a :class:`Disturbance` is made from them."""

    keys: KindKeys
    make: Callable[[dict[str, Any]], Disturbance]


DISTURBANCE_KINDS: dict[str, DisturbanceKind] = {
    "impulse": DisturbanceKind(
        KindKeys("impulse", IMPULSE_KEYS, "a push: force over [start, start + duration)"), _impulse),
    "step": DisturbanceKind(KindKeys("step", STEP_KEYS, "a load that stays: value from start on"), _step),
}
KIND = Key("kind", string(tuple(DISTURBANCE_KINDS)), meaning="the kind of disturbance", example='"impulse"')
SECTION = Section(
    "disturbance", (KIND,),
    "external loads on the joint, on top of u, in MuJoCo (qfrc_applied) and in the ODE (the matched "
    "term d = F / I, I the joint's inertia from the MuJoCo model, 1 without one); held over each step "
    "at their average there; any number of them, each its own [[disturbance]]",
    {name: kind.keys for name, kind in DISTURBANCE_KINDS.items()}, array=True,
)


def parse_disturbances(raw: Any, source: str) -> tuple[Disturbance, ...]:
    """Read the scenario's ``[[disturbance]]`` list (absent: none); every problem one line naming
    ``disturbance[i].key``."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise QcontrolInputError(f"{source}: disturbance: must be a list of tables, got {type_name(raw)}; "
                                 "write one [[disturbance]] section per disturbance")
    items = []
    for i, item in enumerate(raw):
        name = f"disturbance[{i}]"
        head = Table(item, source, name)
        kind = read_keys(head, (KIND,), {})["kind"]
        entry = DISTURBANCE_KINDS[kind]
        table = Table(item, source, name, ("kind", *entry.keys.names))
        items.append(entry.make(read_keys(table, entry.keys.keys, {})))
    return tuple(items)


# --------------------------------------------------------------------------------------------
# The schedule on a time grid


def _overlap(a0: float, a1: float, b0: float, b1: float) -> float:
    return max(0.0, min(a1, b1) - max(a0, b0))


@dataclass(frozen=True)
class Schedule:
    """The disturbances of a run as the generalized force held over each step of ``dt``."""

    items: tuple[Disturbance, ...]

    def __bool__(self) -> bool:
        return bool(self.items)

    def on_step(self, k: int, dt: float) -> float:
        """The force held over step k, ``[k dt, (k + 1) dt)``: each item's average over the step
        (a boundary within ``RELATIVE_SLACK`` of a step's edge counts as on it)."""
        t0, t1 = k * dt, (k + 1) * dt
        total = 0.0
        for item in self.items:
            share = _overlap(t0, t1, item.start, item.end) / dt
            share = 0.0 if share < RELATIVE_SLACK else 1.0 if share > 1.0 - RELATIVE_SLACK else share
            total += item.force * share
        return total

    def changes(self, dt: float, rows: int) -> list[tuple[int, float]]:
        """``(row, force)`` at row 0 and at every row where the held force changes, in order."""
        candidates = {0}
        for item in self.items:
            for edge in (item.start, item.end):
                if math.isfinite(edge):
                    k = math.floor(edge / dt)
                    candidates.update((k - 1, k, k + 1))
        out: list[tuple[int, float]] = []
        for k in sorted(c for c in candidates if 0 <= c < rows):
            value = self.on_step(k, dt)
            if not out or value != out[-1][1]:
                out.append((k, value))
        return out

    def per_row(self, dt: float, rows: int) -> np.ndarray:
        """The force held over each row's step, shape ``(rows,)`` (figures, recordings)."""
        out = np.zeros(rows)
        for k, value in self.changes(dt, rows):
            out[k:] = value
        return out


def scaled_changes(schedule: Schedule, dt: float, rows: int, inertia: float) -> Sequence[tuple[int, float]]:
    """:meth:`Schedule.changes` in u's units: ``d = F / I`` (see the module docstring)."""
    return [(k, value / inertia) for k, value in schedule.changes(dt, rows)]
