"""Scenario files: TOML -> validated :class:`Scenario` (DESIGN "Scenario files").

A scenario is data: the plant (order, psi, phi, theta, x0, optional MuJoCo model), the controller
(kind, delta, gains, kappa, gamma, sigma, bounding functions r), the reference, and the simulation
settings. Every problem is reported as one line naming the file, the key, what is wrong and the
fix. Unknown keys are errors. ``--set key=value`` overrides are applied before validation.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import QcontrolInputError
from .expr import Expression, compile_expression

_MISSING = object()
CONTROLLER_KINDS = ("proposed", "baseline")
BACKENDS = ("ode", "mujoco")
REFERENCE_KINDS = ("sine", "constant", "sum_of_sines")
# The engine keeps every row of a run in memory (about 20 float64 per row for n = 2, more for larger
# n): 20 million steps is ~3 GB. Longer runs are refused at load instead of failing mid-way.
MAX_STEPS = 20_000_000
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+(\[[0-9]+\])*")


@dataclass(frozen=True)
class ReferenceConfig:
    kind: str
    amplitude: float = 1.0
    frequency: float = 1.0
    phase: float = 0.0
    offset: float = 0.0
    value: float = 0.0
    terms: tuple[tuple[float, float, float], ...] = ()  # (amplitude, frequency, phase)


@dataclass(frozen=True)
class ControllerConfig:
    kind: str
    delta: float
    c: tuple[float, ...]
    kappa: float | None
    kappa_margin: float | None
    gamma: float
    sigma: float
    r: tuple[str, ...]
    r_scale: float
    baseline_gain: float
    baseline_theta: str


@dataclass(frozen=True)
class SimulationConfig:
    duration: float
    dt: float
    control_period: float | None
    backend: str
    state_bound: float


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. Expressions are compiled once (``psi_expr``, ``phi_expr``, ``r_expr``)."""

    name: str
    description: str
    source: str  # where it came from (file path or "<string>")
    text: str  # the TOML text as read
    overrides: tuple[str, ...]
    order: int
    psi: str | None
    phi: tuple[str, ...]
    theta: tuple[float, ...]
    x0: tuple[float, ...]
    controller: ControllerConfig
    reference: ReferenceConfig
    simulation: SimulationConfig
    mujoco: Any = None  # qcontrol.plants.mujoco.MujocoOptions when [plant.mujoco] is given
    psi_expr: Expression | None = field(default=None, repr=False)
    phi_expr: tuple[Expression, ...] = field(default=(), repr=False)
    r_expr: tuple[Expression, ...] = field(default=(), repr=False)

    @property
    def state_names(self) -> list[str]:
        return [f"x{i + 1}" for i in range(self.order)]

    @property
    def uncertain_terms(self) -> int:
        """Entries of eps: one per phi_i, plus one for psi (SPEC 6)."""
        return len(self.phi) + (self.psi is not None)


# --------------------------------------------------------------------------------------------
# loading


def load_scenario(path: str | Path, overrides: Sequence[str] = ()) -> Scenario:
    """Read and validate a scenario file, applying ``--set key=value`` overrides first."""
    path = Path(path)
    if path.is_dir():
        raise QcontrolInputError(f"{path}: is a folder, not a scenario file; pass a .toml scenario")
    if not path.is_file():
        raise QcontrolInputError(f"{path}: scenario file not found; pass the path of a .toml scenario")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise QcontrolInputError(f"{path}: cannot read the scenario ({exc}); check the file") from None
    return parse_scenario(text, source=str(path), base_dir=path.parent, overrides=overrides,
                          default_name=path.stem)


def parse_scenario(
    text: str,
    source: str = "<string>",
    base_dir: Path | None = None,
    overrides: Sequence[str] = (),
    default_name: str = "scenario",
) -> Scenario:
    """Validate scenario TOML ``text``; ``source`` names it in messages."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise QcontrolInputError(f"{source}: malformed TOML ({exc}); fix the syntax") from None
    for item in overrides:
        apply_override(data, item, source)
    return _build(data, source, base_dir or Path("."), text, tuple(overrides), default_name)


def apply_override(data: dict, item: str, source: str) -> None:
    """Apply one ``key.path=value`` override; the value is read as TOML, else as a string."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise QcontrolInputError(
            f"--set {item!r}: expected KEY=VALUE; write e.g. --set controller.kappa_margin=0.1"
        )
    parts = key.split(".")
    if any(not p for p in parts):
        raise QcontrolInputError(f"--set {item!r}: key {key!r} has an empty part; write a.b.c=value")
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    node = data
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise QcontrolInputError(
                f"--set {item!r}: {part!r} is a value, not a table; set {'.'.join(parts[:-1])} directly"
            )
        node = child
    node[parts[-1]] = value


class _Table:
    """Typed, message-producing access to one TOML table."""

    def __init__(self, data: Any, source: str, name: str, allowed: Sequence[str]) -> None:
        self.source = source
        self.name = name
        if not isinstance(data, dict):
            raise self.error_at(name or "(top level)", f"must be a table, got {_type(data)}",
                                f"write [{name}]")
        unknown = sorted(set(data) - set(allowed))
        if unknown:
            raise self.error(
                unknown[0], "unknown key",
                f"allowed keys {'in [' + name + '] ' if name else ''}are {', '.join(allowed)}",
            )
        self.data = data

    def error_at(self, key: str, problem: str, fix: str) -> QcontrolInputError:
        return QcontrolInputError(f"{self.source}: {key}: {problem}; {fix}")

    def error(self, key: str, problem: str, fix: str) -> QcontrolInputError:
        return self.error_at(self._path(key), problem, fix)

    def _path(self, key: str) -> str:
        key = _show_key(key)
        return f"{self.name}.{key}" if self.name else key

    def has(self, key: str) -> bool:
        return key in self.data

    def _get(self, key: str, default: Any) -> Any:
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            raise self.error(key, "missing", "add it to the scenario")
        return default

    def number(self, key: str, default: Any = _MISSING, *, positive: bool = False,
               nonnegative: bool = False) -> float:
        value = self._get(key, default)
        if value is None:
            return value
        return self._check_number(key, value, positive, nonnegative)

    def _check_number(self, key: str, value: Any, positive: bool, nonnegative: bool) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"must be a number, got {_type(value)} {value!r}", "write e.g. 1.5")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {value}", "use a finite number")
        if positive and value <= 0:
            raise self.error(key, f"must be > 0, got {value:g}", "use a positive number")
        if nonnegative and value < 0:
            raise self.error(key, f"must be >= 0, got {value:g}", "use a number >= 0")
        return value

    def numbers(self, key: str, length: int | None = None, *, positive: bool = False,
                default: Any = _MISSING) -> tuple[float, ...]:
        value = self._get(key, default)
        if not isinstance(value, list):
            raise self.error(key, f"must be a list of numbers, got {_type(value)}", "write e.g. [1.0, 2.0]")
        if length is not None and len(value) != length:
            raise self.error(key, f"has {len(value)} entries, expected {length}",
                             f"give exactly {length} number(s)")
        return tuple(self._check_number(f"{key}[{i}]", v, positive, False) for i, v in enumerate(value))

    def integer(self, key: str, default: Any = _MISSING, minimum: int | None = None) -> int:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be a whole number, got {_type(value)} {value!r}", "write e.g. 2")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum}, got {value}", f"use a value >= {minimum}")
        return value

    def string(self, key: str, default: Any = _MISSING, choices: Sequence[str] | None = None) -> str:
        value = self._get(key, default)
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {_type(value)}", 'write e.g. "text"')
        if choices is not None and value not in choices:
            raise self.error(key, f"{value!r} is not allowed", f"use one of {', '.join(choices)}")
        return value

    def strings(self, key: str, default: Any = _MISSING) -> tuple[str, ...]:
        value = self._get(key, default)
        if isinstance(value, str) or not isinstance(value, list):
            raise self.error(key, f"must be a list of expression strings, got {_type(value)}",
                             'write e.g. ["x2", "sin(x1)"]')
        for i, v in enumerate(value):
            if not isinstance(v, str):
                raise self.error(f"{key}[{i}]", f"must be an expression string, got {_type(v)}",
                                 'quote it, e.g. "1 + q2**2"')
        return tuple(value)

    def table(self, key: str, allowed: Sequence[str], default: Any = _MISSING) -> _Table:
        return _Table(self._get(key, default), self.source, self._path(key), allowed)


def _show_key(key: str) -> str:
    """A key as it may appear in a one-line message: bare if it is a plain name (or an indexed
    one such as ``c[1]``), otherwise quoted like a TOML quoted key (newlines escaped)."""
    if _BARE_KEY.fullmatch(key):
        return key
    return json.dumps(key)


def _type(value: Any) -> str:
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            list: "a list", dict: "a table"}.get(type(value), type(value).__name__)


_TOP = ("scenario", "plant", "controller", "reference", "simulation")
_PLANT = ("order", "psi", "phi", "theta", "x0", "mujoco")
_CONTROLLER = ("kind", "delta", "c", "kappa", "kappa_margin", "gamma", "sigma", "r", "r_scale",
               "baseline_gain", "baseline_theta")
_REFERENCE = ("kind", "amplitude", "frequency", "phase", "offset", "value", "terms")
_SIMULATION = ("duration", "dt", "control_period", "backend", "state_bound")


def _build(data: dict, source: str, base_dir: Path, text: str, overrides: tuple[str, ...],
           default_name: str) -> Scenario:
    root = _Table(data, source, "", _TOP)
    for key in ("plant", "controller", "reference", "simulation"):
        if key not in data:
            raise QcontrolInputError(f"{source}: [{key}]: missing table; add a [{key}] section")
    meta = _Table(data.get("scenario", {}), source, "scenario", ("name", "description"))
    name = meta.string("name", default_name)
    description = meta.string("description", "")

    plant = root.table("plant", _PLANT)
    order = plant.integer("order", minimum=2)
    x_names = [f"x{i + 1}" for i in range(order)]
    q_names = [f"q{i + 1}" for i in range(order)]
    psi = plant.string("psi", None) if plant.has("psi") else None
    phi = plant.strings("phi", [])
    theta = plant.numbers("theta", len(phi), default=[])
    x0 = plant.numbers("x0", order)
    psi_expr = compile_expression(psi, x_names, f"{source}: plant.psi") if psi is not None else None
    phi_expr = tuple(compile_expression(p, x_names, f"{source}: plant.phi[{i}]") for i, p in enumerate(phi))

    ctrl = root.table("controller", _CONTROLLER)
    kind = ctrl.string("kind", "proposed", CONTROLLER_KINDS)
    delta = ctrl.number("delta", positive=True)
    c = ctrl.numbers("c", order, positive=True)
    kappa = ctrl.number("kappa", None, positive=True) if ctrl.has("kappa") else None
    kappa_margin = ctrl.number("kappa_margin", None, positive=True) if ctrl.has("kappa_margin") else None
    if kappa is not None and kappa_margin is not None:
        raise ctrl.error("kappa", "given together with kappa_margin",
                         "give either kappa or kappa_margin (kappa = L + kappa_margin), not both")
    r: tuple[str, ...] = ()
    r_expr: tuple[Expression, ...] = ()
    if kind == "proposed":
        if kappa is None and kappa_margin is None:
            raise ctrl.error("kappa_margin", "missing", "give kappa_margin (kappa = L + margin) or kappa")
        r = ctrl.strings("r")
        terms = len(phi) + (psi is not None)
        if len(r) != terms:
            raise ctrl.error("r", f"has {len(r)} bounding function(s) but the plant has {terms} "
                             "uncertain term(s)", "give one r_i per phi_i, plus one for psi (SPEC 6)")
        r_expr = tuple(
            compile_expression(e, q_names, f"{source}: controller.r[{i}]") for i, e in enumerate(r)
        )
    else:
        r = ctrl.strings("r", [])
    controller = ControllerConfig(
        kind=kind,
        delta=delta,
        c=c,
        kappa=kappa,
        kappa_margin=kappa_margin,
        gamma=ctrl.number("gamma", 1.0 if kind == "baseline" else _MISSING, positive=True),
        sigma=ctrl.number("sigma", 1.0 if kind == "baseline" else _MISSING, positive=True),
        r=r,
        r_scale=ctrl.number("r_scale", 1.0, positive=True),
        baseline_gain=ctrl.number("baseline_gain", 1.0, positive=True),
        baseline_theta=ctrl.string("baseline_theta", "adaptive", ("adaptive", "known")),
    )
    if kind == "proposed":
        from .controller import lemma2_bounds

        with np.errstate(all="ignore"):
            L = float(lemma2_bounds(c, delta / 2.0)[0][-1])
        if not math.isfinite(L):
            raise ctrl.error("delta", f"with c = {list(c)} gives L = L_z{order} = {L:g}, not a finite number",
                             "use a smaller quantizer step delta or smaller gains c")
        if kappa is not None and kappa <= L:
            raise ctrl.error("kappa", f"must exceed L = L_z{order} = {L:g} (Theorem 1), got {kappa:g}",
                             f"use kappa > {L:g}, or kappa_margin = kappa - L > 0")
        if kappa_margin is not None and not math.isfinite(L + kappa_margin):
            raise ctrl.error("kappa_margin", f"{kappa_margin:g} makes kappa = L + kappa_margin overflow "
                             f"(L = {L:g})", "use a smaller margin")
        if kappa_margin is not None and not L + kappa_margin > L:
            raise ctrl.error("kappa_margin", f"{kappa_margin:g} is lost in floating point next to L = "
                             f"L_z{order} = {L:g}, so kappa = L + kappa_margin would not exceed L",
                             f"use kappa_margin > {max(L, 1.0) * 1e-12:g}, or a smaller delta or gains c")
    if kind == "proposed" and controller.r_scale < 1.0:
        raise ctrl.error("r_scale", f"must be >= 1 to keep r_i >= 1, got {controller.r_scale:g}",
                         "use a scale >= 1")

    reference = _reference(root.table("reference", _REFERENCE), order)
    sim = root.table("simulation", _SIMULATION)
    simulation = SimulationConfig(
        duration=sim.number("duration", positive=True),
        dt=sim.number("dt", positive=True),
        control_period=(
            sim.number("control_period", positive=True) if sim.has("control_period") else None
        ),
        backend=sim.string("backend", "ode", BACKENDS),
        state_bound=sim.number("state_bound", 1e6, positive=True),
    )
    from .sim import step_count  # local import: sim imports the controller, not the scenario

    ratio = simulation.duration / simulation.dt
    if ratio > MAX_STEPS:
        raise sim.error("duration", f"{simulation.duration:g} s at dt = {simulation.dt:g} s is {ratio:.3g} "
                        f"steps, more than the limit of {MAX_STEPS:,} (every step is kept in memory)",
                        "shorten the run or use a larger dt")
    try:
        step_count(simulation.duration, simulation.dt)
    except QcontrolInputError as exc:
        raise QcontrolInputError(f"{source}: {exc}") from None
    period = simulation.control_period
    if period is not None:
        hold = round(period / simulation.dt)
        if hold < 1 or abs(hold * simulation.dt - period) > 1e-9 * period:
            raise sim.error("control_period", f"{period:g} s is not a whole number of steps dt = "
                            f"{simulation.dt:g} s", "choose a control period that is a multiple of dt")

    mujoco_options = None
    if plant.has("mujoco"):
        from .plants.mujoco import parse_mujoco_options

        mujoco_options = parse_mujoco_options(
            plant.data["mujoco"], f"{source}: plant.mujoco", base_dir, len(phi), psi is not None
        )
    if simulation.backend == "mujoco" and mujoco_options is None:
        raise sim.error("backend", "is 'mujoco' but the plant has no [plant.mujoco] table",
                        "add [plant.mujoco] with the MJCF model, or use backend = \"ode\"")

    scenario = Scenario(
        name=name, description=description, source=source, text=text, overrides=overrides,
        order=order, psi=psi, phi=phi, theta=theta, x0=x0, controller=controller,
        reference=reference, simulation=simulation, mujoco=mujoco_options,
        psi_expr=psi_expr, phi_expr=phi_expr, r_expr=r_expr,
    )
    _check_expressions(scenario)
    return scenario


def _check_derivatives(ref: _Table, key: str, amplitude: float, frequency: float, order: int) -> None:
    """The controller uses y_d^(k) = amplitude frequency^k (...) for k <= n: all must be finite."""
    try:
        biggest = max(abs(amplitude) * abs(frequency) ** k for k in range(order + 1))
    except OverflowError:
        biggest = math.inf
    if not math.isfinite(biggest):
        raise ref.error(key, f"amplitude {amplitude:g} at frequency {frequency:g} rad/s gives a non-finite "
                        f"derivative y_d^(k), k <= {order}", "use a smaller amplitude or frequency")


def _reference(ref: _Table, order: int) -> ReferenceConfig:
    kind = ref.string("kind", "sine", REFERENCE_KINDS)
    if kind == "constant":
        return ReferenceConfig(kind, value=ref.number("value", 0.0))
    if kind == "sine":
        config = ReferenceConfig(
            kind,
            amplitude=ref.number("amplitude", 1.0),
            frequency=ref.number("frequency", 1.0),
            phase=ref.number("phase", 0.0),
            offset=ref.number("offset", 0.0),
        )
        _check_derivatives(ref, "frequency", config.amplitude, config.frequency, order)
        return config
    raw = ref._get("terms", _MISSING)
    if not isinstance(raw, list) or not raw:
        raise ref.error("terms", "must be a non-empty list of tables",
                        "write terms = [{amplitude = 1.0, frequency = 2.0}]")
    terms = []
    for i, term in enumerate(raw):
        t = _Table(term, ref.source, f"{ref.name}.terms[{i}]", ("amplitude", "frequency", "phase"))
        terms.append((t.number("amplitude", 1.0), t.number("frequency", 1.0), t.number("phase", 0.0)))
        _check_derivatives(t, "frequency", terms[-1][0], terms[-1][1], order)
    return ReferenceConfig(kind, offset=ref.number("offset", 0.0), terms=tuple(terms))


def _check_expressions(sc: Scenario) -> None:
    """Load-time checks: plant terms finite at x0; every r_i finite and >= 1 on sampled states."""
    x0 = np.asarray(sc.x0)[None, :]
    for label, expr in [("plant.psi", sc.psi_expr)] + [
        (f"plant.phi[{i}]", e) for i, e in enumerate(sc.phi_expr)
    ]:
        if expr is None:
            continue
        with np.errstate(all="ignore"):
            value = expr(x0)
        if not np.all(np.isfinite(value)):
            raise QcontrolInputError(
                f"{sc.source}: {label}: {expr.source!r} is not finite at x0 = {list(sc.x0)}; "
                "fix the formula or the initial state"
            )
    if not sc.r_expr:
        return
    rng = np.random.default_rng(0)
    samples = np.vstack([np.zeros(sc.order), rng.uniform(-10.0, 10.0, size=(2000, sc.order))])
    samples = sc.controller.delta * np.round(samples / sc.controller.delta)
    for i, expr in enumerate(sc.r_expr):
        with np.errstate(all="ignore"):
            value = expr(samples)
        bad = ~np.isfinite(value) | (value < 1.0 - 1e-12)
        if bad.any():
            first = np.flatnonzero(bad)[0]
            at = samples[first]
            raise QcontrolInputError(
                f"{sc.source}: controller.r[{i}]: {expr.source!r} must be finite and >= 1 for every "
                f"quantized state (SPEC 6) but is {float(value[first]):g} at q = {at.tolist()}; "
                "e.g. add 1 to it"
            )
