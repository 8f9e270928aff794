"""Scenario files: TOML -> a validated :class:`Scenario`.

A scenario is data: the plant (order, psi, phi, theta, x0, and a model per backend), the
controller (kind, delta, gains and the kind's own settings), the reference, and the simulation
settings. Every key is declared once (:mod:`.keys`, and the kinds' own modules); every problem is
reported as one line naming the file (or the override, when the value came from one), the key,
what is wrong and the fix. Unknown keys, and keys that do not apply to the chosen kind, are errors.
``--unset key`` removals, then ``--set key=value`` overrides, are applied to the file's data before
validation (:mod:`.overrides`; docs/scenarios.md); the ``[plant]`` table is read by :mod:`.plant_table`.
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from ..controller.law import KIND_ALIASES, LawContext, check_plant_class, law_kind
from ..disturbance import Disturbance, parse_disturbances
from ..engine import MetricSettings
from ..errors import KeyNotForKind, OverrideError, QcontrolInputError, shown
from ..expr import Expression
from ..outputs import check_name, path_kind
from ..plants.base import PlantTerms, timed
from ..quantizers import QuantizerSpec, channel_bounds, quantizer_step, read_quantizers
from ..reference import REFERENCE_KINDS
from ..resources import scenario_path, shipped_scenarios
from ..schema import Section, Table, kind_table, read_keys
from ..sharing import WITHOUT_X0, Stages, kept, per_object, sharing
from ..timegrid import TimeGrid
from .definition import ControllerConfig, ReferenceConfig, SimulationConfig
from .from_model import from_model, provisional
from .keys import (
    MAX_STEPS,
    METRICS,
    TOP,
    controller_section,
    reference_section,
    required_tables,
    scenario_section,
    simulation_section,
)
from .limits import check_limits
from .overrides import (
    Overrides,
    apply_override,
    as_given,
    check_overrides,
    command_line_fix,
    from_override,
    owned,
    remove_key,
    set_key,
)
from .plant_table import backend_sections, initial_state, plant_section, plant_terms


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
    rows_expr: tuple[tuple[Expression, ...], ...] = field(default=(), repr=False)  # phi_1 .. phi_{n-1}
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
                              overrides=(*self.overrides, *as_given(overrides)), default_name=self.name,
                              unset=self.unset)

    @cached_property
    def terms(self) -> PlantTerms:
        """The right-hand side of eq. (1) as the plants are built from it (made once)."""
        return PlantTerms(self.order, self.psi_expr, self.phi_expr, self.theta, self.input_gain,
                          rows=self.rows_expr)

    @cached_property
    def law_context(self) -> LawContext:
        """What the controller kind reads of the scenario (see :class:`LawContext`; made once)."""
        c = self.controller
        sim = self.simulation
        return LawContext(self.source, self.order, c.delta, c.c, self.psi_expr, self.phi_expr, self.theta,
                          sim.dt, sim.period, input_gain=self.terms.b,
                          quantizer_error=channel_bounds(self.quantizer), rows=self.rows_expr)

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


def read_only(value: Any) -> Any:
    """A read-only view of parsed TOML: tables as ``MappingProxyType``, arrays as tuples, so a
    scenario's ``data`` cannot drift from what it ran (and its provenance). While
    :func:`~qcontrol.sharing.sharing` is on, the view of a table or array is made once per object
    (the variants of a file share the views of the tables they did not write)."""
    if isinstance(value, Mapping):
        return MappingProxyType({k: _view(v) for k, v in value.items()})
    if isinstance(value, list | tuple):
        return tuple(_view(v) for v in value)
    return value


def _view(value: Any) -> Any:
    return per_object(read_only, value) if isinstance(value, Mapping | list | tuple) else value


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
    return load_variants(path, [overrides], unset)[0]


def load_variants(path: str | Path, override_sets: Sequence[Overrides], unset: Sequence[str] = (),
                  each: Callable[[Scenario], object] | None = None) -> list[Scenario]:
    """The scenario of each override set, each exactly what :func:`load_scenario` gives it: the
    file read once, and what the variants share checked once (:func:`~qcontrol.sharing.sharing`); the
    first bad variant is refused as it would be alone. ``each`` is called on every variant as soon
    as it is loaded (a check of the caller's, which may refuse it before the next one loads)."""
    if not isinstance(path, str | Path):
        raise QcontrolInputError(f"load_scenario: path must be a file path (str or Path) or a shipped "
                                 f"scenario's name, got {type(path).__name__}")
    for overrides in override_sets:
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
    name = path.stem if path.stem.isprintable() else repr(path.stem)[1:-1]
    variants = []
    with sharing():
        for overrides in override_sets:
            variants.append(parse_scenario(text, source=str(path), base_dir=path.parent, overrides=overrides,
                                           default_name=name, unset=unset))
            if each is not None:
                each(variants[-1])
    return variants


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
    data = _file_data(text, source, tuple(unset))
    given = as_given(overrides)
    for item in given:  # strings and (key, value) pairs: the latter come from dicts
        owned(data, item.partition("=")[0].strip() if isinstance(item, str) else str(item[0]))
        if isinstance(item, str):
            apply_override(data, item)
        else:
            set_key(data, item[0], item[1], item)
    try:
        _current_kind_names(data, source)
        scenario = _build(data, source, base_dir or Path("."), text, given, default_name)
    except KeyNotForKind as exc:
        raise command_line_fix(exc, given) from None
    except OverrideError:
        raise
    except QcontrolInputError as exc:  # (what the file holds tells the overrides' keys apart)
        raise from_override(exc, source, given, _file_data(text, source, tuple(unset))) from None
    return replace(scenario, unset=tuple(unset)) if unset else scenario


def _file_data(text: str, source: str, unset: tuple[str, ...]) -> dict:
    """The file's data, checked against :mod:`.limits`, with the ``unset`` keys removed. While
    :func:`~qcontrol.sharing.sharing` is on, the file is read once and its tables are shared by
    the variants: whatever writes into a table of the data (an override, the load) writes into a
    copy of it made first (:func:`.overrides.owned`)."""
    return dict(kept(("file", text, source, unset), lambda: _read_file(text, source, unset)))


def _read_file(text: str, source: str, unset: tuple[str, ...]) -> dict:
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
    return data


def _current_kind_names(data: dict, source: str) -> None:
    """A controller kind (and its sub-table) written under a former name takes its current one
    (``baseline`` -> ``comparison``), so that older scenario files and commands keep working."""
    controller = data.get("controller")
    if not isinstance(controller, dict):
        return
    kind = controller.get("kind")
    if isinstance(kind, str) and kind in KIND_ALIASES or any(isinstance(controller.get(o), dict)
                                                             for o in KIND_ALIASES):
        controller = data["controller"] = dict(controller)  # (the file's table may be shared: _file_data)
    if isinstance(kind, str) and kind in KIND_ALIASES:
        controller["kind"] = KIND_ALIASES[kind]
    for old, new in KIND_ALIASES.items():
        if isinstance(controller.get(old), dict):
            if new in controller:
                raise QcontrolInputError(f"{source}: [controller.{old}] is the former name of "
                                         f"[controller.{new}], which is there too; keep one of them")
            controller[new] = controller.pop(old)


def _build(data: dict, source: str, base_dir: Path, text: str, overrides: tuple[str | tuple[str, Any], ...],
           default_name: str) -> Scenario:
    """The scenario of ``data``, stage by stage; each stage a function of the tables it names
    (kept for the next variant while :func:`~qcontrol.sharing.sharing` is on)."""
    root = Table(data, source, "", TOP)
    for key in kept(("required tables",), required_tables):
        if key not in data:
            raise QcontrolInputError(f"{source}: [{key}]: missing table; add a [{key}] section")
    stages = Stages(data, source, base_dir)
    meta = stages.run("scenario", ("scenario",), _meta, root, default_name, also=(default_name,))
    plant = plant_section(root)
    terms, _ = stages.run("plant", (WITHOUT_X0,), plant_terms, plant)
    x0 = initial_state(plant, terms.order)  # (the stage's is the first variant's with these terms)
    simulation = stages.run("simulation", ("simulation",), _simulation, root)
    backends, terms, written = stages.run("backends", (WITHOUT_X0, "simulation"), _backends, plant, terms,
                                          base_dir, simulation)
    if written:  # the coefficients left to the model: the scenario's data states them
        data["plant"] = plant.data | plain_data(written)  # (a copy: the file's table may be shared)
        stages.changed("plant")
    quantizer, input_quantizer = (None, None) if "quantizer" not in data else stages.run(
        "quantizer", ("quantizer",), read_quantizers, root.table("quantizer"), terms.order,
        also=(terms.order,))
    controller = stages.run("controller", ("controller", WITHOUT_X0, "simulation", "quantizer"), _controller,
                            root.table("controller", default={}), terms, simulation, quantizer)
    signal = stages.run("reference", ("reference",), _reference, root.table("reference", default={}),
                        terms.order, also=(terms.order,))
    metrics = stages.run("metrics", ("metrics",), _metrics, root.table("metrics", default={}))
    disturbances = stages.run("disturbance", ("disturbance",), parse_disturbances, data.get("disturbance"),
                              source)
    scenario = Scenario(
        name=meta["name"], description=meta["description"], source=source, text=text, overrides=overrides,
        data=read_only(data), base_dir=base_dir,
        order=terms.order, theta=terms.theta, x0=x0, controller=controller,
        reference=signal, simulation=simulation, backends=MappingProxyType(backends),
        disturbances=disturbances,
        psi_expr=terms.psi, phi_expr=terms.phi, rows_expr=terms.rows, metrics=metrics,
        paper_example=meta["paper_example"],
        input_gain=terms.input_gain, quantizer=quantizer, input_quantizer=input_quantizer,
    )
    stages.run("x0", ("plant",), _check_terms_at_x0, scenario)
    return scenario


def _meta(root: Table, default_name: str) -> dict[str, Any]:
    about = scenario_section(default_name)
    table = Table(root.data.get("scenario", {}), root.source, "scenario", about.names)
    return read_keys(table, about.keys, {})


def _backends(plant: Table, terms: PlantTerms, base_dir: Path, simulation: SimulationConfig
              ) -> tuple[dict[str, Any], PlantTerms, dict[str, Any]]:
    """Each backend's section, and the terms with the coefficients left to the model resolved
    (and the entries of ``[plant]`` that state them; :func:`~.from_model.from_model`)."""
    backends = backend_sections(plant, provisional(terms), base_dir, simulation)
    return backends, *from_model(plant, terms, backends, simulation.dt)


def _chosen(table: Table, section: Section, sizes: dict[str, int] | None = None
            ) -> tuple[dict[str, Any], Table]:
    """The common keys of a kinded table (``kind`` first) and the merged table of the chosen kind's
    keys; ``sizes`` gives the lengths the common keys' lists must have."""
    common = read_keys(table, section.keys, sizes or {})
    return common, kind_table(table, section.names, section.kinds, common["kind"])


def _controller(table: Table, terms: PlantTerms, simulation: SimulationConfig,
                quantizer: QuantizerSpec | None) -> ControllerConfig:
    v, merged = _chosen(table, kept(("controller section",), controller_section), {"n": terms.order})
    kind, delta = v["kind"], quantizer_step(table, v["delta"], quantizer)
    ctx = LawContext(table.source, terms.order, delta, v["c"], terms.psi, terms.phi, terms.theta,
                     simulation.dt, simulation.period, controller=table, input_gain=terms.b,
                     quantizer_error=channel_bounds(quantizer), rows=terms.rows)
    check_plant_class(kind, ctx, table.path("kind"))
    return ControllerConfig(kind, delta, v["c"], law_kind(kind).parse(merged, ctx))


def _reference(table: Table, order: int) -> ReferenceConfig:
    common, merged = _chosen(table, reference_section())
    return ReferenceConfig(common["kind"], REFERENCE_KINDS[common["kind"]].parse(merged, order))


def _simulation(root: Table) -> SimulationConfig:
    section = simulation_section()
    table = root.table("simulation", section.names, default={})
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


def _check_terms_at_x0(sc: Scenario) -> None:
    """The plant's terms must be finite at the initial state."""
    rows = [(f"plant.phi[{r}][{j}]", e) for r, row in enumerate(sc.rows_expr) for j, e in enumerate(row)]
    last = "plant.phi[{i}]" if not rows else f"plant.phi[{len(sc.rows_expr)}][{{i}}]"
    at = np.asarray([list(sc.x0)], dtype=float), np.asarray([[*sc.x0, 0.0]], dtype=float)  # (t = 0)
    for label, expr in [("plant.psi", sc.psi_expr)] + rows + [(last.format(i=i), e) for i,
                                                              e in enumerate(sc.phi_expr)]:
        if expr is None:
            continue
        with np.errstate(all="ignore"):
            value = expr(at[timed(expr)])
        if not np.all(np.isfinite(value)):
            raise QcontrolInputError(
                f"{sc.source}: {label}: {expr.source!r} is not finite at x0 = {list(sc.x0)}; "
                "fix the formula or the initial state"
            )
