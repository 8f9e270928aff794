"""A run is put together once (:func:`qcontrol.assembly.assemble`): the API, the command line,
recordings and ``qcontrol check`` read the parts of that one assembly instead of building them
again. Each builder is counted through the registries and the assembly module while whole
commands run."""

from __future__ import annotations

import dataclasses
import importlib.util
import re
from collections import Counter
from pathlib import Path

import pytest
from conftest import EX2, PACKAGE

import qcontrol
from qcontrol import assembly
from qcontrol.cli import main
from qcontrol.controller import LAW_KINDS
from qcontrol.plants import BACKENDS

SHORT = ["--duration", "0.05", "-q"]
ONCE = ("assemble", "runnable_backend", "law", "separation", "quantizer", "reference", "loads")


def _counted(counts: Counter, name: str, function):
    def counting(*args, **kwargs):
        counts[name] += 1
        return function(*args, **kwargs)

    return counting


@pytest.fixture
def builds(monkeypatch) -> Counter:
    """How often each part of a run is built: the plant and the scene of each backend, the law of
    each kind, and the assembly's own builders (an assembly makes one run spec)."""
    counts: Counter = Counter()
    for name, backend in list(BACKENDS.items()):
        scene = backend.scene and _counted(counts, f"scene {name}", backend.scene)
        monkeypatch.setitem(BACKENDS, name, dataclasses.replace(
            backend, build=_counted(counts, f"plant {name}", backend.build), scene=scene))
    for name, kind in list(LAW_KINDS.items()):
        counted = dataclasses.replace(kind, build=_counted(counts, "law", kind.build))
        monkeypatch.setitem(LAW_KINDS, name, counted)
    for name, function in (("assemble", assembly.run_spec), ("runnable_backend", assembly.runnable_backend),
                           ("separation", assembly.build_separation), ("quantizer", assembly.build_quantizer),
                           ("reference", assembly.build_reference), ("loads", assembly.loads),
                           ("constants", assembly.controller_constants)):
        monkeypatch.setattr(assembly, function.__name__, _counted(counts, name, function))
    return counts


def _once_per_backend(counts: Counter, backends: int) -> None:
    for part in ONCE:
        assert counts[part] == backends, (part, dict(counts))


def test_a_run_is_put_together_once(builds: Counter, tmp_path: Path) -> None:
    assert main(["run", str(EX2), *SHORT, "--out", str(tmp_path / "out")]) == 0
    _once_per_backend(builds, 1)
    assert builds["plant mujoco"] == 1 and builds["plant ode"] == 0
    assert builds["constants"] == 0 and builds["scene mujoco"] == 0  # nothing recorded, nothing drawn


def test_a_recorded_run_builds_its_scene_and_constants_once(builds: Counter, tmp_path: Path) -> None:
    rrd = tmp_path / "run.rrd"
    assert main(["run", str(EX2), *SHORT, "--rrd", str(rrd)]) == 0
    assert rrd.stat().st_size > 0
    _once_per_backend(builds, 1)
    assert builds["plant mujoco"] == builds["scene mujoco"] == builds["constants"] == 1


def test_the_api_run_with_a_recording_builds_each_part_once(builds: Counter, tmp_path: Path) -> None:
    sc = qcontrol.load_scenario(EX2, {"simulation.duration": 0.05})
    res = qcontrol.run(sc, "ode", rrd=tmp_path / "run.rrd", record="metrics")
    assert res.summary["backend"] == "ode" and res.assembly.backend == "ode"
    _once_per_backend(builds, 1)
    assert builds["plant ode"] == builds["scene mujoco"] == builds["constants"] == 1
    assert builds["plant mujoco"] == 0  # the ODE run replays the MuJoCo model without building its plant


def test_compare_builds_each_part_once_per_backend(builds: Counter, tmp_path: Path) -> None:
    assert main(["compare", str(EX2), *SHORT, "--rrd", str(tmp_path / "cmp.rrd")]) == 0
    _once_per_backend(builds, 2)
    assert builds["plant mujoco"] == builds["plant ode"] == 1
    assert builds["scene mujoco"] == builds["constants"] == 1  # the twin is drawn in the main run's scene


def test_check_puts_the_run_together_once_per_backend_section(builds: Counter, capsys) -> None:
    assert main(["check", str(EX2), "--backend", "ode"]) == 0
    assert "ode: the plant of eq. (1) built; mujoco: the model compiled" in capsys.readouterr().out
    _once_per_backend(builds, 2)  # the chosen backend (ode) and the file's [plant.mujoco]
    assert builds["plant mujoco"] == builds["plant ode"] == 1


def test_a_batch_is_one_assembly(builds: Counter) -> None:
    sc = qcontrol.load_scenario(EX2, {"simulation.duration": 0.05})
    rows = qcontrol.sweep(sc, {"controller.kappa_margin": [0.1, 0.2, 0.3, 0.4, 0.5]}, backend="ode")
    assert len(rows) == 5 and not any(r["diverged"] for r in rows)
    _once_per_backend(builds, 1)  # five variants sharing their structure: one batch, one plant, one law


def test_the_assembly_runs_what_it_was_built_from() -> None:
    """The spec the engine runs is made of the assembly's parts; a second run reuses them (the plant
    is reset) and gives the same numbers."""
    sc = qcontrol.load_scenario(EX2, {"simulation.duration": 0.05})
    run = assembly.assemble(sc, "ode")
    assert (run.plant, run.law, run.backend) == (run.spec.plant, run.spec.law, "ode")
    assert run.spec.separation is not None and run.spec.grid.rows == 51 and run.loads == []
    first, again = run.run()[0], run.run()[0]
    assert (first.x == again.x).all() and (first.u == again.u).all()
    assert run.constants["delta"] == sc.controller.delta and run.constants["L"] == run.law.coordinates.L


def test_every_module_a_docstring_names_exists() -> None:
    """A docstring's :mod: reference names a module of the package (one named a `.model` module
    that had become mjcf.py)."""
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        package = ".".join(parts[:-1])
        for name in re.findall(r":mod:`~?([.\w]+)`", path.read_text()):
            full = importlib.util.resolve_name(name, package) if name.startswith(".") else name
            if importlib.util.find_spec(full) is None:
                missing.append(f"{path.relative_to(PACKAGE.parent)}: {name}")
    assert not missing


def test_the_api_takes_a_run_already_put_together() -> None:
    """What the command line does: put the run together first (to check --video against its scene),
    then hand it to qcontrol.run / compare, which build nothing again."""
    sc = qcontrol.load_scenario(EX2, {"simulation.duration": 0.05})
    run = assembly.assemble(sc, "ode")
    res = qcontrol.run(run, record="metrics")
    assert res.assembly is run and res.backend == "ode" and res.summary["steps"] == 50
    assert res.summary == {**qcontrol.run(sc, "ode", record="metrics").summary,
                           "wall_time_s": res.summary["wall_time_s"], "provenance": res.summary["provenance"]}
    with pytest.raises(qcontrol.QcontrolInputError, match="put together on 'ode'; leave out backend"):
        qcontrol.run(run, "mujoco")
    with pytest.raises(qcontrol.QcontrolInputError, match="compare: the run given was put together on 'ode'"):
        qcontrol.compare(run)
