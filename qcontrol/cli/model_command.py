"""``qcontrol model``: the equation a one-joint MJCF model realises, and a scenario that runs it.

    qcontrol model MODEL.xml [--joint NAME] [--scenario OUT.toml]

Prints x2' = b u + theta^T phi(x) for the model's one actuated hinge or slide joint: its inertia
I, the input gain b = gear / I, each term MuJoCo's physics produces with its coefficient to full
precision (the shortest decimal that reads back as the same double), and what the model does
outside that smooth form. ``--scenario`` writes a scenario of that plant (every term native, the
paper's law with a bounding function for each) after checking it as ``qcontrol check`` would:
nothing is written when it would not run. A joint driven through a first-order filter actuator
(``dyntype="filter"``) is a plant of order 3, x3 its scaled activation: x2' = x3 + theta^T phi_2,
x3' = b u + theta^T phi_3 with b = gear / (I tau); its scenario runs the tuning-function law.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from .. import api
from ..errors import shown
from ..outputs import check_output_file
from .arguments import EXIT_OK

if TYPE_CHECKING:  # reading a model imports mujoco: only the command itself does, not every qcontrol command
    from ..plants.mujoco.equation import ModelEquation


def add_model_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``qcontrol model`` (its handler is :func:`cmd_model`)."""
    p = sub.add_parser(
        "model",
        help="print the equation a one-joint MJCF model realises; write a scenario for it",
        description="Print the equation x2' = b u + theta^T phi(x) that MuJoCo realises for the model's "
        "one actuated hinge or slide joint (input gain b = gear / I, each term MuJoCo's physics produces "
        "with its coefficient to full precision, and what lies outside that form); with --scenario, write "
        "a scenario of it that runs as it is (checked first: nothing is written when it would not run). "
        "Through a filter actuator (dyntype=\"filter\") the equation has order 3, x3 the actuator's "
        "activation times gear / I: x2' = x3 + theta^T phi_2, x3' = b u + theta^T phi_3, b = gear / (I tau).",
    )
    p.add_argument("model", type=Path, help="an MJCF file (.xml) with one actuated hinge or slide joint")
    p.add_argument("--joint", metavar="NAME", help="the joint meant (checked: it must be the actuated one)")
    p.add_argument("--scenario", type=Path, metavar="OUT.toml", help="write a runnable scenario of the model")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def cmd_model(args: argparse.Namespace) -> int:
    """Print the model's equation; with ``--scenario``, check and write its scenario."""
    from ..plants.mujoco.model_scenario import scenario_problem

    if args.scenario is not None:
        check_output_file(args.scenario, "--scenario", "model.toml")
    eq = api.model_equation(args.model, args.joint)
    label = shown(args.model)
    if not args.quiet:
        print(equation_text(eq, label))
    if args.scenario is None:
        if scenario_problem(eq, label) is None and not args.quiet:
            print(f"a runnable scenario of it: qcontrol model {label} --scenario model.toml")
        return EXIT_OK
    out = api.model_scenario(args.model, args.scenario, args.joint, args.command_line)
    if not args.quiet:
        print(f"wrote {shown(out)}; run it: qcontrol run {shown(out)}; against its ODE twin: "
              f"qcontrol compare {shown(out)}")
    return EXIT_OK


def equation_text(eq: ModelEquation, label: str) -> str:
    """What ``qcontrol model`` prints: the equation, one line per term, what lies outside."""
    position, force, mass = eq.units
    named = (eq.position_sensor, eq.velocity_sensor, eq.activation_sensor)
    sensors = ", ".join(repr(s) for s in named if s) or "none named"
    if eq.tau is None:
        lines = [
            f"{label}: joint {eq.joint!r} ({eq.kind}), actuator {eq.actuator!r} (gear x gain {eq.gear!r}), "
            f"sensors {sensors}",
            f"  x1' = x2,  x2' = b u + theta^T phi(x)    (x1 [{position}], x2 [{position}/s], u = the "
            f"actuator's command [{force}])",
            f"  I = {eq.inertia!r} {mass}    (mj_fullM: the bodies and the armature)",
            f"  b = gear / I = {eq.input_gain!r}",
        ]
    else:
        lines = [
            f"{label}: joint {eq.joint!r} ({eq.kind}), actuator {eq.actuator!r} (gear x gain {eq.gear!r}, "
            f"dyntype filter), sensors {sensors}",
            f"  x1' = x2,  x2' = x3 + theta^T phi_2(x1, x2),  x3' = b u + theta^T phi_3(x3)    (order 3: x1 "
            f"[{position}], x2 [{position}/s], x3 = (gear / I) act, u = the actuator's command [{force}])",
            f"  I = {eq.inertia!r} {mass}    (mj_fullM: the bodies and the armature)",
            f"  tau = {eq.tau!r} s    (the filter: act' = (ctrl - act) / tau)",
            f"  b = gear / (I tau) = {eq.input_gain!r}",
        ]
    width = max([len(t.phi) for t in eq.all_terms] + [1])
    for i, t in enumerate(eq.all_terms, start=1):
        row = "" if eq.tau is None else f"  [x{3 if t in eq.filter_terms else 2}']"
        lines.append(f"  phi{i} = {t.phi:<{width}}  theta{i} = {t.theta!r:<22}{row}  {t.source}")
    if not eq.terms:
        lines.append("  (no term: MuJoCo's physics adds nothing to b u on this joint)" if eq.tau is None else
                     "  (no term in x2': MuJoCo's physics adds nothing to x3 on this joint)")
    for o in eq.outside:
        lines.append(f"  outside the smooth form: {o.what}; {o.fix}")
    if not eq.outside:
        lines.append("  outside the smooth form: nothing (no friction, limits, force clamp, contact, fluid)")
    return "\n".join(lines)
