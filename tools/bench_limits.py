"""The physical limits tools/bench.py measures against, and what its parts share: a bare C
``mj_step`` loop of the plant's model (no passive callback), and a compiled (numba) bare RK4 loop of
the ODE's right-hand side (eq. (1) with u = 0 held); the shipped scenarios by name."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from qcontrol.plants.mujoco.callbacks import untimed
from qcontrol.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parent.parent

SCENARIOS = ("example1", "example2")


def scenario(name: str, duration: float, dt: float | None = None) -> Scenario:
    overrides = [f"simulation.duration={duration!r}"] + ([f"simulation.dt={dt!r}"] if dt else [])
    return load_scenario(ROOT / "scenarios" / f"{name}.toml", overrides)


def mj_step_loop(plant, steps: int, installed: bool) -> Callable[[], None]:
    """``steps`` calls of ``mj_step`` on the plant's first copy, at rest at x = 0 with no input (an
    equilibrium of both examples), with the plant's passive callback installed or with none."""
    model, data = plant.model, plant._datas[0]

    def loop() -> None:
        if installed:
            with plant:
                plant.reset(np.zeros((plant.batch, 2)))
                for _ in range(steps):
                    mujoco.mj_step(model, data)
        else:  # (without the bindings' profiling timer, as a run steps: the physics alone)
            with untimed():
                plant.reset(np.zeros((plant.batch, 2)))
                for _ in range(steps):
                    mujoco.mj_step(model, data)

    return loop


def compiled_rk4(sc: Scenario) -> Callable[[int], None]:
    """The physical limit of the ODE backend: a numba loop of classical RK4 steps of the same
    right-hand side (eq. (1) with u = 0 held), generated from the plant's expression trees."""
    import numba

    from qcontrol.expr.source import FLAG, Statements, float_source

    terms, n = sc.terms, sc.order
    names = [f"s{i}" for i in range(n)]
    body = Statements("t")
    total = float_source(terms.psi._tree, names, body) if terms.psi is not None else "0.0"
    for theta, phi in zip(terms.theta, terms.phi, strict=True):
        total = body.temporary(f"{total} + {float(theta)!r} * {float_source(phi._tree, names, body)}")
    lines = [f"{FLAG} = False", *body.lines, f"return {total}"]
    xs, args = ", ".join(f"x{i}" for i in range(n)), ", ".join(f"y{i}" for i in range(n))

    def stage(k: str, scale: str) -> list[str]:  # y = x + scale * k, then k' = rhs(y)
        return [f"y{i} = x{i} + {scale} * {k}{i}" for i in range(n)]

    def rhs(k: str, state: str) -> list[str]:
        return [f"{k}{i} = {state}{i + 1}" for i in range(n - 1)] + [f"{k}{n - 1} = g({state})"]

    loop = [*rhs("a", "x").copy(), *stage("a", "half"), *rhs("b", "y"), *stage("b", "half"), *rhs("c", "y"),
            *stage("c", "h"), *rhs("d", "y")]
    loop = [line.replace("g(x)", f"g({xs})").replace("g(y)", f"g({args})") for line in loop]
    loop += [f"x{i} = x{i} + sixth * (a{i} + 2.0 * (b{i} + c{i}) + d{i})" for i in range(n)]
    source = (f"def g({', '.join(names)}):\n" + "".join(f"    {line}\n" for line in lines)
              + f"def rk4({xs}, h, steps):\n    half, sixth = 0.5 * h, h / 6.0\n"
              + "    for _ in range(steps):\n" + "".join(f"        {line}\n" for line in loop)
              + "    return x0\n")
    namespace = {"math": math}
    exec(compile(source, "<bench rk4>", "exec"), namespace)  # our own generated text
    namespace["g"] = numba.njit(error_model="numpy")(namespace["g"])
    rk4 = numba.njit(error_model="numpy")(namespace["rk4"])
    x0, h = [0.0] * n, sc.simulation.dt  # at rest (an equilibrium of the examples), as the mj_step loop
    rk4(*x0, h, 1)  # compiled here, not timed

    return lambda steps: rk4(*x0, h, steps)
