"""Scenario -> the parts of a closed loop (quantizer, reference, controller, plant) -> a run."""

from __future__ import annotations

from .controller import BaselineController, Controller, ProposedController, lemma2_bounds
from .plants.base import Plant
from .plants.ode import ChainPlant
from .quantizer import UniformQuantizer
from .reference import Constant, Reference, Sine, SumOfSines
from .scenario import Scenario
from .sim import Observer, ProgressCallback, RunMetrics, Trajectory, simulate


def build_quantizer(sc: Scenario) -> UniformQuantizer:
    """The uniform quantizer of eq. (3) with the scenario's step delta."""
    return UniformQuantizer(sc.controller.delta)


def build_reference(sc: Scenario) -> Reference:
    """The reference y_d with its derivatives (Assumption 3)."""
    ref = sc.reference
    if ref.kind == "constant":
        return Constant(ref.value)
    if ref.kind == "sine":
        return Sine(ref.amplitude, ref.frequency, ref.phase, ref.offset)
    return SumOfSines(tuple(Sine(a, w, p) for a, w, p in ref.terms), ref.offset)


def controller_L(sc: Scenario) -> float:
    """Lemma 2's ``L = L_zn`` for the scenario's gains and quantizer."""
    return float(lemma2_bounds(sc.controller.c, sc.controller.delta / 2.0)[0][-1])


def controller_kappa(sc: Scenario) -> float:
    """``kappa`` as given, or ``L + kappa_margin`` (the paper writes kappa = 1.1 + L)."""
    cfg = sc.controller
    if cfg.kappa is not None:
        return cfg.kappa
    assert cfg.kappa_margin is not None
    return controller_L(sc) + cfg.kappa_margin


def build_controller(sc: Scenario) -> Controller:
    """The proposed law (44)-(45), or the baseline (46) of reference [20]."""
    cfg = sc.controller
    max_error = build_quantizer(sc).max_error
    if cfg.kind == "baseline":
        return BaselineController(
            cfg.c,
            max_error,
            sc.psi_expr,
            sc.phi_expr,
            adaptation_gain=cfg.baseline_gain,
            known_theta=sc.theta if cfg.baseline_theta == "known" else None,
        )
    return ProposedController(
        cfg.c,
        max_error,
        kappa=controller_kappa(sc),
        gamma=cfg.gamma,
        sigma=cfg.sigma,
        r=sc.r_expr,
        r_scale=cfg.r_scale,
        expected_terms=sc.uncertain_terms,
    )


def controller_constants(sc: Scenario) -> dict:
    """The controller's constants as a recording shows them: delta, c, L, L_z, and kappa, gamma,
    sigma, r_scale (proposed law) or the adaptation gain (baseline)."""
    controller = build_controller(sc)
    constants: dict = {"delta": sc.controller.delta, "c": list(sc.controller.c), "L": controller.L,
                       "L_z": list(controller.L_z)}
    if sc.controller.kind == "proposed":
        constants.update(kappa=controller.kappa, gamma=controller.gamma, sigma=controller.sigma,
                         r_scale=controller.r_scale)
    else:
        constants.update(baseline_gain=sc.controller.baseline_gain)
    return constants


def build_plant(sc: Scenario, backend: str | None = None, batch: int = 1) -> Plant:
    """The ODE chain of eq. (1), or the MuJoCo model of ``[plant.mujoco]``."""
    backend = backend or sc.simulation.backend
    if backend == "mujoco":
        from .plants.mujoco import MujocoPlant

        return MujocoPlant(
            sc.mujoco, sc.order, sc.psi_expr, sc.phi_expr, sc.theta, batch=batch,
            timestep=sc.simulation.dt,
        )
    return ChainPlant(sc.order, sc.psi_expr, sc.phi_expr, sc.theta, batch=batch)


def run_scenario(
    sc: Scenario,
    backend: str | None = None,
    progress: ProgressCallback | None = None,
    observer: Observer | None = None,
    plant: Plant | None = None,
    record: str = "full",
) -> Trajectory | RunMetrics:
    """One closed-loop run of the scenario on the chosen backend (``record`` as in
    :func:`~qcontrol.sim.simulate`: ``"metrics"`` keeps memory bounded on long runs)."""
    controller = build_controller(sc)
    plant = plant if plant is not None else build_plant(sc, backend)
    return simulate(
        plant,
        controller,
        build_quantizer(sc),
        build_reference(sc),
        sc.x0,
        sc.simulation.duration,
        sc.simulation.dt,
        control_period=sc.simulation.control_period,
        state_bound=sc.simulation.state_bound,
        progress=progress,
        observer=observer,
        record=record,
    )[0]
