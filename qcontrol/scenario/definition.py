"""The validated sections of a scenario: the controller, the reference and the simulation settings
(the :class:`~qcontrol.scenario.load.Scenario` holding them is made where it is parsed)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..reference import Reference


@dataclass(frozen=True)
class ControllerConfig:
    """``[controller]``: the kind, the quantizer step ``delta`` and the gains ``c`` every kind
    takes, and the kind's own validated ``settings`` (e.g. kappa, gamma, sigma, r)."""

    kind: str
    delta: float
    c: tuple[float, ...]
    settings: Any


@dataclass(frozen=True)
class ReferenceConfig:
    """``[reference]``: the kind and the reference it describes (with its derivatives)."""

    kind: str
    signal: Reference


@dataclass(frozen=True)
class SimulationConfig:
    duration: float
    dt: float
    control_period: float | None
    backend: str
    state_bound: float
    velocity_source: str = "sensor"
