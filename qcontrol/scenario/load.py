"""Scenario files: TOML -> a validated :class:`Scenario`.

A scenario is data: the plant (order, psi, phi, theta, x0, and a model per backend), the
controller (kind, delta, gains and the kind's own settings), the reference, and the simulation
settings. Every key is declared once (:mod:`.keys`, and the kinds' own modules); every problem is
reported as one line naming the file (or the override, when the value came from one), the key,
what is wrong and the fix. Unknown keys, and keys that do not apply to the chosen kind, are errors.
``--unset key`` removals, then ``--set key=value`` overrides, are applied to the file's data before
validation (docs/scenarios.md).
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from ..controller.law import KIND_ALIASES, LawContext, law_kind
from ..disturbance import Disturbance, parse_disturbances
from ..engine import MetricSettings
from ..errors import KeyNotForKind, OverrideError, QcontrolInputError, brief, shown
from ..expr import Expression, compile_expression
from ..outputs import check_name, path_kind
from ..plants.backends import BACKENDS, PlantContext
from ..plants.base import TIME, PlantTerms, timed
from ..quantizers import QuantizerSpec, channel_bounds, quantizer_step, read_quantizers
from ..reference import REFERENCE_KINDS
from ..resources import scenario_path, shipped_scenarios
from ..schema import Section, Table, kind_table, read_keys, show_key
from ..timegrid import TimeGrid
from .definition import ControllerConfig, ReferenceConfig, SimulationConfig
from .from_model import from_model, provisional
from .keys import (
    MAX_STEPS,
    METRICS,
    PLANT,
    TOP,
    controller_section,
    reference_section,
    required_tables,
    scenario_section,
    simulation_section,
)
from .limits import check_limits

Overrides = Sequence[str] | Mapping[str, Any]  # "key=value" strings (the value read as TOML), or a dict


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
    theta: tuple[float, ...]
    x0: tuple[float, ...]
    controller: ControllerConfig
    reference: ReferenceConfig
    simulation: SimulationConfig
    backends: Mapping[str, Any] = field(default_factory=dict)  # read-only: a MappingProxyType
    disturbances: tuple[Disturbance, ...] = ()
    metrics: MetricSettings = field(default_factory=MetricSettings)
    # the TOML after overrides, read-only (tables as mappingproxy, arrays as tuples; plain_data copies it)
    data: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    base_dir: Path = field(default=Path("."), repr=False, compare=False)  # paths in it are relative to it
    psi_expr: Expression | None = field(default=None, repr=False)
    phi_expr: tuple[Expression, ...] = field(default=(), repr=False)
    unset: tuple[str, ...] = ()  # keys removed from the file (--unset) before the overrides
    paper_example: int | None = None  # the paper's example this scenario reproduces, if any
    input_gain: float | None = None  # plant.input_gain as stated (None: not stated, b = 1)
    quantizer: QuantizerSpec | None = None  # [quantizer] (None: controller.delta's uniform step)
    input_quantizer: QuantizerSpec | None = None  # [quantizer.input] (None: u applied as computed)

    def with_overrides(self, overrides: Mapping[str, Any] | Sequence[str]) -> Scenario:
        """A new scenario: this one's file with its overrides and then ``overrides`` (a dict
        ``{"controller.kappa_margin": 0.1}`` or ``"key=value"`` strings) applied. Scenarios are
        immutable: this one is unchanged."""
        check_overrides(overrides, "with_overrides")
        return parse_scenario(self.text, source=self.source, base_dir=self.base_dir,
                              overrides=(*self.overrides, *_as_given(overrides)), default_name=self.name,
                              unset=self.unset)

    @cached_property
    def terms(self) -> PlantTerms:
        """The right-hand side of eq. (1) as the plants are built from it (made once)."""
        return PlantTerms(self.order, self.psi_expr, self.phi_expr, self.theta, self.input_gain)

    @cached_property
    def law_context(self) -> LawContext:
        """What the controller kind reads of the scenario (see :class:`LawContext`; made once)."""
        c = self.controller
        sim = self.simulation
        return LawContext(self.source, self.order, c.delta, c.c, self.psi_expr, self.phi_expr, self.theta,
                          sim.dt, sim.period, input_gain=self.terms.b,
                          quantizer_error=channel_bounds(self.quantizer))

    @property
    def psi(self) -> str | None:
        """The text of psi(x) as given (None: no psi)."""
        return None if self.psi_expr is None else self.psi_expr.source

    @property
    def phi(self) -> tuple[str, ...]:
        """The texts of phi_1(x) .. phi_l(x) as given."""
        return tuple(p.source for p in self.phi_expr)

    @property
    def uncertain_terms(self) -> int:
        """Entries of eps, eqs. (37)-(43) (:attr:`LawContext.uncertain_terms`)."""
        return self.law_context.uncertain_terms


def check_overrides(overrides: object, function: str) -> None:
    """Overrides as :func:`load_scenario` takes them, else one line naming ``function``."""
    strings = isinstance(overrides, list | tuple) and all(isinstance(o, str) for o in overrides)
    if not strings and not (isinstance(overrides, Mapping) and all(isinstance(k, str) for k in overrides)):
        raise QcontrolInputError(f"{function}: overrides must be a dict {{\"key\": value}} or a list of "
                                 f"\"key=value\" strings, got {overrides!r}")


def read_only(value: Any) -> Any:
    """A read-only view of parsed TOML: tables as ``MappingProxyType``, arrays as tuples, so a
    scenario's ``data`` cannot drift from what it ran (and its provenance)."""
    if isinstance(value, Mapping):
        return MappingProxyType({k: read_only(v) for k, v in value.items()})
    if isinstance(value, list | tuple):
        return tuple(read_only(v) for v in value)
    return value


def plain_data(value: Any) -> Any:
    """A writable copy of :func:`read_only`'s view: dicts and lists again."""
    if isinstance(value, Mapping):
        return {k: plain_data(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return [plain_data(v) for v in value]
    return value


def load_scenario(path: str | Path, overrides: Overrides = (), unset: Sequence[str] = ()) -> Scenario:
    """Read and validate a scenario file (or a shipped scenario by name, e.g. ``"example2"``),
    removing the ``unset`` keys and applying the overrides first: ``"key=value"`` strings as on the
    command line (``--set``), or a dict ``{"controller.kappa_margin": 0.1}``."""
    if not isinstance(path, str | Path):
        raise QcontrolInputError(f"load_scenario: path must be a file path (str or Path) or a shipped "
                                 f"scenario's name, got {type(path).__name__}")
    check_overrides(overrides, "load_scenario")
    if not isinstance(unset, list | tuple) or not all(isinstance(k, str) for k in unset):
        raise QcontrolInputError(f"load_scenario: unset must be a list of keys (strings), got {unset!r}")
    path = scenario_path(check_name(path, "scenario"))
    kind = path_kind(path)
    if kind is not None:
        raise QcontrolInputError(f"{shown(path)}: is {kind}, not a scenario file; pass a .toml scenario file")
    if not path.is_file():
        shipped = ", ".join(shipped_scenarios()) or "none"
        raise QcontrolInputError(f"{shown(path)}: scenario file not found; pass the path of a .toml scenario "
                                 f"or the name of a shipped one ({shipped})")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise QcontrolInputError(f"{shown(path)}: cannot read the scenario ({exc}); check the file") from None
    return parse_scenario(text, source=str(path), base_dir=path.parent, overrides=overrides,
                          default_name=path.stem if path.stem.isprintable() else repr(path.stem)[1:-1],
                          unset=unset)


def parse_scenario(
    text: str,
    source: str = "<string>",
    base_dir: Path | None = None,
    overrides: Overrides = (),
    default_name: str = "scenario",
    unset: Sequence[str] = (),
) -> Scenario:
    """Validate scenario TOML ``text``; ``source`` names it in messages, ``base_dir`` is the folder
    paths in it are relative to. The ``unset`` keys are removed first, then the overrides applied."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        if text.startswith("\ufeff"):
            raise QcontrolInputError(f"{source}: the file starts with a byte-order mark (U+FEFF), which TOML "
                                     "does not allow; save it as UTF-8 without a BOM") from None
        raise QcontrolInputError(f"{source}: malformed TOML ({exc}); fix the syntax") from None
    except (RecursionError, ValueError):  # ValueError: an integer literal of thousands of digits
        raise QcontrolInputError(f"{source}: arrays or tables nested too deep, or a number too long, to "
                                 "read; no key takes such a value: flatten or shorten it") from None
    check_limits(data, source)
    for key in unset:
        remove_key(data, key, source)
    given = _as_given(overrides)
    file_data = copy.deepcopy(data) if given else data  # what the file holds, to tell its keys apart
    for item in given:  # strings and (key, value) pairs: the latter come from dicts
        if isinstance(item, str):
            apply_override(data, item)
        else:
            set_key(data, item[0], item[1], item)
    try:
        _current_kind_names(data, source)
        scenario = _build(data, source, base_dir or Path("."), text, given, default_name)
    except KeyNotForKind as exc:
        raise _command_line_fix(exc, given) from None
    except OverrideError:
        raise
    except QcontrolInputError as exc:
        raise _from_override(exc, source, given, file_data) from None
    return replace(scenario, unset=tuple(unset)) if unset else scenario


def _current_kind_names(data: dict, source: str) -> None:
    """A controller kind (and its sub-table) written under a former name takes its current one
    (``baseline`` -> ``comparison``), so that older scenario files and commands keep working."""
    controller = data.get("controller")
    if not isinstance(controller, dict):
        return
    kind = controller.get("kind")
    if isinstance(kind, str) and kind in KIND_ALIASES:
        controller["kind"] = KIND_ALIASES[kind]
    for old, new in KIND_ALIASES.items():
        if isinstance(controller.get(old), dict):
            if new in controller:
                raise QcontrolInputError(f"{source}: [controller.{old}] is the former name of "
                                         f"[controller.{new}], which is there too; keep one of them")
            controller[new] = controller.pop(old)


def _command_line_fix(exc: KeyNotForKind, given: Sequence[str | tuple[str, Any]]) -> QcontrolInputError:
    """A key the chosen kind does not take, with the fix on the command line when the overrides
    chose the kind (the key is then the file's: ``--unset`` it) or set the key (named as the
    override: leave it out)."""
    keys = [(item.partition("=")[0] if isinstance(item, str) else item[0]).strip() for item in given]
    table = exc.key.rsplit(".", 1)[0]
    if exc.key in keys:
        item = given[len(keys) - 1 - keys[::-1].index(exc.key)]
        detail = str(exc).split(f": {exc.key}: ", 1)[-1]
        return OverrideError(override_label(item), f"{detail}; or leave out --set {exc.key}=...", item)
    if f"{table}.kind" in keys:
        return QcontrolInputError(f"{exc}; or, as the kind came from --set, remove the file's key: "
                                  f"--unset {exc.key}")
    return QcontrolInputError(str(exc))


def _from_override(exc: QcontrolInputError, source: str, given: Sequence[str | tuple[str, Any]],
                   file_data: dict) -> QcontrolInputError:
    """A problem the validator found at a key (``SOURCE: key: problem; fix``), named as the override
    that gave the key its value when one did (the last one, as it wins): the key itself or a table
    above it was set, or the key is a table the override made (it is not in the file)."""
    prefix = f"{source}: "
    message = str(exc)
    if not given or not message.startswith(prefix):
        return exc
    rest = message[len(prefix):]
    at = rest.split(": ", 1)[0]
    for item in reversed(given):
        key = (item.partition("=")[0] if isinstance(item, str) else item[0]).strip()
        if at == key:
            return OverrideError(override_label(item), rest[len(at) + 2:], item)
        inside = at.startswith((f"{key}.", f"{key}["))
        made = key.startswith(f"{at}.") and not _has_key(file_data, at)
        if inside or made:
            return OverrideError(override_label(item), rest, item)
    return exc


def _has_key(data: dict, dotted: str) -> bool:
    node: Any = data
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def override_label(item: str | tuple[str, Any]) -> str:
    """How a message names one override: ``--set key=value`` for a string (as on the command
    line), ``override key=value`` for an entry of a dict (the API); a long value is cut short."""
    if isinstance(item, str):
        key, sep, raw = item.partition("=")
        return f"--set {shown(key.strip())}{sep}{brief(raw.strip())}"
    return f"override {shown(item[0])}={brief(repr(item[1]))}"


def _as_given(overrides: Overrides) -> tuple[str | tuple[str, Any], ...]:
    """The overrides as entries: ``"key=value"`` strings, or ``(key, value)`` pairs from a dict
    (entries already in that form pass through)."""
    if isinstance(overrides, Mapping):
        return tuple((str(key), value) for key, value in overrides.items())
    if isinstance(overrides, str):
        raise QcontrolInputError(f"overrides {overrides!r}: give a list of \"key=value\" strings or a dict; "
                                 f"e.g. [{overrides!r}]")
    return tuple(item if isinstance(item, str) else (str(item[0]), item[1]) for item in overrides)


def remove_key(data: dict, key: str, source: str) -> None:
    """Remove one ``--unset`` key (a dotted path) from the file's data; a key that is not there is
    one line naming where it would be and what is there instead."""
    parts = key.strip().split(".")
    if not key.strip() or any(not p for p in parts):
        raise QcontrolInputError(f"--unset {key!r}: not a key path; write e.g. --unset reference.amplitude")
    node, where = data, "the top level"
    for depth, part in enumerate(parts[:-1]):
        child = node.get(part)
        if not isinstance(child, dict):
            path = ".".join(parts[: depth + 1])
            problem = (f"{path} is a value, not a table" if part in node
                       else f"{source} has no table [{path}]")
            raise QcontrolInputError(f"--unset {key}: {problem}; " + _present(node, where))
        node, where = child, f"[{'.'.join(parts[: depth + 1])}]"
    last = parts[-1]
    if last not in node:
        raise QcontrolInputError(f"--unset {key}: {source} has no key {last} in {where}; "
                                 + _moved(node, parts) + _present(node, where))
    del node[last]


def _moved(node: dict, parts: Sequence[str]) -> str:
    """A hint when the key sits in a sub-table of the table named (e.g. a kind's settings)."""
    holders = [name for name, value in node.items() if isinstance(value, dict) and parts[-1] in value]
    if not holders:
        return ""
    inner = ".".join([*parts[:-1], holders[0], parts[-1]])
    return f"it is in a sub-table: --unset {inner}; "


def _present(node: dict, where: str) -> str:
    names = ", ".join(show_key(k) for k in node) or "none"
    return f"the keys in {where} are {names}"


def apply_override(data: dict, item: str) -> None:
    """Apply one ``key.path=value`` override; the value is read as TOML, else as a string."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise OverrideError(override_label(item), "expected KEY=VALUE; write e.g. "
                            "--set controller.kappa_margin=0.1", item)
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError, ValueError):
        value = raw
    set_key(data, key, value, item)


def set_key(data: dict, key: str, value: Any, item: str | tuple[str, Any]) -> None:
    """Set the dotted ``key`` of the scenario's data to ``value`` (tables made as needed); ``item``
    is the override as given, which a problem names."""
    parts = key.split(".")
    if not key or any(not p for p in parts):
        raise OverrideError(override_label(item), f"key {shown(key)} has an empty part; write e.g. "
                            "--set controller.kappa_margin=0.1", item)
    node = data
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise OverrideError(override_label(item), f"{part!r} is a value, not a table; set "
                                f"{'.'.join(parts[:-1])} directly", item)
        node = child
    try:
        check_limits(value, "", key)
    except QcontrolInputError as exc:
        raise OverrideError(override_label(item), str(exc).removeprefix(f"{key}: "), item) from None
    node[parts[-1]] = value


def _build(data: dict, source: str, base_dir: Path, text: str, overrides: tuple[str | tuple[str, Any], ...],
           default_name: str) -> Scenario:
    root = Table(data, source, "", TOP)
    for key in required_tables():
        if key not in data:
            raise QcontrolInputError(f"{source}: [{key}]: missing table; add a [{key}] section")
    about = scenario_section(default_name)
    meta = read_keys(Table(data.get("scenario", {}), source, "scenario", about.names), about.keys, {})
    plant = _plant_table(root)
    terms, x0 = _plant(plant)
    simulation = _simulation(root.table("simulation", default={}))
    backends = _backends(plant, provisional(terms), base_dir, simulation)
    terms = from_model(plant, terms, backends, simulation.dt)  # the coefficients left to the model
    quantizer, input_quantizer = (read_quantizers(root.table("quantizer"), terms.order) if "quantizer" in data
                                  else (None, None))
    controller = _controller(root.table("controller", default={}), terms, simulation, quantizer)
    signal = _reference(root.table("reference", default={}), terms.order)
    metrics = _metrics(root.table("metrics", default={}))
    disturbances = parse_disturbances(data.get("disturbance"), source)
    scenario = Scenario(
        name=meta["name"], description=meta["description"], source=source, text=text, overrides=overrides,
        data=read_only(data), base_dir=base_dir,
        order=terms.order, theta=terms.theta, x0=x0, controller=controller,
        reference=signal, simulation=simulation, backends=MappingProxyType(backends),
        disturbances=disturbances,
        psi_expr=terms.psi, phi_expr=terms.phi, metrics=metrics, paper_example=meta["paper_example"],
        input_gain=terms.input_gain, quantizer=quantizer, input_quantizer=input_quantizer,
    )
    _check_terms_at_x0(scenario)
    return scenario


def _plant_table(root: Table) -> Table:
    """``[plant]``: the keys of eq. (1) and one sub-table per backend; a backend's key written
    directly in [plant] is refused with the sub-table it belongs in."""
    plant = root.table("plant")
    for key in plant.data:
        owners = [name for name, backend in BACKENDS.items()
                  if backend.section is not None and key in backend.section.names]
        if key not in PLANT.names and key not in BACKENDS and owners:
            raise plant.error(key, f"does not apply to [plant] (it is a setting of backend {owners[0]!r})",
                              f"write it in [plant.{owners[0]}]")
    return Table(plant.data, plant.source, plant.name, (*PLANT.names, *BACKENDS))


def _plant(plant: Table) -> tuple[PlantTerms, tuple[float, ...]]:
    """The terms of eq. (1), compiled, and the initial state."""
    order = plant.integer("order", minimum=2)
    phi_text = plant.strings("phi", [])
    v = read_keys(plant, PLANT.keys, {"n": order, "l": len(phi_text)})
    x_names = [f"x{i + 1}" for i in range(order)]
    where = f"{plant.source}: {plant.name}"
    psi = None if v["psi"] is None else _plant_term(v["psi"], x_names, f"{where}.psi")
    phi = tuple(_plant_term(p, x_names, f"{where}.phi[{i}]") for i, p in enumerate(v["phi"]))
    return PlantTerms(order, psi, phi, v["theta"], v["input_gain"]), v["x0"]


def _plant_term(text: str, x_names: list[str], where: str) -> Expression:
    """A term of eq. (1) over ``x1..xn``, or over ``x1..xn, t`` when it uses time t."""
    term = compile_expression(text, [*x_names, TIME], where)
    return term if TIME in term.used else compile_expression(text, x_names, where)


def _chosen(table: Table, section: Section, sizes: dict[str, int] | None = None
            ) -> tuple[dict[str, Any], Table]:
    """The common keys of a kinded table (``kind`` first) and the merged table of the chosen kind's
    keys; ``sizes`` gives the lengths the common keys' lists must have."""
    common = read_keys(table, section.keys, sizes or {})
    return common, kind_table(table, section.names, section.kinds, common["kind"])


def _controller(table: Table, terms: PlantTerms, simulation: SimulationConfig,
                quantizer: QuantizerSpec | None) -> ControllerConfig:
    v, merged = _chosen(table, controller_section(), {"n": terms.order})
    kind, delta = v["kind"], quantizer_step(table, v["delta"], quantizer)
    ctx = LawContext(table.source, terms.order, delta, v["c"], terms.psi, terms.phi, terms.theta,
                     simulation.dt, simulation.period, controller=table, input_gain=terms.b,
                     quantizer_error=channel_bounds(quantizer))
    return ControllerConfig(kind, delta, v["c"], law_kind(kind).parse(merged, ctx))


def _reference(table: Table, order: int) -> ReferenceConfig:
    common, merged = _chosen(table, reference_section())
    return ReferenceConfig(common["kind"], REFERENCE_KINDS[common["kind"]].parse(merged, order))


def _simulation(table: Table) -> SimulationConfig:
    section = simulation_section()
    table = Table(table.data, table.source, table.name, section.names)
    v = read_keys(table, section.keys, {})
    ratio = v["duration"] / v["dt"]
    if ratio > MAX_STEPS:
        raise table.error("duration", f"{v['duration']:g} s at dt = {v['dt']:g} s is {ratio:.3g} steps, more "
                          f"than the limit of {MAX_STEPS:,} steps per run (qcontrol run keeps only its "
                          "metrics, but compare and reproduce keep every step in memory: several GB at "
                          "the limit)", "shorten the run or use a larger dt")
    try:
        TimeGrid.of(v["duration"], v["dt"], v["control_period"])
    except QcontrolInputError as exc:
        raise QcontrolInputError(f"{table.source}: {exc}") from None
    return SimulationConfig(**v)


def _metrics(table: Table) -> MetricSettings:
    table = Table(table.data, table.source, table.name, METRICS.names)
    v = read_keys(table, METRICS.keys, {})
    if len(set(v["omega"])) != len(v["omega"]):
        raise table.error("omega", f"repeats a threshold in {list(v['omega'])}", "list each omega once")
    return MetricSettings(tuple(v["omega"]), v["samples"])


def _backends(plant: Table, terms: PlantTerms, base_dir: Path, simulation: SimulationConfig) -> dict[str,
                                                                                                     Any]:
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


def _check_terms_at_x0(sc: Scenario) -> None:
    """The plant's terms must be finite at the initial state."""
    for label, expr in [("plant.psi", sc.psi_expr)] + [(f"plant.phi[{i}]", e) for i,
                                                       e in enumerate(sc.phi_expr)]:
        if expr is None:
            continue
        with np.errstate(all="ignore"):
            value = expr(np.asarray([[*sc.x0, 0.0] if timed(expr) else list(sc.x0)]))
        if not np.all(np.isfinite(value)):
            raise QcontrolInputError(
                f"{sc.source}: {label}: {expr.source!r} is not finite at x0 = {list(sc.x0)}; "
                "fix the formula or the initial state"
            )
