"""Does the MJCF describe the scenario's plant? MuJoCo's acceleration against eq. (1).

At sampled states and inputs, ``qacc`` must equal ``u + psi + theta^T phi`` to
:data:`TOLERANCE` (relative to the size of the terms). The residual is regressed on the terms (and
on ``u`` and a constant) to say which term disagrees and by how much. With a realism option on
(friction, armature, noise, ...) the mismatch is expected: it is reported, not refused.
"""

from __future__ import annotations

import copy
from functools import partial
from typing import Any

import mujoco
import numpy as np

from ...errors import QcontrolInputError
from ...expr.rows import is_zero
from ...sharing import kept
from ..base import PlantTerms, timed
from .callbacks import GeneralizedForce, passive_forces
from .equation import SAMPLES, ModelEquation, compiled_equation, matches, sampled_states
from .mjcf import CompiledModel
from .options import MujocoOptions

TOLERANCE = 1e-9


def consistency_report(compiled: CompiledModel, options: MujocoOptions, terms: PlantTerms,
                       native: tuple[bool, ...], force: GeneralizedForce | None) -> dict[str, Any]:
    """Compare MuJoCo's qacc with eq. (1) at :data:`SAMPLES` states; refuse a mismatch
    (:class:`QcontrolInputError` naming the term) unless a realism option is on. A report is a
    function of its arguments alone (the same samples each time): while
    :func:`~qcontrol.sharing.sharing` is on (plants built from variants loaded together: a
    batch's, a study's), one measured for the same compiled model, terms, native terms, force and
    realism options is given again (a copy), so runs that differ in a noise seed or the law
    measure it once."""
    key = ("model check", id(compiled), terms, native, tuple(options.realism),
           None if force is None else tuple(c for c, _ in force.total.fast))
    try:
        hash(key)
    except TypeError:  # (an unhashable part: measured every time)
        return _measured(compiled, options, terms, native, force)
    _, report = kept(key, partial(_with_model, compiled, options, terms, native, force))
    return copy.deepcopy(report)


def _with_model(compiled: CompiledModel, *args: Any) -> tuple[CompiledModel, dict[str, Any]]:
    """The model with its measured report (kept together: while kept, its id names no other model)."""
    return compiled, _measured(compiled, *args)


def _measured(compiled: CompiledModel, options: MujocoOptions, terms: PlantTerms,
              native: tuple[bool, ...], force: GeneralizedForce | None) -> dict[str, Any]:
    """:func:`consistency_report`, measured."""
    x, u, t = sampled_states(terms.timed)  # terms in t: at sampled times too
    columns, coefficient = _columns(terms, x, u, t)
    coefficient["u"] = terms.b  # x2' = b u + psi + theta^T phi
    rhs = sum(coefficient[k] * columns[k] for k in columns)
    scale = 1.0 + sum(np.abs(coefficient[k] * columns[k]) for k in columns)
    residual = _accelerations(compiled, x, compiled.ctrl_per_u(terms) * u, force, t) - rhs
    relative = np.abs(residual) / scale
    names = list(columns) + ["constant"]
    basis = np.column_stack([columns[k] for k in columns] + [np.ones(SAMPLES)])
    fit, *_ = np.linalg.lstsq(basis, residual, rcond=None)
    contribution = {k: float(np.max(np.abs(fit[j] * basis[:, j]))) for j, k in enumerate(names)}
    report = {
        "ok": bool(np.all(relative <= TOLERANCE)), "samples": SAMPLES, "tolerance": TOLERANCE,
        "max_abs_mismatch": float(np.max(np.abs(residual))),
        "max_relative_mismatch": float(np.max(relative)),
        "unexplained_by_terms": float(np.max(np.abs(residual - basis @ fit))),
        "terms": {k: {"scenario": coefficient.get(k, 0.0), "mujoco": coefficient.get(k, 0.0) + float(fit[j]),
                      "max_abs_mismatch": contribution[k]} for j, k in enumerate(names)},
        "realism": list(options.realism), "inertia": compiled.inertia,
    }
    if not (report["ok"] or options.realism):
        raise _refusal(report, contribution, terms, options, compiled, native)
    return report


def _columns(terms: PlantTerms, x: np.ndarray, u: np.ndarray, t: np.ndarray | None = None
             ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Each term's value at the samples (a term in t at the sampled times ``t``), and its
    coefficient (1 for u and psi, theta_i for phi_i)."""
    exprs, coefficients = terms.expressions, terms.coefficients
    xt = x if t is None else np.column_stack([x, t])
    columns = {"u": u} | {name: np.broadcast_to(e(xt if timed(e) else x), u.shape)
                          for name, e in zip(terms.names, exprs, strict=True)}
    return columns, {"u": 1.0} | dict(zip(terms.names, coefficients, strict=True))


def _accelerations(compiled: CompiledModel, x: np.ndarray, ctrl: np.ndarray,
                   force: GeneralizedForce | None, t: np.ndarray | None = None) -> np.ndarray:
    """MuJoCo's ``qacc`` at each sampled state and actuator command (the passive callback installed)."""
    model, ids = compiled.model, compiled.ids
    qacc = np.empty(len(ctrl))
    data = mujoco.MjData(model)
    with passive_forces(model, [data], ids.qpos, ids.dof, None if force is None else [force]):
        for i in range(len(ctrl)):
            data.qpos[ids.qpos], data.qvel[ids.dof] = x[i]
            data.ctrl[ids.actuator] = ctrl[i]
            if t is not None:
                data.time = t[i]
            mujoco.mj_forward(model, data)
            qacc[i] = data.qacc[ids.dof]
    return qacc


def _refusal(report: dict, contribution: dict[str, float], terms: PlantTerms, options: MujocoOptions,
             compiled: CompiledModel, native: tuple[bool, ...]) -> QcontrolInputError:
    """One line: every term whose coefficient differs from what MuJoCo realises, at full precision,
    with its likely cause and the values that fix it (from the model's own equation,
    :mod:`.equation`); the regression's view where the model's terms do not explain it."""
    eq = compiled_equation(compiled, options.model.name)
    found = _diagnoses(eq, terms, native)
    if found is None:
        return _unexplained(report, contribution, terms, options, eq)
    problems, fix = found
    return QcontrolInputError(
        f"{options.where}: MuJoCo's acceleration differs from x2' = b u + psi + theta^T phi by up to "
        f"{report['max_abs_mismatch']:.3g} at {SAMPLES} sampled states: {'; '.join(problems)}; fix: {fix}; "
        f"or leave each native term's theta to the model: \"model\" in its place; {_model_command(options)}")


def _diagnoses(eq: ModelEquation, terms: PlantTerms,
               native: tuple[bool, ...]) -> tuple[list[str], str] | None:
    """Each term's problem (a wrong coefficient, a term counted twice, a native term the model does
    not make, a term of the model the scenario lacks) and the [plant] values that fix them all;
    None when the model's equation does not explain MuJoCo's acceleration itself."""
    if eq.unexplained > TOLERANCE:
        return None
    problems, used, theta, natives = [], set(), [], []
    for name, e, c, made, hit in zip(terms.names, terms.expressions, terms.coefficients, native,
                                     matches(eq, terms.expressions), strict=True):
        model = None if hit is None else eq.terms[hit[0]].theta / hit[1]
        source = "" if hit is None else eq.terms[hit[0]].source
        used |= set() if hit is None else {hit[0]}
        problem = _problem(f"{name} = {e.source}", made, c, model, source, eq)
        problems += [problem] if problem else []
        fixed = model if model is not None and name != "psi" and not _same(model, c) else c
        theta += [] if name == "psi" else [fixed]
        natives += [name] if model is not None and _same(model, fixed) else []
    missing = [t for j, t in enumerate(eq.terms) if j not in used]
    problems += [f"MuJoCo's physics also makes {t.phi} ({t.theta!r}: {t.source}), which the scenario lacks "
                 "(a missing native term)" for t in missing]
    if not problems:
        return None
    phi = [p.source for p in terms.phi] + [t.phi for t in missing]
    natives += [f"phi{len(terms.phi) + k + 1}" for k in range(len(missing))]
    theta += [t.theta for t in missing]
    values = ", ".join(map(repr, theta))
    bounds = (f"; add to the law's r, one per added term: {_toml([t.bound for t in missing])}" if missing
              else "")
    return problems, (f"in [plant] write phi = {_toml(phi)}; write theta = [{values}]; in [plant.mujoco] "
                      f"write native_terms = {_toml(natives)}{bounds}")


def _problem(label: str, made: bool, stated: float, model: float | None, source: str,
             eq: ModelEquation) -> str | None:
    """What is wrong with one term: ``made`` whether the scenario leaves it to MuJoCo, ``model``
    MuJoCo's coefficient of it (None: MuJoCo's physics does not make it)."""
    if made and model is None:
        return (f"{label} is in native_terms but MuJoCo's physics does not make it (a native term the model "
                "lacks: leave it out of native_terms and the passive callback adds it)")
    if made and not _same(model, stated):
        return f"{label}: MuJoCo's coefficient is {model!r} ({source}), the scenario's {stated!r}" + _scaled(
            stated, model, eq)
    if not made and model is not None:
        return (f"{label} is counted twice: MuJoCo makes it ({model!r}: {source}) and the passive callback "
                f"adds the scenario's {stated!r} again")
    return None


def _same(model: float, stated: float) -> bool:
    """Whether a stated coefficient is MuJoCo's to the check's relative :data:`TOLERANCE`."""
    return abs(model - stated) <= TOLERANCE * max(abs(model), abs(stated), 1.0)


def _toml(items: list[str]) -> str:
    return "[" + ", ".join(f'"{i}"' for i in items) + "]"


def _scaled(stated: float, model: float, eq: ModelEquation) -> str:
    """The likely cause when the scenario's coefficient is MuJoCo's force, not divided by I."""
    if abs(eq.inertia - 1.0) > 1e-6 and _same(model * eq.inertia, stated):
        return (f" (the force's coefficient, not divided by the inertia I = {eq.inertia!r}: the input gain "
                f"is {eq.input_gain!r}, not 1)")
    return ""


def _unexplained(report: dict, contribution: dict[str, float], terms: PlantTerms, options: MujocoOptions,
                 eq: ModelEquation) -> QcontrolInputError:
    """The regression's view: the term the mismatch follows, or that it follows none."""
    labels = {nm: f"{nm} = {e.source}" for nm, e in zip(terms.names, terms.expressions, strict=True)} | {
        "u": "the input gain (u)", "constant": "a constant offset"}
    worst = max(contribution, key=contribution.__getitem__)
    unexplained, mismatch = report["unexplained_by_terms"], report["terms"][worst]
    if contribution[worst] >= unexplained:
        blame = (f"the mismatch follows {labels[worst]}: MuJoCo's coefficient is {mismatch['mujoco']!r}, "
                 f"the scenario's {mismatch['scenario']!r} (up to {contribution[worst]:.3g})")
    else:
        blame = (f"the mismatch (up to {unexplained:.3g}) is not a multiple of any term; "
                 f"largest term-wise part {labels[worst]} (up to {contribution[worst]:.3g})")
    outside = "; ".join(f"{o.what} ({o.fix})" for o in eq.outside)
    return QcontrolInputError(
        f"{options.where}: MuJoCo's acceleration differs from x2' = b u + psi + theta^T phi by up to "
        f"{report['max_abs_mismatch']:.3g} at {SAMPLES} sampled states; {blame}"
        + (f"; the model has physics outside eq. (1): {outside}" if outside else "")
        + "; make the MJCF (model, parameters, native_terms) and [plant] (psi, phi, theta) describe the same "
        f"plant ({_model_command(options)})"
    )


def _model_command(options: MujocoOptions) -> str:
    """Where the model's own equation is printed."""
    overridden = " (before the scenario's parameters)" if options.parameters else ""
    return f"qcontrol model {options.model} prints the model's equation{overridden}"


def filter_consistency_report(compiled: CompiledModel, options: MujocoOptions,
                              terms: PlantTerms) -> dict[str, Any]:
    """:func:`consistency_report` for order 3 (a joint driven through a filter actuator, every term
    MuJoCo's own): at sampled states (x1, x2, x3) and inputs, MuJoCo's ``qacc`` against ``x3 +
    theta^T phi_2(x)`` and its ``act_dot`` (times gear / I) against ``b u + theta^T phi_3(x)``;
    each term's coefficient as MuJoCo realises it fitted per equation. A mismatch is refused in
    one line naming the equation and the term, unless a realism option is on."""
    x, u, _ = sampled_states(order=3)
    model, ids = compiled.model, compiled.ids
    data = mujoco.MjData(model)
    rates = np.empty((SAMPLES, 2))
    for i in range(SAMPLES):
        data.qpos[ids.qpos], data.qvel[ids.dof] = x[i, 0], x[i, 1]
        data.act[ids.act] = x[i, 2] / compiled.x3_per_act
        data.ctrl[ids.actuator] = compiled.ctrl_per_u(terms) * u[i]
        mujoco.mj_forward(model, data)
        rates[i] = data.qacc[ids.dof], compiled.x3_per_act * data.act_dot[ids.act]
    rows = terms.regressor_rows
    report: dict[str, Any] = {"ok": True, "samples": SAMPLES, "tolerance": TOLERANCE, "max_abs_mismatch": 0.0,
                              "max_relative_mismatch": 0.0, "terms": {}, "realism": list(options.realism),
                              "inertia": compiled.inertia}
    problems = []
    for row, known, name in ((1, x[:, 2], "x3"), (2, terms.b * u, "u")):
        columns = {name: known / (1.0 if name == "x3" else terms.b)} | {
            f"{n}": np.broadcast_to(e(x), (SAMPLES,)) for n, e in zip(terms.names, rows[row], strict=True)
            if not is_zero(e)}
        coefficient = {name: 1.0 if name == "x3" else terms.b} | {
            n: c for n, c in zip(terms.names, terms.theta, strict=True) if n in columns}
        residual = rates[:, row - 1] - sum(coefficient[k] * columns[k] for k in columns)
        scale = 1.0 + sum(np.abs(coefficient[k] * columns[k]) for k in columns)
        fit, *_ = np.linalg.lstsq(np.column_stack(list(columns.values())), residual, rcond=None)
        label = f"x{row + 1}'"
        for j, k in enumerate(columns):
            mujoco_value = coefficient[k] + float(fit[j])
            report["terms"][f"{label} {k}"] = {"scenario": coefficient[k], "mujoco": mujoco_value}
            if not _same(mujoco_value, coefficient[k]):
                problems.append(f"in {label}, {k}: MuJoCo's coefficient is {mujoco_value!r}, the scenario's "
                                f"{coefficient[k]!r}")
        relative = float(np.max(np.abs(residual) / scale))
        report["max_abs_mismatch"] = max(report["max_abs_mismatch"], float(np.max(np.abs(residual))))
        report["max_relative_mismatch"] = max(report["max_relative_mismatch"], relative)
        report["ok"] = report["ok"] and relative <= TOLERANCE
    if not (report["ok"] or options.realism):
        found = "; ".join(problems) or "the mismatch is not a multiple of any term"
        raise QcontrolInputError(
            f"{options.where}: MuJoCo's rates differ from x2' = x3 + theta^T phi_2, x3' = b u + theta^T "
            f"phi_3 by up to {report['max_abs_mismatch']:.3g} at {SAMPLES} sampled states: {found}; "
            f"{_model_command(options)}")
    return report
