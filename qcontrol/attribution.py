"""What makes a MuJoCo run differ from its ODE twin: each realism option of ``[plant.mujoco]`` alone.

``qcontrol compare`` runs the same controller on MuJoCo and on the ODE of eq. (1). Without realism
options they agree to about 1e-13; with them, the gap is the physics the ODE leaves out. To say
which term causes it, the MuJoCo run is repeated with each option alone on the nominal model and
compared with the same ODE twin (same controller, control period, velocity source and
disturbances). The options interact, so the parts need not add up to the whole.
"""

from __future__ import annotations

from dataclasses import replace

from .assembly import run_scenario
from .engine import Trajectory
from .metrics import backend_deviation
from .scenario import Scenario


def realism_attribution(sc: Scenario, ode: Trajectory) -> dict[str, dict]:
    """``{option: deviation of MuJoCo with that option alone from the ODE twin ode}`` for every
    realism option the scenario's ``[plant.mujoco]`` turns on (see :func:`backend_deviation`)."""
    options = sc.backends["mujoco"]
    parts = {}
    for name in options.realism:
        alone = replace(sc, backends=sc.backends | {"mujoco": options.only(name)})
        parts[name] = backend_deviation(run_scenario(alone, "mujoco"), ode)
    return parts


def attribution_lines(parts: dict[str, dict], whole: dict) -> list[str]:
    """The printed table: one line per option alone, then all of them together."""
    lines = ["MuJoCo vs ODE, each realism option alone on the nominal model (same controller):"]
    for name, d in [*parts.items(), ("all together", whole)]:
        lines.append(f"  {name:<14} max |dy| = {d['max_abs_dy']:.3g}   "
                     f"max |dx2| = {d['max_abs_dx'][-1]:.3g}   max |du| = {d['max_abs_du']:.3g}")
    return lines
