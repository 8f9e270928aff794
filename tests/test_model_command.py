"""`qcontrol model`: the equation a one-joint MJCF realises, against independent computations
(rigid-body formulas, MuJoCo's own forces), the recipe of docs/your-model.md performed step by step,
the shipped models through it to their scenarios' coefficients, coefficients left to the model,
the messages of a scenario that disagrees with its model (each fix applied and loaded), the bad
inputs, and the default camera and light of a model without them."""

from __future__ import annotations

import json
import math
import re
import shlex
import tomllib
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import EX1, EX2, MODELS, ROOT

import qcontrol
from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError
from qcontrol.plants.mujoco.equation import model_equation
from qcontrol.render.frames import DEFAULT_CAMERA, FrameRenderer, Instant, camera_id
from qcontrol.scenario import load_scenario

RECIPE = (ROOT / "docs" / "your-model.md").read_text()
ARM_XML = re.search(r"```xml\n(.*?)```", RECIPE, re.S).group(1)

SPRING_XML = """<mujoco model="spring">
  <option timestep="0.001" gravity="0 0 -9.81"><flag contact="disable"/></option>
  <worldbody>
    <body name="cart">
      <joint name="x" type="slide" axis="1 0 1" stiffness="40" springref="0.2" damping="0.8"/>
      <inertial pos="0 0 0" mass="3" diaginertia="0.1 0.1 0.1"/>
      <geom type="box" size="0.1 0.1 0.1"/>
    </body>
  </worldbody>
  <actuator><motor name="push" joint="x" gear="2"/></actuator>
  <sensor><jointpos name="pos" joint="x"/><jointvel name="vel" joint="x"/></sensor>
</mujoco>
"""


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


def _theta(eq: qcontrol.plants.mujoco.equation.ModelEquation) -> dict[str, float]:
    return {t.phi: t.theta for t in eq.terms}


def test_the_arm_of_the_recipe_against_rigid_body_formulas(tmp_path: Path) -> None:
    """I = m l^2 + I_yy + armature, b = gear / I, damping -d / I, gravity -m g l sin(x1) / I."""
    eq = model_equation(_write(tmp_path, "arm.xml", ARM_XML))
    inertia = 2.5 * 0.4**2 + 0.05 + 0.02
    assert eq.inertia == pytest.approx(inertia, rel=1e-15)
    assert eq.input_gain == pytest.approx(5.0 / inertia, rel=1e-15)
    assert set(_theta(eq)) == {"x2", "sin(x1)"}
    assert _theta(eq)["x2"] == pytest.approx(-0.3 / inertia, rel=1e-15)
    assert _theta(eq)["sin(x1)"] == pytest.approx(-2.5 * 9.81 * 0.4 / inertia, rel=1e-14)
    assert eq.outside == () and eq.unexplained < 1e-14


def test_a_spring_on_a_tilted_slide_against_its_formulas(tmp_path: Path) -> None:
    """Stiffness k about springref r: -k (x1 - r) / m; gravity along the slide: m g . axis / m."""
    eq = model_equation(_write(tmp_path, "spring.xml", SPRING_XML))
    assert eq.inertia == pytest.approx(3.0, rel=1e-15) and eq.input_gain == pytest.approx(2 / 3, rel=1e-15)
    theta = _theta(eq)
    assert set(theta) == {"x2", "x1 - 0.2", "1"}  # (I: the mass times the axis' squared length, rounded)
    assert theta["x2"] == pytest.approx(-0.8 / 3, rel=1e-15)
    assert theta["x1 - 0.2"] == pytest.approx(-40 / 3, rel=1e-15)
    assert theta["1"] == pytest.approx(-9.81 / math.sqrt(2), rel=1e-14)  # g . axis, axis (1, 0, 1)/sqrt(2)


def test_polynomial_damping_actuator_damping_and_gravity_off_the_reference(tmp_path: Path) -> None:
    """MuJoCo's polynomial damping f(v) = a v + b v|v| + c v^3 with an actuator's a' gear^2 added,
    and gravity at a hinge whose reference angle is not 0, each against MuJoCo's own forces."""
    xml = """<mujoco><option gravity="0 0 -9.81"/><compiler angle="radian"/><worldbody><body>
      <joint name="j" axis="0 1 0" damping="0.5 0.2 0.1" ref="0.3"/>
      <geom size="0.05" pos="0.1 0 -0.5" mass="1.5"/></body></worldbody>
      <actuator><motor name="m" joint="j" gear="3" damping="0.1"/></actuator>
      <sensor><jointpos name="p" joint="j"/><jointvel name="v" joint="j"/></sensor></mujoco>"""
    eq = model_equation(_write(tmp_path, "poly.xml", xml))
    theta = _theta(eq)
    assert theta["x2"] == pytest.approx(-(0.5 + 0.1 * 9) / eq.inertia, rel=1e-15)
    assert theta["x2*abs(x2)"] == pytest.approx(-0.2 / eq.inertia, rel=1e-15)
    assert theta["x2**3"] == pytest.approx(-0.1 / eq.inertia, rel=1e-15)
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "poly.xml"))
    data = mujoco.MjData(model)
    for q in (-2.0, 0.1, 1.7):
        data.qpos[0], data.qvel[0] = q, 0.0
        mujoco.mj_forward(model, data)
        gravity = theta["cos(x1 - 0.3)"] * math.cos(q - 0.3) + theta["sin(x1 - 0.3)"] * math.sin(q - 0.3)
        assert gravity == pytest.approx(-data.qfrc_bias[0] / eq.inertia, rel=1e-12)


def test_the_shipped_models_give_their_scenarios_coefficients() -> None:
    """The slider: b = 1 and no term (example1: native_terms = []). The pendulum: damping and
    gravity, the terms example2 leaves to MuJoCo (phi1, phi3); its inertia is 1 + 1e-14 (the bob's
    smallest rotational inertia MuJoCo accepts), so its coefficients are the scenario's -1 and -34.3
    divided by that: equal to 1e-13, and exactly MuJoCo's own forces over I."""
    slider = model_equation(MODELS / "slider.xml")
    assert (slider.inertia, slider.input_gain, slider.terms, slider.outside) == (1.0, 1.0, (), ())
    assert load_scenario(EX1).backends["mujoco"].native_terms == ()
    pendulum = model_equation(MODELS / "pendulum.xml")
    ex2 = load_scenario(EX2)
    shipped = {p: t for p, t, n in zip(ex2.phi, ex2.theta, ("phi1", "phi2", "phi3"), strict=True)
               if n in ex2.backends["mujoco"].native_terms}
    assert set(_theta(pendulum)) == set(shipped) == {"x2", "sin(x1)"}
    for phi, theta in _theta(pendulum).items():
        assert theta == pytest.approx(shipped[phi], rel=1e-13)
    model = mujoco.MjModel.from_xml_path(str(MODELS / "pendulum.xml"))
    data = mujoco.MjData(model)
    data.qpos[0] = math.pi / 2
    mujoco.mj_forward(model, data)
    assert _theta(pendulum) == {"x2": -model.dof_damping[0] / pendulum.inertia,
                                "sin(x1)": -data.qfrc_bias[0] / pendulum.inertia}


def _commands(text: str) -> list[list[str]]:
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    lines = [line for block in blocks for line in block.splitlines()]
    return [shlex.split(line)[1:] for line in lines if line.startswith("qcontrol")]


def test_the_recipe_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """docs/your-model.md: the model written, its printed equation as shown, the scenario written,
    run and compared: MuJoCo and its ODE twin agree to 1e-13 over 10 s."""
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, "arm.xml", ARM_XML)
    commands = _commands(RECIPE)
    assert [c[0] for c in commands] == ["model", "model", "run", "compare"]
    assert main(commands[0]) == 0
    shown = re.search(r"prints\n\n```\n(.*?)```", RECIPE, re.S).group(1)
    assert capsys.readouterr().out.startswith(shown)
    for command in commands[1:]:
        assert main([*command, "-q"] + (["--out", "cmp"] if command[0] == "compare" else [])) == 0
    plant = tomllib.loads((tmp_path / "arm.toml").read_text())["plant"]
    assert plant["input_gain"] == model_equation("arm.xml").input_gain
    assert plant["mujoco"]["native_terms"] == ["phi1", "phi2"]
    deviation = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert deviation["max_abs_dy"] < 1e-13 and max(deviation["max_abs_dx"]) < 1e-13


def test_a_written_scenario_of_a_spring_runs_like_its_twin(tmp_path: Path) -> None:
    model = _write(tmp_path, "spring.xml", SPRING_XML)
    out = qcontrol.model_scenario(model, tmp_path / "spring.toml")
    sc = load_scenario(out)
    assert sc.phi == ("x2", "x1 - 0.2", "1") and sc.input_gain == pytest.approx(2 / 3, rel=1e-15)
    deviation = qcontrol.compare(sc.with_overrides({"simulation.duration": 3.0})).summary
    assert deviation["max_abs_dy"] < 1e-13


def test_coefficients_left_to_the_model_are_read_at_load_and_written_into_the_provenance() -> None:
    left = {"plant.theta": ["model", -3.5, "model"], "plant.input_gain": "model"}
    sc = load_scenario(EX2, overrides=left)
    pendulum = model_equation(MODELS / "pendulum.xml")
    assert sc.theta == (_theta(pendulum)["x2"], -3.5, _theta(pendulum)["sin(x1)"])
    assert sc.input_gain == pendulum.input_gain
    from qcontrol.scenario.resolve import resolved_toml

    resolved = tomllib.loads(resolved_toml(sc))["plant"]
    assert resolved["theta"] == list(sc.theta) and resolved["input_gain"] == pendulum.input_gain
    stated = load_scenario(EX2, overrides={"plant.theta": list(sc.theta), "plant.input_gain": sc.input_gain})
    short = {"simulation.duration": 1.0}
    assert (qcontrol.run(sc.with_overrides(short)).summary["max_abs_z1_last_half"]
            == qcontrol.run(stated.with_overrides(short)).summary["max_abs_z1_last_half"])


@pytest.mark.parametrize(("overrides", "says"), [
    ({"plant.theta": ["model", "model", "model"]}, "phi2 is not in plant.mujoco.native_terms"),
    ({"plant.theta": ["model", "model", "model"], "plant.mujoco.native_terms": ["phi1", "phi2", "phi3"]},
     "MuJoCo's physics makes no term x2**2*cos(x1)"),
    ({"plant.theta": ["model", -3.5, "mdl"]}, 'must be a number or "model"'),
])
def test_model_entries_that_cannot_be_read_are_one_line(overrides: dict, says: str) -> None:
    with pytest.raises(QcontrolInputError, match=re.escape(says)):
        load_scenario(EX2, overrides=overrides)


def _fix(message: str) -> tuple[dict[str, object], list[str]]:
    """The [plant] values a refusal offers, as overrides, and the bounding functions to add."""
    found = {key: tomllib.loads(f"v = {value}")["v"]
             for key, value in re.findall(r"write (phi|theta|native_terms) = (\[[^]]*\])", message)}
    fix = {("plant.mujoco." if k == "native_terms" else "plant.") + k: value for k, value in found.items()}
    added = re.search(r"add to the law's r, one per added term: (\[[^]]*\])", message)
    return fix, [] if added is None else tomllib.loads(f"v = {added.group(1)}")["v"]


@pytest.mark.parametrize(("overrides", "cause"), [
    ({"plant.mujoco.native_terms": ["phi3"]}, "phi1 = x2 is counted twice"),
    ({"plant.mujoco.native_terms": ["phi1", "phi2", "phi3"]}, "phi2 = x2**2*cos(x1) is in native_terms but "
                                                             "MuJoCo's physics does not make it"),
    ({"plant.phi": ["x2**2*cos(x1)", "sin(x1)"], "plant.theta": [-3.5, -34.3],
      "plant.mujoco.native_terms": ["phi2"], "controller.proposed.r": ["1 + 2*q2**2", "1"]},
     "MuJoCo's physics also makes x2 (-0.99999999999999"),
    ({"plant.theta": [-1.0, -3.5, -20.2549]}, "phi3 = sin(x1): MuJoCo's coefficient is -34.29999999999966"),
])
def test_a_scenario_that_disagrees_with_its_model_is_told_the_cause_and_the_fix(overrides: dict,
                                                                                  cause: str) -> None:
    """Each refusal names the cause at full precision, and the values it offers load and check."""
    with pytest.raises(QcontrolInputError) as refused:
        qcontrol.assembly.build_plant(load_scenario(EX2, overrides=overrides), "mujoco")
    message = str(refused.value)
    assert cause in message and "\n" not in message and "qcontrol model" in message
    fix, bounds = _fix(message)
    r = list(overrides.get("controller.proposed.r", load_scenario(EX2).data["controller"]["proposed"]["r"]))
    fixed = load_scenario(EX2, overrides={**overrides, **fix, "controller.proposed.r": r + bounds})
    assert qcontrol.assembly.build_plant(fixed, "mujoco").consistency_report["ok"]


def test_coefficients_of_forces_not_divided_by_the_inertia_are_named(tmp_path: Path) -> None:
    model = _write(tmp_path, "arm.xml", ARM_XML)
    sc = load_scenario(qcontrol.model_scenario(model, tmp_path / "arm.toml"),
                       overrides={"plant.theta": [-0.3, -9.810000000000002]})
    with pytest.raises(QcontrolInputError, match=r"not divided by the inertia I = 0\.47000000000000003: the "
                                                 r"input gain is 10\.638297872340425, not 1"):
        qcontrol.assembly.build_plant(sc, "mujoco")


SENSORS = '<sensor><jointpos name="p" joint="j"/><jointvel name="v" joint="j"/></sensor>'


def _one_joint(actuator: str, joint: str = "", sensors: str = SENSORS) -> str:
    """A model of one hinge ``j`` (with the attributes ``joint``), ``actuator`` and ``sensors``."""
    return ('<mujoco><worldbody><body name="b"><joint name="j" axis="0 1 0" ' + joint + '/><geom size="0.1" '
            'pos="0 0 -0.5" mass="1"/></body></worldbody>' + actuator + sensors + "</mujoco>")


BAD = {
    "no actuator": (_one_joint(""), "no actuated joint"),
    "two actuated joints": ('<mujoco><worldbody><body><joint name="a" axis="0 1 0"/><geom size="0.1"/>'
                            '<body><joint name="b" axis="0 1 0"/><geom size="0.1" pos="0 0 -1"/></body>'
                            '</body>'
                            '</worldbody><actuator><motor joint="a"/><motor joint="b"/></actuator>'
                            '</mujoco>', "2 actuated joints ('a', 'b')"),
    "ball joint": ('<mujoco><worldbody><body><joint name="ball" type="ball"/><geom size="0.1" '
                   'pos="0 0 -0.5"/></body></worldbody><actuator><motor joint="ball" gear="1 0 0 0 0 0"/>'
                   '</actuator></mujoco>', "is a ball joint"),
    "position servo": (_one_joint('<actuator><position name="s" joint="j" kp="10"/></actuator>'),
                       "has a bias"),
    "filter without its sensor": (_one_joint('<actuator><general name="f" joint="j" dyntype="filter" '
                                             'dynprm="0.1"/></actuator>'),
                                  '<actuatorfrc name="x3" actuator="f"/>'),
    "urdf": ('<?xml version="1.0"?>\n<robot name="r"><link name="a"/></robot>\n',
             "its root element is <robot>"),
    "not xml": ("hello\n", "not an MJCF file"),
    "no sensors": (_one_joint('<actuator><motor name="m" joint="j"/></actuator>', sensors=""),
                   'add <sensor><jointpos name="x1" joint="j"/><jointvel name="x2" joint="j"/></sensor>'),
    "joint limits": (_one_joint('<actuator><motor name="m" joint="j"/></actuator>',
                                'range="-1 1" limited="true"'), "remove range"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_models_are_one_line_and_write_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   case: str) -> None:
    text, says = BAD[case]
    model = _write(tmp_path, "bad.xml", text)
    assert main(["model", str(model), "--scenario", str(tmp_path / "out.toml"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(model) in err and says in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.xml"]


def test_frictionloss_and_a_command_limit_become_realism_options(tmp_path: Path) -> None:
    """Outside the smooth form but stated by realism keys: the scenario runs, MuJoCo with them."""
    text = _one_joint('<actuator><motor name="m" joint="j" ctrlrange="-5 5" ctrllimited="true"/></actuator>',
                      'frictionloss="0.2"')
    sc = load_scenario(qcontrol.model_scenario(_write(tmp_path, "f.xml", text), tmp_path / "f.toml"))
    options = sc.backends["mujoco"]
    assert (options.frictionloss, options.torque_limit) == (0.2, 5.0)


def test_a_model_without_camera_or_light_is_framed_and_lit(tmp_path: Path) -> None:
    """The default camera sees the moving body whole at every position shown, and the key light
    makes it bright (MuJoCo's headlight alone leaves it dark)."""
    pytest.importorskip("OpenGL")
    model = mujoco.MjModel.from_xml_path(str(_write(tmp_path, "arm.xml", ARM_XML)))
    assert model.ncam == 0 and model.nlight == 0
    cid = camera_id(model, None, "arm.xml")
    assert cid == DEFAULT_CAMERA
    positions = np.linspace(-1.2, 1.2, 5)
    with FrameRenderer(model, "shoulder", cid, 160, 120, positions=positions) as renderer:
        for q in positions:
            frame = renderer.render(Instant(0.0, q, q, 0.0, q)).astype(float)
            body = frame.max(axis=2) > 60
            rows, cols = np.nonzero(body[20:-20])  # away from the overlay's text
            assert body.sum() > 100 and frame[body].mean() > 120
            assert cols.min() > 0 and cols.max() < 159 and rows.min() > 0


def test_a_model_that_makes_no_term_gets_the_viscous_one_at_zero(tmp_path: Path) -> None:
    """The slider's physics adds nothing to b u: the law still needs an uncertain term, so the
    scenario carries x2 with MuJoCo's coefficient 0 (no damping), native, and agrees with it."""
    sc = load_scenario(qcontrol.model_scenario(MODELS / "slider.xml", tmp_path / "slider.toml"))
    assert (sc.phi, sc.theta, sc.backends["mujoco"].native_terms) == (("x2",), (0.0,), ("phi1",))
    report = qcontrol.assembly.build_plant(sc, "mujoco").consistency_report
    assert report["ok"] and report["max_abs_mismatch"] == 0.0
