"""Scenario files (TOML) -> validated scenarios: the keys (:mod:`.keys`), the loader
(:mod:`.load`) with the :class:`Scenario` it makes, and its validated sections (:mod:`.definition`)."""

from .definition import ControllerConfig, ReferenceConfig, SimulationConfig
from .keys import MAX_STEPS
from .load import Scenario, apply_override, load_scenario, parse_scenario, remove_key

__all__ = [
    "MAX_STEPS",
    "ControllerConfig",
    "ReferenceConfig",
    "Scenario",
    "SimulationConfig",
    "apply_override",
    "load_scenario",
    "parse_scenario",
    "remove_key",
]
