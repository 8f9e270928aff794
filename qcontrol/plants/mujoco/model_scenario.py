"""The scenario ``qcontrol model MODEL.xml --scenario OUT.toml`` writes: the model's equation
(:mod:`.equation`) as a plant every term of which MuJoCo's own physics produces, a uniform
quantizer per channel, the paper's law (44)-(45) with Example 2's settings and a bounding function r
for each term, a reference and the simulation settings. It runs as it is, on MuJoCo and on its ODE
twin, which integrate the same equation.
"""

from __future__ import annotations

import os
from pathlib import Path

from ...errors import QcontrolInputError
from ...resources import shipped_label
from .equation import TOLERANCE, ModelEquation

# A model that makes no term: the law needs one to adapt to, the joint's viscous term (its damping, 0)
NO_TERM = ("x2", 0.0, "1 + q2**2", "the model makes no term, and the law needs one to adapt to: the joint's "
           "viscous term, 0 as its damping")


def scenario_problem(eq: ModelEquation, label: str) -> str | None:
    """Why no runnable scenario can be written for ``eq`` (one line naming the fix), or None."""
    joint = eq.joint or "NAME"
    if not eq.joint or not eq.actuator:
        what = "joint" if not eq.joint else "actuator"
        return f"{label}: the {what} has no name, which a scenario needs; name it in the MJCF (name=\"...\")"
    missing = [tag for tag, name in (("jointpos", eq.position_sensor), ("jointvel", eq.velocity_sensor))
               if name is None]
    if missing:
        sensors = "".join(f"<{tag} name=\"{'x1' if tag == 'jointpos' else 'x2'}\" joint=\"{joint}\"/>"
                          for tag in missing)
        return (f"{label}: no named {' or '.join(missing)} sensor on joint {joint!r}, which a scenario reads "
                f"x1 and x2 from; add <sensor>{sensors}</sensor> to the MJCF")
    if eq.order == 3 and eq.activation_sensor is None:
        return (f"{label}: no named actuatorfrc sensor on the filter actuator {eq.actuator!r}, which a "
                f"scenario reads x3 from; add <sensor><actuatorfrc name=\"x3\" actuator=\"{eq.actuator}\"/>"
                "</sensor> to the MJCF")
    if eq.order == 3 and any(o.option for o in eq.outside):
        return (f"{label}: {'; '.join(o.what for o in eq.outside if o.option)}: realism options are not "
                "supported through a filter actuator yet; remove it from the MJCF")
    fixed = [o for o in eq.outside if o.option is None]
    if fixed:
        return f"{label}: {'; '.join(f'{o.what}: {o.fix}' for o in fixed)} (outside eq. (1)'s smooth form)"
    if eq.unexplained > TOLERANCE:
        return (f"{label}: MuJoCo's acceleration differs from the derived equation by up to "
                f"{eq.unexplained:.3g} (relative) at sampled states: the model has physics qcontrol does not "
                "read; remove it, or describe it in [plant] by hand")
    return None


def _model_reference(model: Path, out: Path) -> str:
    """The model as the scenario names it: ``qcontrol:models/...`` when shipped, else its path
    relative to the scenario's folder."""
    return shipped_label(model) or Path(os.path.relpath(model.resolve(), out.resolve().parent)).as_posix()


def _toml_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _strings(items: list[str]) -> str:
    return "[" + ", ".join(_toml_string(i) for i in items) + "]"


def scenario_text(eq: ModelEquation, model: Path, out: Path, command: str, input_gain: bool = True) -> str:
    """The scenario of ``eq`` (the model file ``model``), to be written at ``out``; ``command``
    is the command line named in its header. Raises :class:`QcontrolInputError` where none can
    run (:func:`scenario_problem`). ``input_gain``: write ``plant.input_gain = b`` (u is then the
    actuator's command) instead of the default b = 1 (u an acceleration)."""
    problem = scenario_problem(eq, str(model))
    if problem is not None:
        raise QcontrolInputError(problem)
    if eq.order == 3:
        return filter_scenario_text(eq, model, out, command)
    terms = [(t.phi, t.theta, t.bound, t.source) for t in eq.terms] or [NO_TERM]
    names = [f"phi{i + 1}" for i in range(len(terms))]
    position, force, mass = eq.units
    lines = [
        f"# Written by `{command}`: the equation {model.name} realises for joint {eq.joint!r},",
        "#     x1' = x2,   x2' = b u + theta^T phi(x)",
        f"# with I = {eq.inertia!r} {mass} (mj_fullM) and b = gear / I = {eq.input_gain!r}. Every term is",
        "# MuJoCo's own (native_terms): its ODE twin integrates the same equation. Each theta may be",
        "# written \"model\" instead: the coefficient is then read from the model when the scenario loads.",
        *(f"#   {n} = {phi}: {source}" for n, (phi, _, _, source) in zip(names, terms, strict=True)),
        *(f"# outside eq. (1): {o.what}; {o.fix}" for o in eq.outside),
        "", "[scenario]", f"name = {_toml_string(model.stem)}",
        f"description = {_toml_string(f'The one-joint MJCF model {model.name} under the law (44)-(45)')}",
        "", "[plant]", "order = 2", f"phi = {_strings([t[0] for t in terms])}",
        "theta = [" + ", ".join(repr(t[1]) for t in terms) + "]",
    ]
    if input_gain:
        lines.append(f"input_gain = {eq.input_gain!r}  # b = gear / I: u is the actuator's command ({force})")
    lines += [
        "x0 = [0.3, 0.3]", "", "[plant.mujoco]", f"model = {_toml_string(_model_reference(model, out))}",
        f"joint = {_toml_string(eq.joint)}", f"position_sensor = {_toml_string(eq.position_sensor or '')}",
        f"velocity_sensor = {_toml_string(eq.velocity_sensor or '')}",
        f"actuator = {_toml_string(eq.actuator)}",
        f"native_terms = {_strings(names)}",
        *(f"{o.option[0]} = {o.option[1]!r}  # {o.what}: a realism option" for o in eq.outside if o.option),
        "", "[quantizer]  # what the controller reads of x1 and x2: a uniform quantizer per channel, eq. (3)",
        'kind = "uniform"', f"delta = [0.01, 0.01]  # [{position}, {position}/s]",
        "", "[controller]", 'kind = "proposed"  # the paper\'s law (44)-(45), with its Example 2 settings',
        "c = [4.0, 3.0]", "",
        "[controller.proposed]", "kappa_margin = 1.1  # kappa = 1.1 + L", "gamma = 1.0", "sigma = 1.0",
        f"r = {_strings([t[2] for t in terms])}  # |phi_i(x)| <= beta_i r_i(q) near q, eqs. (37)-(43)", "",
        "[reference]", 'kind = "sine"', "amplitude = 1.0", "frequency = 1.5", "",
        "[simulation]", "duration = 10.0", "dt = 0.001",
        'backend = "mujoco"  # --backend ode: its ODE twin', "",
    ]
    return "\n".join(lines)


def filter_scenario_text(eq: ModelEquation, model: Path, out: Path, command: str) -> str:
    """:func:`scenario_text` for a joint driven through a filter actuator (order 3): the regressor
    rows of the joint's terms (x2') and of the filter's (x3'), every term native, b = gear / (I tau)
    stated, all three readings quantized, the tuning-function law (the plant is in the
    strict-feedback class, not the paper's chain, wherever the joint has a term)."""
    terms = list(eq.all_terms)
    names = [f"phi{i + 1}" for i in range(len(terms))]
    zero = ["0"] * len(terms)
    rows = [zero, [t.phi if t in eq.terms else "0" for t in terms],
            [t.phi if t in eq.filter_terms else "0" for t in terms]]
    position, force, mass = eq.units
    lines = [
        f"# Written by `{command}`: the equation {model.name} realises for joint {eq.joint!r}",
        f"# driven through the filter actuator {eq.actuator!r} (order 3, x3 = (gear / I) act):",
        "#     x1' = x2,   x2' = x3 + theta^T phi_2(x),   x3' = b u + theta^T phi_3(x)",
        f"# with I = {eq.inertia!r} {mass} (mj_fullM), tau = {eq.tau!r} s and b = gear / (I tau) =",
        f"# {eq.input_gain!r}. Every term is MuJoCo's own (native_terms): its ODE twin integrates the same",
        "# equation. A term in x2' puts the plant outside the paper's chain class: the tuning-function law.",
        *(f"#   {n} = {t.phi}: {t.source}" for n, t in zip(names, terms, strict=True)),
        "", "[scenario]", f"name = {_toml_string(model.stem)}",
        "description = " + _toml_string(f"The MJCF model {model.name} through its filter actuator, "
                                        "tuning-function law"),
        "", "[plant]", "order = 3", "phi = [" + ", ".join(_strings(row) for row in rows) + "]",
        "theta = [" + ", ".join(repr(t.theta) for t in terms) + "]",
        f"input_gain = {eq.input_gain!r}  # b = gear / (I tau): u is the actuator's command ({force})",
        "x0 = [0.3, 0.0, 0.0]", "", "[plant.mujoco]", f"model = {_toml_string(_model_reference(model, out))}",
        f"joint = {_toml_string(eq.joint)}", f"position_sensor = {_toml_string(eq.position_sensor or '')}",
        f"velocity_sensor = {_toml_string(eq.velocity_sensor or '')}",
        f"activation_sensor = {_toml_string(eq.activation_sensor or '')}",
        f"actuator = {_toml_string(eq.actuator)}", f"native_terms = {_strings(names)}",
        "", "[quantizer]  # what the controller reads of x1, x2, x3: uniform per channel, eq. (3)",
        'kind = "uniform"', f"delta = [0.01, 0.01, 0.01]  # [{position}, {position}/s, {position}/s^2]",
        "", "[controller]", 'kind = "tuning"  # the tuning-function law at the quantized readings',
        "c = [10.0, 10.0, 10.0]", "", "[controller.tuning]", "gamma = 1.0", "sigma = 0.0", "",
        "[reference]", 'kind = "sine"', "amplitude = 0.5", "frequency = 1.0", "",
        "[simulation]", "duration = 10.0", "dt = 0.001",
        'backend = "mujoco"  # --backend ode: its ODE twin', "",
    ]
    return "\n".join(lines)
