"""The arm driven through a first-order actuator (models/arm3.xml, scenarios/arm3.toml): a
strict-feedback plant of order 3 that MuJoCo's own physics makes, its activation the third state."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import MODELS, SCENARIOS

import qcontrol
from qcontrol.cli import main
from qcontrol.plants.mujoco.equation import model_equation

ARM3 = MODELS / "arm3.xml"


def _mjcf_numbers() -> dict[str, float]:
    """The arm's numbers read from the MJCF text itself, without MuJoCo."""
    root = ET.parse(ARM3).getroot()
    inertial = root.find(".//body[@name='arm']/inertial")
    motor = root.find(".//actuator/general")
    return {"mass": float(inertial.get("mass")), "l": -float(inertial.get("pos").split()[2]),
            "iyy": float(inertial.get("diaginertia").split()[1]),
            "damping": float(root.find(".//joint[@name='hinge']").get("damping")),
            "g": -float(root.find("option").get("gravity").split()[2]), "tau": float(motor.get("dynprm")),
            "gear": float(motor.get("gear")), "gain": float(motor.get("gainprm"))}


def test_the_model_command_prints_the_coefficients_of_the_mjcf_numbers(
        capsys: pytest.CaptureFixture[str]) -> None:
    """I = M l^2 + I_yy, b = gear gain / (I tau), theta = [-d / I, -M g l / I, -1 / tau], as printed
    (full precision) against the same formulas of the MJCF's numbers."""
    n = _mjcf_numbers()
    inertia = n["mass"] * n["l"] ** 2 + n["iyy"]
    expected = {"x2": -n["damping"] / inertia, "sin(x1)": -n["mass"] * n["g"] * n["l"] / inertia,
                "x3": -1.0 / n["tau"]}
    assert main(["model", str(ARM3)]) == 0
    out = capsys.readouterr().out
    printed = dict(re.findall(r"phi\d = (\S+)\s+theta\d = (\S+)", out))
    assert set(printed) == set(expected)
    for phi, value in expected.items():
        assert float(printed[phi]) == pytest.approx(value, rel=1e-13)
    assert float(re.search(r"I = (\S+)", out).group(1)) == pytest.approx(inertia, rel=1e-15)
    assert float(re.search(r"tau = (\S+) s", out).group(1)) == n["tau"]
    b = float(re.search(r"b = gear / \(I tau\) = (\S+)", out).group(1))
    assert b == pytest.approx(n["gear"] * n["gain"] / (inertia * n["tau"]), rel=1e-15)
    assert "[x2']" in out and "[x3']" in out


def test_the_order_3_equation_is_mujocos_own_derivative_at_sampled_states() -> None:
    """At random (qpos, qvel, act, ctrl): mj_forward's qacc is x3 + theta^T phi_2 and its act_dot
    times gear / I is b ctrl + theta^T phi_3, with x3 = (gear / I) act, from the printed equation."""
    eq = model_equation(ARM3)
    theta = {t.phi: t.theta for t in eq.all_terms}
    model = mujoco.MjModel.from_xml_path(str(ARM3))
    data = mujoco.MjData(model)
    per_act = eq.gear / eq.inertia
    rng = np.random.default_rng(7)
    for q, v, act, ctrl in rng.uniform([-3, -5, -30, -30], [3, 5, 30, 30], (20, 4)):
        data.qpos[0], data.qvel[0], data.act[0], data.ctrl[0] = q, v, act, ctrl
        mujoco.mj_forward(model, data)
        x3 = per_act * act
        assert data.qacc[0] == pytest.approx(x3 + theta["x2"] * v + theta["sin(x1)"] * math.sin(q),
                                             rel=1e-12, abs=1e-12)
        assert per_act * data.act_dot[0] == pytest.approx(eq.input_gain * ctrl + theta["x3"] * x3,
                                                          rel=1e-12, abs=1e-12)


def test_the_shipped_arm3_runs_alike_on_mujoco_and_its_ode_twin() -> None:
    """The shipped scenario (its round coefficients, MuJoCo's to 1e-13): MuJoCo's run with the
    activation read through the quantized actuatorfrc sensor, and the ODE's RK4, agree to 1e-10
    over 0.5 s, the same quantized readings and inputs; x3 is the scaled activation."""
    sc = qcontrol.load_scenario(SCENARIOS / "arm3.toml", {"simulation.duration": 0.5})
    cmp = qcontrol.compare(sc)
    assert cmp.mujoco.x.shape[1] == 3
    assert np.max(np.abs(cmp.mujoco.x - cmp.ode.x)) < 1e-10
    assert np.max(np.abs(cmp.mujoco.u - cmp.ode.u)) < 1e-10
    assert np.array_equal(cmp.mujoco.x_q, cmp.ode.x_q)
    assert np.max(np.abs(cmp.mujoco.x_q - cmp.mujoco.x)) <= 0.005 + 1e-12  # every reading quantized
    assert cmp.mujoco.x[0, 2] == 0.0 and np.max(np.abs(cmp.mujoco.x[:, 2])) > 1.0


@pytest.mark.parametrize("dyntype, says", [("integrator", "activation dynamics (integrator)"),
                                           ("filterexact", "write dyntype=\"filter\"")])
def test_a_filter_actuator_of_another_kind_is_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], dyntype: str, says: str) -> None:
    path = tmp_path / "other.xml"
    path.write_text(ARM3.read_text().replace('dyntype="filter"', f'dyntype="{dyntype}"'))
    assert main(["model", str(path), "--scenario", str(tmp_path / "out.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err and "Traceback" not in err
    assert not (tmp_path / "out.toml").exists()


def test_the_model_command_writes_a_runnable_order_3_scenario(tmp_path: Path) -> None:
    """--scenario on the filter actuator: checked on both backends before it is written; the
    plant of order 3 with the model's exact coefficients and the tuning law."""
    out = tmp_path / "arm.toml"
    assert main(["model", str(ARM3), "--scenario", str(out), "-q"]) == 0
    sc = qcontrol.load_scenario(out)
    eq = model_equation(ARM3)
    assert sc.order == 3 and sc.controller.kind == "tuning"
    assert list(sc.theta) == [t.theta for t in eq.all_terms]


def test_a_load_on_the_order_3_arm_is_refused_before_the_run() -> None:
    """A load torque on the joint is not the ODE twin's matched load of x3': one line, no run."""
    sc = qcontrol.load_scenario(SCENARIOS / "arm3.toml", {"simulation.duration": 0.1, "disturbance": [
        {"kind": "step", "start": 0.05, "value": 2.0}]})
    with pytest.raises(qcontrol.QcontrolInputError, match=r"\[\[disturbance\]\]: backend 'mujoco' takes no "):
        qcontrol.run(sc, backend="mujoco")


def test_u_is_drawn_in_its_own_unit() -> None:
    """u is x1's n-th derivative only where the input gain is 1 (eq. (1)): the figures and the
    video overlay label it so there, and without a unit where u is the filter actuator's input."""
    from qcontrol.plots.run_figures import scenario_units
    from qcontrol.render.frames import overlay_input_unit

    arm3 = qcontrol.load_scenario(SCENARIOS / "arm3.toml")
    example2 = qcontrol.load_scenario(SCENARIOS / "example2.toml")
    chain3 = qcontrol.load_scenario(SCENARIOS / "chain3.toml")
    assert arm3.terms.b != 1.0 and scenario_units(arm3).u == ""
    assert overlay_input_unit("rad", arm3.order, arm3.terms.b) == ""
    assert scenario_units(example2).u == "rad/s$^2$"
    assert overlay_input_unit("rad", example2.order, example2.terms.b) == "rad/s^2"
    assert scenario_units(chain3).u == "x$_1$ unit/s$^3$"
