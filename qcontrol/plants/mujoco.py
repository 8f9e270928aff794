"""A MuJoCo-backed plant for eq. (1) with n = 2: one joint of an MJCF model (SPEC 9.1, 9.2).

How the ODE maps to the model. The plant of eq. (1),

    x1' = x2,    x2' = u + psi(x) + theta^T phi(x),

is one scalar joint with x1 = its position (``qpos``) and x2 = its velocity (``qvel``). MuJoCo
integrates ``I qacc = tau + qfrc_bias + qfrc_passive`` where ``I`` is the joint's generalized
inertia. So:

* ``u`` is acceleration-level (the ODE's unit input gain); the actuator command is ``I * u``
  (divided by the motor's gain), with ``I`` read from the model by ``mujoco.mj_fullM``.
* Terms MuJoCo's own physics produces (listed in ``native_terms``, e.g. joint damping for
  ``theta1 * x2`` and gravity for ``theta3 * sin(x1)`` in Example 2) are left to MuJoCo.
* Every other term of ``psi + theta^T phi`` has no rigid-body counterpart; a passive callback
  (``mujoco.set_mjcb_passive``) adds ``I * term(qpos, qvel)`` to ``qfrc_passive``. MuJoCo 4's RK4
  calls it at each of its four stages (checked by the tests), so the ODE and MuJoCo integrate the
  same vector field with the same scheme. The callback is process-global: the plant installs it
  in ``__enter__`` and restores the previous one in ``__exit__``, also when the run raises.
* The controller reads ``sensordata`` (jointpos, jointvel sensors), never ``qpos``/``qvel``.

At construction the plant checks, at a few hundred sampled states and inputs, that MuJoCo's
``qacc`` equals ``u + psi + theta^T phi`` to 1e-9 (relative to the size of the terms), and refuses
with a message naming the mismatching term otherwise (issue 3, item 3).

Physical parameters have one source of truth: the MJCF holds the canonical numbers; a scenario
may override them through ``mujoco.MjSpec`` with ``[plant.mujoco] parameters``:

    mass     mass of the joint's body (its explicit <inertial>)        [kg]
    length   distance from the hinge to that body's centre of mass;     [m]
             the body's geoms are scaled with it (hinge joints only)
    damping  joint damping                                              [N s/m or N m s/rad]
    gravity  magnitude of gravity, pointing along -z                    [m/s^2]

e.g. the rigid reading of Example 2 (SPEC 9.2): ``parameters = {mass = 1.0, length = 3.5,
damping = 12.25}`` gives I = 12.25, theta = [-1, -1/3.5, -2.8].

Realism options (issue 3, item 5), each off by default. With any of them on the consistency check
reports the measured mismatch in ``plant.consistency_report`` instead of refusing. The actuator
gain and the callback keep using the nominal inertia (the model with armature and rod mass off),
so armature and rod mass act as unmodelled dynamics, as they would on hardware.

    torque_limit   MJCF ctrlrange [-limit, limit] on the actuator (force/torque units)
    frictionloss   joint dry friction (MuJoCo's frictionloss constraint)
    armature       rotor inertia added to the joint (MuJoCo's armature)
    rod_mass       a uniform rod of this mass from the hinge to the bob (an extra welded body)
    sensor_noise   Gaussian noise std dev added to the readings by the plant (MuJoCo's sensor
                   ``noise`` attribute is metadata only), seeded by the required ``noise_seed``
    sensor_delay   reading delay in seconds, by MuJoCo's sensor ``nsample``/``delay`` history
                   buffers (verified on mujoco 4.0); the readings before t = delay are x(0)
    sensor_period  sample-and-hold of the readings, by MuJoCo's sensor ``interval`` attribute
"""

from __future__ import annotations

import math
import pathlib
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import mujoco
import numpy as np

from ..errors import QcontrolInputError
from ..expr import Expression, ScalarFn, scalar_function
from .base import ScalarIO

_mj_step, _mj_sensor_pos, _mj_sensor_vel = mujoco.mj_step, mujoco.mj_sensorPos, mujoco.mj_sensorVel
INTEGRATORS = {
    "RK4": mujoco.mjtIntegrator.mjINT_RK4,
    "Euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}
PARAMETERS = ("mass", "length", "damping", "gravity")
_REQUIRED = ("model", "joint", "position_sensor", "velocity_sensor", "actuator")
_OPTIONAL = (
    "native_terms", "integrator", "parameters", "torque_limit", "frictionloss", "armature",
    "rod_mass", "sensor_noise", "noise_seed", "sensor_delay", "sensor_period",
)
KEYS = _REQUIRED + _OPTIONAL
CONSISTENCY_SAMPLES = 300
CONSISTENCY_TOLERANCE = 1e-9
CONSISTENCY_SEED = 3160  # the paper's article number; any fixed seed works


@dataclass(frozen=True)
class MujocoOptions:
    """The validated ``[plant.mujoco]`` table of a scenario (see the module docstring)."""

    where: str
    model: pathlib.Path
    joint: str
    position_sensor: str
    velocity_sensor: str
    actuator: str
    native_terms: tuple[str, ...] = ()
    integrator: str = "RK4"
    parameters: dict[str, float] = field(default_factory=dict)
    torque_limit: float | None = None
    frictionloss: float = 0.0
    armature: float = 0.0
    rod_mass: float = 0.0
    sensor_noise: tuple[float, float] = (0.0, 0.0)
    noise_seed: int | None = None
    sensor_delay: float = 0.0
    sensor_period: float = 0.0

    @property
    def realism(self) -> tuple[str, ...]:
        """Names of the realism options that are on (empty for the ideal model)."""
        on = {
            "torque_limit": self.torque_limit is not None,
            "frictionloss": self.frictionloss > 0,
            "armature": self.armature > 0,
            "rod_mass": self.rod_mass > 0,
            "sensor_noise": any(s > 0 for s in self.sensor_noise),
            "sensor_delay": self.sensor_delay > 0,
            "sensor_period": self.sensor_period > 0,
        }
        return tuple(name for name, active in on.items() if active)

    def nominal(self) -> MujocoOptions:
        """The same model with every realism option off: what the ODE describes."""
        return replace(
            self, torque_limit=None, frictionloss=0.0, armature=0.0, rod_mass=0.0,
            sensor_noise=(0.0, 0.0), noise_seed=None, sensor_delay=0.0, sensor_period=0.0,
        )


def term_names(n_phi: int, has_psi: bool) -> list[str]:
    """Names of the terms of ``psi + theta^T phi``: ``psi`` (if present), ``phi1`` .. ``phil``."""
    return (["psi"] if has_psi else []) + [f"phi{i + 1}" for i in range(n_phi)]


# --------------------------------------------------------------------------------------------
# [plant.mujoco] validation


def parse_mujoco_options(
    table: dict, where: str, base_dir: pathlib.Path, n_phi: int, has_psi: bool
) -> MujocoOptions:
    """Validate a scenario's ``[plant.mujoco]`` table; every error is one line naming the key.

    ``where`` prefixes messages (``"scenarios/example2.toml: plant.mujoco"``); ``base_dir`` is the
    scenario file's folder, against which ``model`` is resolved. The model is compiled once here,
    so wrong joint/sensor/actuator names are reported when the scenario is loaded.
    """

    def fail(key: str, problem: str, fix: str) -> QcontrolInputError:
        return QcontrolInputError(f"{where}.{key}: {problem}; {fix}")

    if not isinstance(table, dict):
        raise QcontrolInputError(f"{where}: expected a table, got {type(table).__name__}; "
                                 "write [plant.mujoco] with model = \"...\" and the element names")
    for key in table:
        if key not in KEYS:
            raise fail(key, "unknown key", f"allowed keys are {', '.join(KEYS)}")
    for key in _REQUIRED:
        if key not in table:
            raise QcontrolInputError(
                f"{where}.{key}: missing; [plant.mujoco] needs {', '.join(_REQUIRED)}"
            )

    def name(key: str) -> str:
        value = table[key]
        if not isinstance(value, str) or not value.strip():
            raise fail(key, f"expected a non-empty string, got {value!r}",
                       "give the name of the MJCF element")
        return value

    def number(key: str, default: float, positive: bool = False) -> float:
        value = table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise fail(key, f"expected a finite number, got {value!r}", "write a number such as 0.1")
        if value < 0 or (positive and value == 0):
            raise fail(key, f"must be {'> 0' if positive else '>= 0'}, got {value!r}",
                       "use a non-negative value (0 or absent turns the option off)"
                       if not positive else "use a positive value, or remove the key")
        return float(value)

    model_text = name("model")
    model = (pathlib.Path(base_dir) / model_text).resolve()
    if not model.is_file():
        raise fail("model", f"file {model_text!r} not found (looked at {model})",
                   "give the MJCF path relative to the scenario file's folder, "
                   "e.g. \"../models/pendulum.xml\"")

    allowed_terms = term_names(n_phi, has_psi)
    native = table.get("native_terms", [])
    if not isinstance(native, list) or not all(isinstance(t, str) for t in native):
        raise fail("native_terms", f"expected a list of term names, got {native!r}",
                   f"write e.g. [\"phi1\"]; allowed names are {', '.join(allowed_terms) or 'none'}")
    for term in native:
        if term not in allowed_terms:
            raise fail("native_terms", f"unknown term {term!r}",
                       f"allowed names are {', '.join(allowed_terms) or 'none (the plant has no terms)'}")
    if len(set(native)) != len(native):
        raise fail("native_terms", f"repeated names in {native!r}", "list each term once")

    integrator = table.get("integrator", "RK4")
    if integrator not in INTEGRATORS:
        raise fail("integrator", f"unknown integrator {integrator!r}",
                   f"choose one of {', '.join(INTEGRATORS)}")

    parameters = table.get("parameters", {})
    if not isinstance(parameters, dict):
        raise fail("parameters", f"expected a table, got {parameters!r}",
                   "write e.g. parameters = {mass = 1.0, length = 3.5, damping = 12.25}")
    checked: dict[str, float] = {}
    for key, value in parameters.items():
        if key not in PARAMETERS:
            raise fail(f"parameters.{key}", "unknown parameter", f"allowed are {', '.join(PARAMETERS)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise fail(f"parameters.{key}", f"expected a finite number, got {value!r}", "write a number")
        if value < 0 or (key in ("mass", "length") and value == 0):
            raise fail(f"parameters.{key}", f"must be {'> 0' if key in ('mass', 'length') else '>= 0'}, "
                       f"got {value!r}", "use a physical value")
        checked[key] = float(value)

    torque_limit = number("torque_limit", 0.0, positive=True) if "torque_limit" in table else None
    noise_raw = table.get("sensor_noise", 0.0)
    if isinstance(noise_raw, list):
        if len(noise_raw) != 2:
            raise fail("sensor_noise", f"expected 2 values (position, velocity), got {len(noise_raw)}",
                       "write one std dev for all sensors or [position_std, velocity_std]")
        noise = tuple(_number_value(fail, "sensor_noise", v) for v in noise_raw)
    else:
        value = _number_value(fail, "sensor_noise", noise_raw)
        noise = (value, value)
    seed = table.get("noise_seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise fail("noise_seed", f"expected a non-negative integer, got {seed!r}",
                   "write e.g. noise_seed = 1")
    if any(s > 0 for s in noise) and seed is None:
        raise fail("noise_seed", "missing while sensor_noise is on",
                   "add an explicit integer seed, e.g. noise_seed = 1, so runs are reproducible")

    for key in ("sensor_delay", "sensor_period"):
        if number(key, 0.0) > MAX_SENSOR_TIME:
            raise fail(key, f"{table[key]!r} s is longer than any run",
                       f"use a value under {MAX_SENSOR_TIME:g} s")
    options = MujocoOptions(
        where=where,
        model=model,
        joint=name("joint"),
        position_sensor=name("position_sensor"),
        velocity_sensor=name("velocity_sensor"),
        actuator=name("actuator"),
        native_terms=tuple(native),
        integrator=integrator,
        parameters=checked,
        torque_limit=torque_limit,
        frictionloss=number("frictionloss", 0.0),
        armature=number("armature", 0.0),
        rod_mass=number("rod_mass", 0.0),
        sensor_noise=(float(noise[0]), float(noise[1])),
        noise_seed=seed,
        sensor_delay=number("sensor_delay", 0.0),
        sensor_period=number("sensor_period", 0.0),
    )
    build_model(options)  # report wrong names and compile errors when the scenario is loaded
    return options


MAX_SENSOR_TIME = 1e3  # seconds; MuJoCo's sensor history length is an int of delay / timestep


def _number_value(fail: Callable[[str, str, str], QcontrolInputError], key: str, value: Any) -> float:
    real = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not real or not math.isfinite(value) or value < 0:
        raise fail(key, f"expected a finite number >= 0, got {value!r}",
                   "write a standard deviation such as 0.001")
    return float(value)


# --------------------------------------------------------------------------------------------
# Model building


@dataclass(frozen=True)
class _Ids:
    joint: int
    dof: int
    position_sensor: int
    velocity_sensor: int
    actuator: int
    actuator_gain: float  # generalized force per unit ctrl


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def build_model(options: MujocoOptions, timestep: float | None = None) -> mujoco.MjModel:
    """Compile the MJCF with the scenario's parameter overrides and realism options (MjSpec).

    ``timestep`` (the scenario's dt) replaces the MJCF's; it sizes the sensor history buffers.
    Compile errors and missing or unsuitable elements raise :class:`QcontrolInputError`.
    """
    model, _ = _build(options, timestep)
    return model


def _build(options: MujocoOptions, timestep: float | None) -> tuple[mujoco.MjModel, _Ids]:
    where = options.where

    def fail(key: str, problem: str, fix: str) -> QcontrolInputError:
        return QcontrolInputError(f"{where}.{key}: {problem}; {fix}")

    try:
        spec = mujoco.MjSpec.from_file(str(options.model))
    except Exception as exc:  # MuJoCo raises ValueError with a multi-line parser message
        raise fail("model", f"MuJoCo cannot load {options.model.name}: {_one_line(exc)}",
                   "fix the MJCF file") from None
    joint = _find(spec.joints, options.joint)
    if joint is None:
        raise fail("joint", f"no joint named {options.joint!r} in {options.model.name}",
                   f"use one of {_names(spec.joints)}")
    for key in ("position_sensor", "velocity_sensor"):
        if _find(spec.sensors, getattr(options, key)) is None:
            raise fail(key, f"no sensor named {getattr(options, key)!r} in {options.model.name}",
                       f"use one of {_names(spec.sensors)}")
    actuator = _find(spec.actuators, options.actuator)
    if actuator is None:
        raise fail("actuator", f"no actuator named {options.actuator!r} in {options.model.name}",
                   f"use one of {_names(spec.actuators)}")
    if timestep is not None:
        spec.option.timestep = timestep
    spec.option.integrator = INTEGRATORS[options.integrator]
    _apply_parameters(spec, joint, options, fail)
    _apply_realism(spec, joint, actuator, options, fail)
    try:
        model = spec.compile()
    except Exception as exc:
        raise fail("model", f"MuJoCo cannot compile {options.model.name}: {_one_line(exc)}",
                   "fix the MJCF file or the [plant.mujoco] options") from None
    return model, _check_elements(model, options, fail)


def _find(elements: Sequence[Any], name: str) -> Any:
    return next((e for e in elements if e.name == name), None)


def _names(elements: Sequence[Any]) -> str:
    names = [repr(e.name) for e in elements if e.name]
    return ", ".join(names) if names else "(none: name the element in the MJCF)"


def _apply_parameters(spec: mujoco.MjSpec, joint: Any, options: MujocoOptions, fail: Callable) -> None:
    body = joint.parent
    params = options.parameters
    if "damping" in params:
        damping = np.array(joint.damping, dtype=float)  # [linear, polynomial terms...] in mujoco 4
        damping[0] = params["damping"]
        joint.damping = damping
    if "gravity" in params:
        spec.option.gravity = [0.0, 0.0, -params["gravity"]]
    if ("mass" in params or "length" in params) and not body.explicitinertial:
        raise fail("parameters", f"body {body.name!r} of joint {joint.name!r} has no explicit <inertial>",
                   "give the body an <inertial> element so mass and length have one source of truth")
    if "mass" in params:
        body.mass = params["mass"]
    if "length" in params:
        if joint.type != mujoco.mjtJoint.mjJNT_HINGE:
            raise fail("parameters.length", f"joint {joint.name!r} is not a hinge",
                       "remove length (it is the hinge-to-centre-of-mass distance)")
        arm = np.asarray(body.ipos, dtype=float) - np.asarray(joint.pos, dtype=float)
        old = float(np.linalg.norm(arm))
        if old == 0.0:
            raise fail("parameters.length", f"the centre of mass of {body.name!r} is on the hinge",
                       "place the <inertial> away from the joint in the MJCF")
        scale = params["length"] / old
        body.ipos = np.asarray(joint.pos) + arm * scale
        for geom in body.geoms:  # keep the picture consistent with the physics
            geom.pos = np.asarray(joint.pos) + (np.asarray(geom.pos) - np.asarray(joint.pos)) * scale
            fromto = np.asarray(geom.fromto, dtype=float)
            if np.all(np.isfinite(fromto)):
                base = np.tile(np.asarray(joint.pos, dtype=float), 2)
                geom.fromto = base + (fromto - base) * scale


def _apply_realism(spec: mujoco.MjSpec, joint: Any, actuator: Any, options: MujocoOptions,
                   fail: Callable) -> None:
    if options.torque_limit is not None:
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.ctrlrange = [-options.torque_limit, options.torque_limit]
    joint.frictionloss = options.frictionloss or joint.frictionloss
    joint.armature = options.armature or joint.armature
    if options.rod_mass > 0:
        if joint.type != mujoco.mjtJoint.mjJNT_HINGE:
            raise fail("rod_mass", f"joint {joint.name!r} is not a hinge", "remove rod_mass")
        body = joint.parent
        arm = np.asarray(body.ipos, dtype=float) - np.asarray(joint.pos, dtype=float)
        length = float(np.linalg.norm(arm))
        axis = arm / length
        # thin uniform rod about its centre (plus MuJoCo's minimum along the rod's axis)
        rod_inertia = options.rod_mass * length**2 / 12.0 * (np.eye(3) - np.outer(axis, axis))
        rod_inertia += 1e-12 * np.eye(3)
        rod = body.add_body(name=f"{body.name}_rod_mass", pos=[0.0, 0.0, 0.0])
        rod.explicitinertial = True
        rod.mass = options.rod_mass
        rod.ipos = np.asarray(joint.pos, dtype=float) + arm / 2.0
        rod.fullinertia = [rod_inertia[0, 0], rod_inertia[1, 1], rod_inertia[2, 2],
                           rod_inertia[0, 1], rod_inertia[0, 2], rod_inertia[1, 2]]
    delay, period = options.sensor_delay, options.sensor_period
    noise = dict(zip((options.position_sensor, options.velocity_sensor), options.sensor_noise, strict=True))
    for sensor in spec.sensors:
        if sensor.name in noise:
            sensor.noise = noise[sensor.name]  # metadata only; the plant adds the noise
            if delay > 0 or period > 0:
                step = spec.option.timestep
                sensor.nsample = int(math.ceil(delay / step - 1e-9)) + 1
                sensor.delay = delay
                sensor.interval = [period, 0.0]


def _check_elements(model: mujoco.MjModel, options: MujocoOptions, fail: Callable) -> _Ids:
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, options.joint)
    if int(model.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
        raise fail("joint", f"joint {options.joint!r} is not a hinge or slide joint",
                   "eq. (1) with n = 2 needs one scalar joint")
    if model.nv != 1:
        raise fail("model", f"{options.model.name} has {model.nv} degrees of freedom",
                   "a plant of order 2 needs a model with exactly one scalar joint")
    wanted = {"position_sensor": mujoco.mjtSensor.mjSENS_JOINTPOS,
              "velocity_sensor": mujoco.mjtSensor.mjSENS_JOINTVEL}
    sensor_ids = {}
    for key, kind in wanted.items():
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, getattr(options, key))
        if int(model.sensor_type[sid]) != int(kind) or int(model.sensor_objid[sid]) != jid:
            raise fail(key, f"sensor {getattr(options, key)!r} is not a {kind.name[6:].lower()} sensor "
                       f"on joint {options.joint!r}",
                       f"use <{kind.name[6:].lower()} joint=\"{options.joint}\"/> in the MJCF")
        sensor_ids[key] = sid
    aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, options.actuator)
    plain_motor = (
        int(model.actuator_trntype[aid]) == int(mujoco.mjtTrn.mjTRN_JOINT)
        and int(model.actuator_trnid[aid, 0]) == jid
        and int(model.actuator_dyntype[aid]) == int(mujoco.mjtDyn.mjDYN_NONE)
        and int(model.actuator_gaintype[aid]) == int(mujoco.mjtGain.mjGAIN_FIXED)
        and int(model.actuator_biastype[aid]) == int(mujoco.mjtBias.mjBIAS_NONE)
    )
    gain = float(model.actuator_gainprm[aid, 0] * model.actuator_gear[aid, 0])
    if not plain_motor or gain == 0.0:
        raise fail("actuator", f"actuator {options.actuator!r} is not a <motor> on joint {options.joint!r}",
                   f"use <motor joint=\"{options.joint}\" gear=\"1\"/> in the MJCF")
    return _Ids(jid, int(model.jnt_dofadr[jid]), sensor_ids["position_sensor"],
                sensor_ids["velocity_sensor"], aid, gain)


def joint_inertia(model: mujoco.MjModel) -> float:
    """The (1x1) generalized inertia of a one-dof model at ``qpos0``, via ``mj_fullM``.

    For a single hinge or slide joint it does not depend on the joint's position.
    """
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return float(full[0, 0])


# --------------------------------------------------------------------------------------------
# The passive callback's generalized force (plain floats: see :func:`qcontrol.expr.scalar_function`)

GeneralizedForce = Callable[[float, float], float]  # (qpos, qvel) -> generalized force


def _callback_term(terms: Sequence[tuple[float, ScalarFn]], inertia: float) -> GeneralizedForce:
    """``(q, v) -> I * sum(coefficient * term(q, v))``, NaN if a term is undefined there."""
    pairs = tuple((inertia * c, f) for c, f in terms)

    def generalized_force(q: float, v: float) -> float:
        xs = (q, v)
        total = 0.0
        try:
            for c, f in pairs:
                total += c * f(xs)
        except (ValueError, ZeroDivisionError, OverflowError):
            return math.nan
        return total

    return generalized_force


# --------------------------------------------------------------------------------------------
# The process-global passive callback: one dispatcher, entries per MjData


_ENTRIES: dict[int, Callable[[], None]] = {}  # id(MjData) -> adds the non-native terms to it
_PREVIOUS: list[Any] = []  # the passive callback that was installed before the dispatcher


def _dispatch(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """The installed ``mjcb_passive``: MuJoCo passes the very MjData objects the plants own."""
    apply = _ENTRIES.get(id(data))
    if apply is not None:
        apply()
    elif _PREVIOUS and _PREVIOUS[0] is not None:
        _PREVIOUS[0](model, data)


def _applier(data: mujoco.MjData, qadr: int, dof: int, force: GeneralizedForce) -> Callable[[], None]:
    qpos, qvel, qfrc = data.qpos, data.qvel, data.qfrc_passive  # views, made once

    def apply() -> None:
        qfrc[dof] += force(qpos.item(qadr), qvel.item(dof))

    return apply


@contextmanager
def _callback_installed(datas: Sequence[mujoco.MjData], qadr: int, dof: int,
                        force: GeneralizedForce | None) -> Iterator[None]:
    """Register ``datas`` with the dispatcher, installing it if needed; undo everything on exit.

    ``mjcb_passive`` is process-global. One dispatcher serves every plant in use (each MjData
    has its own entry), and the callback found before the first plant is restored after the last.
    """
    if force is None:
        yield
        return
    if not _ENTRIES:
        previous = mujoco.get_mjcb_passive()
        _PREVIOUS[:] = [None if previous is _dispatch else previous]
        mujoco.set_mjcb_passive(_dispatch)
    keys = []
    try:
        for data in datas:
            _ENTRIES[id(data)] = _applier(data, qadr, dof, force)
            keys.append(id(data))
        yield
    finally:
        for key in keys:
            _ENTRIES.pop(key, None)
        if not _ENTRIES:
            mujoco.set_mjcb_passive(_PREVIOUS[0] if _PREVIOUS else None)
            _PREVIOUS.clear()


def _unstable(messages: Sequence[str]) -> bool:
    """Whether MuJoCo reported a blow-up among its ``messages``.

    MuJoCo resets a copy whose ctrl/qpos/qvel/qacc turns NaN, Inf or huge and carries on from
    the reset pose. It reports it through the warning handler the first time per MjData until
    ``mj_resetData`` clears the counters, which :meth:`MujocoPlant.reset` does before every run;
    so the first reset of a run always leaves an "unstable" message, and a copy is marked dead
    from it (the plant's state and readings are NaN from then on).
    """
    return any("unstable" in m for m in messages)


# --------------------------------------------------------------------------------------------
# The plant


class MujocoPlant:
    """Batch of ``batch`` MuJoCo copies of the plant of eq. (1), n = 2 (see the module docstring).

    ``timestep`` is the scenario's dt: ``model.opt.timestep`` is set to it, so ``step(u, dt)`` is
    one ``mj_step``; a step ``h`` that is a multiple of it takes several. After construction,
    ``consistency_report`` holds the measured agreement of MuJoCo's acceleration with eq. (1).
    """

    def __init__(
        self,
        options: MujocoOptions,
        n: int,
        psi: Expression | None,
        phi: Sequence[Expression],
        theta: Sequence[float],
        batch: int = 1,
        timestep: float | None = None,
    ) -> None:
        where = options.where
        if n != 2:
            raise QcontrolInputError(
                f"{where}: the MuJoCo backend models one joint, i.e. plant order 2, but the plant has "
                f"order {n}; use backend = \"ode\" for this scenario"
            )
        theta_arr = np.asarray(theta, dtype=float)
        if len(phi) != theta_arr.size:
            raise QcontrolInputError(f"{where}: phi has {len(phi)} terms but theta has {theta_arr.size}; "
                                     "give one theta per phi")
        if batch < 1:
            raise QcontrolInputError(f"{where}: batch must be >= 1, got {batch}")
        if timestep is not None and not (math.isfinite(timestep) and timestep > 0):
            raise QcontrolInputError(f"{where}: timestep must be a finite number > 0, got {timestep!r}")
        self.n, self.batch, self.options = 2, int(batch), options
        self.model, ids = _build(options, timestep)
        self.timestep = float(self.model.opt.timestep)
        self._check_sensor_timing(where)
        self._ids = ids
        self._aid = ids.actuator
        nominal = self.model if not (options.armature or options.rod_mass) else build_model(
            options.nominal(), timestep)
        self.inertia = joint_inertia(nominal)  # the gain between u and generalized force
        self._ctrl_per_u = self.inertia / ids.actuator_gain

        # terms: (name, coefficient, vectorized expression, native?)
        names = term_names(len(phi), psi is not None)
        exprs = ([psi] if psi is not None else []) + list(phi)
        coefs = ([1.0] if psi is not None else []) + theta_arr.tolist()
        self.terms = [
            (nm, c, e, nm in options.native_terms) for nm, c, e in zip(names, coefs, exprs, strict=True)
        ]
        applied = [(c, scalar_function(e)) for nm, c, e, native in self.terms if not native]
        self._force = _callback_term(applied, self.inertia) if applied else None

        self._datas = [mujoco.MjData(self.model) for _ in range(self.batch)]
        self._qadr = int(self.model.jnt_qposadr[ids.joint])
        self._sadr = (int(self.model.sensor_adr[ids.position_sensor]),
                      int(self.model.sensor_adr[ids.velocity_sensor]))
        self._views = [(d.ctrl, d.sensordata, d.qpos, d.qvel) for d in self._datas]
        self._dead = [False] * self.batch
        self._steppers: dict[float, list[Callable[[float], None]]] = {}  # h -> one per copy
        self._noise = np.asarray(options.sensor_noise, dtype=float)
        self._noisy = bool(self._noise.any())
        self._rng = np.random.default_rng(options.noise_seed)
        self._entered: Any = None
        self._previous_warning: Any = None
        self.mujoco_warnings: list[str] = []  # MuJoCo's warnings during the last run
        self.consistency_report = self._consistency_check()

    # ---- context manager: the process-global passive callback and warning handler
    def __enter__(self) -> MujocoPlant:
        if self._entered is not None:
            raise RuntimeError("MujocoPlant is already in use by a 'with' block")
        manager = _callback_installed(self._datas, self._qadr, self._ids.dof, self._force)
        manager.__enter__()
        self._entered = manager
        # MuJoCo's default warning handler appends to MUJOCO_LOG.TXT in the working directory;
        # keep its messages here instead (the engine reports a blow-up as a divergence).
        self.mujoco_warnings = []
        self._steppers = {}  # (they hold the warnings list)
        self._previous_warning = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(self.mujoco_warnings.append)
        return self

    def __exit__(self, *exc: object) -> None:
        manager, self._entered = self._entered, None
        mujoco.set_mju_user_warning(self._previous_warning)
        if manager is not None:
            manager.__exit__(None, None, None)

    # ---- Plant protocol
    def reset(self, x0: np.ndarray) -> None:
        """Put every copy at ``x0`` (shape ``(batch, 2)``); sensor histories are filled with it."""
        x0 = np.broadcast_to(np.asarray(x0, dtype=float), (self.batch, 2))
        model = self.model
        for b, data in enumerate(self._datas):
            mujoco.mj_resetData(model, data)
            data.qpos[self._qadr] = x0[b, 0]
            data.qvel[self._ids.dof] = x0[b, 1]
            mujoco.mj_forward(model, data)
            for sid, value in ((self._ids.position_sensor, x0[b, 0]), (self._ids.velocity_sensor, x0[b, 1])):
                nsample = int(model.sensor_history[sid, 0])
                if nsample > 0:  # the sensor has read x(0) for all t < 0
                    mujoco.mj_initSensorHistory(model, data, sid, None, np.full((nsample, 1), value), 0.0)
            if model.nhistory:
                mujoco.mj_forward(model, data)
        self._dead[:] = [False] * self.batch  # in place: the step closures hold this list
        self._rng = np.random.default_rng(self.options.noise_seed)

    def state(self) -> np.ndarray:
        """The true ``(qpos, qvel)`` of every copy (NaN for a copy MuJoCo had to reset)."""
        q, dof = self._qadr, self._ids.dof
        out = np.array([(qpos.item(q), qvel.item(dof)) for _, _, qpos, qvel in self._views])
        if True in self._dead:
            out[np.asarray(self._dead)] = np.nan
        return out

    def read_sensors(self) -> np.ndarray:
        """``sensordata`` of the position and velocity sensors (plus noise, if configured)."""
        p, v = self._sadr
        out = np.array([(data.item(p), data.item(v)) for _, data, _, _ in self._views])
        if self._noisy:
            out += self._rng.normal(0.0, 1.0, size=out.shape) * self._noise
        if True in self._dead:
            out[np.asarray(self._dead)] = np.nan
        return out

    def step(self, u: np.ndarray, h: float) -> None:
        """Hold ``u`` for ``h`` seconds: ``h / timestep`` calls of ``mj_step`` per copy.

        ``mj_step`` leaves ``sensordata`` at the state before its last substep, so
        ``mj_sensorPos``/``mj_sensorVel`` then bring the (joint position and velocity) sensors to
        the new state; with a sensor delay they read MuJoCo's history buffer instead.
        """
        if self._entered is None and self._force is not None:
            raise RuntimeError("use MujocoPlant in a 'with' block: its passive callback is installed there")
        steppers = self._steppers.get(h) or self._make_steppers(h)
        values = np.asarray(u, dtype=float).ravel().tolist()
        if len(values) != self.batch:
            values = values * self.batch if len(values) == 1 else list(np.broadcast_to(values, (self.batch,)))
        for step_copy, value in zip(steppers, values):  # noqa: B905 (one value per copy)
            step_copy(value)

    def _make_steppers(self, h: float) -> list[Callable[[float], None]]:
        """One ``step(u)`` per copy for steps of ``h``: closures over the copy's MjData views,
        made once per step length and ``with`` block (they hold its list of MuJoCo warnings)."""
        substeps = self._count_substeps(h)
        model, dead, messages = self.model, self._dead, self.mujoco_warnings
        actuator, ctrl_per_u = self._aid, self._ctrl_per_u

        def stepper(b: int) -> Callable[[float], None]:
            data, ctrl = self._datas[b], self._views[b][0]

            def step_copy(u: float) -> None:
                """Copy ``b`` through ``substeps`` calls of ``mj_step`` with ``u`` held."""
                if dead[b]:
                    return
                ctrl[actuator] = ctrl_per_u * u
                seen = len(messages)
                _mj_step(model, data, substeps)
                _mj_sensor_pos(model, data)
                _mj_sensor_vel(model, data)
                if len(messages) != seen and _unstable(messages[seen:]):  # a blow-up always warns
                    dead[b] = True

            return step_copy

        steppers = self._steppers[h] = [stepper(b) for b in range(self.batch)]
        return steppers

    # ---- a batch of one on plain floats (the engine's fast path)
    def scalar_io(self, h: float) -> ScalarIO:
        """``observe() -> ([qpos, qvel], [position, velocity])`` (:meth:`state` and
        :meth:`read_sensors` of the one copy, as floats) and ``step(u)`` (:meth:`step` by ``h``
        with ``u`` a float) for a batch of one: closures over the copy's MjData views, made once
        per run inside the ``with`` block, so a step costs one ``mj_step`` call and a few
        attribute-free Python operations more."""
        if self.batch != 1:
            raise ValueError(f"scalar_io is for a batch of one, the plant has {self.batch} copies")
        if self._entered is None:
            raise RuntimeError("use MujocoPlant in a 'with' block: scalar_io belongs to one run")
        steppers = self._steppers.get(h) or self._make_steppers(h)
        sensordata, qpos, qvel = self._views[0][1:]
        q, dof = self._qadr, self._ids.dof
        p, v = self._sadr
        dead = self._dead
        noise = self._noise.tolist() if self._noisy else None
        nan = [math.nan, math.nan]

        def observe() -> tuple[list[float], list[float]]:
            if noise is not None:  # one draw per reading, the same stream as read_sensors
                e = self._rng.normal(0.0, 1.0, size=(1, 2))[0].tolist()
            if dead[0]:
                return nan[:], nan[:]
            x = [qpos.item(q), qvel.item(dof)]
            if noise is not None:
                return x, [sensordata.item(p) + e[0] * noise[0], sensordata.item(v) + e[1] * noise[1]]
            return x, [sensordata.item(p), sensordata.item(v)]

        return observe, steppers[0]

    def _count_substeps(self, h: float) -> int:
        substeps = round(h / self.timestep)
        if substeps < 1 or abs(substeps * self.timestep - h) > 1e-9 * h:
            raise QcontrolInputError(
                f"{self.options.where}: step {h!r} s is not a whole number of MuJoCo timesteps "
                f"{self.timestep!r} s; use a dt that is a multiple of the model timestep"
            )
        return substeps

    # ---- consistency of the MJCF with eq. (1)
    def _check_sensor_timing(self, where: str) -> None:
        for key in ("sensor_delay", "sensor_period"):
            value = getattr(self.options, key)
            if value > 0 and abs(round(value / self.timestep) * self.timestep - value) > 1e-9 * value:
                raise QcontrolInputError(
                    f"{where}.{key}: {value!r} s is not a whole number of steps dt = {self.timestep!r}; "
                    "use a multiple of the scenario's dt"
                )

    def _consistency_check(self) -> dict[str, Any]:
        """Compare MuJoCo's qacc with ``u + psi + theta^T phi`` at sampled states (issue 3, item 3).

        The residual is regressed on the terms (and on ``u`` and a constant) to say which term
        disagrees and by how much. Refuses (QcontrolInputError) unless a realism option is on.
        """
        rng = np.random.default_rng(CONSISTENCY_SEED)
        count = CONSISTENCY_SAMPLES
        x = np.column_stack([rng.uniform(-math.pi, math.pi, count), rng.uniform(-4.0, 4.0, count)])
        u = rng.uniform(-20.0, 20.0, count)
        columns = {"u": u}
        for nm, _, expr, _ in self.terms:
            columns[nm] = np.broadcast_to(expr(x), (count,))
        coefficient = {"u": 1.0} | {nm: c for nm, c, _, _ in self.terms}
        rhs = sum(coefficient[k] * columns[k] for k in columns)
        scale = 1.0 + sum(np.abs(coefficient[k] * columns[k]) for k in columns)

        qacc = np.empty(count)
        data = mujoco.MjData(self.model)
        with _callback_installed([data], self._qadr, self._ids.dof, self._force):
            for i in range(count):
                data.qpos[self._qadr], data.qvel[self._ids.dof] = x[i]
                data.ctrl[self._ids.actuator] = self._ctrl_per_u * u[i]
                mujoco.mj_forward(self.model, data)
                qacc[i] = data.qacc[self._ids.dof]
        residual = qacc - rhs
        relative = np.abs(residual) / scale
        names = list(columns) + ["constant"]
        basis = np.column_stack([columns[k] for k in columns] + [np.ones(count)])
        fit, *_ = np.linalg.lstsq(basis, residual, rcond=None)
        contribution = {k: float(np.max(np.abs(fit[j] * basis[:, j]))) for j, k in enumerate(names)}
        unexplained = float(np.max(np.abs(residual - basis @ fit)))
        ok = bool(np.all(relative <= CONSISTENCY_TOLERANCE))
        terms = {
            k: {"scenario": coefficient.get(k, 0.0), "mujoco": coefficient.get(k, 0.0) + float(fit[j]),
                "max_abs_mismatch": contribution[k]}
            for j, k in enumerate(names)
        }
        report = {
            "ok": ok, "samples": count, "tolerance": CONSISTENCY_TOLERANCE,
            "max_abs_mismatch": float(np.max(np.abs(residual))),
            "max_relative_mismatch": float(np.max(relative)),
            "unexplained_by_terms": unexplained, "terms": terms,
            "realism": list(self.options.realism), "inertia": self.inertia,
        }
        if ok or self.options.realism:
            return report
        worst = max(contribution, key=contribution.__getitem__)
        labels = {nm: f"{nm} = {e.source}" for nm, _, e, _ in self.terms} | {
            "u": "the input gain (u)", "constant": "a constant offset"}
        if contribution[worst] >= unexplained:
            blame = (f"the mismatch follows {labels[worst]}: MuJoCo's coefficient is "
                     f"{terms[worst]['mujoco']:.6g}, the scenario's {terms[worst]['scenario']:.6g} "
                     f"(up to {contribution[worst]:.3g})")
        else:
            blame = (f"the mismatch (up to {unexplained:.3g}) is not a multiple of any term; "
                     f"largest term-wise part {labels[worst]} (up to {contribution[worst]:.3g})")
        raise QcontrolInputError(
            f"{self.options.where}: MuJoCo's acceleration differs from x2' = u + psi + theta^T phi by up "
            f"to {report['max_abs_mismatch']:.3g} at {count} sampled states; {blame}; make the MJCF "
            "(model, parameters, native_terms) and [plant] (psi, phi, theta) describe the same plant"
        )
