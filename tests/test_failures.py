"""Failures on the newer surfaces, each one line with its documented exit status: sizes bounded
before anything runs (a region's grid, the API's sweep and region), a region terminated by
SIGTERM, a scheduler that never answers, files MuJoCo would block on, a user law that fails
during a run, and the API refusing what the command line refuses."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import EX2, ROOT

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
    """SIGTERM during a region on worker processes: 143 (as a sweep), nothing written."""
    out = tmp_path / "region"
    proc = subprocess.Popen([sys.executable, "-m", "qcontrol.cli", "region", str(EX2), "--workers", "2",
                             "--resolution", "300", "--duration", "10", "-q", "--out", str(out)],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "HOME": str(tmp_path)})
    deadline = time.monotonic() + 60
    while not _has_children(proc.pid) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
    time.sleep(1.0)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "terminated" in err and "Traceback" not in err
    assert not out.exists()


def _has_children(pid: int) -> bool:
    try:
        return bool(Path(f"/proc/{pid}/task/{pid}/children").read_text().split())
    except OSError:
        return False


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
    """Ctrl-C stops the wait for the handshake: exit 130 well before the handshake's timeout
    (the bound below is the test's, not a speed requirement)."""
    pytest.importorskip("distributed")
    proc = subprocess.Popen([sys.executable, "-m", "qcontrol.cli", "region", str(EX2), "--resolution", "3",
                             "-q", "--out", str(tmp_path / "r"), "--scheduler", f"tcp://127.0.0.1:{silent_port}"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "HOME": str(tmp_path)},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while not _connected_to(silent_port) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=8)  # the handshake alone would wait 10 s
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
