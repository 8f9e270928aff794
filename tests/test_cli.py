"""The `qcontrol` command: output contract, exit statuses, one-line errors."""

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import EX1, EX2, ROOT, run_forked

from qcontrol.cli import main

SUMMARY_KEYS = {
    "scenario", "backend", "duration", "dt", "steps", "wall_time_s", "diverged", "error_rate",
    "max_abs_z1_last_half", "max_abs_u", "final_eps_hat", "lemma2_max_ratio",
}


def test_run_writes_summary_per_contract(tmp_path, capsys):
    out = tmp_path / "ex2"
    assert main(["run", str(EX2), "--out", str(out), "--duration", "2", "-q"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(s)
    assert s["scenario"] == "example2" and s["backend"] == "mujoco"  # the scenario's default
    assert s["duration"] == 2.0 and s["dt"] == 0.001 and s["steps"] == 2000
    assert list(s["error_rate"]) == ["0.100", "0.125", "0.150", "0.175", "0.200"]
    assert all(0.0 <= v <= 1.0 for v in s["error_rate"].values())
    assert s["diverged"] is False and len(s["final_eps_hat"]) == 3
    assert 0.5 < s["lemma2_max_ratio"] <= 1.0
    assert list(out.iterdir()) == [out / "summary.json"]  # no temporary files left
    printed = capsys.readouterr().out
    assert "error rate" in printed and "Lemma 2" in printed


@pytest.mark.usefixtures("python_loop")
def test_diverged_run_exit_1_and_summary_says_so(tmp_path):
    out = tmp_path / "div"
    status = main(["run", str(EX1), "--out", str(out), "-q", "--set", 'plant.psi="x2**3"',
                   "--set", "simulation.state_bound=5.0"])
    assert status == 1
    s = json.loads((out / "summary.json").read_text())
    assert s["diverged"] is True and 0 < s["diverged_time"] < 10


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


def _variant(old: str, new: str) -> str:
    """Example 2 with one edit, loadable from any folder (absolute MJCF path)."""
    text = EX2.read_text().replace('"qcontrol:models/', f'"{ROOT}/models/')
    assert old in text
    return text.replace(old, new)


BAD_SCENARIOS = {
    "kappa <= L": (_variant("kappa_margin = 1.1", "kappa = 0.025"),
                   "controller.proposed.kappa: must exceed L"),
    "zero gain": (_variant("c = [4.0, 3.0]", "c = [4.0, 0.0]"), "controller.c[1]: must be > 0"),
    "negative delta": (_variant("delta = 0.01", "delta = -0.01"), "controller.delta: must be > 0"),
    "zero gamma": (_variant("gamma = 1.0", "gamma = 0"), "controller.proposed.gamma: must be > 0"),
    "zero sigma": (_variant("sigma = 1.0", "sigma = 0.0"), "controller.proposed.sigma: must be > 0"),
    "n < 2": (_variant("order = 2", "order = 1"), "plant.order: must be >= 2"),
    "r length": (_variant('r = ["1 + q2**2", "1 + 2*q2**2", "1"]', 'r = ["1"]'),
                 "controller.proposed.r: has 1"),
    "theta length": (_variant("theta = [-1.0, -3.5, -34.3]", "theta = [-1.0]"), "plant.theta: has 1"),
    "x0 length": (_variant("x0 = [0.3, 0.3]", "x0 = [0.3]"), "plant.x0: has 1"),
    "unknown key": (_variant("gamma = 1.0", "gamma = 1.0\ngama = 2.0"),
                    "controller.proposed.gama: unknown key"),
    "malformed": ("[plant\norder = 2", "malformed TOML"),
    "bad expression": (_variant('"sin(x1)"]', '"__import__(1)"]'), "unknown function '__import__'"),
    "r below one": (_variant('"1"]\n', '"0.5"]\n'), "controller.proposed.r[2]"),
    "dt not dividing": (_variant("dt = 0.001", "dt = 0.003"), "not a whole number of steps"),
    "nan": (_variant("sigma = 1.0", "sigma = nan"), "controller.proposed.sigma: must be finite"),
    "missing MJCF": (_variant("models/pendulum.xml", "models/no-such-model.xml"), "plant.mujoco.model"),
    "joint not in MJCF": (_variant('joint = "hinge"', 'joint = "elbow"'), "plant.mujoco.joint"),
    "sensor not in MJCF": (_variant('position_sensor = "angle"', 'position_sensor = "theta"'),
                           "plant.mujoco.position_sensor"),
    "broken MJCF": (_variant(f"{ROOT}/models/pendulum.xml", "broken.xml"), "plant.mujoco.model"),
}


@pytest.mark.parametrize("case", sorted(BAD_SCENARIOS))
def test_bad_scenario_exit_2_one_line(tmp_path, capsys, case):
    text, expected = BAD_SCENARIOS[case]
    (tmp_path / "broken.xml").write_text("<mujoco><worldbody><body><joint type='hinge'/></body>")
    out = tmp_path / "out"
    assert main(["run", str(_write(tmp_path, text)), "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("qcontrol: error: ")
    assert expected in err
    assert str(tmp_path / "bad.toml") in err
    assert not (out / "summary.json").exists()


@pytest.mark.parametrize(
    "args, expected",
    [
        (["run", "missing.toml"], "scenario file not found"),
        (["run", str(EX2), "--set", "nokey"], "expected KEY=VALUE"),
        (["run", str(EX2), "--set", "controller.kapa=1"], "--set controller.kapa=1: unknown key"),
        (["run", str(EX2), "--set", "controller.c=[1, 2, 3]"], "has 3 entries, expected 2"),
        (["run", str(ROOT / "scenarios" / "chain3.toml"), "--backend", "mujoco"], "[plant.mujoco]"),
        (["run", str(EX2), "--duration", "-1"], "--duration -1.0: must be a positive number of seconds"),
        (["run", str(EX2), "--dt", "0"], "--dt 0.0: must be a positive number of seconds"),
        (["run", str(EX2), "--backend", "gpu"], "backend 'gpu': use one of ode, mujoco"),
    ],
)
def test_bad_command_line_exit_2_one_line(capsys, args, expected):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert expected in err




def test_unwritable_output_dir(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["run", str(EX2), "--out", str(blocker / "sub"), "-q", "--duration", "0.01"]) == 2
    assert "--out" in capsys.readouterr().err


def test_console_script_no_traceback(fresh):
    status, _, err = fresh["bad input"]
    assert status == 2
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_compare_writes_contract_and_backends_agree(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", str(EX2), "--out", str(out), "--duration", "2", "-q"]) == 0
    c = json.loads((out / "compare.json").read_text())
    assert {"max_abs_dx", "max_abs_dy", "max_abs_du", "mujoco", "ode"} <= set(c)
    assert len(c["max_abs_dx"]) == 2 and c["max_abs_dy"] <= 1e-9 and c["max_abs_du"] <= 1e-9
    assert c["mujoco"]["backend"] == "mujoco" and c["ode"]["backend"] == "ode"
    assert SUMMARY_KEYS <= set(c["mujoco"]) and SUMMARY_KEYS <= set(c["ode"])
    assert "MuJoCo vs ODE" in capsys.readouterr().out


def test_compare_needs_a_mujoco_model(capsys):
    assert main(["compare", str(ROOT / "scenarios" / "chain3.toml"), "-q"]) == 2
    assert "[plant.mujoco]" in capsys.readouterr().err


def test_compare_rrd_holds_both_runs(tmp_path, capsys):
    from test_record import read_entities, temporal

    rrd = tmp_path / "rec" / "ex2.rrd"
    out = tmp_path / "cmp"
    assert main(["compare", str(EX2), "--rrd", str(rrd), "--out", str(out), "--duration", "1", "-q"]) == 0
    assert rrd.is_file() and not list(rrd.parent.glob(".*.tmp"))
    entities = read_entities(rrd)
    for path in ("world/bodies/arm", "world/ode_ghost/arm", "world/target", "signals/tracking/y",
                 "signals/tracking/y_d", "signals/tracking/y_ode", "signals/input/u",
                 "theory/lemma2/ratios", "info/scenario"):
        assert path in entities, path
    times, y = temporal(entities["signals/tracking/y"], "Scalars:scalars")
    assert len(times) == 1001 and times[-1] == 1_000_000_000
    _, y_ode = temporal(entities["signals/tracking/y_ode"], "Scalars:scalars")
    c = json.loads((out / "compare.json").read_text())
    assert np.max(np.abs(y - y_ode)) == c["max_abs_dy"] <= 1e-9  # the recording holds the same two runs
    _, dy = temporal(entities["signals/difference/y/ode"], "Scalars:scalars")  # the ODE run is the twin
    np.testing.assert_array_equal(dy, np.log10(np.maximum(np.abs(y - y_ode), 1e-16)))  # as log10, floored


# The commands whose subject is a process of their own (what it has imported, the console's exit
# path), run in forks of one interpreter that has imported the package and nothing else
# (conftest.run_forked: numba, MuJoCo, rerun, matplotlib not among them), with QCONTROL_COMPILE
# unset: the tests below read each one's exit status, stdout and stderr.
CHAIN3 = ROOT / "scenarios" / "chain3.toml"
IMPORTS = (f"import sys; from qcontrol.cli import main; main(['run', {str(CHAIN3)!r}, '--duration', '0.01', "
           f"'-q']); print('mujoco imported', 'mujoco' in sys.modules); main(['run', {str(EX2)!r}, "
           "'--duration', '0.01', '-q']); print('rerun imported', 'rerun' in sys.modules)")
SHORT_RUN = ("import sys; from qcontrol.cli import main; main(['run', {ex2!r}, '--backend', {backend!r}, "
             "'--duration', '2', '-q']); print('numba' in sys.modules)")
CHECK_THEN_RUN = (f"import sys; from qcontrol.cli import main; main(['check', {str(EX2)!r}, '-q']); "
                  "print('numba' in sys.modules); from qcontrol.assembly import build_plant; "
                  "from qcontrol.scenario import load_scenario; "
                  f"plant = build_plant(load_scenario({str(EX2)!r}), 'mujoco'); "
                  "print(plant.native_for_run() is not None and 'numba' in sys.modules)")


@pytest.fixture(scope="module")
def fresh(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[int, str, str]]:
    folder = tmp_path_factory.mktemp("fresh")
    bad = _write(folder, _variant("kappa_margin = 1.1", "kappa = 0.01"))
    commands = {"bad input": ["python", "-m", "qcontrol.cli", "run", str(bad)],
                "imports": ["python", "-c", IMPORTS],
                "check then run": ["python", "-c", CHECK_THEN_RUN],
                **{f"short {backend}": ["python", "-c", SHORT_RUN.format(ex2=str(EX2), backend=backend)]
                   for backend in ("ode", "mujoco")}}
    env = {k: v for k, v in os.environ.items() if k != "QCONTROL_COMPILE"}
    return dict(zip(commands, run_forked(list(commands.values()), folder, env, timeout=300), strict=True))


def test_a_run_imports_neither_rerun_nor_mujoco_before_it_needs_them(fresh):
    """Nor does a command import MuJoCo before a scenario with a MuJoCo model asks for it: not the
    parser (--video's options), not a run of a scenario without one."""
    status, out, err = fresh["imports"]
    said = [line for line in out.splitlines() if " imported " in line]
    assert status == 0 and said == ["mujoco imported False", "rerun imported False"], out + err


@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_a_short_run_in_a_new_process_leaves_numba_unstarted(fresh, backend: str) -> None:
    """A single run too short to pay for numba's start (here 2 s, below COLD_MIN_ROWS) runs every
    part in Python, MuJoCo's passive callback included: the same numbers, without the start."""
    status, out, err = fresh[f"short {backend}"]
    assert status == 0 and out.strip().splitlines()[-1] == "False", out + err


def test_check_builds_the_mujoco_plant_without_numba_and_run_still_compiles(fresh):
    """check compares the model with eq. (1) through the Python passive callback (bit-identical
    to the compiled one; nothing runs), so it does not pay numba's import; a run after it in the
    same process still gets the compiled callback (built when a run that pays for it starts)."""
    status, out, err = fresh["check then run"]
    assert status == 0 and out.strip().splitlines()[-2:] == ["False", "True"], out + err


@pytest.mark.parametrize("overrides", [[], ['plant.psi="x2**3"', "simulation.state_bound=5.0"]],
                         ids=["bounded", "diverging"])
def test_run_streams_chunks_with_bounded_memory_same_numbers(tmp_path, overrides):
    """`run` keeps only metrics and streams the recording chunk by chunk; the file and the
    summary hold exactly what a fully recorded run of the same loop gives."""
    from test_record import read_entities, temporal

    from qcontrol.assembly import run_scenario
    from qcontrol.metrics import summary
    from qcontrol.scenario import load_scenario

    sets = [x for o in overrides for x in ("--set", o)]
    rrd, out = tmp_path / "run.rrd", tmp_path / "out"
    status = main(["run", str(EX1), "--rrd", str(rrd), "--out", str(out), "-q", "--duration", "3", *sets])
    full = run_scenario(load_scenario(EX1, [*overrides, "simulation.duration=3"]), "mujoco")
    assert status == (1 if full.diverged else 0)
    entities = read_entities(rrd)
    times, y = temporal(entities["signals/tracking/y"], "Scalars:scalars")
    _, u = temporal(entities["signals/input/u"], "Scalars:scalars")
    np.testing.assert_array_equal(times, np.round(full.t * 1e9).astype(np.int64))
    np.testing.assert_array_equal(y[:, 0], full.x[:, 0])
    np.testing.assert_array_equal(u[:, 0], full.u)
    got = json.loads((out / "summary.json").read_text())
    want = json.loads(json.dumps(summary(full, "example1", "mujoco")))
    for key in ("error_rate", "max_abs_u", "max_abs_z1_last_half", "final_eps_hat", "lemma2_max_ratio",
                "diverged", "diverged_time", "steps"):
        assert got[key] == want[key], key


def test_progress_is_shown_on_a_terminal_only(tmp_path, capsys, monkeypatch, figure_not_drawn):
    """Piped (here: captured), no command writes progress lines; on a terminal the line is redrawn."""
    import io

    from qcontrol.progress import ProgressLine

    assert main(["sweep", str(EX2), "--backend", "ode", "--grid", "controller.gamma=0.5,2", "--set",
                 "simulation.duration=0.2", "--out", str(tmp_path / "sweep")]) == 0
    assert main(["run", str(EX2), "--duration", "0.2"]) == 0
    assert capsys.readouterr().err == ""

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    line = ProgressLine("sweep", True, "runs")
    for done in range(5):
        line(done, 4)
    drawn = "".join(f"\rsweep: {100 * d // 4:3d}% ({d}/4 runs)" for d in range(5))
    assert terminal.getvalue() == drawn + "\n"


def test_actuator_line_says_never_saturated_or_how_often(tmp_path, capsys):
    common = ["run", str(EX2), "--duration", "1", "-q"]
    assert main([*common, "--out", str(tmp_path / "free")]) == 0
    free = capsys.readouterr().out
    assert "never saturated" in free and "0.0%" not in free
    assert main([*common, "--out", str(tmp_path / "cut"), "--set", "plant.mujoco.torque_limit=12.0"]) == 0
    cut = capsys.readouterr().out
    fraction = json.loads((tmp_path / "cut" / "summary.json").read_text())["saturated_fraction"]
    assert 0.0 < fraction < 1.0 and f"saturated at {100 * fraction:.2g}% of the control samples" in cut
