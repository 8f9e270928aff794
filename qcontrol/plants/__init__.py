"""Plants the closed-loop engine can drive, and the registry of backends a scenario selects:
the ideal ODE chain of eq. (1) (:mod:`.ode`) and the MuJoCo model (:mod:`.mujoco`)."""

from . import mujoco, ode
from .backends import BACKENDS, Backend, PlantContext, SceneSource, register_backend
from .base import (
    Actuated,
    ColumnIO,
    ColumnStepping,
    Disturbable,
    NativeStepper,
    NativeStepping,
    PhysicsReport,
    Plant,
    PlantTerms,
)

for _backend in (ode.BACKEND, mujoco.BACKEND):
    register_backend(_backend)

__all__ = ["BACKENDS", "Actuated", "Backend", "Disturbable", "ColumnIO", "ColumnStepping", "NativeStepper",
           "NativeStepping", "PhysicsReport", "Plant", "PlantContext", "PlantTerms", "SceneSource",
           "register_backend"]
