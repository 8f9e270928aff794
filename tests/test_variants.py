"""Variants of one scenario loaded together (sweeps, region maps, studies) are each exactly the
scenario that loading the file with its overrides alone gives: what they share is checked once,
and nothing else changes (values, types, float bits, the data a provenance states, messages)."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest

from qcontrol.assembly import batch_structure
from qcontrol.errors import QcontrolInputError
from qcontrol.scenario import load_scenario
from qcontrol.scenario.load import load_variants
from qcontrol.scenario.resolve import resolved_toml
from qcontrol.sharing import exact, sharing
from qcontrol.sweep.runs import planned

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE2 = ROOT / "scenarios" / "example2.toml"

# each touches a different part: the law's number (an int, then a float equal to it), x(0) (with
# a negative zero), the simulation, the kind (a different structure), the gains c (Lemma 2's L),
# coefficients left to the MuJoCo model (written into the data), the noise of the MuJoCo plant,
# a sub-table's key, the file as it is; some repeated, so that later variants reuse the first's
SETS = [
    ["controller.kappa_margin=0.5"],
    ["controller.kappa_margin=1"],
    ["controller.kappa_margin=1.0"],
    ["plant.x0=[-0.0, 0.25]"],
    ["plant.x0=[0.0, 0.25]"],
    ["simulation.duration=2.0", "controller.kappa_margin=0.5"],
    ["controller.kind=comparison"],
    ["controller.c=[5.0, 2.0]"],
    {"plant.theta": ["model", -3.5, "model"], "plant.input_gain": "model"},
    ["plant.mujoco.sensor_noise=0.001", "plant.mujoco.noise_seed=3"],
    ["controller.proposed.r_scale=2.0"],
    [],
    ["plant.x0=[-0.0, 0.25]"],
    ["controller.kappa_margin=0.5"],
    {"plant.theta": ["model", -3.5, "model"], "plant.input_gain": "model"},
]


def _same(together, alone) -> None:
    assert together == alone
    assert repr(together) == repr(alone)
    assert exact(together.data) == exact(alone.data)  # types and float bits of every value
    assert exact((together.x0, together.theta)) == exact((alone.x0, alone.theta))
    assert resolved_toml(together) == resolved_toml(alone)
    for backend in ("ode", "mujoco"):
        assert batch_structure(together, backend) == batch_structure(alone, backend)


def test_variants_loaded_together_are_each_the_scenario_loaded_alone() -> None:
    together = load_variants(EXAMPLE2, SETS, unset=["reference.amplitude"])
    assert len(together) == len(SETS)
    for overrides, variant in zip(SETS, together, strict=True):
        _same(variant, load_scenario(EXAMPLE2, overrides, ["reference.amplitude"]))
    # what the overrides changed is there, the rest shared: x(0)'s sign bit, the resolved model
    assert math.copysign(1.0, together[3].x0[0]) == -1.0 and math.copysign(1.0, together[4].x0[0]) == 1.0
    assert together[1].data["controller"]["kappa_margin"] == 1 and \
        type(together[1].data["controller"]["kappa_margin"]) is int
    assert type(together[2].data["controller"]["kappa_margin"]) is float
    assert together[8].theta[0] != "model" and together[8].data["plant"]["theta"][1] == -3.5
    assert together[0].data["plant"] is together[13].data["plant"]  # one view of a table both share
    # a sweep's planned variants are these very scenarios
    chunks, variants = planned(EXAMPLE2, SETS[:3], "ode")
    assert [v.controller.settings.kappa for v in variants] == \
        [s.controller.settings.kappa for s in together[:3]]


def test_a_bad_variant_is_refused_with_the_line_it_gets_alone(tmp_path: Path) -> None:
    for bad in (["controller.kappa_margin=-1"], ["plant.x0=[0.1]"], ["plant.x0=[0.1, true]"]):
        sets = [["plant.x0=[0.2, 0.3]"], ["controller.kappa_margin=0.5"], bad, ["plant.x0=[0.5, 0.0]"]]
        with pytest.raises(QcontrolInputError) as alone:
            load_scenario(EXAMPLE2, bad)
        with pytest.raises(QcontrolInputError) as together:
            load_variants(EXAMPLE2, sets)
        assert str(together.value) == str(alone.value)
    # a start where a term of the plant is not finite is refused, though its other stages are shared
    path = tmp_path / "singular.toml"
    path.write_text(EXAMPLE2.read_text().replace('phi = ["x2",', 'psi = "1/x1"\nphi = ["x2",').replace(
        'r = ["1 + q2**2", "1 + 2*q2**2", "1"]', 'r = ["1 + q2**2", "1 + 2*q2**2", "1", "1"]'))
    starts = [["plant.x0=[0.5, 0.0]"], ["plant.x0=[0.0, 0.0]"]]
    with pytest.raises(QcontrolInputError) as alone:
        load_scenario(path, starts[1])
    with pytest.raises(QcontrolInputError) as together:
        load_variants(path, starts)
    assert str(together.value) == str(alone.value) and "not finite at x0" in str(alone.value)


def test_exact_keys_tell_apart_what_equality_does_not() -> None:
    assert exact(1) != exact(1.0) != exact(True)
    assert exact(0.0) != exact(-0.0)
    assert exact([1.0, 2.0]) != exact((1.0, 2.0))
    assert exact({"a": [1.0, {"b": "x"}]}) == exact({"a": [1.0, {"b": "x"}]})
    assert exact({"a": 1.0, "b": 2.0}) != exact({"b": 2.0, "a": 1.0})  # order is what a file states


def test_only_loads_together_share_a_model_file_read(tmp_path: Path) -> None:
    """Outside a batch of variants every load reads its files afresh: a model file broken between
    two loads is refused by the second."""
    shutil.copy(ROOT / "models" / "pendulum.xml", tmp_path / "pendulum.xml")
    path = tmp_path / "s.toml"
    path.write_text(EXAMPLE2.read_text().replace("qcontrol:models/pendulum.xml", "pendulum.xml"))
    with sharing():
        first = load_scenario(path)
        (tmp_path / "pendulum.xml").write_text("<mujoco><worldbody></mujoco>")
        assert load_scenario(path) == first  # inside one batch, read once
    with pytest.raises(QcontrolInputError, match="pendulum.xml"):
        load_scenario(path)
