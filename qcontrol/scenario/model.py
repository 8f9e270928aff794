"""A validated scenario: the plant, the controller, the reference and the simulation settings."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..controller.law import LawContext
from ..disturbance import Disturbance
from ..engine import MetricSettings
from ..expr import Expression
from ..plants.base import PlantTerms
from ..reference import Reference
from ..timegrid import TimeGrid


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

    @property
    def period(self) -> float:
        """The control period T the law holds u over: ``control_period`` as whole steps of ``dt``
        (``dt`` when none is given)."""
        return TimeGrid.of(self.duration, self.dt, self.control_period).hold * self.dt


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. Expressions are compiled once (``psi_expr``, ``phi_expr``); each
    ``[plant.<backend>]`` section is parsed into ``backends[name]`` by its backend; the
    ``[[disturbance]]`` list into ``disturbances``."""

    name: str
    description: str
    source: str  # where it came from (file path or "<string>")
    text: str  # the TOML text as read
    overrides: tuple[str | tuple[str, Any], ...]  # as given: "key=value" strings or (key, value) pairs
    order: int
    psi: str | None
    phi: tuple[str, ...]
    theta: tuple[float, ...]
    x0: tuple[float, ...]
    controller: ControllerConfig
    reference: ReferenceConfig
    simulation: SimulationConfig
    backends: dict[str, Any] = field(default_factory=dict)
    disturbances: tuple[Disturbance, ...] = ()
    metrics: MetricSettings = field(default_factory=MetricSettings)
    data: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)  # the TOML after overrides
    base_dir: Path = field(default=Path("."), repr=False, compare=False)  # paths in it are relative to it
    psi_expr: Expression | None = field(default=None, repr=False)
    phi_expr: tuple[Expression, ...] = field(default=(), repr=False)
    unset: tuple[str, ...] = ()  # keys removed from the file (--unset) before the overrides
    paper_example: int | None = None  # the paper's example this scenario reproduces, if any

    def with_overrides(self, overrides: Mapping[str, Any] | Sequence[str]) -> Scenario:
        """A new scenario: this one's file with its overrides and then ``overrides`` (a dict
        ``{"controller.kappa_margin": 0.1}`` or ``"key=value"`` strings) applied. Scenarios are
        immutable: this one is unchanged."""
        from .load import _as_given, parse_scenario

        return parse_scenario(self.text, source=self.source, base_dir=self.base_dir,
                              overrides=(*self.overrides, *_as_given(overrides)), default_name=self.name,
                              unset=self.unset)

    @property
    def terms(self) -> PlantTerms:
        """The right-hand side of eq. (1) as the plants are built from it."""
        return PlantTerms(self.order, self.psi_expr, self.phi_expr, self.theta)

    @property
    def law_context(self) -> LawContext:
        """What the controller kind reads of the scenario (see :class:`LawContext`)."""
        c, sim = self.controller, self.simulation
        return LawContext(self.source, self.order, c.delta, c.c, self.psi_expr, self.phi_expr, self.theta,
                          sim.dt, sim.period)

    @property
    def uncertain_terms(self) -> int:
        """Entries of eps, eqs. (37)-(43): one per phi_i, plus one for psi."""
        return len(self.phi) + (self.psi is not None)
