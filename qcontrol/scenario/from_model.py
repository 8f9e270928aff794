"""Coefficients a scenario leaves to the plant's model: ``"model"`` in place of a number.

A term the MuJoCo model's own physics produces (a native term: joint damping, a spring, gravity)
has its coefficient fixed by the model: the scenario may write ``"model"`` for its theta_i, and
for ``input_gain`` (b = gear / I), instead of typing the number. The backend reads each from the
compiled model when the scenario loads (:attr:`~qcontrol.plants.backends.Backend.model_coefficients`),
and the number is written into the scenario's data, so the resolved scenario of every output's
provenance states it. A number given instead is checked against the model as before.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from ..plants.backends import BACKENDS
from ..plants.base import PlantTerms
from ..schema import Table, type_name

FROM_MODEL = "model"


def _entry(table: Table, key: str, value: Any, positive: bool = False) -> float | str:
    """A number, or ``"model"``; any other string is one line naming both choices."""
    if value == FROM_MODEL:
        return FROM_MODEL
    if isinstance(value, str):
        raise table.error(key, f"must be a number or \"model\", got {type_name(value)} {value!r}",
                          "write a number, or \"model\" for a coefficient MuJoCo's physics makes (read "
                          "from the model at load)")
    return table.check_number(key, value, positive)


def read_theta(table: Table, key: str, default: Any, sizes: dict[str, int]) -> tuple[float | str, ...]:
    """``plant.theta``: one number (or ``"model"``) per phi_i."""
    value = table.get(key, default)
    if not isinstance(value, list):
        raise table.error(key, f"must be a list of numbers, got {type_name(value)}", "write e.g. [1.0, 2.0]")
    if len(value) != sizes["l"]:
        raise table.error(key, f"has {len(value)} entries, expected {sizes['l']}",
                          f"give exactly {sizes['l']} number(s), one per phi_i")
    return tuple(_entry(table, f"{key}[{i}]", v) for i, v in enumerate(value))


def read_input_gain(table: Table, key: str, default: Any, sizes: dict[str, int]) -> float | str | None:
    """``plant.input_gain``: a number > 0, ``"model"``, or absent (None)."""
    value = table.get(key, default)
    return None if value is None else _entry(table, key, value, positive=True)


def provisional(terms: PlantTerms) -> PlantTerms:
    """``terms`` with 0 in place of each ``"model"`` (for checks that read only the terms' form)."""
    theta = tuple(0.0 if t == FROM_MODEL else t for t in terms.theta)
    gain = None if terms.input_gain == FROM_MODEL else terms.input_gain
    return replace(terms, theta=theta, input_gain=gain)


def from_model(plant: Table, terms: PlantTerms, backends: dict[str, Any], dt: float
               ) -> tuple[PlantTerms, dict[str, Any]]:
    """``terms`` with every ``"model"`` replaced by the model's number, and the entries of
    ``[plant]`` that then state the numbers (the scenario's data is updated with them, so that its
    resolved text states them; none when nothing was left to the model); one line naming the key
    where no model gives it."""
    left = [i for i, t in enumerate(terms.theta) if t == FROM_MODEL]
    if not left and terms.input_gain != FROM_MODEL:
        return terms, {}
    first = f"theta[{left[0]}]" if left else "input_gain"
    deriving = [name for name, backend in BACKENDS.items()
                if name in backends and backend.model_coefficients is not None]
    if not deriving:
        raise plant.error(first, "is \"model\", but the plant has no model that makes its terms",
                          "write the number, or add [plant.mujoco] (the MJCF whose physics makes the term)")
    name = deriving[0]
    coefficients, gain = BACKENDS[name].model_coefficients(backends[name], provisional(terms), dt)
    theta = list(terms.theta)
    for i in left:
        theta[i] = _coefficient(plant, i, terms, coefficients, name)
    stated = gain if terms.input_gain == FROM_MODEL else terms.input_gain
    written = {"theta": tuple(theta)} | ({"input_gain": stated} if stated is not None else {})
    return replace(terms, theta=tuple(theta), input_gain=stated), written


def _coefficient(plant: Table, i: int, terms: PlantTerms, coefficients: dict[str, float | None],
                 backend: str) -> float:
    """The model's theta_i, or one line saying why it has none."""
    term = f"phi{i + 1}"
    if term not in coefficients:
        raise plant.error(f"theta[{i}]", f"is \"model\", but {term} is not in plant.{backend}.native_terms",
                          f"add \"{term}\" to native_terms (MuJoCo's physics then makes it), or write the "
                          "number")
    value = coefficients[term]
    if value is None:
        raise plant.error(f"theta[{i}]", f"is \"model\", but MuJoCo's physics makes no term "
                          f"{terms.phi[i].source} (qcontrol model prints the terms it makes)",
                          "write the number, and leave the term out of native_terms (the passive callback "
                          "then adds it)")
    return value
