"""The MuJoCo backend: one joint of an MJCF model as the plant of eq. (1) with n = 2.

Split by job: :mod:`.options` (the ``[plant.mujoco]`` keys; no mujoco import), :mod:`.model`
(MjSpec: overrides, realism options, compile once), :mod:`.callbacks` (the process-global
passive callback and warning handler), :mod:`.plant` (the runtime plant), :mod:`.consistency`
(MuJoCo's acceleration against eq. (1)).
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from typing import TYPE_CHECKING

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

    options = parse_options(table, ctx.terms, ctx.base_dir)
    compiled(options, ctx.dt)
    return options


def build(terms: Sequence[PlantTerms], options: MujocoOptions, dt: float) -> MujocoPlant:
    """A batch of ``len(terms)`` MuJoCo copies (the variants share their terms: see ``structure``)."""
    from .plant import MujocoPlant

    return MujocoPlant(options, terms[0], batch=len(terms), timestep=dt)


def structure(terms: PlantTerms, options: MujocoOptions) -> Hashable:
    """Everything but x0 is shared: the model's own physics cannot take theta per copy."""
    psi = None if terms.psi is None else terms.psi.source
    return terms.order, psi, tuple(p.source for p in terms.phi), terms.theta, options


def scene(options: MujocoOptions, dt: float) -> SceneSource:
    from .mjcf import build_model

    return SceneSource(build_model(options, dt), options.joint)


def inertia(options: MujocoOptions, dt: float) -> float:
    """The nominal joint inertia I (``mj_fullM``, realism options off): u's gain to a torque."""
    from .mjcf import compiled

    return compiled(options, dt).inertia


BACKEND = Backend(name="mujoco", build=build, structure=structure,
                  summary="MuJoCo physics of an MJCF model (order 2: one joint)",
                  section=SECTION, parse=parse, scene=scene, inertia=inertia)

__all__ = ["BACKEND", "MujocoOptions"]
