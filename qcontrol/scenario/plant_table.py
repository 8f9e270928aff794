"""The ``[plant]`` table: the terms of eq. (1) (psi, phi, theta, the input gain, x0), phi as
regressor rows for a strict-feedback plant, and one sub-table per backend, each parsed by its
backend."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import QcontrolInputError
from ..expr import Expression, compile_expression
from ..plants.backends import BACKENDS, PlantContext
from ..plants.base import TIME, PlantTerms
from ..schema import Table, read_keys
from .definition import SimulationConfig
from .keys import PLANT


def plant_section(root: Table) -> Table:
    """``[plant]``: the keys of eq. (1) and one sub-table per backend; a backend's key written
    directly in [plant] is refused with the sub-table it belongs in."""
    plant = root.table("plant")
    names = PLANT.names
    for key in plant.data:
        if key in names or key in BACKENDS:
            continue
        owners = [name for name, backend in BACKENDS.items()
                  if backend.section is not None and key in backend.section.names]
        if owners:
            raise plant.error(key, f"does not apply to [plant] (it is a setting of backend {owners[0]!r})",
                              f"write it in [plant.{owners[0]}]")
    return Table(plant.data, plant.source, plant.name, (*names, *BACKENDS))


def plant_terms(plant: Table) -> tuple[PlantTerms, tuple[float, ...]]:
    """The terms of eq. (1), compiled, and the initial state."""
    order = plant.integer("order", minimum=2)
    given = plant.get("phi", [])
    table_rows = isinstance(given, list) and any(isinstance(row, list) for row in given)
    rows_text = _regressor_rows(plant, order) if table_rows else ()
    last = Table(dict(plant.data, phi=list(rows_text[-1])), plant.source, plant.name) if table_rows else plant
    phi_text = last.strings("phi", [])
    v = read_keys(last, PLANT.keys, {"n": order, "l": len(phi_text)})
    x_names = [f"x{i + 1}" for i in range(order)]
    where = f"{plant.source}: {plant.name}"
    psi = None if v["psi"] is None else _plant_term(v["psi"], x_names, f"{where}.psi")
    if not table_rows:
        phi = tuple(_plant_term(p, x_names, f"{where}.phi[{i}]") for i, p in enumerate(v["phi"]))
        return PlantTerms(order, psi, phi, v["theta"], v["input_gain"]), v["x0"]
    earlier = tuple(tuple(_regressor(plant, text, x_names, r, j) for j, text in enumerate(row))
                    for r, row in enumerate(rows_text[:-1]))
    last_row = tuple(_plant_term(p, x_names, f"{where}.phi[{order - 1}][{j}]")
                     for j, p in enumerate(v["phi"]))
    return PlantTerms(order, psi, last_row, v["theta"], v["input_gain"], rows=earlier), v["x0"]


def initial_state(plant: Table, order: int) -> tuple[float, ...]:
    """``plant.x0``, read as :func:`plant_terms` reads it (which checks the keys before it)."""
    return _X0.type.read(plant, _X0.name, _X0.default, {"n": order})


_X0 = next(key for key in PLANT.keys if key.name == "x0")


def _plant_term(text: str, x_names: list[str], where: str) -> Expression:
    """A term of eq. (1) over ``x1..xn``, or over ``x1..xn, t`` when it uses time t."""
    term = compile_expression(text, [*x_names, TIME], where)
    return term if TIME in term.used else compile_expression(text, x_names, where)


def _regressor_rows(plant: Table, order: int) -> tuple[tuple[str, ...], ...]:
    """``plant.phi`` given as n rows (row i: the regressors of equation i, every row of the same
    length l, "0" where absent), as text."""
    given = plant.get("phi")
    if len(given) != order or not all(isinstance(row, list) for row in given):
        raise plant.error("phi", f"has {len(given)} entries, not {order} rows (one list per equation)",
                          f"give {order} lists of the same length, \"0\" where a term is absent, or one "
                          "flat list for the last equation")
    rows = tuple(Table({"row": row}, plant.source, plant.path(f"phi[{r}]")).strings("row")
                 for r, row in enumerate(given))
    for r, row in enumerate(rows):
        if len(row) != len(rows[-1]):
            raise plant.error(f"phi[{r}]", f"has {len(row)} regressors but the last row has {len(rows[-1])}",
                              "give every row the same length l, \"0\" where a term is absent")
    return rows


def _regressor(plant: Table, text: str, x_names: list[str], r: int, j: int) -> Expression:
    """Regressor j of row r (0-based) before the last, compiled; it reads x1 .. x_{r+1} only
    (lower-triangular: phi_i depends on the first i states)."""
    where = f"{plant.source}: {plant.path(f'phi[{r}][{j}]')}"
    allowed = x_names[: r + 1]
    expression = compile_expression(text, [*x_names, TIME], where)
    later = sorted(set(expression.used) - set(allowed), key=[*x_names, TIME].index)
    if later:
        raise QcontrolInputError(
            f"{where}: {text!r} reads {later[0]}, which row {r + 1} may not read; row {r + 1} (the "
            f"regressors of x{r + 1}') may read {', '.join(allowed)} only (a strict-feedback plant)")
    return compile_expression(text, x_names, where)


def backend_sections(plant: Table, terms: PlantTerms, base_dir: Path,
                     simulation: SimulationConfig) -> dict[str, Any]:
    """Each backend's ``[plant.<name>]`` section, parsed by the backend (the sections written in
    the file first, then those left out whose keys all default, parsed from their defaults); the
    chosen backend must have the section it needs."""
    ctx = PlantContext(terms, base_dir, simulation.dt)
    parsed = {}
    for name, backend in BACKENDS.items():
        if name in plant.data and backend.parse is not None:
            parsed[name] = backend.parse(plant.table(name), ctx)
        elif name in plant.data:
            raise plant.error(name, f"backend {name!r} takes no settings", f"remove [plant.{name}]")
    for name, backend in BACKENDS.items():
        if name not in parsed and backend.section is not None and backend.section.optional and backend.parse:
            parsed[name] = backend.parse(plant.table(name, default={}), ctx)
    chosen = BACKENDS[simulation.backend]
    if chosen.section is not None and simulation.backend not in parsed:
        raise QcontrolInputError(
            f"{plant.source}: simulation.backend: is {simulation.backend!r} but the plant has no "
            f"[plant.{simulation.backend}] table; add [plant.{simulation.backend}] "
            f"({chosen.section.meaning}), or use backend = \"ode\""
        )
    return parsed
