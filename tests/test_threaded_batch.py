"""Batches on ``mujoco.batch`` give the numbers of one MjData per copy, blow-ups included."""

from __future__ import annotations

import pathlib

import pytest
from conftest import ROOT

from qcontrol.assembly import batch_structure, build_plant, build_plants, run_variants
from qcontrol.compiled import ENVIRONMENT_SWITCH
from qcontrol.plants.mujoco.plant import MujocoPlant
from qcontrol.scenario import load_scenario

SCENARIOS = [p for p in sorted(ROOT.glob("scenarios/*.toml"))  # MuJoCo's: order 2, with a MuJoCo twin
             if load_scenario(p).order == 2 and "mujoco" in load_scenario(p).backends]


def variants(path: pathlib.Path, extra: list[str], x0s: tuple[str, ...] = ("[0.3, 0.3]", "[-0.5, 0.2]",
                                                                          "[1.0, -1.0]", "[0.0, 0.0]"),
             duration: float = 0.3) -> list:
    return [load_scenario(path, [f"simulation.duration={duration}", f"plant.x0={x0}", *extra]) for x0 in x0s]


def compare_batches(scs: list, monkeypatch: pytest.MonkeyPatch) -> tuple[list, list]:
    threaded_plant = build_plant(scs[0], "mujoco", batch=len(scs))
    threaded = run_variants(scs, "mujoco", plant=threaded_plant)
    with monkeypatch.context() as patch:
        patch.setenv(ENVIRONMENT_SWITCH, "0")
        per_copy_plant = build_plant(scs[0], "mujoco", batch=len(scs))
        assert per_copy_plant._threaded is None
        per_copy = run_variants(scs, "mujoco", plant=per_copy_plant)
    for a, b in zip(threaded, per_copy, strict=True):
        assert a.diverged == b.diverged and a.steps == b.steps
        for name in ("x", "x_meas", "u", "adaptive"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name
    assert threaded_plant.warnings == per_copy_plant.warnings
    return threaded_plant, threaded


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_threaded_batch_equals_one_mjdata_per_copy(path: pathlib.Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    scs = variants(path, [])
    plant, _ = compare_batches(scs, monkeypatch)
    plain_sensors = not plant.model.nhistory and not plant.model.sensor_cutoff.any()
    # sensor delays keep one MjData per copy; so do terms in t (evaluated at data.time in Python)
    assert (plant._threaded is not None) == (plain_sensors and not scs[0].terms.timed)


def test_a_copy_mujoco_resets_stops_as_on_the_per_copy_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """exp(x2)^2 at x2 = 30 is ~1e26: MuJoCo resets that copy at once (warning counters), the
    others run on; over 0.3 s they blow up too, each at the row of the per-copy path."""
    path = ROOT / "scenarios" / "example1.toml"
    unstable = ['plant.psi="exp(x2)**2"', "simulation.state_bound=1e30"]
    x0s = ("[0.3, 0.3]", "[-0.5, 0.2]", "[0.8, 30.0]", "[0.0, 0.0]")
    plant, runs = compare_batches(variants(path, unstable, x0s, duration=0.1), monkeypatch)
    assert plant._threaded is not None
    assert [r.diverged for r in runs] == [False, False, True, False]
    plant, runs = compare_batches(variants(path, unstable, x0s, duration=0.3), monkeypatch)
    assert all(r.diverged for r in runs) and len({r.steps for r in runs}) == 4
    assert plant.warnings and "unstable" in plant.warnings[0]


def assert_batch_equals_single_runs(scs: list) -> MujocoPlant:
    """One batch of variants against each variant run alone (its own plant of one copy)."""
    batch_plant = build_plants(scs, "mujoco")
    batched = run_variants(scs, "mujoco", plant=batch_plant)
    for sc, a in zip(scs, batched, strict=True):
        (b,) = run_variants([sc], "mujoco")
        assert a.diverged == b.diverged and a.steps == b.steps
        for name in ("x", "x_meas", "u", "adaptive"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (sc.x0, name)
    return batch_plant


THETA_AND_SEEDS = [("[-1.0, -3.5, -34.3]", 1), ("[-1.0, 3.5, -34.3]", 2), ("[-1.0, -7.0, -34.3]", 3),
                   ("[-1.0, 0.0, -34.3]", 1)]


@pytest.mark.parametrize("name, on_batch", [("example2", True), ("example2-arm", False)])
def test_theta_and_noise_seed_per_copy_equal_single_runs(name: str, on_batch: bool) -> None:
    """Example 2's theta2 (the passive callback's term) and the noise seed differ per copy: one
    batch, on mujoco.batch (no sensor history) or one MjData per copy (the arm's delay), gives
    each variant the numbers of its run alone."""
    path = ROOT / "scenarios" / f"{name}.toml"
    noise = ["plant.mujoco.sensor_noise=[0.001, 0.05]"]
    scs = [load_scenario(path, ["simulation.duration=0.4", "disturbance=[]", f"plant.theta={theta}",
                                f"plant.mujoco.noise_seed={seed}", *noise])
           for theta, seed in THETA_AND_SEEDS]
    assert len({batch_structure(sc, "mujoco") for sc in scs}) == 1  # one batch
    plant = assert_batch_equals_single_runs(scs)
    assert (plant._threaded is not None) == on_batch
    # the copies really differ: theta2's sign changes the path, and so does the seed's noise
    assert len({r.x_meas.tobytes() for r in run_variants(scs, "mujoco", plant=plant)}) == len(scs)


def test_the_theta_of_a_native_term_splits_the_batch() -> None:
    """theta1 is the model's damping: variants that differ there cannot share one model."""
    path = ROOT / "scenarios" / "example2.toml"
    a, b = (load_scenario(path, [f"plant.theta={t}", "plant.mujoco.parameters={damping = 2.0}"])
            for t in ("[-2.0, -3.5, -34.3]", "[-2.0, 3.5, -34.3]"))
    c = load_scenario(path)
    assert batch_structure(a, "mujoco") == batch_structure(b, "mujoco") != batch_structure(c, "mujoco")
