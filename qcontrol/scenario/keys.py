"""Every key of a scenario file, declared once (see :mod:`qcontrol.schema`).

The top-level tables are declared here; the keys of each controller kind, reference kind and
plant backend are declared by the kind's own module and collected from the registries, so a law
or backend registered later takes part in validation (and in the documentation) like a built-in.
"""

from __future__ import annotations

from ..controller.law import LAW_KINDS
from ..engine.velocity import VELOCITY_SOURCES
from ..error_rate import TABLE1_OMEGAS, TABLE1_SAMPLES
from ..plants.backends import BACKENDS
from ..reference import REFERENCE_KINDS
from ..schema import (
    OPTIONAL,
    Key,
    KindKeys,
    Section,
    expression,
    expressions,
    integer,
    number,
    numbers,
    string,
)

TOP = ("scenario", "plant", "controller", "reference", "simulation", "metrics", "disturbance")
REQUIRED_TABLES = ("plant", "controller", "reference", "simulation")
# The engine keeps what a run needs in memory that does not grow with the run, but a full record
# (compare, reproduce, --save) keeps every row: 20 million steps is a few GB. Longer runs are
# refused at load instead of failing mid-way.
MAX_STEPS = 20_000_000


def scenario_section(default_name: str = "the file name") -> Section:
    return Section("scenario", (
        Key("name", string(), default_name, meaning="the scenario's name in outputs"),
        Key("description", string(), "", meaning="what it models"),
    ), "what the scenario is")


PLANT = Section(
    "plant",
    (
        Key("order", integer(2), meaning="n >= 2: x1' = x2, ..., xn' = u + psi + theta^T phi, eq. (1)"),
        Key("psi", expression("x1..xn"), OPTIONAL,
            meaning="the unknown term psi(x) (never seen by the controller)"),
        Key("phi", expressions("x1..xn"), [],
            meaning="known functions phi_i(x) of the uncertain term theta^T phi"),
        Key("theta", numbers("l"), [], meaning="the unknown constants theta_i, one per phi_i"),
        Key("x0", numbers("n"), unit="state", meaning="initial state x(0)"),
    ),
    "the plant of eq. (1); [plant.<backend>] sub-tables hold each backend's model",
)


def controller_section() -> Section:
    """``[controller]``: the keys every kind takes, and each registered kind's own keys."""
    return Section(
        "controller",
        (
            Key("kind", string(tuple(LAW_KINDS)), "proposed", meaning="the control law"),
            Key("delta", number(positive=True), unit="state", meaning="quantizer step delta, eq. (3)"),
            Key("c", numbers("n", positive=True), meaning="backstepping gains c_1..c_n > 0, eqs. (7)-(27)"),
        ),
        "the control law; settings of kinds not chosen may sit in [controller.<kind>]",
        {name: kind.keys or KindKeys(name, (), "a law registered from Python") for name,
         kind in LAW_KINDS.items()},
    )


def reference_section() -> Section:
    return Section(
        "reference",
        (Key("kind", string(tuple(REFERENCE_KINDS)), "sine", meaning="the reference signal y_d"),),
        "the reference y_d (Assumption 3: its derivatives up to order n are known)",
        {name: kind.keys for name, kind in REFERENCE_KINDS.items()},
    )


def simulation_section() -> Section:
    return Section(
        "simulation",
        (
            Key("duration", number(positive=True), unit="s", meaning="simulated time T"),
            Key("dt", number(positive=True), unit="s", meaning="fixed RK4 step; u is held over each step"),
            Key("control_period", number(positive=True), OPTIONAL, "s",
                "the controller samples every control_period (a multiple of dt; default dt) and holds u"),
            Key("backend", string(tuple(BACKENDS)), "ode", meaning="the plant backend (a [plant.<backend>] "
                "table holds its model)"),
            Key("state_bound", number(positive=True), 1e6, "state",
                "|x_i| beyond this stops the run as diverged"),
            Key("velocity_source", string(VELOCITY_SOURCES), "sensor",
                meaning="the controller's x2: the velocity sensor's reading, quantized (the paper), or the "
                "quantized position differenced over the control period (an encoder only; outside the "
                "paper's assumptions)"),
        ),
        "how the closed loop is run",
    )


METRICS = Section(
    "metrics",
    (
        Key("omega", numbers(positive=True), list(TABLE1_OMEGAS), "y",
            "thresholds omega of the error rate E(omega) = #{i: |z_1(t_i)| > omega} / M (Table 1)"),
        Key("samples", integer(2), TABLE1_SAMPLES,
            meaning="samples M of the error rate, at t_i = i T / (M - 1)"),
    ),
    "what a run reports: the error rate's thresholds and samples (default: the paper's Table 1)",
)
