"""The MuJoCo backend: one joint of an MJCF model as the plant of eq. (1) with n = 2.

Split by job: :mod:`.options` (the ``[plant.mujoco]`` keys; no mujoco import), :mod:`.mjcf`
(the MJCF through MjSpec: overrides, realism options, compiled once), :mod:`.callbacks` (the
process-global passive callback and warning handler), :mod:`.native` (the passive terms as a
compiled C callback), :mod:`.noise` (the sensor noise), :mod:`.plant` (the runtime plant),
:mod:`.native_step` (one copy's observe and step for the compiled loop), :mod:`.threaded` (a batch
stepped by ``mujoco.batch``), :mod:`.consistency` (MuJoCo's acceleration against eq. (1)).
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

from ...errors import QcontrolInputError
from ...schema import Table
from ..backends import Backend, PlantContext, SceneSource
from ..base import PlantTerms
from .options import SECTION, MujocoOptions
from .options import parse as parse_options

if TYPE_CHECKING:
    from .plant import MujocoPlant


def parse(table: Table, ctx: PlantContext) -> MujocoOptions:
    """The options, and the model compiled with the scenario's dt: wrong element names and compile
    errors are reported when the scenario loads (the plant reuses the compiled model)."""
    from .mjcf import compiled

    row = ctx.terms.first_nonzero_row
    if row is not None:
        raise QcontrolInputError(f"{table.source}: plant.phi[{row - 1}]: row {row} has a regressor, but "
                                 f"[{table.name}] realises a chain (terms in the last equation only); run "
                                 "this plant on the ode backend, or give every row before the last as \"0\"")
    options = parse_options(table, ctx.terms, ctx.base_dir)
    compiled(options, ctx.dt)
    return options


def build(terms: Sequence[PlantTerms], options: Sequence[MujocoOptions], dt: float) -> MujocoPlant:
    """A batch of ``len(terms)`` MuJoCo copies of variants that share ``structure``: each copy
    with its own theta for the terms the passive callback adds, and its own noise seed."""
    from .plant import MujocoPlant

    return MujocoPlant(options[0], terms[0], batch=len(terms), timestep=dt, copies=terms,
                       noise_seeds=[o.noise_seed for o in options])


def structure(terms: PlantTerms, options: MujocoOptions) -> Hashable:
    """What copies share: the terms' form, the theta of the terms MuJoCo's own physics makes (the
    model holds them) and the model's options. Per copy: x0, the theta of the terms the passive
    callback adds (each copy's coefficients in its userdata) and the sensor noise's seed (each
    copy its own stream)."""
    psi = None if terms.psi is None else terms.psi.source
    native = tuple(c for name, c in zip(terms.names, terms.coefficients, strict=True)
                   if name in options.native_terms)
    return (terms.order, psi, tuple(p.source for p in terms.phi), native, replace(options, noise_seed=None),
            terms.input_gain)


def scene(options: MujocoOptions, dt: float) -> SceneSource:
    from .mjcf import build_model

    return SceneSource(build_model(options, dt), options.joint)


def inertia(options: MujocoOptions, dt: float) -> float:
    """The nominal joint inertia I (``mj_fullM``, realism options off): u's gain to a torque."""
    from .mjcf import compiled

    return compiled(options, dt).inertia


def model_coefficients(options: MujocoOptions, terms: PlantTerms, dt: float) -> tuple[dict[str, float | None],
                                                                                     float]:
    """The model's coefficient of each native term (None: its physics makes no such term) and
    its b = gear / I, from the equation of the model as the scenario compiles it, realism off
    (:mod:`.equation`)."""
    from .equation import compiled_equation, matches
    from .mjcf import compiled

    built = compiled(options.nominal(), dt)
    eq = compiled_equation(built, options.model.name)
    found = dict(zip(terms.names, matches(eq, terms.expressions), strict=True))
    coefficients = {name: None if found[name] is None else eq.terms[found[name][0]].theta / found[name][1]
                    for name in options.native_terms}
    return coefficients, built.input_gain


BACKEND = Backend(name="mujoco", build=build, structure=structure,
                  summary="MuJoCo physics of an MJCF model (order 2: one joint)",
                  section=SECTION, parse=parse, scene=scene, inertia=inertia,
                  model_coefficients=model_coefficients)

__all__ = ["BACKEND", "MujocoOptions"]
