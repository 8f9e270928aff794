"""Batches on ``mujoco.batch`` give the numbers of one MjData per copy, blow-ups included."""

from __future__ import annotations

import pathlib

import pytest

from qcontrol.assembly import build_plant, run_variants
from qcontrol.compiled import ENVIRONMENT_SWITCH
from qcontrol.scenario import load_scenario

ROOT = pathlib.Path(__file__).resolve().parent.parent
SCENARIOS = [p for p in sorted(ROOT.glob("scenarios/*.toml")) if load_scenario(p).order == 2]  # MuJoCo's


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
    assert (plant._threaded is not None) == plain_sensors  # sensor delays keep one MjData per copy


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
