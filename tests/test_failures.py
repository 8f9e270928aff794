"""Failures on the newer surfaces, each one line with its documented exit status: sizes bounded
before anything runs (a region's grid, the API's sweep and region), a region terminated by
SIGTERM, a reproduction whose whole process group is sent SIGTERM, a scheduler that never
answers, files MuJoCo would block on, a user law that fails during a run, and the API refusing
what the command line refuses."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import EX2, ROOT, busy, forks_of, process_fields, processes

import qcontrol
from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError
from qcontrol.region import LawSpec, RegionGrid, measure_region, parse_grid
from qcontrol.sweep.grid import MAX_RUNS


def _one_line(capsys: pytest.CaptureFixture[str], *expected: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for text in expected:
        assert text in err, err
    assert "Traceback" not in err
    return err


# --------------------------------------------------------------------------------------------
# sizes: refused before anything runs or is made


@pytest.mark.parametrize("argv, words", [
    (["--resolution", "100000"], ["10,000,000,000 runs", "give --resolution 1000 or less"]),
    (["--resolution", "1001"], ["1,002,001 runs", f"{MAX_RUNS:,}"]),
    (["--resolution", "800", "--law", "proposed", "--law", "comparison"], ["1,280,000 runs", "707 or less"]),
    (["--box", "1e308"], ["within the divergence bound"]),
    (["--box", "-5"], ["a half-width must be > 0"]),
])
def test_a_region_too_large_is_refused_before_it_runs(tmp_path, capsys, argv, words):
    out = tmp_path / "region"
    assert main(["region", str(EX2), "-q", "--out", str(out), *argv]) == 2
    _one_line(capsys, *words)
    assert not out.exists()


def test_the_api_bounds_a_sweep_and_a_region(short_example2):
    grid = {"controller.kappa_margin": list(range(1001)), "controller.gamma": list(range(1000))}
    with pytest.raises(QcontrolInputError, match="1,001,000 runs is more than"):
        qcontrol.sweep(short_example2, grid)
    big = RegionGrid((0, 1), (-1.0, -1.0), (1.0, 1.0), 1001)
    with pytest.raises(QcontrolInputError, match="1,002,001 runs"):
        measure_region(EX2, big, [LawSpec("proposed")])
    with pytest.raises(QcontrolInputError, match="must be a RegionGrid"):
        measure_region(EX2, "21", [LawSpec("proposed")])  # type: ignore[arg-type]
    assert parse_grid(short_example2, "1,2", "-2,3", 1000).resolution == 1000  # the cap itself is fine


def test_a_region_terminated_exits_143(tmp_path):
    """SIGTERM during a region on worker processes: 143 (as a sweep), nothing written. (The array
    form: a compile on an empty cache would hold the signal until it returns, several seconds for
    so large a batch; Ctrl-C while compiling: tests/test_reliability.py.)"""
    out = tmp_path / "region"
    proc = subprocess.Popen([sys.executable, "-m", "qcontrol.cli", "region", str(EX2), "--workers", "2",
                             "--resolution", "40", "--duration", "10", "-q", "--out", str(out)],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "HOME": str(tmp_path), "QCONTROL_COMPILE": "0"})
    deadline, workers = time.monotonic() + 60, []
    while not workers and time.monotonic() < deadline and proc.poll() is None:
        workers = forks_of(proc.pid)
        time.sleep(0.02)
    assert workers and busy(workers[0]), "the region did not start its second worker"
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "terminated" in err and "Traceback" not in err
    assert not out.exists()


_SIGNAL_WHILE_FORKING = """
import os, signal, sys, time
from qcontrol.workers import Forks

class Stop(Exception):
    pass

def stop(signum, frame):
    raise Stop

signal.signal(signal.SIGTERM, stop)
sent = []

def kill_once():  # the signal lands inside a hook run around the fork
    if not sent:
        sent.append(1)
        os.kill(os.getpid(), signal.SIGTERM)

os.register_at_fork(before=kill_once)
try:
    forks = Forks(2, 2, lambda i: time.sleep(60))
except Stop:
    try:
        os.waitpid(-1, os.WNOHANG)
    except ChildProcessError:  # its workers ended and waited for, not left running
        print("stopped", 0)
    sys.exit(0)
forks.close()
print("ran on")
"""


def test_a_signal_while_the_workers_fork_is_not_lost():
    """SIGTERM arriving inside the hooks Python runs around a worker's fork (where an exception a
    handler raises is ignored) still stops the command once the workers are forked, and the workers
    forked meanwhile end."""
    done = subprocess.run([sys.executable, "-c", _SIGNAL_WHILE_FORKING], capture_output=True, text=True,
                          timeout=60, cwd=ROOT)
    assert done.stdout.split() == ["stopped", "0"], done.stdout + done.stderr
    assert "Exception ignored" not in done.stderr


_STOP_IN_A_FINALIZER = """
import os, signal, sys
from qcontrol.cli import main
from qcontrol.reproduce import drawing

class Finalized:
    def __del__(self):  # the group's SIGTERM handled inside a finalizer: Python ignores its Terminated
        os.killpg(0, signal.SIGTERM)

draw, sent = drawing.Apart.draw, []

def draw_then_stop(self, figures):  # once the first figures' worker is forked (and drawing)
    draw(self, figures)
    if not sent:
        sent.append(1)
        Finalized()

drawing.Apart.draw = draw_then_stop
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
def test_sigterm_to_the_process_group_ends_reproduce(tmp_path):
    """SIGTERM to a reproduction's whole process group (a job scheduler, ``timeout``, a closing
    terminal) while a worker draws, its handler run inside a finalizer (where Python ignores the
    ``Terminated`` it raises) and the worker ended by the same signal: the command still stops,
    143, nothing written, no worker and no scratch folder left (it once waited forever for the
    dead worker's figures)."""
    out, scratch = tmp_path / "out", tmp_path / "tmp"
    scratch.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", _STOP_IN_A_FINALIZER, "reproduce", "--quick", "--backend",
                             "ode", "--workers", "2", "-q", "--out", str(out)], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, "HOME": str(tmp_path),
                                                         "TMPDIR": str(scratch), "QCONTROL_COMPILE": "0"})
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 143, err
    assert "Exception ignored" in err and "terminated after" in err  # (the stop was lost, then acted on)
    assert not _in_group(proc.pid), "a worker outlived the command"
    assert not list(scratch.iterdir())
    assert not out.exists() or not [p for p in out.iterdir() if ".partial." not in p.name]


def _in_group(group: int) -> list[int]:
    """The processes of process group ``group`` still alive 2 s on (asked until then)."""
    deadline = time.monotonic() + 2.0
    while True:
        alive = [pid for pid in processes()
                 if (fields := process_fields(pid)) and fields[0] != "Z" and int(fields[2]) == group]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.05)


# --------------------------------------------------------------------------------------------
# nothing hangs: a scheduler that never answers, files MuJoCo would block on


@pytest.fixture
def silent_port():
    """A socket on 127.0.0.1 that accepts connections and never says a word."""
    import socket

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(16)
    accepted: list[socket.socket] = []
    stop = False

    def accept() -> None:
        while not stop:
            try:
                accepted.append(server.accept()[0])
            except OSError:
                return

    import threading

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    yield server.getsockname()[1]
    stop = True
    server.close()
    for conn in accepted:
        conn.close()


def test_a_scheduler_that_never_answers_is_one_line(silent_port, monkeypatch, capsys, tmp_path):
    pytest.importorskip("distributed")
    from qcontrol.sweep import runs

    monkeypatch.setattr(runs, "DASK_CONNECT_TIMEOUT", 1.0)
    out = tmp_path / "sw"
    assert main(["sweep", str(EX2), "--grid", "controller.gamma=1,2", "-q", "--out", str(out),
                 "--scheduler", f"tcp://127.0.0.1:{silent_port}"]) == 2
    _one_line(capsys, "no Dask handshake within 1 s", "--scheduler tcp://127.0.0.1:")
    assert not out.exists()


@pytest.mark.parametrize("address", ["tls://127.0.0.1:{port}", "ucx://127.0.0.1:{port}"])
def test_a_scheduler_address_dask_cannot_use_is_one_line(silent_port, capsys, tmp_path, address):
    pytest.importorskip("distributed")
    out = tmp_path / "sw"
    assert main(["sweep", str(EX2), "--grid", "controller.gamma=1,2", "-q", "--out", str(out),
                 "--scheduler", address.format(port=silent_port)]) == 2
    _one_line(capsys, "cannot connect")
    assert not out.exists()


def test_ctrl_c_while_connecting_to_a_scheduler(silent_port, tmp_path):
    """Ctrl-C stops the wait for the handshake: exit 130 long before the handshake's timeout, made
    10 minutes in the command here so that a wait deaf to Ctrl-C cannot end within the test's 60 s
    (a bound on hangs, loose enough for a loaded machine: the exit takes ~0.2 s of CPU)."""
    pytest.importorskip("distributed")
    command = ("import sys; from qcontrol.sweep import runs; runs.DASK_CONNECT_TIMEOUT = 600.0; "
               "from qcontrol._entry import main; sys.exit(main())")
    proc = subprocess.Popen([sys.executable, "-c", command, "region", str(EX2), "--resolution", "3",
                             "-q", "--out", str(tmp_path / "r"), "--scheduler", f"tcp://127.0.0.1:{silent_port}"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "HOME": str(tmp_path)},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while not _connected_to(silent_port) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err


def _connected_to(port: int) -> bool:
    """Whether some process holds an established TCP connection to 127.0.0.1:``port``."""
    wanted = f"0100007F:{port:04X}"
    for table in ("/proc/net/tcp",):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[2] == wanted and fields[3] == "01":
                return True
    return False


CUBE = " ".join(f'file{face}="asset.bin"' for face in ("right", "left", "up", "down", "front", "back"))


@pytest.mark.parametrize("asset, words", [
    ('<texture name="tx" type="2d" file="asset.bin"/>', "texture tx reads asset.bin"),
    (f'<texture name="cb" type="cube" {CUBE}/>', "texture cb reads asset.bin"),
    ('<mesh name="ms" file="asset.bin"/>', "mesh ms reads asset.bin"),
    ('<hfield name="hf" file="asset.bin" size="1 1 1 1"/>', "height field hf reads asset.bin"),
    ('<skin name="sk" file="asset.bin"/>', "skin sk reads asset.bin"),
])
@pytest.mark.parametrize("command", [["check"], ["run", "--backend", "ode", "--duration", "0.05", "-q"]])
def test_an_asset_that_is_a_fifo_is_refused_before_mujoco_opens_it(tmp_path, capsys, asset, words, command):
    """MuJoCo would block forever reading a FIFO (deaf to Ctrl-C): refused in one line, even for
    an ODE run (the scenario's model is checked at load)."""
    os.mkfifo(tmp_path / "asset.bin")
    text = (ROOT / "models" / "pendulum.xml").read_text()
    (tmp_path / "model.xml").write_text(text.replace("<worldbody>", f"<asset>{asset}</asset><worldbody>", 1))
    assert main([command[0], str(EX2), *command[1:], "--set",
                 f'plant.mujoco.model="{tmp_path / "model.xml"}"']) == 2
    _one_line(capsys, words, "a FIFO (named pipe), not a regular file")


# --------------------------------------------------------------------------------------------
# a user law that fails during a run: one line, the run stopped like a divergence, exit 4

FAILING_LAW = '''
import numpy as np
import qcontrol


class Failing:
    """The backstepping input with an integrator; from t >= fail_at its method `where` does `how`."""

    state_size = 1

    def __init__(self, table):
        self.c, self.fail_at = table["c"], table.get("fail_at", 1e9)
        self.where, self.how = table.get("where", "control"), table.get("how", "raise")

    def initial_state(self):
        return np.zeros(1)

    def _out(self, method, good, t):
        if method != self.where or t < self.fail_at:
            return good
        if self.how == "raise":
            return {}["no such key"]  # the line the report names
        return {"none": None, "string": "1.5", "shape": np.zeros(3)}[self.how]

    def control(self, t, x_q, yd, state):
        u = float(qcontrol.quantized_backstepping(self.c, x_q, yd)[1][-1] - 0.5 * state[0])
        return self._out("control", u, t)

    def state_rate(self, t, x_q, yd, state):
        return self._out("state_rate", np.array([x_q[0] - yd[0]]), t)


qcontrol.register_law("failing", lambda table, n: Failing(table), replace=True)
'''
RAISE_LINE = 1 + next(i for i, line in enumerate(FAILING_LAW.splitlines()) if "the line the report" in line)


@pytest.fixture
def failing_law(tmp_path):
    module = tmp_path / "failing.py"
    module.write_text(FAILING_LAW)
    from qcontrol.controller.plugins import load_law_module

    load_law_module(module)
    return module


def _failing(**settings: object) -> qcontrol.Scenario:
    over = {"controller.kind": "failing", "simulation.duration": 0.3} | {f"controller.{k}": v
                                                                       for k, v in settings.items()}
    return qcontrol.load_scenario(EX2, overrides=over)


@pytest.mark.parametrize("where, how, words", [
    ("control", "raise", ["control() raised KeyError: 'no such key'", f"failing.py, line {RAISE_LINE}"]),
    ("control", "none", ["control() returned NoneType None, not a real number u"]),
    ("control", "string", ["control() returned str '1.5', not a real number u"]),
    ("control", "shape", ["control() returned ndarray", "not a real number u"]),
    ("state_rate", "raise", ["state_rate() raised KeyError", f"failing.py, line {RAISE_LINE}"]),
    ("state_rate", "string", ["state_rate() returned str '1.5', not an array of 1 real numbers"]),
    ("state_rate", "shape", ["state_rate() returned ndarray", "not an array of 1 real numbers"]),
])
@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_a_law_failing_after_its_first_call_stops_the_run_like_a_divergence(failing_law, where, how, words,
                                                                            backend):
    result = qcontrol.run(_failing(fail_at=0.1, where=where, how=how), backend)
    s = result.typed_summary
    assert s.law_failure is not None and s.divergence_reason == s.law_failure
    for text in ["controller kind 'failing'", "at t = 0.1 s", *words]:
        assert text in s.law_failure, s.law_failure
    assert "\n" not in s.law_failure
    # the run stops at the row where control() failed, or where the state it could not update is
    assert s.diverged and s.diverged_time == pytest.approx(0.1 if where == "control" else 0.101)
    alone = qcontrol.run(_failing(), backend)  # the same law that never fails: the same rows before
    rows = len(result.t) - 1
    np.testing.assert_array_equal(result.x[:rows], alone.x[:rows])
    assert not result.typed_summary.physics_warnings  # the plant was never fed a NaN input


def test_a_failing_copy_of_a_batch_leaves_the_others_as_they_run_alone(failing_law):
    rows = qcontrol.sweep(_failing(), {"controller.fail_at": [0.05, 1e9, 0.2, 1e9, 1e9, 1e9]}, backend="ode")
    alone = qcontrol.run(_failing(), "ode").typed_summary
    assert [r["diverged"] for r in rows] == [True, False, True, False, False, False]
    for row in rows[1:2] + rows[3:]:
        assert row["max_abs_u"] == alone.max_abs_u and row["error_rate_0.100"] == alone.error_rate["0.100"]


@pytest.mark.parametrize("argv", [
    ["run", "--backend", "ode", "--duration", "0.3"],
    ["compare", "--duration", "0.3"],
    ["sweep", "--grid", "controller.fail_at=0.1,0.2,0.25", "--workers", "2", "--backend", "ode",
     "--set", "simulation.duration=0.3"],
    ["region", "--law", "failing:fail_at=0.1", "--resolution", "2", "--duration", "0.3", "--workers", "2"],
])
def test_every_command_reports_a_failing_law_in_one_line_exit_4(failing_law, tmp_path, capsys, argv,
                                                                monkeypatch):
    from qcontrol.sweep import runs

    monkeypatch.setattr(runs, "SPREAD_MIN_WORK", {})  # the sweep's and region's on workers however short
    command, *rest = argv
    out = ["--out", str(tmp_path / "out")] if command in ("sweep", "region") else []
    kind = {"region": [], "sweep": ["--set", "controller.kind=failing"]}.get(
        command, ["--set", "controller.kind=failing", "--set", "controller.fail_at=0.1"])
    assert main([command, str(EX2), "--law-module", str(failing_law), *kind, *rest, *out, "-q"]) == 4
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("qcontrol: error: the law failed: controller kind 'failing': control() raised "
                          "KeyError")
    assert f"failing.py, line {RAISE_LINE}" in err and "Traceback" not in err


def test_the_debug_switch_prints_the_traceback(failing_law, monkeypatch, capsys):
    monkeypatch.setenv("QCONTROL_DEBUG", "1")
    law = ["--law-module", str(failing_law), "--set", "controller.kind=failing",
           "--set", "controller.fail_at=0.1"]
    assert main(["run", str(EX2), "--backend", "ode", "--duration", "0.3", "-q", *law]) == 4
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and 'return {}["no such key"]' in err


def test_a_factory_that_raises_and_a_module_that_exits_are_bad_input(tmp_path, capsys):
    module = tmp_path / "factory.py"
    module.write_text("import qcontrol\n\ndef make(table, n):\n    return 1 / 0\n\n"
                      "qcontrol.register_law('broken-factory', make, replace=True)\n")
    assert main(["check", str(EX2), "--law-module", str(module), "--set",
                 "controller.kind=broken-factory"]) == 2
    _one_line(capsys, "the law's factory failed (ZeroDivisionError: division by zero, factory.py, line 4)")
    exits = tmp_path / "exits.py"
    exits.write_text("import sys\nsys.exit(0)\n")
    assert main(["run", str(EX2), "--law-module", str(exits), "-q"]) == 2
    _one_line(capsys, "exits.py: the file called sys.exit(0) while it was imported, line 2")


def test_reproduce_with_a_law_refused_at_its_first_call_creates_nothing(tmp_path, capsys):
    module = tmp_path / "first.py"
    module.write_text("import numpy as np\nimport qcontrol\n\n\nclass First:\n    state_size = 0\n\n"
                      "    def initial_state(self):\n        return np.zeros(0)\n\n"
                      "    def control(self, t, x_q, yd, state):\n        return 'oops'\n\n"
                      "    def state_rate(self, t, x_q, yd, state):\n        return np.zeros(0)\n\n\n"
                      "qcontrol.register_law('first-refused', lambda table, n: First(), replace=True)\n")
    out = tmp_path / "results" / "deep"
    assert main(["reproduce", "--law-module", str(module), "--law", "first-refused", "--quick", "--duration",
                 "0.2", "--backend", "ode", "--out", str(out), "-q"]) == 2
    _one_line(capsys, "control() must return a real number u, got str 'oops'")
    assert not (tmp_path / "results").exists()


# --------------------------------------------------------------------------------------------
# the API refuses like the command line; names on a terminal; a byte-order mark


def test_the_api_refuses_wrong_types_and_suffixes_in_one_line(short_example2, tmp_path):
    result = qcontrol.run(short_example2, "ode")
    cases = [
        (lambda: qcontrol.load_scenario(EX2, unset=123), "load_scenario: unset must be a list of keys"),
        (lambda: result.save(None), "save: path must be str or Path, got NoneType None"),
        (lambda: result.plot(None), "plot: path must be str or Path, got NoneType None"),
        (lambda: result.plot(tmp_path / "p.csv"), "unknown figure format '.csv'"),
        (lambda: result.save(tmp_path / "x.txt"), "unknown format '.txt'; save as .npz or .csv"),
        (lambda: qcontrol.register_law("baseline", lambda table, n: None),
         "controller kind 'baseline' is a built-in name (of kind 'comparison') and cannot be registered"),
    ]
    for call, words in cases:
        with pytest.raises(QcontrolInputError) as err:
            call()
        assert words in str(err.value) and "\n" not in str(err.value)
    assert list(tmp_path.iterdir()) == []
    aliased = qcontrol.load_scenario(EX2, overrides={"controller.kind": "baseline"})
    assert aliased.controller.kind == "comparison"  # the alias still names the built-in law


def test_a_scenario_name_that_would_drive_a_terminal_is_refused_or_escaped(tmp_path, capsys):
    text = EX2.read_text()
    named = tmp_path / "named.toml"
    named.write_text(text.replace('name = "example2"', 'name = "\\u001b[31mred"'))
    assert main(["check", str(named)]) == 2
    _one_line(capsys, "scenario.name: '\\x1b[31mred' holds control characters")
    unnamed = tmp_path / "e\x1b[31mvil.toml"
    unnamed.write_text(text.replace('name = "example2"\n', ""))
    assert qcontrol.load_scenario(unnamed).name == "e\\x1b[31mvil"  # the file's name, escaped


def test_a_byte_order_mark_is_named(tmp_path, capsys):
    bom = tmp_path / "bom.toml"
    bom.write_text("\ufeff" + EX2.read_text(), encoding="utf-8")
    assert main(["check", str(bom)]) == 2
    _one_line(capsys, "bom.toml: the file starts with a byte-order mark (U+FEFF)", "without a BOM")
