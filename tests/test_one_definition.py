"""Every formula is written once and every faster form is derived from it: a formula changed in
its one place (monkeypatched here) changes the result of every form that runs it, the Python loop
of a single run (float form), a batch (array form), the compiled loop and the compiled batch
(generated from the same code), and the compiled forms still give the Python loop's numbers to the
last bit."""

import math

import mujoco
import numpy as np
import pytest
from conftest import SCENARIOS

import qcontrol.engine.compiled_loop as compiled_loop
import qcontrol.engine.velocity as velocity
import qcontrol.plants.ode as ode
import qcontrol.quantizers as quantizers
from qcontrol.assembly import (
    assemble,
    build_controller,
    build_plant,
    build_separation,
    run_spec,
    run_variants,
)
from qcontrol.controller.backstepping import Backstepping
from qcontrol.controller.comparison import ComparisonLaw, RateAdvance
from qcontrol.controller.proposed import DecayAdvance, PaperLaw
from qcontrol.engine import ClosedLoop
from qcontrol.plants.mujoco import native_step
from qcontrol.plants.mujoco.noise import SensorNoise
from qcontrol.quantizer import UniformQuantizer
from qcontrol.scenario import load_scenario

# the names the MuJoCo step below calls, as native_step defines them (and as the compiled loop's
# module defines them: MuJoCo's C functions by symbol)
mj_step, mj_sensorPos, mj_sensorVel = mujoco.mj_step, mujoco.mj_sensorPos, mujoco.mj_sensorVel  # noqa: N816
UNSTABLE = native_step.UNSTABLE
RK4 = ode._rk4


def half_torque_step(m, d, ctrl, actuator, ctrl_per_u, u, substeps, warning, sensed):  # noqa: ANN001, ANN201
    """:func:`native_step.step_copy` with the motor's command halved."""
    ctrl[actuator] = 0.5 * ctrl_per_u * u
    calm = 0
    for i in UNSTABLE:
        if warning[i] == 0:
            calm += 1 << i
    for _ in range(substeps):
        mj_step(m, d)
    if sensed:
        mj_sensorPos(m, d)
        mj_sensorVel(m, d)
    for i in UNSTABLE:
        if (calm >> i) & 1 and warning[i] != 0:
            return True
    return False


def offset_reading(qpos, qvel, sensordata, qadr, dof, p, v, dead, sensed):  # noqa: ANN001, ANN201
    """:func:`native_step.read_copy` with the angle read 0.02 rad high."""
    if dead:
        return math.nan, math.nan, math.nan, math.nan
    x1 = qpos[qadr]
    x2 = qvel[dof]
    return x1, x2, x1 + 0.02, x2


def _wrapped(owner, name: str, change):  # noqa: ANN001, ANN202
    original = getattr(owner, name)

    def changed(*args):  # noqa: ANN002, ANN202
        return change(original(*args))
    return changed


def _quantizer(self, x, floor):  # noqa: ANN001, ANN202
    return self.delta * floor(x / self.delta + 0.25)  # levels shifted by delta / 4


def _half_range(q, low, high, minimum=np.minimum, maximum=np.maximum):  # noqa: ANN001, ANN202
    return minimum(maximum(q, 0.5 * low), 0.5 * high)  # readings held in half the range


# (what is changed, in its one place) -> (object, attribute, replacement, scenario overrides, backend)
CHANGES = {
    "quantizer (3)": (UniformQuantizer, "apply", _quantizer, [], "ode"),
    "quantizer's range": (quantizers, "within_range", _half_range,
                          ["quantizer.delta=[0.01, 0.01]", "quantizer.range=[0.2, 20.0]"], "ode"),  # x1 ~ 0.3
    "law (44), paper hold": (PaperLaw, "robust_term", _wrapped(PaperLaw, "robust_term", lambda v: 2.0 * v),
                             [], "ode"),
    "law (44), exact hold": (PaperLaw, "robust_term", _wrapped(PaperLaw, "robust_term", lambda v: 2.0 * v),
                             ['controller.hold="exact"'], "ode"),
    "adaptive law (45)": (DecayAdvance, "advance",
                          _wrapped(DecayAdvance, "advance", lambda eps: tuple(e + 1e-3 for e in eps)), [],
                          "ode"),
    "law (46)": (ComparisonLaw, "control",
                 _wrapped(ComparisonLaw, "control", lambda out: out._replace(u=out.u - 1.0)),
                 ['controller.kind="comparison"'], "ode"),
    "adaptive law of (46)": (RateAdvance, "advance",
                             _wrapped(RateAdvance, "advance", lambda th: tuple(e - 1e-3 for e in th)),
                             ['controller.kind="comparison"'], "ode"),
    "recursion (31)-(34)": (Backstepping, "recursion",
                            _wrapped(Backstepping, "recursion", lambda za: (za[0], [a * 1.5 for a in za[1]])),
                            [], "ode"),
    "RK4 of eq. (1)": (ode, "_rk4", lambda x, u, h, g, *rest: RK4(x, u, 0.5 * h, g, *rest), [], "ode"),  # h/2
    "MuJoCo step": (native_step, "step_copy", half_torque_step, [], "mujoco"),
    "MuJoCo observe": (native_step, "read_copy", offset_reading, [], "mujoco"),
    "MuJoCo sensor noise": (SensorNoise, "ahead", _wrapped(SensorNoise, "ahead", lambda noise: 3.0 * noise),
                            ["plant.mujoco.sensor_noise=[0.001, 0.05]", "plant.mujoco.noise_seed=7"],
                            "mujoco"),
    "differenced velocity": (velocity, "differenced", lambda p, past, period: 0.5 * (p - past) / period,
                             ['simulation.velocity_source="difference"', "simulation.control_period=0.002"],
                             "mujoco"),
}


# the changes that also run through the compiled batch of ODE copies (the quantizer, the law and
# the plant's step)
COMPILED_BATCH = ("quantizer (3)", "law (44), paper hold", "RK4 of eq. (1)")


def _single(sc, backend: str):
    spec = run_spec(sc, build_plant(sc, backend), build_controller(sc), [sc.x0], build_separation(sc))
    loop = ClosedLoop(spec)
    return loop, loop.run()[0]


def _python_forms(monkeypatch, sc, backend: str) -> dict:
    """The Python loop of a single run and a batch of two copies (copy 0) in the array form."""
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    python_loop, python = _single(sc, backend)
    batch = run_variants([sc, sc], backend)[0]
    monkeypatch.delenv("QCONTROL_COMPILE")
    assert python_loop.handover == 0  # all of it in Python
    return {"python": python, "batch": batch}


def _compiled_forms(sc, backend: str, compiled_batch: bool) -> dict:
    """The compiled loop and, with ``compiled_batch``, the compiled batch of two copies (copy 0)."""
    compiled_run, compiled = _single(sc, backend)
    assert compiled_run.handover is None  # it ran compiled to the end
    runs = {"compiled": compiled}
    if compiled_batch:
        loop = ClosedLoop(assemble([sc, sc], backend).spec)
        runs["compiled batch"] = loop.run()[0]
        assert loop.handover is None
    return runs


def _bytes(record, name: str) -> bytes:
    return np.asarray(record.signals[name]).tobytes()


def _scenario(overrides: list[str]):
    quantizer_table = any(o.startswith("quantizer.") for o in overrides)  # (the step given there)
    return load_scenario(SCENARIOS / "example2.toml", ["simulation.duration=0.3", *overrides],
                         unset=["controller.delta"] if quantizer_table else [])


def _changed(forms_before: dict, forms_after: dict, python_after) -> None:  # noqa: ANN001
    """Each form's u changed, and each form gives the Python loop's numbers after the change."""
    for form in forms_after:
        assert _bytes(forms_after[form], "u") != _bytes(forms_before[form], "u"), form  # it reached the form
        for signal in ("x", "x_q", "u", "adaptive"):
            assert _bytes(forms_after[form], signal) == _bytes(python_after, signal), (form, signal)


@pytest.mark.parametrize("change", list(CHANGES))
def test_a_formula_changed_in_its_one_place_changes_every_form(monkeypatch, change: str) -> None:
    """The Python loop and the array form, one change at a time (the compiled forms: below)."""
    owner, name, replacement, overrides, backend = CHANGES[change]
    sc = _scenario(overrides)
    before = _python_forms(monkeypatch, sc, backend)
    monkeypatch.setattr(owner, name, replacement)
    after = _python_forms(monkeypatch, sc, backend)
    _changed(before, after, after["python"])


# the changes made together where they share a scenario and a backend: one changed module of the
# compiled loop to compile for each group, not one per change (each change alone changes the
# Python loop's numbers, above: a change the compiled form missed leaves it apart from the Python
# loop's); the ODE group also through the compiled batch of copies
GROUPS: dict[tuple, list[str]] = {}
for _name, (*_, _overrides, _backend) in CHANGES.items():
    GROUPS.setdefault((tuple(_overrides), _backend), []).append(_name)


@pytest.mark.parametrize("changes", list(GROUPS.values()), ids=[" + ".join(g) for g in GROUPS.values()])
def test_the_compiled_forms_follow_the_changed_formulas(monkeypatch, changes: list[str]) -> None:
    """The compiled loop and the compiled batch are generated from the same code: the formulas
    changed in their one place change them too, and they still give the Python loop's numbers to
    the last bit."""
    *_, overrides, backend = CHANGES[changes[0]]
    monkeypatch.setattr(compiled_loop, "MIN_ROWS", 0)  # short runs compiled too
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)
    sc = _scenario(overrides)
    batched = any(change in COMPILED_BATCH for change in changes)
    before = _compiled_forms(sc, backend, batched)
    for change in changes:
        owner, name, replacement, *_ = CHANGES[change]
        monkeypatch.setattr(owner, name, replacement)
    python = _python_forms(monkeypatch, sc, backend)["python"]
    _changed(before, _compiled_forms(sc, backend, batched), python)
