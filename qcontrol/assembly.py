"""Scenario -> the parts of a closed loop (quantizer, reference, law, plant) -> a run.

The law and the plant come from the registries (:data:`~qcontrol.controller.LAW_KINDS`,
:data:`~qcontrol.plants.BACKENDS`), for one scenario or for a batch of variants that share
:func:`batch_structure` (a sweep steps those as one batch).
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import fields
from typing import Any

from .controller import BatchLaw, law_kind
from .controller.user_diagnostics import diagnostic_columns
from .disturbance import Schedule, scaled_changes
from .engine import Observer, ProgressCallback, RunMetrics, RunSpec, Separation, Trajectory, simulate
from .engine.results import RunRecord
from .engine.signals import SIGNALS, ColumnNaming, column_names
from .errors import QcontrolInputError
from .expr import Expression
from .plants import BACKENDS, Plant, SceneSource
from .quantizer import UniformQuantizer
from .reference import Reference
from .scenario import Scenario
from .summary import Summary
from .timegrid import TimeGrid


def build_quantizer(sc: Scenario) -> UniformQuantizer:
    """The uniform quantizer of eq. (3) with the scenario's step delta."""
    return UniformQuantizer(sc.controller.delta)


def build_reference(sc: Scenario) -> Reference:
    """The reference y_d with its derivatives (Assumption 3)."""
    return sc.reference.signal


def build_law(variants: Sequence[Scenario]) -> BatchLaw:
    """One law for a batch of variants of the same kind (their settings that may differ become
    per-copy parameters; see :func:`batch_structure`)."""
    first = variants[0]
    law = law_kind(first.controller.kind).build([v.controller.settings for v in variants], first.law_context)
    check_diagnostic_names(law, first)
    return law


# beside the signals: names a saved file or a Result gives, and the npz writer's own arguments
RESERVED_NAMES = ("t", "y", "summary", "file", "allow_pickle")


def check_diagnostic_names(law: BatchLaw, sc: Scenario) -> None:
    """Refuse a diagnostic of the law whose name (or a column of it) is already the name of a
    signal, of a signal's column in the saved files, or whose summary key ``<reduce>_<name>`` is a
    field of the summary: one line naming the law and the diagnostic."""
    separation = build_separation(sc)
    naming = ColumnNaming(law.state_name, () if separation is None else separation.names)
    sizes = (sc.law_context.order, law.state_size, len(naming.bound_names))
    taken = set(RESERVED_NAMES) | {s.name for s in SIGNALS}
    taken.update(name for s in SIGNALS if s.width != "diagnostics"
                 for name in column_names(s, s.size(*sizes), naming))
    keys = {f.name for f in fields(Summary)}
    for d in law.diagnostics:
        clash = next((c for c in (d.name, *diagnostic_columns((d,))) if c in taken), None)
        if clash is not None:
            raise QcontrolInputError(f"controller kind {sc.controller.kind!r}: diagnostic {d.name!r}: "
                                     f"{clash!r} already names a recorded signal or its column in the saved "
                                     "files; rename the diagnostic")
        if d.summary_key in keys:
            raise QcontrolInputError(f"controller kind {sc.controller.kind!r}: diagnostic {d.name!r}: its "
                                     f"summary key {d.summary_key!r} is already a summary field; rename the "
                                     "diagnostic")


def build_controller(sc: Scenario) -> BatchLaw:
    """The scenario's law for a single run."""
    return build_law([sc])


def build_separation(sc: Scenario) -> Separation | None:
    """The terms of eq. (1) and the law's bounding functions r to check along a run (eqs. (37)-(43):
    phi_1..phi_l, then psi), or None when the law has no r."""
    kind = law_kind(sc.controller.kind)
    r = kind.bounds(sc.controller.settings) if kind.bounds is not None else None
    if r is None:
        return None
    bounded = sc.terms.bounded
    return Separation(tuple(name for name, _ in bounded), tuple(e for _, e in bounded), tuple(r))


def backend_of(sc: Scenario, backend: str | None = None) -> str:
    """The backend to run on: ``backend``, or the scenario's ``simulation.backend``."""
    return backend or sc.simulation.backend


def runnable_backend(sc: Scenario, backend: str | None = None) -> str:
    """:func:`backend_of`, refused in one line if no backend has that name or the scenario lacks
    the section it needs (e.g. ``--backend mujoco`` without ``[plant.mujoco]``)."""
    name = backend_of(sc, backend)
    if name not in BACKENDS:
        raise QcontrolInputError(f"backend {name!r}: use one of {', '.join(BACKENDS)}")
    BACKENDS[name].require(sc.backends.get(name), sc.source)
    return name


def build_plants(variants: Sequence[Scenario], backend: str | None = None) -> Plant:
    """One plant with a copy per variant, on ``backend`` (default: the first variant's)."""
    first = variants[0]
    entry = BACKENDS[runnable_backend(first, backend)]
    return entry.build([v.terms for v in variants], [v.backends.get(entry.name) for v in variants],
                       first.simulation.dt)


def build_plant(sc: Scenario, backend: str | None = None, batch: int = 1) -> Plant:
    """``batch`` identical copies of the scenario's plant on ``backend``."""
    return build_plants([sc] * batch, backend)


def batch_structure(sc: Scenario, backend: str | None = None) -> Hashable:
    """What variants must share to be stepped as one batch: everything but the numbers the law
    and the backend take per copy (e.g. kappa, gamma, sigma, r_scale, x0; theta on the ODE; on
    MuJoCo the theta of terms the passive callback adds, and the sensor noise's seed)."""
    name = backend_of(sc, backend)
    entry = BACKENDS[name]
    c = sc.controller
    return (
        name, entry.structure(sc.terms, sc.backends.get(name)), c.kind, c.delta, c.c,
        law_kind(c.kind).structure(c.settings, sc.law_context), sc.reference, sc.simulation, sc.disturbances,
    )


def scene(sc: Scenario) -> SceneSource | None:
    """What a recording of the scenario draws in 3-D, whichever backend runs it: the model of the
    first backend section that has one (an ODE run of Example 2 replays the MuJoCo pendulum)."""
    for name, options in sc.backends.items():
        backend = BACKENDS[name]
        drawn = None if backend.scene is None else backend.scene(options, sc.simulation.dt)
        if drawn is not None:
            return drawn
    return None


def input_inertia(sc: Scenario) -> float:
    """The joint's generalized inertia I that relates u (and a disturbance's generalized force F,
    ``d = F / I``) to a force on the joint: from the first backend section that has a joint (the
    MuJoCo model's ``mj_fullM``), else 1 (the ODE's unit input gain)."""
    for name, options in sc.backends.items():
        inertia = BACKENDS[name].inertia
        if inertia is not None:
            return inertia(options, sc.simulation.dt)
    return 1.0


def loads(sc: Scenario) -> list[tuple[int, float]]:
    """The rows where the scenario's external load changes and its new value in u's units
    (``d = F / I``; see :mod:`qcontrol.disturbance`); empty without disturbances."""
    if not sc.disturbances:
        return []
    sim = sc.simulation
    grid = TimeGrid.of(sim.duration, sim.dt, sim.control_period)
    return list(scaled_changes(Schedule(sc.disturbances), grid.dt, grid.rows, input_inertia(sc)))


def controller_constants(sc: Scenario, law: BatchLaw | None = None) -> dict[str, Any]:
    """The controller's constants as a recording shows them: delta, c, L, L_z and the law's own."""
    law = law if law is not None else build_controller(sc)
    coordinates = law.coordinates
    return {"delta": sc.controller.delta, "c": list(sc.controller.c), "L": coordinates.L,
            "L_z": list(coordinates.L_z)} | law.constants()


def run_variants(
    variants: Sequence[Scenario],
    backend: str | None = None,
    progress: ProgressCallback | None = None,
    observer: Observer | None = None,
    plant: Plant | None = None,
    record: str = "full",
) -> list[RunRecord]:
    """Closed-loop runs of variants that share :func:`batch_structure`, as one batch."""
    first = variants[0]
    plant = plant if plant is not None else build_plants(variants, backend)
    x0 = [v.x0 for v in variants]
    # the separation (37)-(43) is checked along single runs (a sweep's batch skips it: it would
    # cost about a quarter of the plant's own evaluations)
    separation = build_separation(first) if len(variants) == 1 else None
    return simulate(run_spec(first, plant, build_law(variants), x0, separation, record, progress, observer))


def run_spec(sc: Scenario, plant: Plant, law: BatchLaw, x0: Sequence, separation: Separation | None,
             record: str = "full", progress: ProgressCallback | None = None,
             observer: Observer | None = None) -> RunSpec:
    """The specification of a run of the scenario's closed loop with this plant and law."""
    sim = sc.simulation
    return RunSpec(plant=plant, law=law, quantizer=build_quantizer(sc), reference=build_reference(sc), x0=x0,
                   grid=TimeGrid.of(sim.duration, sim.dt, sim.control_period), state_bound=sim.state_bound,
                   record=record, metrics=sc.metrics, separation=separation, loads=loads(sc),
                   velocity_source=sim.velocity_source, terms=named_terms(sc), progress=progress,
                   observer=observer, chain=sc.terms.first_nonzero_row is None)


def named_terms(sc: Scenario) -> list[tuple[str, Expression]]:
    """The plant's expressions of eq. (1) by their scenario keys, ``plant.phi[1]`` .. ``plant.psi``
    (the order of eqs. (37)-(43))."""
    return [("plant.psi" if name == "psi" else f"plant.phi[{name[3:]}]", e) for name, e in sc.terms.bounded]


def run_scenario(
    sc: Scenario,
    backend: str | None = None,
    progress: ProgressCallback | None = None,
    observer: Observer | None = None,
    plant: Plant | None = None,
    record: str = "full",
) -> Trajectory | RunMetrics:
    """One closed-loop run of the scenario on the chosen backend (``record`` as in
    :func:`~qcontrol.engine.simulate`: ``"metrics"`` keeps memory bounded on long runs)."""
    return run_variants([sc], backend, progress, observer, plant, record)[0]
