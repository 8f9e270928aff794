"""Scenario -> the parts of a closed loop, each built once (:class:`Assembly`) -> a run.

:func:`assemble` puts a run together once: the backend (checked), the plant and the law from the
registries (:data:`~qcontrol.plants.BACKENDS`, :data:`~qcontrol.controller.LAW_KINDS`), the
quantizer of eq. (3), the reference, the time grid, the external loads, the separation
(37)-(43) checked along a single run, and, when something asks, the 3-D scene and the constants a
recording shows. The API, the command line, recordings, video and ``qcontrol check`` read these
parts from the one :class:`Assembly`; nothing rebuilds them. It serves one scenario or a batch of
variants that share :func:`batch_structure` (a sweep steps those as one batch). The ``build_*``
functions build one part each (and serve tests that put a loop together by hand).
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass, fields, replace
from functools import cached_property
from typing import Any

from .controller import BatchLaw, law_kind
from .controller.gain import divided_by_gain
from .controller.law import BUILT_IN_KINDS
from .controller.user_diagnostics import diagnostic_columns
from .disturbance import Schedule, scaled_changes
from .engine import Observer, ProgressCallback, RunMetrics, RunSpec, Separation, Trajectory, simulate
from .engine.results import RunRecord
from .engine.signals import SIGNALS, ColumnNaming, column_names
from .errors import QcontrolInputError
from .expr import Expression
from .plants import BACKENDS, Plant, SceneSource
from .plants.base import Disturbable, PhysicsReport, physics_report, timed
from .quantizer import Quantizer, UniformQuantizer
from .reference import Reference
from .scenario import Scenario
from .summary import Summary
from .timegrid import TimeGrid


def build_quantizer(sc: Scenario) -> Quantizer:
    """The scenario's quantizer of the state: its ``[quantizer]`` table's (a new one for every run:
    a hysteresis quantizer's levels belong to one), else the uniform quantizer of eq. (3) with the
    step ``controller.delta``."""
    return sc.quantizer.build() if sc.quantizer is not None else UniformQuantizer(sc.controller.delta)


def build_reference(sc: Scenario) -> Reference:
    """The reference y_d with its derivatives (Assumption 3)."""
    return sc.reference.signal


_BUILT = object()  # build_law's default: the separation is built for the check


def build_law(variants: Sequence[Scenario], separation: Separation | None | object = _BUILT) -> BatchLaw:
    """One law for a batch of variants of the same kind (their settings that may differ become
    per-copy parameters; see :func:`batch_structure`); its diagnostics' names are checked against
    the recorded columns, which ``separation`` (the first variant's, :func:`build_separation`)
    names."""
    first = variants[0]
    kind = law_kind(first.controller.kind)
    law = kind.build([v.controller.settings for v in variants], first.law_context)
    check_diagnostic_names(law, first, build_separation(first) if separation is _BUILT else separation)
    if kind.name in BUILT_IN_KINDS or kind.extends is not None:  # a built-in kind, or one extending it
        law = divided_by_gain(law, first.terms.b)  # x_n' = b u + ...: u = u_1 / b
    return law


# beside the signals: names a saved file or a Result gives, and the npz writer's own arguments
RESERVED_NAMES = ("t", "y", "summary", "file", "allow_pickle")


def check_diagnostic_names(law: BatchLaw, sc: Scenario, separation: Separation | None) -> None:
    """Refuse a diagnostic of the law whose name (or a column of it) is already the name of a
    signal, of a signal's column in the saved files (``separation`` names the bound ratios'), or
    whose summary key ``<reduce>_<name>`` is a field of the summary: one line naming the law and
    the diagnostic."""
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
    if sc.terms.timed:  # r bounds the terms at x_q alone; a term in t is checked by its constant r entry only
        return None
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
    return _plants(variants, runnable_backend(variants[0], backend))


def _plants(variants: Sequence[Scenario], name: str) -> Plant:
    entry = BACKENDS[name]
    return entry.build([v.terms for v in variants], [v.backends.get(name) for v in variants],
                       variants[0].simulation.dt)


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
        sc.quantizer, sc.input_quantizer,
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


def named_terms(sc: Scenario) -> list[tuple[str, Expression]]:
    """The plant's expressions of eq. (1) by their scenario keys, ``plant.phi[1]`` .. ``plant.psi``
    (the order of eqs. (37)-(43))."""
    return [("plant.psi" if name == "psi" else f"plant.phi[{name[3:]}]", e) for name, e in sc.terms.bounded
            if not timed(e)]  # (a term in t cannot be evaluated at a state alone)


@dataclass(frozen=True, eq=False)
class Assembly:
    """One run of a scenario (or a batch of its variants), put together once by :func:`assemble`.

    ``spec`` holds the parts the engine runs (plant, law, quantizer, reference, x0, time grid,
    loads, the separation checked along a single run; :class:`~qcontrol.engine.RunSpec`), with
    ``record="full"`` and no watchers: :meth:`run` sets those per run. ``scene`` (what recordings
    and video draw in 3-D) and ``constants`` (what a recording shows of the law) are built the
    first time they are read; ``report`` is the plant's :class:`~qcontrol.plants.PhysicsReport`
    or its default (:func:`~qcontrol.plants.base.physics_report`).
    """

    scenario: Scenario  # the run's scenario (a batch's first variant)
    backend: str
    spec: RunSpec

    @property
    def plant(self) -> Plant:
        return self.spec.plant

    @property
    def law(self) -> BatchLaw:
        return self.spec.law

    @property
    def loads(self) -> Sequence[tuple[int, float]]:
        """The rows where the external load changes and its new value in u's units (:func:`loads`)."""
        return self.spec.loads

    @property
    def report(self) -> PhysicsReport:
        """The plant's warnings and consistency report (a plant without them: none)."""
        return physics_report(self.plant)

    @cached_property
    def scene(self) -> SceneSource | None:
        """What recordings and video draw in 3-D (:func:`scene`), built once when first read."""
        return scene(self.scenario)

    @cached_property
    def constants(self) -> dict[str, Any]:
        """The controller's constants as a recording shows them (:func:`controller_constants`)."""
        return controller_constants(self.scenario, self.law)

    def run(self, record: str = "full", progress: ProgressCallback | None = None,
            observer: Observer | None = None) -> list[RunRecord]:
        """The closed loop of every copy (``record`` as in :func:`~qcontrol.engine.simulate`)."""
        return simulate(replace(self.spec, record=record, progress=progress, observer=observer))


def assemble(variants: Scenario | Sequence[Scenario], backend: str | None = None,
             plant: Plant | None = None) -> Assembly:
    """Put a run together once: the backend (``backend``, default the scenario's; refused in one
    line if unknown or its section is missing), the plant (``plant``, or one with a copy per
    variant), the law, the quantizer of eq. (3), the reference, the grid, the loads and the
    separation (37)-(43), checked along every copy as along a run alone. Variants must share
    :func:`batch_structure`. A scenario with ``[[disturbance]]`` on a plant that takes no external
    load is refused in one line."""
    variants = [variants] if isinstance(variants, Scenario) else list(variants)
    first = variants[0]
    name = runnable_backend(first, backend)
    plant = plant if plant is not None else _plants(variants, name)
    # variants of one batch share their terms' expressions and r (their batch structure), so the
    # separation of the first is every copy's: a copy's summary is its run alone's, key for key
    separation = build_separation(first)
    spec = run_spec(first, plant, build_law(variants, separation), [v.x0 for v in variants], separation)
    if spec.loads and not isinstance(plant, Disturbable):
        raise QcontrolInputError(f"{first.source}: [[disturbance]]: backend {name!r} takes no external load "
                                 "(its plant is not Disturbable); remove the [[disturbance]] tables or "
                                 "choose another backend")
    return Assembly(first, name, spec)


def run_spec(sc: Scenario, plant: Plant, law: BatchLaw, x0: Sequence, separation: Separation | None,
             record: str = "full", progress: ProgressCallback | None = None,
             observer: Observer | None = None) -> RunSpec:
    """The specification of a run of the scenario's closed loop with this plant and law: what
    :func:`assemble` makes of them (and a test that puts a loop together by hand)."""
    sim = sc.simulation
    return RunSpec(plant=plant, law=law, quantizer=build_quantizer(sc), reference=build_reference(sc), x0=x0,
                   grid=TimeGrid.of(sim.duration, sim.dt, sim.control_period), state_bound=sim.state_bound,
                   record=record, metrics=sc.metrics, separation=separation, loads=loads(sc),
                   velocity_source=sim.velocity_source, terms=named_terms(sc), progress=progress,
                   observer=observer, chain=sc.terms.first_nonzero_row is None,
                   input_quantizer=None if sc.input_quantizer is None else sc.input_quantizer.build())


def run_variants(
    variants: Sequence[Scenario],
    backend: str | None = None,
    progress: ProgressCallback | None = None,
    observer: Observer | None = None,
    plant: Plant | None = None,
    record: str = "full",
) -> list[RunRecord]:
    """Closed-loop runs of variants that share :func:`batch_structure`, as one batch."""
    return assemble(variants, backend, plant).run(record, progress, observer)


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
