"""A plant backend made as docs/architecture.md's recipe says, with only the core ``Plant`` (no
physics report, no actuator, no external load, no scene), works through every command and the
API: the optional parts take their defaults (plants/base.py), its ``[plant.core]`` section, whose
keys all default, need not be written, and a scenario with ``[[disturbance]]`` is refused in one
line before anything runs. Its numbers are the ODE backend's (the same eq. (1), stepped by the
same RK4 through the core protocol only)."""

from __future__ import annotations

import csv
import json
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import EX2, ROOT, SCENARIOS

import qcontrol
from qcontrol.cli import main
from qcontrol.law_comparison import compare_laws
from qcontrol.plants import BACKENDS
from qcontrol.scenario.load import parse_scenario

# The recipe's step 1, as a user's module: the plant class (the core Plant in array form), the keys
# of its [plant.core] section and its Backend. Step 2 (registering it) is the module's last line.
CORE_BACKEND = '''
from qcontrol.plants import Backend, register_backend
from qcontrol.plants.ode import ChainPlant
from qcontrol.schema import Key, Section, Table, integer, read_keys

SECTION = Section("plant.core", (Key("substeps", integer(1), 1, meaning="RK4 steps per step of dt"),),
                  "eq. (1) through the core Plant only")


class CorePlant:
    """eq. (1) with only the core of the Plant protocol: n, batch, reset, observe, step, close."""

    def __init__(self, terms, substeps):
        first = terms[0]
        self.inner = ChainPlant(first.order, first.psi, first.phi, first.theta, batch=len(terms))
        self.n, self.batch, self.substeps = self.inner.n, self.inner.batch, substeps

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def reset(self, x0):
        self.inner.reset(x0)

    def observe(self):
        x = self.inner.state()
        return x, x

    def step(self, u, h):
        for _ in range(self.substeps):
            self.inner.step(u, h / self.substeps)

    def close(self):
        pass


def parse(table, ctx):
    return read_keys(Table(table.data, table.source, table.name, SECTION.names), SECTION.keys, {})["substeps"]


def structure(terms, substeps):
    return terms.order, terms.theta, tuple(e.source for e in terms.expressions), substeps


BACKEND = Backend(name="core", build=lambda terms, options, dt: CorePlant(terms, options[0]),
                  structure=structure, summary="eq. (1) through the core Plant only", section=SECTION,
                  parse=parse)
register_backend(BACKEND)
'''

SHORT = {"simulation.duration": 0.3}


@pytest.fixture
def core(tmp_path: Path) -> Path:
    """The backend registered (its module run, as ``--law-module`` runs one); unregistered after."""
    path = tmp_path / "core_backend.py"
    path.write_text(CORE_BACKEND)
    before = dict(BACKENDS)
    runpy.run_path(str(path))
    yield path
    BACKENDS.clear()
    BACKENDS.update(before)


def _same_run(mine: dict, ideal: dict) -> None:
    """Two summaries of the same closed loop on different backends."""
    for key in ("error_rate", "max_abs_z1_last_half", "max_abs_u", "final_eps_hat", "lemma2_max_ratio",
                "saturated_fraction", "steps", "diverged"):
        assert mine[key] == ideal[key], key


def test_the_api_runs_it_with_the_default_report(core: Path) -> None:
    sc = qcontrol.load_scenario(EX2, SHORT)
    mine, ideal = qcontrol.run(sc, "core"), qcontrol.run(sc, "ode")
    assert mine.summary["backend"] == "core" and mine.summary["physics_warnings"] == []
    _same_run(mine.summary, ideal.summary)
    np.testing.assert_array_equal(mine.u_applied, mine.u)  # no actuator: u applied as commanded
    assert not mine.saturated.any()
    assert mine.assembly.report.consistency_report == {}


def test_run_from_the_command_line_writes_its_summary_and_files(core: Path, tmp_path: Path) -> None:
    out, npz, rrd = tmp_path / "out", tmp_path / "run.npz", tmp_path / "run.rrd"
    args = ["--duration", "0.3", "-q"]
    assert main(["run", str(EX2), "--backend", "core", *args, "--out", str(out), "--save", str(npz),
                 "--rrd", str(rrd)]) == 0
    assert main(["run", str(EX2), "--backend", "ode", *args, "--out", str(tmp_path / "ode")]) == 0
    mine = json.loads((out / "summary.json").read_text())
    assert mine["backend"] == "core" and mine["physics_warnings"] == []
    _same_run(mine, json.loads((tmp_path / "ode" / "summary.json").read_text()))
    saved = np.load(npz)
    assert saved["x"].shape == (301, 2) and rrd.stat().st_size > 0


def test_its_section_need_not_be_written_and_its_keys_reach_the_plant(core: Path) -> None:
    """The file has no [plant.core]: its defaults are read (one RK4 step per dt, the ODE's
    numbers); a key set from the command line reaches the plant (two smaller steps differ)."""
    sc = qcontrol.load_scenario(EX2, SHORT)
    assert "core" not in sc.data["plant"] and sc.backends["core"] == 1
    finer = qcontrol.load_scenario(EX2, {**SHORT, "plant.core.substeps": 2})
    one, two = qcontrol.run(sc, "core"), qcontrol.run(finer, "core")
    assert 0 < np.abs(one.x - two.x).max() < 1e-6  # RK4 at dt/2: the same trajectory, other rounding


def test_check_builds_it_and_says_so(core: Path, capsys) -> None:
    assert main(["check", str(EX2), "--backend", "core"]) == 0
    line = capsys.readouterr().out
    assert "on core; core: the plant of eq. (1) built; mujoco: the model compiled and agrees" in line


def test_sweep_from_the_command_line_and_the_api(core: Path, tmp_path: Path, figure_not_drawn: list) -> None:
    grid = ["--grid", "controller.kappa_margin=0.1,0.5", "--set", "simulation.duration=0.3", "-q"]
    for backend in ("core", "ode"):
        assert main(["sweep", str(EX2), "--backend", backend, *grid, "--out", str(tmp_path / backend)]) == 0
    rows = {b: list(csv.DictReader((tmp_path / b / "sweep.csv").open())) for b in ("core", "ode")}
    drop = ("wall_time_s",)
    assert [{k: v for k, v in r.items() if k not in drop} for r in rows["core"]] == [
        {k: v for k, v in r.items() if k not in drop} for r in rows["ode"]]
    assert json.loads((tmp_path / "core" / "sweep.json").read_text())["backend"] == "core"
    sc = qcontrol.load_scenario(EX2, SHORT)
    table = qcontrol.sweep(sc, {"controller.kappa_margin": [0.1, 0.5]}, backend="core")
    assert [r["max_abs_u"] for r in table] == [float(r["max_abs_u"]) for r in rows["core"]]


def test_laws_side_by_side_on_it(core: Path, tmp_path: Path) -> None:
    assert main(["laws", str(EX2), "--backend", "core", "--law", "proposed", "--law", "comparison",
                 "--duration", "0.3", "-q", "--out", str(tmp_path / "laws")]) == 0
    written = json.loads((tmp_path / "laws" / "laws.json").read_text())
    assert {run["backend"] for run in written["runs"].values()} == {"core"}
    ideal = compare_laws(qcontrol.load_scenario(EX2, SHORT), ["proposed", "comparison"], backend="ode")
    for kind, run in ideal.runs.items():
        _same_run(written["runs"][kind], run.summary)


def test_a_region_map_on_it(core: Path, tmp_path: Path) -> None:
    common = ["--duration", "0.2", "--resolution", "3", "-q", "--out"]
    for backend in ("core", "ode"):
        assert main(["region", str(EX2), "--backend", backend, *common, str(tmp_path / backend)]) == 0
    assert json.loads((tmp_path / "core" / "region.json").read_text())["backend"] == "core"
    assert (tmp_path / "core" / "region.csv").read_text() == (tmp_path / "ode" / "region.csv").read_text()


def test_compare_applies_to_a_scenario_run_on_it(core: Path, tmp_path: Path) -> None:
    """compare sets MuJoCo beside the ODE: a scenario whose backend is the core plant compares as
    any other (the core plant takes no part)."""
    out = tmp_path / "cmp"
    assert main(["compare", str(EX2), "--set", 'simulation.backend="core"', "--duration", "0.3", "-q",
                 "--out", str(out)]) == 0
    assert json.loads((out / "compare.json").read_text())["ode"]["backend"] == "ode"


def test_a_disturbance_is_refused_before_anything_runs(core: Path, tmp_path: Path, capsys) -> None:
    cart = SCENARIOS / "example1-cart.toml"
    out = tmp_path / "out"
    assert main(["run", str(cart), "--backend", "core", "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "[[disturbance]]: backend 'core' takes no external load" in err
    assert not out.exists()
    assert main(["check", str(cart), "--backend", "core"]) == 2


def test_registered_from_a_module_in_a_fresh_process(core: Path, tmp_path: Path) -> None:
    """The front door: the backend's module given to the command line, the scenario choosing it."""
    out = tmp_path / "out"
    command = ["run", str(EX2), "--law-module", str(core), "--set", 'simulation.backend="core"',
               "--duration", "0.3", "-q", "--out", str(out)]
    done = subprocess.run([sys.executable, "-m", "qcontrol", *command], capture_output=True, text=True,
                          cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    assert json.loads((out / "summary.json").read_text())["backend"] == "core"



def test_named_with_backend_once_its_module_ran(core: Path, tmp_path: Path, capsys) -> None:
    """``--backend`` is checked after the command's law modules ran, so it may name a backend one
    of them registers; an unknown name is still one line and exit status 2."""
    BACKENDS.pop("core")  # registered only by the module the command line runs
    out = tmp_path / "out"
    assert main(["check", str(EX2), "--law-module", str(core), "--backend", "core", "-q"]) == 0
    assert main(["run", str(EX2), "--law-module", str(core), "--backend", "core", "--duration", "0.1", "-q",
                 "--out", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["backend"] == "core"
    capsys.readouterr()
    assert main(["run", str(EX2), "--backend", "gpu", "-q", "--out", str(tmp_path / "gpu")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("backend 'gpu': use one of ode, mujoco, core") and len(err.splitlines()) == 1
    assert not (tmp_path / "gpu").exists()


def test_a_table_whose_keys_all_default_may_be_left_out() -> None:
    """Without [reference], y_d is the default kind's default: sin(t)."""
    text = EX2.read_text()
    start = text.index("[reference]")
    without = text[:start] + text[text.index("\n[", start) + 1:]
    sc = parse_scenario(without, source=str(EX2), base_dir=EX2.parent, overrides=("simulation.duration=0.3",))
    res = qcontrol.run(sc, "ode")
    np.testing.assert_allclose(res.yd[:, 0], np.sin(res.t), rtol=0, atol=1e-15)
    np.testing.assert_allclose(res.yd[:, 1], np.cos(res.t), rtol=0, atol=1e-15)
