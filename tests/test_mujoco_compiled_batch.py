"""The compiled batch of MuJoCo copies: each copy's own MjData stepped from the generated batch
loop, one copy after another between the engine's rare rows; every copy's numbers equal the array
form's batch (one MjData per copy, in Python) and its run alone to the last bit, copies that blow
up and copies with their own theta of the passive term included."""

import dataclasses
import json

import numpy as np
import pytest
from conftest import SCENARIOS

import qcontrol.engine.compiled_loop as compiled_loop
from qcontrol.assembly import assemble
from qcontrol.engine import ClosedLoop
from qcontrol.engine.compiled_batch import CompiledBatch
from qcontrol.metrics import run_summary
from qcontrol.scenario import load_scenario


@pytest.fixture(autouse=True)
def _compile_short_runs(monkeypatch) -> None:
    """Short runs here (which the engine would leave to the array form) run the compiled batch."""
    monkeypatch.setattr(compiled_loop, "MIN_ROWS", 0)
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)


def _variants() -> list:
    """Example 2 copies differing in kappa, the passive term's theta2 and x(0); the fast ones blow up."""
    x2 = [0.3, -2.0, 400.0, 1.0, 1e4, 0.0]
    theta2 = [-3.5, -3.0, -3.5, -4.0, -3.5, -2.5]
    return [load_scenario(SCENARIOS / "example2.toml",
                          ["simulation.duration=0.3", f"plant.x0=[0.3, {v!r}]",
                           f"controller.kappa_margin={m!r}", f"plant.theta=[-1.0, {t!r}, -34.3]"])
            for v, t, m in zip(x2, theta2, np.linspace(0.2, 1.6, len(x2)).tolist(), strict=True)]


def _run(scs, record: str, monkeypatch, compiled: bool = True) -> tuple[ClosedLoop, list]:
    with monkeypatch.context() as patch:
        if not compiled:
            patch.setenv("QCONTROL_COMPILE", "0")
        spec = dataclasses.replace(assemble(scs, "mujoco").spec, record=record)
        loop = ClosedLoop(spec)
        return loop, loop.run()


def _same(a, b) -> None:
    assert (a.diverged, a.divergence_reason, a.steps) == (b.diverged, b.divergence_reason, b.steps)
    for name, values in getattr(a, "signals", {}).items():
        assert np.asarray(values).tobytes() == np.asarray(b.signals[name]).tobytes(), name


def _summary(run) -> str:
    summary = run_summary(run, "x", "mujoco").to_json()
    return json.dumps({k: v for k, v in summary.items() if k != "wall_time_s"}, sort_keys=True, default=repr)


def test_every_mujoco_copy_equals_the_array_form_and_its_run_alone(monkeypatch) -> None:
    scs = _variants()
    for record in ("full", "metrics"):
        loop, compiled = _run(scs, record, monkeypatch)
        assert isinstance(loop.compiled, CompiledBatch) and loop.handover is None  # compiled to the end
        assert loop.plant._threaded is not None and not loop.plant._threads  # moved off mujoco.batch
        array_loop, array = _run(scs, record, monkeypatch, compiled=False)
        assert loop.plant.warnings == array_loop.plant.warnings and loop.plant.warnings  # MuJoCo's messages
        for a, b in zip(compiled, array, strict=True):
            _same(a, b)
            if record == "metrics":
                assert _summary(a) == _summary(b)
    stopped = [r.diverged for r in compiled]
    assert stopped[2] and stopped[4] and not stopped[0]  # some copies stopped, others ran on
    for i in (0, 2):  # runs alone, on the single compiled loop
        alone = assemble([scs[i]], "mujoco").run("metrics")[0]
        _same(compiled[i], alone)
        assert _summary(compiled[i]) == _summary(alone)
