"""The ``[plant.mujoco]`` section of a scenario: its keys and the validated :class:`MujocoOptions`.

This module does not import mujoco: a scenario is typed and checked key by key without it. The
model itself is compiled (and its element names checked) by :mod:`.mjcf` when the scenario loads.
"""

from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, replace
from typing import Any

from ...errors import shown
from ...outputs import check_name, path_kind
from ...resources import resolve_file
from ...schema import Key, Section, Table, custom, number, read_keys, string
from ..base import PlantTerms

INTEGRATORS = ("RK4", "Euler", "implicit", "implicitfast")
REALISM_FIELDS = {  # each realism option and the fields that make it (noise needs its seed)
    "torque_limit": ("torque_limit",), "frictionloss": ("frictionloss",), "armature": ("armature",),
    "rod_mass": ("rod_mass",), "sensor_noise": ("sensor_noise", "noise_seed"),
    "sensor_delay": ("sensor_delay",), "sensor_period": ("sensor_period",),
}
PARAMETERS = ("mass", "length", "damping", "gravity")
MAX_SENSOR_TIME = 1e3  # seconds; MuJoCo's sensor history length is an int of delay / timestep


@dataclass(frozen=True)
class MujocoOptions:
    """The validated ``[plant.mujoco]`` table (see :data:`SECTION` for what each key means)."""

    where: str  # "<file>: plant.mujoco", prefixes messages
    model: pathlib.Path
    joint: str
    position_sensor: str
    velocity_sensor: str
    actuator: str
    native_terms: tuple[str, ...] = ()
    integrator: str = "RK4"
    parameters: tuple[tuple[str, float], ...] = ()
    torque_limit: float | None = None
    frictionloss: float = 0.0
    armature: float = 0.0
    rod_mass: float = 0.0
    sensor_noise: tuple[float, float] = (0.0, 0.0)
    noise_seed: int | None = None
    sensor_delay: float = 0.0
    sensor_period: float = 0.0
    activation_sensor: str | None = None  # order 3: the <actuatorfrc> sensor that reads x3

    @property
    def realism(self) -> tuple[str, ...]:
        """Names of the realism options that are on (empty for the ideal model)."""
        on = {
            "torque_limit": self.torque_limit is not None,
            "frictionloss": self.frictionloss > 0,
            "armature": self.armature > 0,
            "rod_mass": self.rod_mass > 0,
            "sensor_noise": any(s > 0 for s in self.sensor_noise),
            "sensor_delay": self.sensor_delay > 0,
            "sensor_period": self.sensor_period > 0,
        }
        return tuple(name for name, active in on.items() if active)

    def nominal(self) -> MujocoOptions:
        """The same model with every realism option off: what the ODE describes."""
        return replace(
            self, torque_limit=None, frictionloss=0.0, armature=0.0, rod_mass=0.0,
            sensor_noise=(0.0, 0.0), noise_seed=None, sensor_delay=0.0, sensor_period=0.0,
        )

    def only(self, name: str) -> MujocoOptions:
        """The nominal model with the realism option ``name`` (one of :attr:`realism`) alone on."""
        current = vars(self)
        return replace(self.nominal(), **{key: current[key] for key in REALISM_FIELDS[name]})


# --------------------------------------------------------------------------------------------
# Readers of the keys that are more than a plain number or string


def _element_name(table: Table, key: str, default: Any, sizes: Any) -> str:
    value = table.get(key, default)
    if not isinstance(value, str) or not value.strip():
        raise table.error(key, f"expected a non-empty string, got {value!r}",
                          "give the name of the MJCF element")
    return value


def _optional_name(table: Table, key: str, default: Any, sizes: Any) -> str | None:
    return None if table.get(key, default) is None else _element_name(table, key, default, sizes)


def _term_names(table: Table, key: str, default: Any, sizes: Any) -> tuple[str, ...]:
    allowed = sizes["terms"]
    native = table.get(key, default)
    if not isinstance(native, list) or not all(isinstance(t, str) for t in native):
        raise table.error(key, f"expected a list of term names, got {native!r}",
                          f"write e.g. [\"phi1\"]; allowed names are {', '.join(allowed) or 'none'}")
    for term in native:
        if term not in allowed:
            raise table.error(key, f"unknown term {term!r}",
                              f"allowed names are {', '.join(allowed) or 'none (the plant has no terms)'}")
    if len(set(native)) != len(native):
        raise table.error(key, f"repeated names in {native!r}", "list each term once")
    return tuple(native)


def _parameters(table: Table, key: str, default: Any, sizes: Any) -> tuple[tuple[str, float], ...]:
    raw = table.get(key, default)
    if not isinstance(raw, dict):
        raise table.error(key, f"expected a table, got {raw!r}",
                          "write e.g. parameters = {mass = 1.0, length = 3.5, damping = 12.25}")
    inner = Table(raw, table.source, table.path(key))
    checked = []
    for name, value in raw.items():
        if name not in PARAMETERS:
            raise inner.error(name, "unknown parameter", f"allowed are {', '.join(PARAMETERS)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise inner.error(name, f"expected a finite number, got {value!r}", "write a number")
        positive = name in ("mass", "length")
        if value < 0 or (positive and value == 0):
            raise inner.error(name, f"must be {'> 0' if positive else '>= 0'}, got {value!r}",
                              "use a physical value")
        checked.append((name, float(value)))
    return tuple(checked)


def _standard_deviation(table: Table, key: str, value: Any) -> float:
    real = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not real or not math.isfinite(value) or value < 0:
        raise table.error(key, f"expected a finite number >= 0, got {value!r}",
                          "write a standard deviation such as 0.001")
    return float(value)


def _noise(table: Table, key: str, default: Any, sizes: Any) -> tuple[float, float]:
    raw = table.get(key, default)
    if not isinstance(raw, list):
        value = _standard_deviation(table, key, raw)
        return value, value
    if len(raw) != 2:
        raise table.error(key, f"expected 2 values (position, velocity), got {len(raw)}",
                          "write one standard deviation for both readings, e.g. 0.001, or two, e.g. "
                          "[0.001, 0.01] (position, velocity)")
    return _standard_deviation(table, key, raw[0]), _standard_deviation(table, key, raw[1])


def _seed(table: Table, key: str, default: Any, sizes: Any) -> int | None:
    seed = table.get(key, default)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise table.error(key, f"expected a non-negative integer, got {seed!r}", "write e.g. noise_seed = 1")
    return seed


def _seconds(table: Table, key: str, default: Any, sizes: Any) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise table.error(key, f"expected a finite number, got {value!r}", "write a number such as 0.001")
    if value < 0:
        raise table.error(key, f"must be >= 0, got {value!r}", "use 0 (off) or a positive time in seconds")
    if value > MAX_SENSOR_TIME:
        raise table.error(key, f"{value!r} s is longer than any run",
                          f"use a value under {MAX_SENSOR_TIME:g} s")
    return float(value)


def _nonnegative(table: Table, key: str, default: Any, sizes: Any) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise table.error(key, f"expected a finite number, got {value!r}", "write a number such as 0.1")
    if value < 0:
        raise table.error(key, f"must be >= 0, got {value!r}", "use a non-negative value (0 or absent turns "
                          "the option off)")
    return float(value)


_NAME = custom("name of an MJCF element", _element_name)
_OPTIONAL_NAME = custom("name of an MJCF element", _optional_name)
SECTION = Section(
    "plant.mujoco",
    (
        Key("model", custom("path of an MJCF file", _element_name, path=True),
            meaning="the MJCF file, relative to the scenario file's folder, or a model shipped with "
            "qcontrol: \"qcontrol:models/pendulum.xml\", \"qcontrol:models/slider.xml\"",
            example='"qcontrol:models/pendulum.xml"'),
        Key("joint", _NAME, meaning="the hinge or slide joint whose position is x1 and velocity x2",
            example='"hinge"'),
        Key("position_sensor", _NAME, meaning="<jointpos> sensor on the joint: the reading of x1",
            example='"angle"'),
        Key("velocity_sensor", _NAME, meaning="<jointvel> sensor on the joint: the reading of x2",
            example='"angular_velocity"'),
        Key("actuator", _NAME, meaning="<motor> on the joint; its command is I u (I from mj_fullM); for "
            "plant order 3, a <general dyntype=\"filter\"> on it, whose activation is x3",
            example='"torque"'),
        Key("activation_sensor", _OPTIONAL_NAME, None,
            meaning="plant order 3 only: <actuatorfrc> sensor on the filter actuator, the reading of x3 "
                    "(its force times gear / I)"),
        Key("native_terms", custom("list of term names (psi, phi1, ...)", _term_names), [],
            meaning="terms MuJoCo's own physics produces (damping, gravity); the others are added as a "
                    "passive force", example='["phi1", "phi3"]'),
        Key("integrator", string(INTEGRATORS), "RK4", meaning="MuJoCo's integrator"),
        Key("parameters", custom("table {mass, length, damping, gravity}", _parameters), {},
            meaning="override the MJCF: body mass [kg], hinge-to-centre length [m], joint damping, gravity "
                    "[m/s^2]"),
        Key("torque_limit", number(positive=True), None, "N m or N",
            meaning="actuator limit: the command is clipped to +-limit (MJCF ctrlrange)"),
        Key("frictionloss", custom("number >= 0", _nonnegative), 0.0, "N m or N", "joint dry friction"),
        Key("armature", custom("number >= 0", _nonnegative), 0.0, "kg m^2 or kg",
            "rotor inertia added to the joint (unmodelled by the controller)"),
        Key("rod_mass", custom("number >= 0", _nonnegative), 0.0, "kg",
            "a uniform rod from the hinge to the bob (unmodelled by the controller)"),
        Key("sensor_noise", custom("number >= 0, or [position, velocity]", _noise), 0.0, "state units",
            "standard deviation of Gaussian noise added to the readings"),
        Key("noise_seed", custom("whole number >= 0", _seed), None,
            meaning="seed of the sensor noise (required when sensor_noise is on)"),
        Key("sensor_delay", custom("number >= 0", _seconds), 0.0, "s", "delay of the readings"),
        Key("sensor_period", custom("number >= 0", _seconds), 0.0, "s",
            "sample-and-hold period of the readings"),
    ),
    meaning="the MuJoCo model of the plant (order 2: one hinge or slide joint; order 3: the same joint "
            "driven through a first-order filter actuator, its activation x3)",
)


def parse(table: Table, terms: PlantTerms, base_dir: pathlib.Path) -> MujocoOptions:
    """Read and check ``[plant.mujoco]`` (every error one line naming the key); ``base_dir`` is
    the scenario file's folder, against which ``model`` is resolved."""
    table = Table(table.data, table.source, table.name, SECTION.names)
    if terms.order not in (2, 3):
        raise table.error_at(table.name, f"the MuJoCo backend models one joint (plant order 2) or one joint "
                             f"driven through a filter actuator (order 3), but plant.order = {terms.order}",
                             "remove [plant.mujoco] (the ode backend runs any order)")
    v = read_keys(table, SECTION.keys, {"terms": terms.names})
    check_name(v["model"], f"{table.source}: {table.path('model')}")
    model = resolve_file(v["model"], base_dir)
    kind = path_kind(model)
    if kind is not None:
        raise table.error("model", f"{shown(v['model'])} is {kind}, not a regular file",
                          "give the path of an MJCF file")
    if not model.is_file():
        raise table.error("model", f"file {v['model']!r} not found (looked at {model})",
                          "give the MJCF path relative to the scenario file's folder, "
                          "e.g. \"../models/pendulum.xml\", or a shipped model, "
                          "\"qcontrol:models/pendulum.xml\"")
    if any(s > 0 for s in v["sensor_noise"]) and v["noise_seed"] is None:
        raise table.error("noise_seed", "missing while sensor_noise is on",
                          "add an explicit integer seed, e.g. noise_seed = 1, so runs are reproducible")
    _check_order(table, terms, v)
    return MujocoOptions(where=f"{table.source}: {table.name}", **(v | {"model": model}))


def _check_order(table: Table, terms: PlantTerms, v: dict[str, Any]) -> None:
    """Order 3 reads x3 through ``activation_sensor``, and MuJoCo's own physics makes every term
    (its filter and its joint): no psi, no passive force, no sensor noise, delay or hold on x1, x2
    alone. Order 2 has no activation."""
    if terms.order == 2:
        if v["activation_sensor"] is not None:
            raise table.error("activation_sensor", "is for plant order 3 (x3 the actuator's activation), "
                              "but plant.order = 2", "remove it, or model the actuator's filter: order = 3")
        return
    if v["activation_sensor"] is None:
        raise table.error_at(table.name, "plant order 3 on MuJoCo reads x3 from the filter actuator, but "
                             "activation_sensor is missing", "name an <actuatorfrc actuator=\"...\"/> "
                             "sensor: activation_sensor = \"NAME\"")
    added = [name for name in terms.names if name not in v["native_terms"]]
    if added:
        raise table.error("native_terms", f"plant order 3 on MuJoCo needs every term made by MuJoCo's own "
                          f"physics, but it lacks {', '.join(added)}", "list every term (qcontrol model "
                          "MODEL.xml prints the model's terms), or run the ode backend")
    noisy = [k for k in ("sensor_noise", "sensor_delay", "sensor_period")
             if (any(v[k]) if k == "sensor_noise" else v[k] > 0)]
    if noisy:
        raise table.error(noisy[0], "is not supported for plant order 3 on MuJoCo yet", "remove it")


