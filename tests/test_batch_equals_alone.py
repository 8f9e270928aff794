"""A batch of copies in the Python loop (terms in t, which the compiled batch does not take; other
quantizers) gives every copy the numbers of its run alone, bit for bit: every signal, every field
and every metric, the full record and the metrics-only one. numpy's own pow, exp, ... round
otherwise than the math a run alone steps with, so this fails where the batch's loop calls them."""

import dataclasses
import math

import numpy as np
import pytest
from conftest import SCENARIOS

from qcontrol.assembly import assemble
from qcontrol.engine import ClosedLoop
from qcontrol.expr import compile_expression
from qcontrol.scenario import load_scenario

# x1**3 and abs(q1)**3 (pow), 2.1*cos(1.8*t): the forced Duffing oscillator's terms and bounds
SENSORS = {
    "uniform": [],
    "logarithmic": ['quantizer.kind="logarithmic"', "quantizer.rho=0.9", "quantizer.u_min=0.002"],
    "input": ["quantizer.delta=0.01", "quantizer.input.delta=0.0001"],
}


def _variants(extra: list[str]) -> list:
    """Four copies of the Duffing oscillator, 0.4 s, differing in x(0) and kappa's margin."""
    starts = [[0.5, 0.0], [-0.83, 0.61], [0.27, -0.94], [1.3, 0.2]]
    unset = ["controller.delta"] if extra else []
    return [load_scenario(SCENARIOS / "duffing.toml", ["simulation.duration=0.4", f"plant.x0={x0!r}",
                                                       f"controller.kappa_margin={m!r}", *extra], unset=unset)
            for x0, m in zip(starts, (1.0, 0.37, 2.2, 0.81), strict=True)]


def _bits(value) -> object:
    """``value`` with every float as its bits (arrays as bytes), for an exact comparison."""
    if isinstance(value, dict):
        return {k: _bits(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_bits(v) for v in value]
    if isinstance(value, (float, np.floating, np.ndarray)):
        array = np.asarray(value, dtype=float)
        return (array.shape, array.tobytes())
    return value


def _record(run) -> dict:
    fields = {k: v for k, v in vars(run).items() if k != "wall_time_s"}
    return _bits({**fields, "reduced": run.reduced()})


def _run(scs: list, record: str) -> list:
    spec = dataclasses.replace(assemble(scs, "ode").spec, record=record)
    loop = ClosedLoop(spec)
    assert loop.compiled is None  # the Python loop, which this is about
    return loop.run()


@pytest.mark.parametrize("sensors", list(SENSORS))
def test_each_copy_of_a_batch_is_its_run_alone_bit_for_bit(sensors: str) -> None:
    scs = _variants(SENSORS[sensors])
    for record in ("full", "metrics"):
        together = _run(scs, record)
        for sc, copy in zip(scs, together, strict=True):
            alone = _run([sc], record)[0]
            assert _record(copy) == _record(alone), (record, sc.x0)
    assert len({copy.reduced()["max_abs_u"] for copy in together}) == len(scs)  # four different runs


def test_expressions_on_copies_are_their_float_values_bit_for_bit() -> None:
    """Each element of an expression evaluated on a batch's columns is the float evaluation's (a
    run alone's), NaN, Inf, signed zeros and math's refusals (numpy's answer then) included."""
    rng = np.random.default_rng(3)
    special = [0.0, -0.0, math.inf, -math.inf, math.nan, 1e300, -1e-300, 2.0, -1.5]
    x1, x2 = (rng.permutation(np.concatenate([rng.normal(0, 3, 300), special])) for _ in range(2))
    sources = ["x1**3 + abs(x2)**1.5", "exp(x1) - tanh(x2) * log(x2)", "x1/x2 + sqrt(x1)", "min(x1, x2, 0)",
               "max(x1, -x2)", "spow(x1, 1/3) * cbrt(x2)", "tan(x1) + 2.1*cos(1.8*x2)", "exp(2) * x1**x2"]
    with np.errstate(all="ignore"):
        for source in sources:
            e = compile_expression(source, ["x1", "x2"])
            got = np.broadcast_to(e.on_copies([x1, x2]), x1.shape)
            wanted = np.array([e.on_floats(copy) for copy in zip(x1.tolist(), x2.tolist(), strict=True)])
            assert got.tobytes() == wanted.tobytes(), source
            shared = np.broadcast_to(e.on_copies([x1, 0.75]), x1.shape)  # a number beside a column
            assert shared.tobytes() == np.array([e.on_floats([v, 0.75]) for v in x1.tolist()]).tobytes()
