"""Does the MJCF describe the scenario's plant? MuJoCo's acceleration against eq. (1).

At sampled states and inputs, ``qacc`` must equal ``u + psi + theta^T phi`` to
:data:`TOLERANCE` (relative to the size of the terms). The residual is regressed on the terms (and
on ``u`` and a constant) to say which term disagrees and by how much. With a realism option on
(friction, armature, noise, ...) the mismatch is expected: it is reported, not refused.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from ...errors import QcontrolInputError
from ..base import PlantTerms, timed
from .callbacks import GeneralizedForce, passive_forces
from .mjcf import CompiledModel
from .options import MujocoOptions

SAMPLES = 300
TOLERANCE = 1e-9
SEED = 3160  # the paper's article number; any fixed seed works


def consistency_report(compiled: CompiledModel, options: MujocoOptions, terms: PlantTerms,
                       native: tuple[bool, ...], force: GeneralizedForce | None) -> dict[str, Any]:
    """Compare MuJoCo's qacc with eq. (1) at :data:`SAMPLES` states; refuse a mismatch
    (:class:`QcontrolInputError` naming the term) unless a realism option is on."""
    rng = np.random.default_rng(SEED)
    x = np.column_stack([rng.uniform(-math.pi, math.pi, SAMPLES), rng.uniform(-4.0, 4.0, SAMPLES)])
    u = rng.uniform(-20.0, 20.0, SAMPLES)
    t = rng.uniform(0.0, 10.0, SAMPLES) if terms.timed else None  # terms in t: at sampled times too
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
        raise _refusal(report, contribution, terms, options)
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


def _refusal(report: dict, contribution: dict[str, float], terms: PlantTerms,
             options: MujocoOptions) -> QcontrolInputError:
    exprs = terms.expressions
    labels = {nm: f"{nm} = {e.source}" for nm, e in zip(terms.names, exprs, strict=True)} | {
        "u": "the input gain (u)", "constant": "a constant offset"}
    worst = max(contribution, key=contribution.__getitem__)
    unexplained, mismatch = report["unexplained_by_terms"], report["terms"][worst]
    if contribution[worst] >= unexplained:
        blame = (f"the mismatch follows {labels[worst]}: MuJoCo's coefficient is {mismatch['mujoco']:.6g}, "
                 f"the scenario's {mismatch['scenario']:.6g} (up to {contribution[worst]:.3g})")
    else:
        blame = (f"the mismatch (up to {unexplained:.3g}) is not a multiple of any term; "
                 f"largest term-wise part {labels[worst]} (up to {contribution[worst]:.3g})")
    return QcontrolInputError(
        f"{options.where}: MuJoCo's acceleration differs from x2' = u + psi + theta^T phi by up to "
        f"{report['max_abs_mismatch']:.3g} at {SAMPLES} sampled states; {blame}; make the MJCF "
        "(model, parameters, native_terms) and [plant] (psi, phi, theta) describe the same plant"
    )
