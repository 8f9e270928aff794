"""Compiling the MJCF of ``[plant.mujoco]``: parameter overrides and realism options through
``mujoco.MjSpec``, the element checks, and the joint's inertia. A model is compiled once per
options, step and file content (:func:`compiled`), however many plants and recordings use it.

Physical parameters have one source of truth: the MJCF holds the canonical numbers; a scenario
may override them with ``parameters``:

    mass     mass of the joint's body (its explicit <inertial>)        [kg]
    length   distance from the hinge to that body's centre of mass;     [m]
             the body's geoms are scaled with it (hinge joints only)
    damping  joint damping                                              [N s/m or N m s/rad]
    gravity  magnitude of gravity, pointing along -z                    [m/s^2]
"""

from __future__ import annotations

import hashlib
import math
import pathlib
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache, partial
from typing import Any

import mujoco
import numpy as np

from ...errors import QcontrolInputError, shown
from ...outputs import path_kind
from ..base import PlantTerms
from .callbacks import kept_aside
from .native import USERDATA_SLOTS
from .options import MujocoOptions

INTEGRATORS = {
    "RK4": mujoco.mjtIntegrator.mjINT_RK4,
    "Euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}
Fail = Callable[[str, str, str], QcontrolInputError]


@dataclass(frozen=True)
class Ids:
    """Indices of the elements the plant uses, and the actuator's generalized force per ctrl."""

    joint: int
    dof: int
    qpos: int  # the joint's address in qpos
    position_sensor: int
    velocity_sensor: int
    actuator: int
    actuator_gain: float
    activation_sensor: int = -1  # order 3: the actuatorfrc sensor reading x3 (-1: none)
    act: int = -1  # order 3: the actuator's address in act
    tau: float | None = None  # order 3: the filter's time constant (None: a direct actuator)


@dataclass(frozen=True)
class CompiledModel:
    """A compiled model, its element ids and the nominal joint inertia I (the gain between u and
    generalized force: the model with armature and rod mass off, which the ODE describes)."""

    model: mujoco.MjModel
    ids: Ids
    inertia: float

    @property
    def input_gain(self) -> float:
        """The input gain b the model realises for its actuator's own command: ``gear / I``
        (``gear`` the motor's gain times its gear, ``I`` the nominal inertia from ``mj_fullM``);
        through a filter of time constant tau (order 3), ``gear / (I tau)``."""
        b = self.ids.actuator_gain / self.inertia
        return b if self.ids.tau is None else b / self.ids.tau

    @property
    def x3_per_act(self) -> float:
        """Order 3: x3 per unit of the actuator's activation, ``gear / I`` (x2' = x3 + ...)."""
        return self.ids.actuator_gain / self.inertia

    @property
    def x3_per_reading(self) -> float:
        """Order 3: x3 per unit of the actuatorfrc sensor's reading (the force ``gain act``): the
        actuator's gear over I."""
        return float(self.model.actuator_gear[self.ids.actuator, 0]) / self.inertia

    def ctrl_per_u(self, terms: PlantTerms) -> float:
        """The actuator command per unit of u: ``1 / b`` of :attr:`input_gain` when the scenario
        states no input gain (b = 1: u per unit inertia, ``I / gear``, and through a filter ``I tau /
        gear``), else 1 (u is the actuator's command; b as the model realises it, which
        :func:`check_input_gain` has compared with the scenario's)."""
        if terms.input_gain is not None:
            return 1.0
        per_u = self.inertia / self.ids.actuator_gain
        return per_u if self.ids.tau is None else per_u * self.ids.tau


INPUT_GAIN_TOLERANCE = 1e-9  # relative, as the consistency check's coefficients


def check_input_gain(built: CompiledModel, terms: PlantTerms, where: str) -> None:
    """A stated ``plant.input_gain`` must be what the model realises, ``gear / I``, to a relative
    :data:`INPUT_GAIN_TOLERANCE`; else one line with both numbers at full precision."""
    if terms.input_gain is None:
        return
    realised, stated = built.input_gain, float(terms.input_gain)
    if abs(stated - realised) <= INPUT_GAIN_TOLERANCE * abs(realised):
        return
    gear, inertia, tau = built.ids.actuator_gain, built.inertia, built.ids.tau
    formula = (f"gear / I = {gear!r} / {inertia!r}" if tau is None else
               f"gear / (I tau) = {gear!r} / ({inertia!r} * {tau!r})")
    raise QcontrolInputError(
        f"{where.rsplit('.', 1)[0]}.input_gain: is {stated!r} but the model realises b = {formula} = "
        f"{realised!r}; write input_gain = {realised!r} in [plant], or leave it out to have u scaled by "
        "the inertia (b = 1)")


def compiled(options: MujocoOptions, timestep: float | None = None) -> CompiledModel:
    """The model of ``options`` with ``timestep`` (the scenario's dt; it sizes the sensor history
    buffers), compiled once per options, step and MJCF file content (the noise seed aside: the
    plant draws the noise, the model is the same for every seed). Compile errors and missing or
    unsuitable elements raise :class:`QcontrolInputError`. Users of the result must not modify
    the model (it is shared)."""
    kind = path_kind(options.model)
    if kind is not None:
        raise _fail(options)("model", f"{shown(options.model)} is {kind}, not a regular file",
                             "give an MJCF file")
    try:
        content = options.model.read_bytes()
    except OSError as exc:
        raise _fail(options)("model", f"cannot read {options.model.name} ({exc.strerror})",
                             "give a readable MJCF file") from None
    return _compiled(replace(options, noise_seed=None), timestep, hashlib.sha256(content).hexdigest())


def build_model(options: MujocoOptions, timestep: float | None = None) -> mujoco.MjModel:
    """The compiled MjModel of ``options`` (see :func:`compiled`)."""
    return compiled(options, timestep).model


@lru_cache(maxsize=64)
def _compiled(options: MujocoOptions, timestep: float | None, content_sha256: str) -> CompiledModel:
    with kept_aside():  # MuJoCo's warnings while compiling: never to MUJOCO_LOG.TXT
        model, ids = _compile(options, timestep)
        nominal = model if not (options.armature or options.rod_mass) else _compile(options.nominal(),
                                                                                    timestep)[0]
        return CompiledModel(model, ids, joint_inertia(nominal))


def _fail(options: MujocoOptions) -> Fail:
    """``fail(key, problem, fix)``: the one-line error of a key of the options' section."""
    return partial(_error_at, options.where)


def _error_at(where: str, key: str, problem: str, fix: str) -> QcontrolInputError:
    return QcontrolInputError(f"{where}.{key}: {problem}; {fix}")


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


_INCLUDE = re.compile(r"""<include\s+file\s*=\s*["']([^"']+)["']""")
MAX_INCLUDES = 100


def _check_includes(model: pathlib.Path, fail: Fail) -> None:
    """Every file the MJCF includes (and they include) is a regular file: MuJoCo would block
    forever reading a FIFO, or fail on a device, with no message naming it."""
    pending, seen = [model], set()
    while pending and len(seen) < MAX_INCLUDES:
        current = pending.pop()
        seen.add(current)
        try:
            text = current.read_text(encoding="utf-8", errors="replace")
        except OSError:
            continue  # MuJoCo's own message names it
        for name in _INCLUDE.findall(text):
            included = (model.parent / name).resolve()
            kind = path_kind(included)
            if kind is not None:
                raise fail("model", f"{current.name} includes {shown(name)}, which is {kind}, not a regular "
                           "file", "include only MJCF files")
            if included.is_file() and included not in seen:
                pending.append(included)


ASSET_FILES = (("meshes", "mesh", "meshdir", ("file",)),
               ("hfields", "height field", "meshdir", ("file",)),
               ("skins", "skin", "meshdir", ("file",)),
               ("textures", "texture", "texturedir", ("file", "cubefiles")))


def _check_assets(spec: mujoco.MjSpec, model: pathlib.Path, fail: Fail) -> None:
    """Every file the model's assets name (meshes, height fields, skins, textures and their cube
    faces), where MuJoCo will look for it (the model's folder, then meshdir or texturedir), is a
    regular file or nothing: checked before MuJoCo opens it, which would block forever on a FIFO."""
    for elements, what, folder, attributes in ASSET_FILES:
        base = model.parent / (getattr(spec, folder) or "")
        for element in getattr(spec, elements):
            for attribute in attributes:
                value = getattr(element, attribute)
                for name in [value] if isinstance(value, str) else list(value):
                    kind = path_kind(base / name) if name else None
                    if kind is not None:
                        raise fail("model", f"{model.name}'s {what} {shown(element.name or name)} reads "
                                   f"{shown(name)}, which is {kind}, not a regular file",
                                   "name a regular file")


def _compile(options: MujocoOptions, timestep: float | None) -> tuple[mujoco.MjModel, Ids]:
    fail = _fail(options)
    _check_includes(options.model, fail)
    try:
        spec = mujoco.MjSpec.from_file(str(options.model))
    except Exception as exc:  # MuJoCo raises ValueError with a multi-line parser message
        raise fail("model", f"MuJoCo cannot load {options.model.name}: {_one_line(exc)}",
                   "fix the MJCF file") from None
    _check_assets(spec, options.model, fail)
    joint, actuator = _find_elements(spec, options, fail)
    if timestep is not None:
        spec.option.timestep = timestep
    spec.option.integrator = INTEGRATORS[options.integrator]
    spec.nuserdata = max(spec.nuserdata, USERDATA_SLOTS)  # room for the native passive callback's numbers
    _apply_parameters(spec, joint, options, fail)
    _apply_realism(spec, joint, actuator, options, fail)
    try:
        model = spec.compile()
    except Exception as exc:
        raise fail("model", f"MuJoCo cannot compile {options.model.name}: {_one_line(exc)}",
                   "fix the MJCF file or the [plant.mujoco] options") from None
    return model, _check_elements(model, options, fail)


def _find_elements(spec: mujoco.MjSpec, options: MujocoOptions, fail: Fail) -> tuple[Any, Any]:
    """The joint and the actuator the options name (and the sensors exist)."""
    joint = _find(spec.joints, options.joint)
    if joint is None:
        raise fail("joint", f"no joint named {options.joint!r} in {options.model.name}",
                   f"use one of {_names(spec.joints)}")
    for key, name in (("position_sensor", options.position_sensor), ("velocity_sensor",
                                                                     options.velocity_sensor),
                      ("activation_sensor", options.activation_sensor)):
        if name is not None and _find(spec.sensors, name) is None:
            raise fail(key, f"no sensor named {name!r} in {options.model.name}",
                       f"use one of {_names(spec.sensors)}")
    actuator = _find(spec.actuators, options.actuator)
    if actuator is None:
        raise fail("actuator", f"no actuator named {options.actuator!r} in {options.model.name}",
                   f"use one of {_names(spec.actuators)}")
    return joint, actuator


def _find(elements: Sequence[Any], name: str) -> Any:
    return next((e for e in elements if e.name == name), None)


def _names(elements: Sequence[Any]) -> str:
    names = [repr(e.name) for e in elements if e.name]
    return ", ".join(names) if names else "(none: name the element in the MJCF)"


def _apply_parameters(spec: mujoco.MjSpec, joint: Any, options: MujocoOptions, fail: Fail) -> None:
    body = joint.parent
    params = dict(options.parameters)
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
        _scale_length(body, joint, params["length"], fail)


def _scale_length(body: Any, joint: Any, length: float, fail: Fail) -> None:
    """Move the body's centre of mass to ``length`` from the hinge, scaling its geoms with it."""
    if joint.type != mujoco.mjtJoint.mjJNT_HINGE:
        raise fail("parameters.length", f"joint {joint.name!r} is not a hinge",
                   "remove length (it is the hinge-to-centre-of-mass distance)")
    pivot = np.asarray(joint.pos, dtype=float)
    arm = np.asarray(body.ipos, dtype=float) - pivot
    old = float(np.linalg.norm(arm))
    if old == 0.0:
        raise fail("parameters.length", f"the centre of mass of {body.name!r} is on the hinge",
                   "place the <inertial> away from the joint in the MJCF")
    scale = length / old
    body.ipos = pivot + arm * scale
    for geom in body.geoms:  # keep the picture consistent with the physics
        geom.pos = pivot + (np.asarray(geom.pos) - pivot) * scale
        fromto = np.asarray(geom.fromto, dtype=float)
        if np.all(np.isfinite(fromto)):
            base = np.tile(pivot, 2)
            geom.fromto = base + (fromto - base) * scale


def _apply_realism(spec: mujoco.MjSpec, joint: Any, actuator: Any, options: MujocoOptions,
                   fail: Fail) -> None:
    if options.torque_limit is not None:
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.ctrlrange = [-options.torque_limit, options.torque_limit]
    joint.frictionloss = options.frictionloss or joint.frictionloss
    joint.armature = options.armature or joint.armature
    if options.rod_mass > 0:
        _add_rod(joint, options.rod_mass, fail)
    delay, period = options.sensor_delay, options.sensor_period
    noise = dict(zip((options.position_sensor, options.velocity_sensor), options.sensor_noise, strict=True))
    for sensor in spec.sensors:
        if sensor.name in noise:
            sensor.noise = noise[sensor.name]  # metadata only; the plant adds the noise
            if delay > 0 or period > 0:
                sensor.nsample = int(math.ceil(delay / spec.option.timestep - 1e-9)) + 1
                sensor.delay = delay
                sensor.interval = [period, 0.0]


def _add_rod(joint: Any, mass: float, fail: Fail) -> None:
    """A uniform rod of ``mass`` from the hinge to the body's centre of mass (a welded body)."""
    if joint.type != mujoco.mjtJoint.mjJNT_HINGE:
        raise fail("rod_mass", f"joint {joint.name!r} is not a hinge", "remove rod_mass")
    body = joint.parent
    arm = np.asarray(body.ipos, dtype=float) - np.asarray(joint.pos, dtype=float)
    length = float(np.linalg.norm(arm))
    axis = arm / length
    # thin uniform rod about its centre (plus MuJoCo's minimum along the rod's axis)
    inertia = mass * length**2 / 12.0 * (np.eye(3) - np.outer(axis, axis)) + 1e-12 * np.eye(3)
    rod = body.add_body(name=f"{body.name}_rod_mass", pos=[0.0, 0.0, 0.0])
    rod.explicitinertial = True
    rod.mass = mass
    rod.ipos = np.asarray(joint.pos, dtype=float) + arm / 2.0
    rod.fullinertia = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1,
                                                                                                          2]]


def _check_elements(model: mujoco.MjModel, options: MujocoOptions, fail: Fail) -> Ids:
    """One scalar joint with a position and a velocity sensor on it and a plain motor."""
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, options.joint)
    if int(model.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
        raise fail("joint", f"joint {options.joint!r} is not a hinge or slide joint",
                   "eq. (1) with n = 2 needs one scalar joint")
    if model.nv != 1:
        raise fail("model", f"{options.model.name} has {model.nv} degrees of freedom",
                   "a plant of order 2 needs a model with exactly one scalar joint")
    wanted = {"position_sensor": (options.position_sensor, mujoco.mjtSensor.mjSENS_JOINTPOS),
              "velocity_sensor": (options.velocity_sensor, mujoco.mjtSensor.mjSENS_JOINTVEL)}
    sensor_ids = {}
    for key, (name, kind) in wanted.items():
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
        if int(model.sensor_type[sid]) != int(kind) or int(model.sensor_objid[sid]) != jid:
            tag = kind.name.removeprefix("mjSENS_").lower()  # the MJCF element: jointpos, jointvel
            raise fail(key, f"sensor {name!r} is not a {tag} sensor on joint {options.joint!r}",
                       f"use <{tag} joint=\"{options.joint}\"/> in the MJCF")
        sensor_ids[key] = sid
    aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, options.actuator)
    gain = float(model.actuator_gainprm[aid, 0] * model.actuator_gear[aid, 0])
    ids = Ids(jid, int(model.jnt_dofadr[jid]), int(model.jnt_qposadr[jid]), sensor_ids["position_sensor"],
              sensor_ids["velocity_sensor"], aid, gain)
    if options.activation_sensor is not None:
        return _filter_ids(model, options, ids, fail)
    if not _plain_motor(model, aid, jid) or gain == 0.0:
        raise fail("actuator", f"actuator {options.actuator!r} is not a <motor> on joint {options.joint!r}",
                   f"use <motor joint=\"{options.joint}\" gear=\"1\"/> in the MJCF")
    return ids


FILTERS = (int(mujoco.mjtDyn.mjDYN_FILTER), int(mujoco.mjtDyn.mjDYN_FILTEREXACT))


def filter_actuator_problem(model: mujoco.MjModel, aid: int) -> str | None:
    """Why actuator ``aid`` is not a direct torque or force through a first-order filter
    (``act' = (ctrl - act) / tau``, ``force = gain gear act``), or None."""
    name = repr(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, aid) or f"#{aid}")
    if int(model.actuator_dyntype[aid]) != int(mujoco.mjtDyn.mjDYN_FILTER):
        return f"actuator {name} is not a first-order filter; write dyntype=\"filter\" dynprm=\"TAU\""
    if model.actuator_actearly[aid]:
        return (f"actuator {name} has actearly=\"true\" (its force uses the next activation, which no ODE "
                "of the state has); remove actearly")
    if not model.actuator_dynprm[aid, 0] > 0:
        return f"actuator {name} has a filter time constant dynprm {model.actuator_dynprm[aid, 0]!r}; " \
            "give dynprm > 0"
    if int(model.actuator_gaintype[aid]) != int(mujoco.mjtGain.mjGAIN_FIXED) or \
            int(model.actuator_biastype[aid]) != int(mujoco.mjtBias.mjBIAS_NONE):
        return (f"actuator {name} has a gain that is not fixed, or a bias; a filter actuator needs "
                "gaintype=\"fixed\" and biastype=\"none\"")
    if model.actuator_gainprm[aid, 0] * model.actuator_gear[aid, 0] == 0.0:
        return f"actuator {name} has gear or gain 0 (it applies no force); give it gear=\"1\""
    return None


def _filter_ids(model: mujoco.MjModel, options: MujocoOptions, ids: Ids, fail: Fail) -> Ids:
    """Order 3: the actuator a first-order filter on the joint (fixed gain, no bias, activation
    neither clamped nor early), read by an actuatorfrc sensor."""
    aid, name = ids.actuator, options.actuator
    problem = filter_actuator_problem(model, aid)
    if problem is not None or not _plain_motor(model, aid, ids.joint, FILTERS) or ids.actuator_gain == 0.0:
        raise fail("actuator", problem or f"actuator {name!r} is not a <general dyntype=\"filter\"> on joint "
                   f"{options.joint!r}", f"use <general joint=\"{options.joint}\" dyntype=\"filter\" "
                   "dynprm=\"TAU\" gainprm=\"1\" gear=\"1\"/> in the MJCF")
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, options.activation_sensor)
    kind = int(mujoco.mjtSensor.mjSENS_ACTUATORFRC)
    if int(model.sensor_type[sid]) != kind or int(model.sensor_objid[sid]) != aid:
        raise fail("activation_sensor", f"sensor {options.activation_sensor!r} is not an actuatorfrc sensor "
                   f"on actuator {name!r}", f"use <actuatorfrc actuator=\"{name}\"/> in the MJCF")
    return replace(ids, activation_sensor=sid, act=int(model.actuator_actadr[aid]),
                   tau=float(model.actuator_dynprm[aid, 0]))


def _plain_motor(model: mujoco.MjModel, aid: int, jid: int,
                 dyntypes: tuple[int, ...] = (int(mujoco.mjtDyn.mjDYN_NONE),)) -> bool:
    return (
        int(model.actuator_trntype[aid]) == int(mujoco.mjtTrn.mjTRN_JOINT)
        and int(model.actuator_trnid[aid, 0]) == jid
        and int(model.actuator_dyntype[aid]) in dyntypes
        and int(model.actuator_gaintype[aid]) == int(mujoco.mjtGain.mjGAIN_FIXED)
        and int(model.actuator_biastype[aid]) == int(mujoco.mjtBias.mjBIAS_NONE)
    )


def joint_inertia(model: mujoco.MjModel) -> float:
    """The (1x1) generalized inertia of a one-dof model at ``qpos0``, via ``mj_fullM``.

    For a single hinge or slide joint it does not depend on the joint's position.
    """
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return float(full[0, 0])
