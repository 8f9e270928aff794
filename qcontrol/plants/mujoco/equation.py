"""The equation a one-joint MJCF model realises: eq. (1) with n = 2 as MuJoCo's own physics makes it.

For one hinge or slide joint (x1 its position, x2 its velocity) driven by one direct actuator,
MuJoCo integrates ``I x2' = gear ctrl + (passive and gravity forces)``, I the joint's inertia
(``mj_fullM``: bodies and armature). Divided by I, that is

    x2' = b u + theta^T phi(x),      b = gear / I,   u = ctrl,

with one term per force MuJoCo produces, each coefficient read from the compiled model:

    joint (and actuator) damping   -(a x2 + b x2|x2| + c x2^3)          theta = -a / I, ...
    joint spring about springref   -(k d + k2 d^2 + k3 d^3), d = x1 - ref   theta = -k / I, ...
    gravity (less gravcomp)        A cos(x1 - q0) + B sin(x1 - q0) on a hinge, a constant on a slide

(A and B are MuJoCo's own gravity force at the reference angle q0 and a quarter turn past it:
the gravity force on one hinge is exactly of that form.) What is not a smooth function of x of
that form (dry friction, joint limits, a clamped actuator force, contacts, fluid forces, tendon
springs) is named :class:`Outside`, with what a scenario can do about it. :func:`model_equation`
reads an MJCF file (``qcontrol model``); :func:`equation_of` a compiled model (the scenario
loader, which derives the coefficients a scenario leaves to the model, and the consistency
check's messages). Every derived equation is checked against MuJoCo's acceleration at sampled
states (:attr:`ModelEquation.unexplained`).
"""

from __future__ import annotations

import math
import pathlib
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from ...errors import QcontrolInputError, shown
from ...expr import Expression, compile_expression
from ..base import timed
from .callbacks import kept_aside
from .mjcf import CompiledModel, filter_actuator_problem, joint_inertia

TOLERANCE = 1e-9  # relative, as the consistency check at load
SAMPLES = 300
SEED = 3160  # the paper's article number; any fixed seed works
SCALAR = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide"}
JOINT_TYPES = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball", **SCALAR}
UNITS = {"hinge": ("rad", "N m", "kg m^2"), "slide": ("m", "N", "kg")}
_DISABLE = mujoco.mjtDisableBit


@dataclass(frozen=True)
class ModelTerm:
    """One term theta phi(x) of x2' that MuJoCo's physics produces: ``phi`` over x1, x2,
    ``theta`` its coefficient (acceleration units), ``source`` what makes it, ``bound`` a
    bounding function r(q) of eqs. (37)-(43) for it (|phi(x)| <= beta r(q) when |x - q| <= m)."""

    phi: str
    theta: float
    source: str
    bound: str


@dataclass(frozen=True)
class Outside:
    """Physics of the model outside the smooth form of eq. (1): what it is, and what a scenario
    does about it; ``option`` is the ``[plant.mujoco]`` realism key that states it (a run then
    reports MuJoCo's difference from eq. (1) instead of refusing it), None where no key does and
    the model must change (``fix``)."""

    what: str
    fix: str
    option: tuple[str, float] | None = None


@dataclass(frozen=True)
class ModelEquation:
    """The equation of one joint of a compiled model (see the module docstring)."""

    joint: str
    kind: str  # "hinge" or "slide"
    actuator: str
    gear: float  # generalized force per unit ctrl (gear times the actuator's gain)
    inertia: float
    terms: tuple[ModelTerm, ...]
    outside: tuple[Outside, ...]
    position_sensor: str | None
    velocity_sensor: str | None
    unexplained: float  # max |MuJoCo's qacc - this equation| / scale at sampled states (outside off)
    tau: float | None = None  # a filter actuator's time constant (order 3), None for a direct one
    activation_sensor: str | None = None  # order 3: the (first named) actuatorfrc sensor on the actuator

    @property
    def order(self) -> int:
        """2 for a direct actuator; 3 through a filter (x3 the activation, scaled)."""
        return 2 if self.tau is None else 3

    @property
    def input_gain(self) -> float:
        """b = gear / I: x2' per unit of the actuator's command; through a filter, b = gear / (I tau):
        x3' per unit of the command."""
        b = self.gear / self.inertia
        return b if self.tau is None else b / self.tau

    @property
    def filter_terms(self) -> tuple[ModelTerm, ...]:
        """Order 3: the term of x3' = b u - x3 / tau besides b u, ``-1 / tau`` times x3."""
        if self.tau is None:
            return ()
        source = f"the actuator's filter, time constant tau = {self.tau!r} s: -1 / tau"
        return (ModelTerm("x3", -1.0 / self.tau, source, "1 + q3**2"),)

    @property
    def all_terms(self) -> tuple[ModelTerm, ...]:
        """Every term: x2''s (:attr:`terms`), then x3''s (:attr:`filter_terms`)."""
        return self.terms + self.filter_terms

    @property
    def units(self) -> tuple[str, str, str]:
        """(position, force, inertia) units of the joint."""
        return UNITS[self.kind]


def sampled_states(timed: bool = False, order: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The :data:`SAMPLES` states ``(SAMPLES, order)``, inputs and, for terms in t (``timed``),
    times at which a model is checked against eq. (1): x1 in [-pi, pi], x2 in [-4, 4], u in
    [-20, 20], t in [0, 10], and for order 3 x3 in [-20, 20] (drawn last), the same each call."""
    rng = np.random.default_rng(SEED)
    x = np.column_stack([rng.uniform(-math.pi, math.pi, SAMPLES), rng.uniform(-4.0, 4.0, SAMPLES)])
    u = rng.uniform(-20.0, 20.0, SAMPLES)
    t = rng.uniform(0.0, 10.0, SAMPLES) if timed else None
    if order == 3:
        x = np.column_stack([x, rng.uniform(-20.0, 20.0, SAMPLES)])
    return x, u, t


def model_equation(path: str | pathlib.Path, joint: str | None = None) -> ModelEquation:
    """The equation the MJCF file ``path`` realises for its one actuated joint (``joint``: its
    name, checked); one line (:class:`QcontrolInputError`) naming the file and the fix for a file
    that is not MJCF, a model without exactly one actuated hinge or slide joint, or an actuator
    that is not a direct torque or force."""
    path = pathlib.Path(path)
    label = shown(path)
    _check_mjcf(path, label)
    with kept_aside():
        try:
            model = mujoco.MjModel.from_xml_path(str(path))
        except Exception as exc:  # MuJoCo's parser message spans lines
            raise QcontrolInputError(f"{label}: MuJoCo cannot load it: {' '.join(str(exc).split())}; "
                                     "fix the MJCF") from None
        jid, aid = _actuated_joint(model, joint, label)
        return equation_of(model, jid, aid, label)


def _check_mjcf(path: pathlib.Path, label: str) -> None:
    if not path.is_file():
        what = "not found" if not path.exists() else "not a regular file"
        raise QcontrolInputError(f"{label}: {what}; give the path of an MJCF model (.xml)")
    try:
        text = path.read_bytes()[:1 << 20].decode("utf-8", errors="replace")
    except OSError as exc:
        raise QcontrolInputError(f"{label}: cannot read it ({exc.strerror}); give a readable MJCF "
                                 "file") from None
    first = _ROOT.search(_COMMENTS.sub("", text))
    root = first.group(1) if first else None
    if root != "mujoco":
        what = f"its root element is <{root}>" if root else "no XML element found"
        hint = " (a URDF: load it in MuJoCo and save it as MJCF first)" if root == "robot" else ""
        raise QcontrolInputError(f"{label}: not an MJCF file: {what}{hint}; give an MJCF model, whose root "
                                 "element is <mujoco>")


_COMMENTS = re.compile(r"<!--.*?-->|<\?.*?\?>|<!DOCTYPE[^>]*>", re.DOTALL)
_ROOT = re.compile(r"<\s*([A-Za-z_][\w.:-]*)")


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(model, kind, i) or ""


def _driven(model: mujoco.MjModel) -> dict[int, list[int]]:
    """Joint id -> the actuators driving it through a joint transmission."""
    found: dict[int, list[int]] = {}
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) in (int(mujoco.mjtTrn.mjTRN_JOINT),
                                              int(mujoco.mjtTrn.mjTRN_JOINTINPARENT)):
            found.setdefault(int(model.actuator_trnid[a, 0]), []).append(a)
    return found


def _actuated_joint(model: mujoco.MjModel, joint: str | None, label: str) -> tuple[int, int]:
    """The one actuated joint (checked against ``joint``) and its one actuator."""
    joints = [_name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}" for j in range(model.njnt)]
    if joint is not None and joint not in joints:
        raise QcontrolInputError(f"{label}: --joint {shown(joint)}: no joint of that name; the model's "
                                 f"joints are {', '.join(map(repr, joints)) or 'none'}")
    driven = _driven(model)
    if model.nu and not driven:
        raise QcontrolInputError(f"{label}: no actuator drives a joint directly (tendon or site "
                                 "transmissions only); drive the joint: <motor joint=\"NAME\" gear=\"1\"/>")
    if not driven:
        raise QcontrolInputError(f"{label}: no actuated joint (the model has no <actuator>); add one: "
                                 f"<actuator><motor name=\"u\" joint=\"{joints[0] if joints else 'NAME'}\" "
                                 "gear=\"1\"/></actuator>")
    if len(driven) > 1:
        names = ", ".join(repr(joints[j]) for j in driven)
        raise QcontrolInputError(f"{label}: {len(driven)} actuated joints ({names}); the plant is one joint: "
                                 "keep one joint and its actuator, remove the others")
    jid = next(iter(driven))
    if joint is not None and joints[jid] != joint:
        raise QcontrolInputError(f"{label}: --joint {shown(joint)}: that joint has no actuator; the actuated "
                                 f"joint is {joints[jid]!r}")
    kind = JOINT_TYPES.get(int(model.jnt_type[jid]), "unknown")
    if kind not in SCALAR.values():
        raise QcontrolInputError(f"{label}: joint {joints[jid]!r} is a {kind} joint; the plant needs one "
                                 "hinge or slide joint: write type=\"hinge\" or type=\"slide\"")
    if model.nv != 1:
        others = ", ".join(repr(joints[j]) for j in range(model.njnt) if j != jid)
        raise QcontrolInputError(f"{label}: {model.nv} degrees of freedom (joints {others} besides "
                                 f"{joints[jid]!r}); the plant is one joint: remove the other joints")
    if len(driven[jid]) > 1:
        names = ", ".join(repr(_name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}") for a in driven[jid])
        raise QcontrolInputError(f"{label}: {len(driven[jid])} actuators drive joint {joints[jid]!r} "
                                 f"({names}); keep one <motor> on it")
    aid = driven[jid][0]
    filtered = int(model.actuator_dyntype[aid]) == int(mujoco.mjtDyn.mjDYN_FILTER)
    problem = filter_actuator_problem(model, aid) if filtered else direct_actuator_problem(model, aid)
    if problem is not None:
        raise QcontrolInputError(f"{label}: {problem}")
    return jid, aid


def direct_actuator_problem(model: mujoco.MjModel, aid: int) -> str | None:
    """Why actuator ``aid`` is not a direct torque or force (``force = gain gear ctrl``), or None."""
    name = repr(_name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, aid) or f"#{aid}")
    supported = ("qcontrol supports a direct torque or force: <motor joint=\"NAME\" gear=\"...\"/>, or "
                 "<general> with no dyntype, gaintype \"fixed\" and no bias; or one through a first-order "
                 "filter: <general dyntype=\"filter\" dynprm=\"TAU\"> (plant order 3)")
    dyn = int(model.actuator_dyntype[aid])
    if dyn == int(mujoco.mjtDyn.mjDYN_FILTEREXACT):
        return (f"actuator {name} has dyntype=\"filterexact\", whose activation MuJoCo advances by its exact "
                "discrete formula, not by the integrator the ODE twin shares; write dyntype=\"filter\" "
                "(the same first-order equation)")
    if dyn != int(mujoco.mjtDyn.mjDYN_NONE):
        return f"actuator {name} has activation dynamics ({mujoco.mjtDyn(dyn).name[6:].lower()}); {supported}"
    if int(model.actuator_gaintype[aid]) != int(mujoco.mjtGain.mjGAIN_FIXED):
        return f"actuator {name} has a gain that is not fixed; {supported}"
    if int(model.actuator_biastype[aid]) != int(mujoco.mjtBias.mjBIAS_NONE):
        return (f"actuator {name} has a bias (a position or velocity servo: its force depends on the state, "
                f"not on the command alone); {supported}")
    if model.actuator_gainprm[aid, 0] * model.actuator_gear[aid, 0] == 0.0:
        return f"actuator {name} has gear or gain 0 (it applies no force); give it gear=\"1\""
    return None


def equation_of(model: mujoco.MjModel, jid: int, aid: int, label: str) -> ModelEquation:
    """The equation of joint ``jid`` driven by actuator ``aid`` of the compiled one-dof ``model``."""
    kind = SCALAR[int(model.jnt_type[jid])]
    inertia = joint_inertia(model)
    terms = (*_damping(model, jid, inertia), *_spring(model, jid, inertia),
             *_gravity(model, jid, inertia, kind))
    gear = float(model.actuator_gainprm[aid, 0] * model.actuator_gear[aid, 0])
    sensors = _sensors(model, jid)
    filtered = int(model.actuator_dyntype[aid]) == int(mujoco.mjtDyn.mjDYN_FILTER)
    tau = float(model.actuator_dynprm[aid, 0]) if filtered else None
    eq = ModelEquation(_name(model, mujoco.mjtObj.mjOBJ_JOINT, jid), kind,
                       _name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, aid), gear, inertia, terms,
                       tuple(_outside(model, jid, aid, kind)), *sensors, 0.0, tau,
                       _activation_sensor(model, aid) if filtered else None)
    unexplained, contacts = (_check if tau is None else _check_filter)(model, jid, aid, eq)
    touching = Outside("contacts (geoms touch at some positions)", "disable them: <option><flag contact="
                       "\"disable\"/></option>, or contype=\"0\" conaffinity=\"0\" on the geoms")
    outside = eq.outside + ((touching,) if contacts else ())
    return ModelEquation(**(vars(eq) | {"outside": outside, "unexplained": unexplained}))


def _flag(model: mujoco.MjModel, bit: mujoco.mjtDisableBit) -> bool:
    """Whether the physics of ``bit`` is on (not disabled)."""
    return not model.opt.disableflags & int(bit)


def _actuators_on(model: mujoco.MjModel, jid: int) -> list[int]:
    return _driven(model).get(jid, [])


def _damping(model: mujoco.MjModel, jid: int, inertia: float) -> list[ModelTerm]:
    """Joint damping plus the actuators' (times gear^2): f(v) = a v + b v|v| + c v^3, force -f."""
    if not _flag(model, _DISABLE.mjDSBL_DAMPER):
        return []
    dof = int(model.jnt_dofadr[jid])
    linear = float(model.dof_damping[dof])
    poly = [float(c) for c in model.dof_dampingpoly[dof]]
    for a in _actuators_on(model, jid):
        g2 = float(model.actuator_gear[a, 0]) ** 2
        linear += float(model.actuator_damping[a]) * g2
        poly = [p + float(c) * g2 for p, c in zip(poly, model.actuator_dampingpoly[a], strict=True)]
    phis = (("x2", "1 + q2**2"), ("x2*abs(x2)", "1 + 2*q2**2"), ("x2**3", "1 + q2**4"))
    return [ModelTerm(phi, -c / inertia, f"{_order(i)} damping {c!r} (joint and actuators): -{c!r} / I",
                      bound)
            for i, (c, (phi, bound)) in enumerate(zip([linear, *poly], phis, strict=True)) if c != 0.0]


def _order(i: int) -> str:
    return ("linear", "quadratic", "cubic")[i]


def _spring(model: mujoco.MjModel, jid: int, inertia: float) -> list[ModelTerm]:
    """The joint spring about springref: f(d) = k d + k2 d^2 + k3 d^3 with d = x1 - ref, force -f."""
    if not _flag(model, _DISABLE.mjDSBL_SPRING):
        return []
    ref = float(model.qpos_spring[int(model.jnt_qposadr[jid])])
    d = "x1" if ref == 0.0 else f"(x1 - {ref!r})" if ref > 0 else f"(x1 + {-ref!r})"
    q = d.replace("x1", "q1")
    shapes = ((d.strip("()"), f"1 + {q}**2"), (f"{d}**2", f"1 + {q}**2"), (f"{d}**3", f"1 + {q}**4"))
    coefficients = [float(model.jnt_stiffness[jid]), *(float(c) for c in model.jnt_stiffnesspoly[jid])]
    about = f" about springref {ref!r}" if ref else ""
    return [ModelTerm(phi, -k / inertia, f"{_order(i)} spring stiffness {k!r}{about}: -{k!r} / I", bound)
            for i, (k, (phi, bound)) in enumerate(zip(coefficients, shapes, strict=True)) if k != 0.0]


def _gravity_force(model: mujoco.MjModel, data: mujoco.MjData, qadr: int, dof: int, q: float) -> float:
    """MuJoCo's gravity force on the joint at rest at ``q`` (less gravity compensation)."""
    data.qpos[qadr], data.qvel[dof] = q, 0.0
    mujoco.mj_forward(model, data)
    return float(data.qfrc_gravcomp[dof] - data.qfrc_bias[dof])


def _gravity(model: mujoco.MjModel, jid: int, inertia: float, kind: str) -> list[ModelTerm]:
    """Gravity: A cos(x1 - q0) + B sin(x1 - q0) on a hinge (q0 its reference angle), a constant on
    a slide, each read from MuJoCo's own force at q0 and a quarter turn past it."""
    if not _flag(model, _DISABLE.mjDSBL_GRAVITY):
        return []
    qadr, dof = int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid])
    q0 = float(model.qpos0[qadr])
    data = mujoco.MjData(model)
    at_ref = _gravity_force(model, data, qadr, dof, q0)
    if kind == "slide":
        return [ModelTerm("1", at_ref / inertia, f"gravity: MuJoCo's force {at_ref!r} along the slide, / I",
                          "1")] if at_ref else []
    quarter = _gravity_force(model, data, qadr, dof, q0 + math.pi / 2)
    angle = "x1" if q0 == 0.0 else f"x1 - {q0!r}" if q0 > 0 else f"x1 + {-q0!r}"
    pairs = ((f"cos({angle})", at_ref, "at the reference angle"), (f"sin({angle})", quarter,
                                                                    "a quarter turn past it"))
    return [ModelTerm(phi, force / inertia, f"gravity: MuJoCo's force {force!r} {what}, / I", "1")
            for phi, force, what in pairs if force != 0.0]


def _sensors(model: mujoco.MjModel, jid: int) -> tuple[str | None, str | None]:
    """The names of the (first named) jointpos and jointvel sensors on the joint."""
    found: dict[int, str] = {}
    for s in range(model.nsensor):
        name = _name(model, mujoco.mjtObj.mjOBJ_SENSOR, s)
        if int(model.sensor_objid[s]) == jid and name:
            found.setdefault(int(model.sensor_type[s]), name)
    return found.get(int(mujoco.mjtSensor.mjSENS_JOINTPOS)), found.get(int(mujoco.mjtSensor.mjSENS_JOINTVEL))


def _activation_sensor(model: mujoco.MjModel, aid: int) -> str | None:
    """The name of the (first named) actuatorfrc sensor on actuator ``aid``: the reading of x3."""
    kind = int(mujoco.mjtSensor.mjSENS_ACTUATORFRC)
    named = (_name(model, mujoco.mjtObj.mjOBJ_SENSOR, s) for s in range(model.nsensor)
             if int(model.sensor_type[s]) == kind and int(model.sensor_objid[s]) == aid)
    return next((name for name in named if name), None)


def _outside(model: mujoco.MjModel, jid: int, aid: int, kind: str) -> list[Outside]:
    """What the model does besides the smooth terms, and what a scenario does about it."""
    position, force, _ = UNITS[kind]
    dof = int(model.jnt_dofadr[jid])
    found = []
    friction = float(model.dof_frictionloss[dof])
    if friction > 0 and _flag(model, _DISABLE.mjDSBL_FRICTIONLOSS):
        found.append(Outside(f"dry friction: frictionloss {friction!r} {force}", "the scenario states it as "
                             "the realism option frictionloss (MuJoCo runs with it, the ODE twin without)",
                             ("frictionloss", friction)))
    if model.jnt_limited[jid] and _flag(model, _DISABLE.mjDSBL_LIMIT):
        low, high = (float(v) for v in model.jnt_range[jid])
        found.append(Outside(f"joint limits [{low!r}, {high!r}] {position}", "remove range (or write "
                             "limited=\"false\") on the joint: eq. (1) has no limits"))
    if model.actuator_ctrllimited[aid] and _flag(model, _DISABLE.mjDSBL_CLAMPCTRL):
        low, high = (float(v) for v in model.actuator_ctrlrange[aid])
        found.append(Outside(f"command limits ctrlrange [{low!r}, {high!r}]",
                             "the scenario states it as the realism option torque_limit" if low == -high else
                             "make ctrlrange symmetric (qcontrol's torque_limit is +-limit) or remove it",
                             ("torque_limit", high) if low == -high else None))
    if model.actuator_forcelimited[aid] or model.jnt_actfrclimited[jid]:
        found.append(Outside("a clamped actuator force (forcerange or actuatorfrcrange)", "remove it; a "
                             "symmetric ctrlrange is stated as the realism option torque_limit"))
    if model.opt.density > 0 or model.opt.viscosity > 0:
        found.append(Outside(f"fluid forces (density {model.opt.density!r}, viscosity "
                             f"{model.opt.viscosity!r})", "set density and viscosity to 0 in <option>: their "
                             "drag depends on the geoms' shapes"))
    if model.ntendon and (np.any(model.tendon_stiffness) or np.any(model.tendon_damping)
                          or np.any(model.tendon_frictionloss)):
        found.append(Outside("tendon springs, dampers or friction", "remove them, or move them to the joint "
                             "(stiffness, damping)"))
    if model.neq and _flag(model, _DISABLE.mjDSBL_EQUALITY):
        found.append(Outside("equality constraints", "remove the <equality> elements"))
    if model.actuator_actlimited[aid]:
        low, high = (float(v) for v in model.actuator_actrange[aid])
        found.append(Outside(f"an activation range actrange [{low!r}, {high!r}]", "remove actlimited and "
                             "actrange: the filter's equation has no clamp"))
    if model.jnt_plasticadr[jid] >= 0:
        found.append(Outside("a plastic spring (springyield)", "remove springyield"))
    return found


def _check(model: mujoco.MjModel, jid: int, aid: int, eq: ModelEquation) -> tuple[float, bool]:
    """The largest relative difference between MuJoCo's acceleration (constraints off) and ``eq``
    at the consistency check's sampled states and commands, and whether geoms touch at any."""
    x, u, _ = sampled_states()
    ctrl = u / eq.input_gain  # commands of the same accelerations as the check's
    check = _unconstrained(model)
    data = mujoco.MjData(check)
    data_contacts = mujoco.MjData(model)
    qadr, dof = int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid])
    qacc, contacts = np.empty(len(u)), False
    for i in range(len(u)):
        for d in (data, data_contacts):
            d.qpos[qadr], d.qvel[dof] = x[i]
            d.ctrl[aid] = ctrl[i]
        mujoco.mj_forward(check, data)
        qacc[i] = data.qacc[dof]
        if not contacts and _flag(model, _DISABLE.mjDSBL_CONTACT):
            mujoco.mj_kinematics(model, data_contacts)
            mujoco.mj_collision(model, data_contacts)
            contacts = data_contacts.ncon > 0
    parts = [eq.input_gain * ctrl] + [t.theta * compile_expression(t.phi, ("x1", "x2"))(x) for t in eq.terms]
    scale = 1.0 + sum(np.abs(p) for p in parts)
    return float(np.max(np.abs(qacc - sum(parts)) / scale)), contacts


def _check_filter(model: mujoco.MjModel, jid: int, aid: int, eq: ModelEquation) -> tuple[float, bool]:
    """:func:`_check` through a filter actuator (order 3): at sampled states (x1, x2, x3) and
    commands, MuJoCo's ``qacc`` against ``x3 + theta^T phi(x1, x2)`` and its ``act_dot`` (times
    gear / I) against ``b u - x3 / tau``; the largest relative difference of either."""
    x, u, _ = sampled_states(order=3)
    per_act = eq.gear / eq.inertia  # x3 = (gear / I) act
    check = _unconstrained(model)
    data = mujoco.MjData(check)
    qadr, dof, adr = int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid]), int(model.actuator_actadr[aid])
    rates = np.empty((len(u), 2))
    for i in range(len(u)):
        data.qpos[qadr], data.qvel[dof], data.act[adr] = x[i, 0], x[i, 1], x[i, 2] / per_act
        data.ctrl[aid] = u[i]
        mujoco.mj_forward(check, data)
        rates[i] = data.qacc[dof], per_act * data.act_dot[adr]
    worst = 0.0
    for column, first, terms in ((0, x[:, 2], eq.terms), (1, eq.input_gain * u, eq.filter_terms)):
        parts = [first] + [t.theta * compile_expression(t.phi, ("x1", "x2", "x3"))(x) for t in terms]
        scale = 1.0 + sum(np.abs(p) for p in parts)
        worst = max(worst, float(np.max(np.abs(rates[:, column] - sum(parts)) / scale)))
    contacts = _check(model, jid, aid, replace(eq, tau=None))[1]
    return worst, contacts


def _unconstrained(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` with constraints (limits, friction, contacts) and the command clamp off."""
    import copy

    check = copy.copy(model)
    for bit in (_DISABLE.mjDSBL_CONSTRAINT, _DISABLE.mjDSBL_CLAMPCTRL):
        check.opt.disableflags |= int(bit)
    check.actuator_forcelimited[:] = 0
    check.jnt_actfrclimited[:] = 0
    return check


def compiled_equation(compiled: CompiledModel, label: str) -> ModelEquation:
    """The equation of the joint and actuator a scenario names in ``compiled`` (its model as
    compiled for the scenario: overrides applied)."""
    with kept_aside():
        return equation_of(compiled.model, compiled.ids.joint, compiled.ids.actuator, label)


def matches(eq: ModelEquation, expressions: Sequence[Expression],
            order: int = 2) -> list[tuple[int, float] | None]:
    """For each expression over x1, x2 (x1 .. x3 for ``order`` 3), the model term it is a constant
    multiple of, as ``(j, k)`` with ``expression = k * eq.terms[j].phi`` at the sampled states (k =
    1 exactly for the same values), or None."""
    x, _, _ = sampled_states(order=order)
    with np.errstate(all="ignore"):
        model = [compile_expression(t.phi, ("x1", "x2", "x3")[:order])(x) for t in eq.terms]
        found: list[tuple[int, float] | None] = []
        for e in expressions:
            if timed(e):  # MuJoCo's physics makes no term in t
                found.append(None)
                continue
            values = np.broadcast_to(e(x), (len(x),))
            hits = ((j, k) for j, p in enumerate(model) if (k := _multiple(values, p)) is not None)
            found.append(next(hits, None))
    return found


def _multiple(values: np.ndarray, p: np.ndarray) -> float | None:
    """k with ``values = k p`` at every sample (to 1e-12 relative), or None."""
    if np.array_equal(values, p):
        return 1.0
    big = np.abs(p) > 1e-3 * np.max(np.abs(p))
    if not np.all(np.isfinite(values)) or not np.any(big):
        return None
    k = float(np.median(values[big] / p[big]))
    close = np.abs(values - k * p) <= 1e-12 * (np.abs(values) + np.abs(k * p) + 1e-300)
    return k if k != 0.0 and np.all(close | (np.abs(values - k * p) < 1e-14)) else None
