"""A catalogue of bad inputs: each one through the real command line.

Every case must give exit status 2 and exactly one line on stderr, ``qcontrol: error: ...``, that
names where the problem is (the scenario file and key, or the option), what is wrong (usually the
value) and, after a ``;``, the fix. There must be no traceback, no output file under its final
name and no temporary file anywhere under the test's folder. Nothing in a scenario is ever
executed: the expression cases include attempts to import, open and call, and a canary file proves
none of them ran.

Most cases run in-process (``qcontrol.cli.main``); a few go through ``python -m qcontrol.cli`` in a
subprocess to prove the real interpreter prints no traceback either.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import EX1, EX2, ROOT, SCENARIOS, run_forked
from test_messages import assert_toml_hints

from qcontrol.cli import main

CHAIN3 = SCENARIOS / "chain3.toml"
CANARY = "PWNED"  # a file the malicious expressions would create if anything were executed


def _text(base: Path) -> str:
    """A scenario's text, loadable from any folder (absolute MJCF path)."""
    return base.read_text(encoding="utf-8").replace('"qcontrol:models/', f'"{ROOT}/models/')


def _edit(base: Path, old: str, new: str) -> str:
    """``base`` with one exact edit; fails loudly if the scenario no longer contains ``old``."""
    text = _text(base)
    assert old in text, f"{base.name} no longer contains {old!r}: update the catalogue"
    return text.replace(old, new, 1)


def ex2(old: str, new: str) -> str:
    return _edit(EX2, old, new)


def ex1(old: str, new: str) -> str:
    return _edit(EX1, old, new)


def phi(expr: str) -> str:
    """Example 2 with its second known function replaced by ``expr`` (a TOML literal string)."""
    return ex2('"x2**2*cos(x1)"', f"'{expr}'")


def r0(expr: str) -> str:
    """Example 2 with its first bounding function replaced by ``expr``."""
    return ex2('"1 + q2**2"', f"'{expr}'")


def _without_section(base: Path, header: str) -> str:
    """``base`` with the table ``header``, its sub-tables and their keys removed."""
    lines = _text(base).splitlines(keepends=True)
    out, skipping = [], False
    for line in lines:
        if line.startswith("["):
            name = line.split("#")[0].strip()
            skipping = name == header or name.startswith(header[:-1] + ".")
        if not skipping:
            out.append(line)
    return "".join(out)


def _sum_of_sines(terms: str) -> str:
    old = 'kind = "sine"          # y_d = sin(1.5 t)\namplitude = 1.0\nfrequency = 1.5'
    return ex2(old, f'kind = "sum_of_sines"\nterms = {terms}')


@dataclass(frozen=True)
class Case:
    """One bad input: a scenario text (or None: use ``scenario``), extra arguments, and the
    fragments the one-line message must contain."""

    text: str | bytes | None
    args: tuple[str, ...] = ()
    expect: tuple[str, ...] = ()
    scenario: Path | None = None  # when text is None
    command: str = "run"
    names_file: bool = True  # the message names the scenario file
    extra: dict[str, str] = field(default_factory=dict)  # more files to write beside bad.toml


def case(text: str | bytes | None, *expect: str, args: tuple[str, ...] = (), **kw: object) -> Case:
    return Case(text, tuple(args), tuple(expect), **kw)  # type: ignore[arg-type]


BROKEN_XML = "<mujoco><worldbody><body><joint type='hinge'/></body>"
NOT_MUJOCO_XML = "<html><body><p>not a model</p></body></html>"
NEGATIVE_MASS_XML = (ROOT / "models" / "pendulum.xml").read_text().replace('mass="12.25"', 'mass="-1"')
_TERMS_ONE_OK = "[{amplitude = 1.0, frequency = 2.0}]"

CATALOGUE: dict[str, Case] = {
    # ---- malformed files -------------------------------------------------------------------
    "toml: unclosed table header": case("[plant\norder = 2\n", "malformed TOML", "fix the syntax"),
    "toml: duplicate key": case(ex2("gamma = 1.0", "gamma = 1.0\ngamma = 2.0"), "malformed TOML"),
    "toml: unterminated string": case(ex2('name = "example2"', 'name = "example2'), "malformed TOML"),
    "toml: not UTF-8": case(b"[plant]\norder = \xff\xfe\n", "cannot read the scenario"),
    "toml: array of tables instead of a table": case(
        ex2("[controller]", "[[controller]]"), "controller: must be a table, got a list"
    ),
    "file: scenario is a folder": case(
        None, "is a folder, not a scenario file", scenario=ROOT / "scenarios", names_file=False
    ),
    "file: scenario missing": case(
        None, "scenario file not found", scenario=ROOT / "no-such.toml", names_file=False
    ),
    # ---- unknown keys, in every table ------------------------------------------------------
    "unknown: top-level table": case(
        _text(EX2) + "\n[extras]\nanswer = 42\n", "extras: unknown key", "allowed keys are scenario, plant"
    ),
    "unknown: [scenario]": case(
        ex2('name = "example2"', 'name = "example2"\nnmae = "x"'),
        "scenario.nmae: unknown key",
        "name, description",
    ),
    "unknown: [plant]": case(ex2("order = 2", "order = 2\nordr = 2"), "plant.ordr: unknown key"),
    "unknown: [controller]": case(
        ex2("c = [4.0, 3.0]", "c = [4.0, 3.0]\nC = [1.0, 1.0]"), "controller.C: unknown key"
    ),
    "unknown: [reference]": case(
        ex2("frequency = 1.5", "frequency = 1.5\nfreq = 2.0"), "reference.freq: unknown key"
    ),
    "unknown: [simulation]": case(
        ex2("dt = 0.001", "dt = 0.001\nstep = 0.001"), "simulation.step: unknown key"
    ),
    "unknown: [plant.mujoco]": case(
        ex2('joint = "hinge"', 'joint = "hinge"\njoints = "hinge"'), "plant.mujoco.joints: unknown key"
    ),
    "unknown: reference.terms[0]": case(
        _sum_of_sines("[{amplitude = 1.0, freq = 2.0}]"), "reference.terms[0].freq: unknown key"
    ),
    "unknown: quoted key with a newline": case(
        ex2("gamma = 1.0", 'gamma = 1.0\n"gam\\nma" = 1.0'), 'controller.proposed."gam\\nma": unknown key'
    ),
    # ---- wrong types -----------------------------------------------------------------------
    "type: order is a string": case(
        ex2("order = 2", 'order = "two"'), "plant.order: must be a whole number", "'two'"
    ),
    "type: order is a float": case(ex2("order = 2", "order = 2.0"), "plant.order: must be a whole number"),
    "type: delta is a string": case(
        ex2("delta = 0.01", 'delta = "0.01"'), "controller.delta: must be a number, got a string '0.01'"
    ),
    "type: x0 is a number": case(ex2("x0 = [0.3, 0.3]", "x0 = 0.3"), "plant.x0: must be a list of numbers"),
    "type: x0 holds a boolean": case(
        ex2("x0 = [0.3, 0.3]", "x0 = [true, 0.3]"), "plant.x0[0]: must be a number, got a boolean"
    ),
    "type: c holds a string": case(
        ex2("c = [4.0, 3.0]", 'c = [4.0, "3"]'), "controller.c[1]: must be a number"
    ),
    "type: phi is one string": case(
        ex2('phi = ["x2", "x2**2*cos(x1)", "sin(x1)"]', 'phi = "x2"'),
        "plant.phi: must be a list of expression strings",
    ),
    "type: r holds numbers": case(
        ex2('r = ["1 + q2**2", "1 + 2*q2**2", "1"]', "r = [1, 1, 1]"),
        "controller.proposed.r[0]: must be an expression string",
    ),
    "type: psi is a number": case(ex1('psi = "0.1*x2**2"', "psi = 0.1"), "plant.psi: must be a string"),
    "type: controller kind": case(
        ex2('kind = "proposed"', 'kind = "pid"'),
        "controller.kind: 'pid' is not allowed",
        "proposed, comparison",
    ),
    "type: backend is a boolean": case(
        ex2('backend = "mujoco"', "backend = true"), "simulation.backend: must be a string"
    ),
    "type: reference kind": case(
        ex2('kind = "sine"', 'kind = "square"'), "reference.kind: 'square' is not allowed"
    ),
    "type: reference terms empty": case(_sum_of_sines("[]"), "reference.terms: must be a non-empty list"),
    # ---- missing keys and tables -----------------------------------------------------------
    "missing: [simulation]": case(_without_section(EX2, "[simulation]"), "[simulation]: missing table"),
    "missing: [controller]": case(_without_section(EX2, "[controller]"), "[controller]: missing table"),
    "missing: controller.delta": case(ex2("delta = 0.01 ", "# delta "), "controller.delta: missing",
                                      "add it"),
    "missing: plant.x0": case(ex2("x0 = [0.3, 0.3]\n", ""), "plant.x0: missing"),
    "missing: simulation.dt": case(ex2("dt = 0.001\n", ""), "simulation.dt: missing"),
    "missing: simulation.duration": case(ex2("duration = 10.0\n", ""), "simulation.duration: missing"),
    "missing: controller.kappa_margin": case(
        ex2("kappa_margin = 1.1", "# no kappa"), "controller.kappa_margin: missing"
    ),
    "missing: plant.mujoco.joint": case(ex2('joint = "hinge"\n', ""), "plant.mujoco.joint: missing"),
    # ---- zero or negative where a positive number is needed --------------------------------
    "sign: delta = 0": case(ex2("delta = 0.01", "delta = 0"), "controller.delta: must be > 0, got 0"),
    "sign: negative gain": case(
        ex2("c = [4.0, 3.0]", "c = [-4.0, 3.0]"), "controller.c[0]: must be > 0, got -4"
    ),
    "sign: negative gamma": case(
        ex2("gamma = 1.0", "gamma = -1.0"), "controller.proposed.gamma: must be > 0, got -1"
    ),
    "sign: negative sigma": case(
        ex2("sigma = 1.0", "sigma = -0.5"), "controller.proposed.sigma: must be > 0, got -0.5"
    ),
    "sign: negative dt": case(ex2("dt = 0.001", "dt = -0.001"), "simulation.dt: must be > 0"),
    "sign: zero duration": case(ex2("duration = 10.0", "duration = 0.0"), "simulation.duration: must be > 0"),
    "sign: zero kappa_margin": case(
        ex2("kappa_margin = 1.1", "kappa_margin = 0.0"), "controller.proposed.kappa_margin: must be > 0"
    ),
    "sign: r_scale below 1": case(
        ex2("gamma = 1.0", "gamma = 1.0\nr_scale = 0.5"), "controller.proposed.r_scale: must be >= 1", "0.5"
    ),
    "sign: zero state bound": case(
        ex2("dt = 0.001", "dt = 0.001\nstate_bound = 0"), "simulation.state_bound: must be > 0"
    ),
    "sign: comparison gain": case(
        ex2('kind = "proposed"', 'kind = "comparison"').replace("gain = 1.0", "gain = 0.0"),
        "controller.comparison.gain: must be > 0",
    ),
    "sign: negative MJCF mass parameter": case(
        _edit(SCENARIOS / "example2-rigid.toml", "mass = 1.0", "mass = -1.0"),
        "plant.mujoco.parameters.mass: must be > 0",
    ),
    # ---- kappa <= L (Theorem 1) ------------------------------------------------------------
    "kappa: equal to L": case(
        ex2("kappa_margin = 1.1", "kappa = 0.025"), "controller.proposed.kappa: must exceed L", "0.025"
    ),
    "kappa: below L": case(
        ex2("kappa_margin = 1.1", "kappa = 0.001"), "controller.proposed.kappa: must exceed L"
    ),
    "kappa: margin lost in rounding": case(
        ex2("kappa_margin = 1.1", "kappa_margin = 1e-300"), "controller.proposed.kappa_margin: 1e-300 is lost"
    ),
    "kappa: both kappa and margin": case(
        ex2("kappa_margin = 1.1", "kappa_margin = 1.1\nkappa = 2.0"),
        "controller.proposed.kappa: given together with kappa_margin",
    ),
    # ---- NaN and Inf anywhere (TOML has nan and inf) ---------------------------------------
    "nonfinite: x0 nan": case(
        ex2("x0 = [0.3, 0.3]", "x0 = [nan, 0.3]"), "plant.x0[0]: must be finite, got nan"
    ),
    "nonfinite: theta inf": case(
        ex2("theta = [-1.0, -3.5, -34.3]", "theta = [-1.0, inf, -34.3]"),
        "plant.theta[1]: must be finite, got inf",
    ),
    "nonfinite: gain -inf": case(ex2("c = [4.0, 3.0]", "c = [4.0, -inf]"), "controller.c[1]: must be finite"),
    "nonfinite: delta inf": case(ex2("delta = 0.01", "delta = +inf"), "controller.delta: must be finite"),
    "nonfinite: reference amplitude": case(
        ex2("amplitude = 1.0", "amplitude = nan"), "reference.amplitude: must be finite"
    ),
    "nonfinite: state bound": case(
        ex2("dt = 0.001", "dt = 0.001\nstate_bound = inf"), "simulation.state_bound: must be finite"
    ),
    "nonfinite: duration": case(
        ex2("duration = 10.0", "duration = inf"), "simulation.duration: must be finite"
    ),
    "nonfinite: sensor noise": case(
        ex2('actuator = "torque"', 'actuator = "torque"\nsensor_noise = nan'), "plant.mujoco.sensor_noise"
    ),
    "nonfinite: --set gamma=inf": case(
        None, "--set controller.gamma=inf: must be finite", scenario=EX2,
        args=("--set", "controller.gamma=inf"), names_file=False,  # the command line is named, not the file
    ),
    "nonfinite: --duration nan": case(
        None, "--duration nan: must be a positive number", scenario=EX2, args=("--duration", "nan"),
        names_file=False,  # the value came from the command line: the option is named, not the file
    ),
    "nonfinite: expression constant 1e999": case(phi("x2 * 1e999"), "plant.phi[1]", "not finite"),
    "nonfinite: derivative of the reference": case(
        ex2("frequency = 1.5", "frequency = 1e300"), "reference.frequency", "non-finite derivative"
    ),
    # ---- wrong vector lengths --------------------------------------------------------------
    "length: x0": case(ex2("x0 = [0.3, 0.3]", "x0 = [0.3, 0.3, 0.0]"), "plant.x0: has 3 entries, expected 2"),
    "length: c": case(ex2("c = [4.0, 3.0]", "c = [4.0]"), "controller.c: has 1 entries, expected 2"),
    "length: theta": case(
        ex2("theta = [-1.0, -3.5, -34.3]", "theta = [-1.0, -3.5, -34.3, 0.0]"),
        "plant.theta: has 4 entries, expected 3",
    ),
    "length: r": case(
        ex2('r = ["1 + q2**2", "1 + 2*q2**2", "1"]', 'r = ["1", "1", "1", "1"]'),
        "controller.proposed.r: has 4 bounding function(s)",
        "3 uncertain term(s)",
    ),
    "length: sensor noise": case(
        ex2('actuator = "torque"', 'actuator = "torque"\nsensor_noise = [0.1, 0.1, 0.1]\nnoise_seed = 1'),
        "plant.mujoco.sensor_noise: expected 2 values",
    ),
    # ---- expressions -----------------------------------------------------------------------
    "expr: unknown name": case(
        phi("y1 * x2"), "plant.phi[1]", "unknown name 'y1'", "allowed names are x1, x2"
    ),
    "expr: state beyond the order": case(phi("x3"), "plant.phi[1]", "unknown name 'x3'"),
    "expr: quantized name in the plant": case(phi("q1"), "plant.phi[1]", "unknown name 'q1'"),
    "expr: plant name in a bounding function": case(r0("1 + x2**2"), "controller.proposed.r[0]",
                                                    "unknown name 'x2'"),
    "expr: attribute access": case(phi("x1.real"), "plant.phi[1]", "attribute access"),
    "expr: dunder attribute chain": case(phi("x1.__class__.__mro__"), "attribute access"),
    "expr: dunder name": case(phi("__builtins__"), "unknown name '__builtins__'"),
    "expr: __import__ call": case(
        phi(f'__import__("os").system("touch {CANARY}")'), "only calls of plain function names"
    ),
    "expr: __import__ name call": case(phi('__import__("os")'), "unknown function '__import__'"),
    "expr: eval": case(phi(f'eval("open(\\"{CANARY}\\", \\"w\\")")'), "unknown function 'eval'"),
    "expr: open": case(phi(f'open("{CANARY}", "w")'), "unknown function 'open'"),
    "expr: exec via a --set": case(
        None,
        "--set plant.psi=",
        "unknown function 'exec'",
        scenario=EX1,
        args=("--set", f'plant.psi="exec(\'open(\\"{CANARY}\\",\\"w\\")\')"'),
        names_file=False,
    ),
    "expr: lambda": case(phi("lambda x1: x1"), "lambda is not allowed"),
    "expr: called lambda": case(phi("(lambda: 1)()"), "only calls of plain function names"),
    "expr: list comprehension": case(phi("[x1 for x1 in (1, 2)]"), "comprehension is not allowed"),
    "expr: generator inside max": case(phi("max(1, (x1 for x1 in (1, 2)))"), "generator expression"),
    "expr: conditional": case(phi("x1 if x2 else 1"), "conditional expression is not allowed"),
    "expr: comparison": case(phi("x1 > 0"), "comparison is not allowed"),
    "expr: string literal": case(phi('"x1"'), "is not a real number"),
    "expr: keyword argument": case(phi("max(x1, x2, key=abs)"), "keyword arguments to max()"),
    "expr: wrong arity": case(phi("sin(x1, x2)"), "sin() takes exactly 1 argument"),
    "expr: huge exponent": case(phi("x2**1000"), "exponent 1000 is too large", "within +-64"),
    "expr: exponent tower": case(phi("x2**10**10"), "too large"),
    "expr: overflowing constant": case(phi("exp(1000) * x2"), "exp(1000) is not finite"),
    "expr: division by zero": case(phi("x2/0"), "division by zero"),
    "expr: division by a zero constant": case(phi("x2/(2 - 2)"), "division by zero"),
    "expr: log(0)": case(phi("log(0) + x2"), "log(0) is not finite"),
    "expr: not finite at x0": case(phi("1/(x1 - 0.3)"), "plant.phi[1]", "not finite at x0"),
    "expr: bounding function below 1": case(r0("q2**2"), "controller.proposed.r[0]",
                                            "must be finite and >= 1"),
    "expr: bounding function infinite": case(r0("1 + 1/q1"), "controller.proposed.r[0]",
                                             "must be finite and >= 1"),
    "expr: syntax error": case(phi("sin(x1"), "cannot parse"),
    "expr: empty": case(phi(""), "plant.phi[1]", "empty expression"),
    "expr: too long": case(phi("x1+" * 700 + "x1"), "characters long; the limit is 2000"),
    "expr: too many terms": case(phi("+".join(["x1"] * 600)), "too many terms"),
    # ---- MJCF ------------------------------------------------------------------------------
    "mjcf: missing file": case(
        ex2(f"{ROOT}/models/pendulum.xml", "no-such-model.xml"), "plant.mujoco.model", "not found"
    ),
    "mjcf: path is a folder": case(
        ex2(f"{ROOT}/models/pendulum.xml", f"{ROOT}/models"), "plant.mujoco.model"
    ),
    "mjcf: broken XML": case(
        ex2(f"{ROOT}/models/pendulum.xml", "broken.xml"),
        "plant.mujoco.model",
        extra={"broken.xml": BROKEN_XML},
    ),
    "mjcf: not MuJoCo XML": case(
        ex2(f"{ROOT}/models/pendulum.xml", "robot.xml"),
        "plant.mujoco.model",
        extra={"robot.xml": NOT_MUJOCO_XML},
    ),
    "mjcf: model does not compile": case(
        ex2(f"{ROOT}/models/pendulum.xml", "heavy.xml"),
        "plant.mujoco.model",
        extra={"heavy.xml": NEGATIVE_MASS_XML},
    ),
    "mjcf: joint not in the model": case(ex2('joint = "hinge"', 'joint = "elbow"'), "plant.mujoco.joint"),
    "mjcf: unknown native term": case(
        ex2('native_terms = ["phi1", "phi3"]', 'native_terms = ["phi9"]'),
        "plant.mujoco.native_terms",
        "unknown term 'phi9'",
    ),
    "mjcf: unknown integrator": case(
        ex2('actuator = "torque"', 'actuator = "torque"\nintegrator = "RK5"'), "plant.mujoco.integrator"
    ),
    "mjcf: sensor delay beyond any run": case(
        ex2('actuator = "torque"', 'actuator = "torque"\nsensor_delay = 1e300'),
        "plant.mujoco.sensor_delay", "longer than any run",
    ),
    "mjcf: noise without a seed": case(
        ex2('actuator = "torque"', 'actuator = "torque"\nsensor_noise = 0.01'),
        "plant.mujoco.noise_seed: missing",
    ),
    "mjcf: physics disagrees with the scenario": case(
        ex2("theta = [-1.0, -3.5, -34.3]", "theta = [-1.0, -3.5, -20.0]"), "plant.mujoco", "differs"
    ),
    "mjcf: compare without a model": case(None, "[plant.mujoco]", scenario=CHAIN3, command="compare"),
    "mjcf: --backend mujoco without a model": case(
        None, "[plant.mujoco]", scenario=CHAIN3, args=("--backend", "mujoco")
    ),
    # ---- --set -----------------------------------------------------------------------------
    "set: no key": case(None, "expected KEY=VALUE", scenario=EX2, args=("--set", "=1"), names_file=False),
    "set: empty key part": case(
        None, "has an empty part", scenario=EX2, args=("--set", "controller..c=1"), names_file=False
    ),
    "set: through a value": case(
        None,
        "'dt' is a value, not a table",
        scenario=EX2,
        args=("--set", "simulation.dt.x=1"),
        names_file=False,
    ),
    "set: unknown top-level key": case(None, "--set foo.bar=1: foo: unknown key", scenario=EX2,
                                       args=("--set", "foo.bar=1"), names_file=False),
    "set: bad value type": case(
        None,
        "--set controller.delta=abc: must be a number, got a string 'abc'",
        scenario=EX2,
        args=("--set", "controller.delta=abc"),
        names_file=False,
    ),
    "set: bad choice": case(
        None, "--set controller.kind=pid: 'pid' is not allowed", scenario=EX2,
        args=("--set", "controller.kind=pid"), names_file=False,
    ),
    "set: wrong length": case(
        None, "--set plant.x0=[1, 2, 3]: has 3 entries", scenario=EX2, args=("--set", "plant.x0=[1, 2, 3]"),
        names_file=False,
    ),
    "set: table replaced by a value": case(
        None, "--set plant=1: must be a table", scenario=EX2, args=("--set", "plant=1"), names_file=False
    ),
    "set: bad --grid value": case(
        None, "--grid controller.delta=abc: must be a number", scenario=EX2, command="sweep",
        args=("--grid", "controller.delta=0.01,abc"), names_file=False,
    ),
    "set: bad entry of a list": case(
        None, "--set controller.c=[1.0, -3.0]: controller.c[1]: must be > 0", scenario=EX2,
        args=("--set", "controller.c=[1.0, -3.0]"), names_file=False,
    ),
    # ---- run length and steps --------------------------------------------------------------
    "steps: too many (memory)": case(
        None, "--duration 1e+300: ", "more than the limit", scenario=EX2, args=("--duration", "1e300"),
        names_file=False,
    ),
    "steps: tiny dt": case(None, "more than the limit", scenario=EX2, args=("--dt", "1e-300")),
    "steps: negative --dt": case(None, "--dt -0.001: must be a positive number", scenario=EX2,
                                 args=("--dt", "-0.001"), names_file=False),
    "steps: control period not a multiple": case(
        ex2("dt = 0.001", "dt = 0.001\ncontrol_period = 0.0015"),
        "simulation.control_period = 0.0015 s is not a whole number of steps",
        "multiple of dt",
    ),
    # ---- output folder ---------------------------------------------------------------------
    "out: under a regular file": case(
        None,
        "--out",
        "choose a writable folder",
        scenario=EX2,
        args=("--out", "{tmp}/blocker/sub"),
        names_file=False,
    ),
    "out: is a regular file": case(
        None, "--out", scenario=EX2, args=("--out", "{tmp}/blocker"), names_file=False
    ),
    "out: compare under a regular file": case(
        None, "--out", scenario=EX2, command="compare", args=("--out", "{tmp}/blocker/sub"), names_file=False
    ),
    "out: summary.json is a folder": case(
        None,
        "summary.json",
        "is a folder, not a regular file",
        scenario=EX2,
        args=("--out", "{tmp}/taken", "--backend", "ode", "--duration", "0.01"),
        names_file=False,
    ),
}


def _prepare(tmp_path: Path, c: Case) -> tuple[list[str], Path]:
    """Write the case's files; return the argument list and the output folder."""
    for name, content in c.extra.items():
        (tmp_path / name).write_text(content)
    (tmp_path / "blocker").write_text("a regular file, not a folder\n")
    (tmp_path / "taken" / "summary.json").mkdir(parents=True)
    if c.text is None:
        assert c.scenario is not None
        scenario = c.scenario
    else:
        scenario = tmp_path / "bad.toml"
        if isinstance(c.text, bytes):
            scenario.write_bytes(c.text)
        else:
            scenario.write_text(c.text, encoding="utf-8")
    args = [a.replace("{tmp}", str(tmp_path)) for a in c.args]
    out = tmp_path / "out"
    if "--out" not in args:
        args += ["--out", str(out)]
    else:
        out = Path(args[args.index("--out") + 1])
    return [c.command, str(scenario), "-q", *args], out


def _assert_nothing_written(tmp_path: Path, out: Path) -> None:
    leftovers = [
        p
        for p in tmp_path.rglob("*")
        if p.name.endswith((".part", ".tmp")) or p.name.startswith((".summary", ".compare"))
    ]
    assert not leftovers, f"temporary files left: {leftovers}"
    for name in ("summary.json", "compare.json"):
        assert not (out / name).is_file()
    assert not (tmp_path / CANARY).exists() and not Path(CANARY).exists(), "an expression was executed"


def _assert_one_line(err: str, c: Case, scenario: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, f"expected one line, got:\n{err}"
    line = lines[0]
    assert line.startswith("qcontrol: error: "), line
    assert "Traceback" not in err
    assert "; " in line, f"no fix after ';': {line}"
    for fragment in c.expect:
        assert fragment in line, f"{fragment!r} not in {line!r}"
    if c.names_file:
        assert scenario in line, f"file {scenario} not named in {line!r}"
    assert_toml_hints(line)  # every hint that offers TOML to write is valid TOML


def test_catalogue_size() -> None:
    """At least 30 cases, as first asked; the catalogue is self-contained."""
    assert len(CATALOGUE) >= 30
    assert len(CATALOGUE) >= 100  # what we actually cover; keep it from shrinking by accident


@pytest.mark.parametrize("name", list(CATALOGUE))
def test_bad_input_exit_2_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    c = CATALOGUE[name]
    monkeypatch.chdir(tmp_path)  # a canary written relative to the working folder lands here
    argv, out = _prepare(tmp_path, c)
    assert main(argv) == 2
    captured = capsys.readouterr()
    _assert_one_line(captured.err, c, argv[1])
    _assert_nothing_written(tmp_path, out)


SUBPROCESS_CASES = [
    "toml: unclosed table header",
    "expr: __import__ call",
    "mjcf: broken XML",
    "out: under a regular file",
    "nonfinite: x0 nan",
]


@pytest.fixture(scope="module")
def real_interpreter(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple]:
    """Each of SUBPROCESS_CASES as ``python -m qcontrol.cli ARGV`` in a folder of its own, run in
    forks of one interpreter that has imported the package (conftest.run_forked: each a process
    of its own, exiting through the interpreter as the console does): the case's folder, its
    output folder, and the command's exit status, stdout and stderr."""
    prepared = {}
    for name in SUBPROCESS_CASES:
        folder = tmp_path_factory.mktemp("case")
        prepared[name] = (folder, *_prepare(folder, CATALOGUE[name]))
    commands = [{"argv": ["python", "-m", "qcontrol.cli", *argv], "cwd": str(folder)}
                for folder, argv, _ in prepared.values()]
    ran = run_forked(commands, tmp_path_factory.mktemp("runner"), dict(os.environ), timeout=300)
    return {name: (folder, argv, out, result)
            for (name, (folder, argv, out)), result in zip(prepared.items(), ran, strict=True)}


@pytest.mark.parametrize("name", SUBPROCESS_CASES)
def test_bad_input_in_a_real_interpreter(real_interpreter: dict[str, tuple], name: str) -> None:
    """The same contract through ``python -m qcontrol.cli``: no traceback, one line, exit 2."""
    folder, argv, out, (status, stdout, stderr) = real_interpreter[name]
    assert status == 2, stderr
    _assert_one_line(stderr, CATALOGUE[name], argv[1])
    assert stdout == ""
    _assert_nothing_written(folder, out)


def test_usage_errors_are_one_line_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    """argparse errors (unknown option, bad choice, missing scenario) follow the same rule."""
    for argv in (
        ["run"],
        ["run", str(EX2), "--frobnicate"],
        ["run", str(EX2), "--duration", "ten"],
        ["fly", str(EX2)],
    ):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err, err
