"""Batched runs equal single runs: per-copy controller parameters, per-copy theta and x0 (ODE),
and MuJoCo batches; ``record="metrics"`` gives the summaries of the full record."""


import numpy as np
import pytest
from conftest import EX2 as EXAMPLE2
from conftest import SCENARIOS

from qcontrol.assembly import build_law, build_plant, build_quantizer, build_reference, run_scenario
from qcontrol.engine import RunSpec, simulate
from qcontrol.metrics import summary
from qcontrol.plants.ode import ChainPlant
from qcontrol.scenario import load_scenario
from qcontrol.summary import Summary
from qcontrol.sweep import run_batch, sweep_summaries
from qcontrol.timegrid import TimeGrid

SHORT = ["simulation.duration=1.5"]
VARIANTS = [  # several parameter sets in one batch
    [],
    ["controller.kappa_margin=0.1"],
    ["controller.r_scale=3.0", "controller.gamma=2.0"],
    ["controller.sigma=0.25", "plant.x0=[-0.4, 1.0]"],
    ["plant.theta=[-0.5, -3.0, -30.0]", "controller.kappa_margin=0.5"],
]


def _batch(scs, record="full"):
    sc = scs[0]
    plant = ChainPlant(sc.order, sc.psi_expr, sc.phi_expr, np.array([s.theta for s in scs]), batch=len(scs))
    return simulate(RunSpec(plant=plant, law=build_law(scs), quantizer=build_quantizer(sc),
                            reference=build_reference(sc), x0=np.array([s.x0 for s in scs]),
                            grid=TimeGrid.of(sc.simulation.duration, sc.simulation.dt),
                            state_bound=sc.simulation.state_bound, record=record))


def test_batched_runs_equal_single_runs():
    scs = [load_scenario(EXAMPLE2, SHORT + v) for v in VARIANTS]
    batched = _batch(scs)
    finals = set()
    for sc, run in zip(scs, batched, strict=True):
        single = run_scenario(sc, "ode")
        assert len(single.t) == len(run.t)
        for field in ("x", "x_q", "u", "adaptive", "zbar", "e_z"):
            np.testing.assert_allclose(getattr(run, field), getattr(single, field), rtol=0, atol=1e-12,
                                       err_msg=f"{field} of {sc.overrides}")
        finals.add(round(float(run.adaptive[-1, 0]), 6))
    assert len(finals) == len(scs)  # the parameter sets really differ


def test_metrics_record_gives_the_full_summaries():
    scs = [load_scenario(EXAMPLE2, SHORT + v) for v in VARIANTS]
    for full, lean in zip(_batch(scs), _batch(scs, record="metrics"), strict=True):
        a, b = summary(full, "x", "ode"), summary(lean, "x", "ode")
        a.pop("wall_time_s"), b.pop("wall_time_s")
        assert a == b


def test_metrics_record_of_a_diverging_copy():
    scs = [load_scenario(EXAMPLE2, SHORT + ["simulation.state_bound=0.5"] + v) for v in VARIANTS[:2]]
    full, lean = _batch(scs)[0], _batch(scs, record="metrics")[0]
    assert full.diverged and lean.diverged and lean.diverged_time == full.diverged_time
    a, b = summary(full, "x", "ode"), summary(lean, "x", "ode")
    assert a["error_rate"] == b["error_rate"] and a["final_eps_hat"] == b["final_eps_hat"]
    assert a["lemma2_max_ratio"] == b["lemma2_max_ratio"] and a["max_abs_u"] == b["max_abs_u"]


def test_sweep_summaries_equal_single_runs():
    sets = [SHORT + v for v in VARIANTS]
    for overrides, s in zip(sets, sweep_summaries(EXAMPLE2, sets), strict=True):
        single = summary(run_scenario(load_scenario(EXAMPLE2, overrides), "ode"), "example2", "ode")
        assert isinstance(s, Summary)
        for key, value in single["error_rate"].items():
            assert s.error_rate[key] == pytest.approx(value, abs=1e-12)
        for key in ("max_abs_z1_last_half", "max_abs_u", "lemma2_max_ratio"):
            assert getattr(s, key) == pytest.approx(single[key], rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(s.final_eps_hat, single["final_eps_hat"], rtol=1e-12, atol=1e-12)


def test_per_copy_parameters_must_fit_the_batch():
    scs = [load_scenario(EXAMPLE2, SHORT + v) for v in VARIANTS[:2]]
    plant = build_plant(scs[0], "ode", batch=3)
    with pytest.raises(ValueError, match="per-copy parameters for 2 copies"):
        simulate(RunSpec(plant=plant, law=build_law(scs), quantizer=build_quantizer(scs[0]),
                         reference=build_reference(scs[0]), x0=scs[0].x0, grid=TimeGrid.of(0.01, 0.001)))


MUJOCO_TOLERANCE = 1e-12  # the batch runs each copy with the single run's code: same numbers


@pytest.mark.parametrize("name", ["example1", "example2"])
def test_mujoco_batch_agrees_with_single_mujoco_runs(name):
    path = SCENARIOS / f"{name}.toml"
    sets = [["simulation.duration=1.0"] + v for v in (
        [], ["controller.gamma=2.0"], ["plant.x0=[0.1, -0.2]", "controller.sigma=0.3"])]
    batched = run_batch([load_scenario(path, o) for o in sets], "mujoco")
    for overrides, s in zip(sets, batched, strict=True):
        single = summary(run_scenario(load_scenario(path, overrides), "mujoco"), name, "mujoco")
        assert not s.diverged
        for key, value in single["error_rate"].items():
            assert s.error_rate[key] == pytest.approx(value, abs=MUJOCO_TOLERANCE)
        for key in ("max_abs_z1_last_half", "max_abs_u", "lemma2_max_ratio"):
            assert getattr(s, key) == pytest.approx(single[key], rel=MUJOCO_TOLERANCE)
        np.testing.assert_allclose(s.final_eps_hat, single["final_eps_hat"], rtol=MUJOCO_TOLERANCE)
