"""The registry of plant backends a scenario's ``simulation.backend`` selects.

Each backend declares the keys of its own section ``[plant.<name>]`` (None: it takes none),
parses and checks them, builds a :class:`~qcontrol.plants.base.Plant` for a batch of variants, and
says what variants must share to be stepped as one batch. Adding a backend is one module with its
plant class and its :class:`Backend`, plus one :func:`register_backend` call.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import QcontrolInputError
from ..schema import Section, Table
from .base import Plant, PlantTerms


@dataclass(frozen=True)
class PlantContext:
    """What a backend's section is checked against: the plant's terms, the scenario file's folder
    (paths are relative to it) and the step dt."""

    terms: PlantTerms
    base_dir: Path
    dt: float


@dataclass(frozen=True)
class SceneSource:
    """What a recording draws in 3-D: a MuJoCo model and the joint that x1 drives."""

    model: Any  # mujoco.MjModel
    joint: str

    @property
    def hinge(self) -> bool:
        """Whether the joint turns (a hinge: its generalized force is a torque) or slides."""
        import mujoco

        jid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, self.joint)
        return int(self.model.jnt_type[jid]) == int(mujoco.mjtJoint.mjJNT_HINGE)


@dataclass(frozen=True, kw_only=True)
class Backend:
    """One plant backend, built with keywords.

    Required: ``name``; ``build(terms, options, dt)`` makes one plant of ``len(terms)`` copies
    from each copy's terms and options (sequences of equal length); ``structure(terms, options)``
    is what variants stepped as one batch must share (what it leaves out, the plant takes per
    copy); ``summary``
    says what it is in one line. Optional: ``section``/``parse``, the keys of ``[plant.<name>]``
    and their parsed options (None: the backend takes no section); ``scene(options, dt)`` what
    recordings draw in 3-D (None: nothing to draw); ``inertia(options, dt)`` the joint's
    generalized inertia I, the gain between u and a generalized force on the joint (None: the
    backend has no joint of its own, e.g. the ODE with its unit input gain);
    ``model_coefficients(options, terms, dt)`` what the backend's model fixes itself: the
    coefficient of each term it makes (``{name: value}`` for the names its options leave to it,
    None where its physics makes no such term) and the input gain b its actuator's own command
    has (what a scenario's ``"model"`` entries take).
    """

    name: str
    build: Callable[[Sequence[PlantTerms], Sequence[Any], float], Plant]
    structure: Callable[[PlantTerms, Any], Hashable]
    summary: str
    section: Section | None = None
    parse: Callable[[Table, PlantContext], Any] | None = None
    scene: Callable[[Any, float], SceneSource | None] | None = None
    inertia: Callable[[Any, float], float] | None = None
    model_coefficients: Callable[[Any, PlantTerms, float], tuple[dict[str, float | None], float]] | None = (
        None)

    def require(self, options: Any, source: str) -> None:
        """Refuse a scenario that lacks the section this backend needs to run."""
        if self.section is not None and options is None:
            raise QcontrolInputError(
                f"{source}: backend {self.name!r} needs a [plant.{self.name}] table "
                f"({self.section.meaning}); "
                f"add one, or use --backend {_other(self.name)}"
            )


def _other(name: str) -> str:
    return next((b for b in BACKENDS if b != name), "ode")


BACKENDS: dict[str, Backend] = {}


def register_backend(backend: Backend) -> None:
    """Add a plant backend; its name must be new."""
    if backend.name in BACKENDS:
        raise QcontrolInputError(f"plant backend {backend.name!r} is already registered; choose another name")
    BACKENDS[backend.name] = backend
