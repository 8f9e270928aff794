"""Scenario files (TOML) -> validated scenarios: the keys (:mod:`.keys`), the loader
(:mod:`.load`) and the validated data (:mod:`.model`)."""

from .definition import ControllerConfig, ReferenceConfig, Scenario, SimulationConfig
from .keys import MAX_STEPS
from .load import apply_override, load_scenario, parse_scenario, remove_key

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
