"""Every key of a scenario file, declared once (see :mod:`qcontrol.schema`).

The top-level tables are declared here; the keys of each controller kind, reference kind and
plant backend are declared by the kind's own module and collected from the registries, so a law
or backend registered later takes part in validation (and in the documentation) like a built-in.
"""

from __future__ import annotations

from ..controller.law import LAW_KINDS
from ..disturbance import SECTION as DISTURBANCE
from ..engine.velocity import VELOCITY_SOURCES
from ..error_rate import TABLE1_OMEGAS, TABLE1_SAMPLES
from ..errors import shown
from ..plants.backends import BACKENDS
from ..quantizers import QUANTIZER
from ..reference import REFERENCE_KINDS
from ..schema import (
    OPTIONAL,
    Key,
    Section,
    Table,
    custom,
    expression,
    expressions,
    integer,
    number,
    numbers,
    string,
)
from .from_model import read_input_gain, read_theta

# see top_sections()
TOP = ("scenario", "plant", "controller", "quantizer", "reference", "simulation", "metrics", "disturbance")
# `qcontrol run` keeps only its metrics (memory that does not grow with the run), but a full record
# (compare, reproduce, the library's default) keeps every row: 20 million steps is a few GB. Longer
# runs are refused at load, by every command, instead of failing mid-way.
MAX_STEPS = 20_000_000
MAX_SAMPLES = 10_000_000  # metrics.samples: the error rate keeps a flag per sample and copy


PAPER_EXAMPLES = (1, 2)


def _paper_example(table: Table, key: str, default: object, sizes: object) -> int | None:
    value = table.get(key, default)
    if value is not None and (isinstance(value, bool) or value not in PAPER_EXAMPLES):
        raise table.error(key, f"must be 1 or 2 (the paper's Examples 1 and 2), got {value!r}",
                          "write paper_example = 2, or leave the key out")
    return value


def _printable(table: Table, key: str, default: object, sizes: object) -> str:
    """A string with no control characters: the name is printed on terminals, which would act on
    an escape sequence in it."""
    value = table.string(key, default)
    if not value.isprintable():
        raise table.error(key, f"{shown(value)} holds control characters (a terminal would act on them)",
                          'write a name of printable characters, e.g. "my-plant"')
    return value


def scenario_section(default_name: str = "the file name") -> Section:
    return Section("scenario", (
        Key("name", custom("string", _printable), default_name, meaning="the scenario's name in outputs",
            example='"my-plant"',
            default_text="the file's name without .toml"),
        Key("description", string(), "", meaning="what it models", example='"what it models"'),
        Key("paper_example", custom("1 or 2", _paper_example), OPTIONAL,
            meaning="the paper's example this scenario reproduces: a run then prints, under its "
                    "summary, what the paper reports for it (Table 1 for Example 2)"),
    ), "what the scenario is")


PLANT = Section(
    "plant",
    (
        Key("order", integer(2), meaning="n >= 2: x1' = x2, ..., xn' = u + psi + theta^T phi, eq. (1)",
            example="2"),
        Key("psi", expression("x1..xn"), OPTIONAL,
            meaning="the unknown term psi(x) (never seen by the controller)"),
        Key("phi", expressions("x1..xn"), [],
            meaning="known functions phi_i(x) of the uncertain term theta^T phi",
            example='["x2", "x2**2*cos(x1)", "sin(x1)"]'),
        Key("theta", custom("list of l numbers (or \"model\")", read_theta), [],
            meaning="the unknown constants theta_i, one per phi_i; \"model\" for a native term's: read "
            "from the MuJoCo model at load (qcontrol model prints them)",
            example="[-1.0, -3.5, -34.3]"),
        Key("x0", numbers("n"), unit="state", meaning="initial state x(0)", example="[0.3, 0.3]"),
        Key("input_gain", custom("number > 0 (or \"model\")", read_input_gain), OPTIONAL, "-",
            "the known input gain b of x_n' = b u + psi + theta^T phi (default 1); the built-in laws "
            "divide their input by it. On MuJoCo it must be what the model realises, gear / I; "
            "left out, u is scaled by the joint's inertia I so that b = 1; \"model\": gear / I read from "
            "the model at load"),
    ),
    "the plant of eq. (1); [plant.<backend>] sub-tables hold each backend's model",
)


REGISTER_A_KIND = (", or register yours: --law-module FILE (a Python file that calls qcontrol.register_law), "
                   "an installed plugin, or qcontrol.register_law from Python")


def controller_section() -> Section:
    """``[controller]``: the keys every kind takes, and each registered kind's own keys."""
    return Section(
        "controller",
        (
            Key("kind", string(tuple(LAW_KINDS), more=REGISTER_A_KIND), "proposed",
                meaning="the control law"),
            Key("delta", number(positive=True), OPTIONAL, "state",
                "quantizer step delta of every state, eq. (3) (required unless a [quantizer] table gives "
                "the quantizers)", example="0.01"),
            Key("c", numbers("n", positive=True), meaning="backstepping gains c_1..c_n > 0, eqs. (7)-(27)",
                example="[4.0, 3.0]"),
        ),
        "the control law; settings of kinds not chosen may sit in [controller.<kind>]",
        {name: kind.keys for name, kind in LAW_KINDS.items()},
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
            Key("duration", number(positive=True), unit="s", meaning="simulated time T", example="10.0"),
            Key("dt", number(positive=True), unit="s", meaning="fixed RK4 step; u is held over each step",
                example="0.001"),
            Key("control_period", number(positive=True), OPTIONAL, "s",
                "the controller samples every control_period (a multiple of dt; default dt) and holds u"),
            Key("backend", string(tuple(BACKENDS)), "ode", meaning="the plant backend (a [plant.<backend>] "
                "table holds its model)", example='"mujoco"'),
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
            "thresholds omega of the error rate E(omega) = #{i: |z_1(t_i)| > omega} / M (Table 1)",
            example="[0.05, 0.1, 0.2]"),
        Key("samples", integer(2, MAX_SAMPLES), TABLE1_SAMPLES,
            meaning="samples M of the error rate, at t_i = i T / (M - 1)", example="1302"),
    ),
    "what a run reports: the error rate's thresholds and samples (default: the paper's Table 1)",
)


def top_sections(default_name: str = "the file name") -> tuple[Section, ...]:
    """Every top-level table of a scenario file, in the order docs/scenarios.md shows them (each
    backend's ``[plant.<backend>]`` comes from the backend registry). A new table is declared here
    and named in :data:`TOP`."""
    return (scenario_section(default_name), PLANT, controller_section(), QUANTIZER, reference_section(),
            simulation_section(), METRICS, DISTURBANCE)


def required_tables() -> tuple[str, ...]:
    """The top-level tables a file must have: those with a key that has no default
    (:attr:`Section.optional <qcontrol.schema.Section.optional>`); a table whose keys all default may
    be left out."""
    return tuple(s.name for s in top_sections() if not s.array and not s.optional)
