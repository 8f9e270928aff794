"""Bad input creates nothing, by any command: exit status 2, one line on stderr, and no folder or
file left behind (the output folder, the recording's folder, a sweep's or a reproduction's
folder). Also `qcontrol check` on good and bad files, and `--spawn` without a display.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import EX2, ROOT, SCENARIOS

from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError
from qcontrol.recording import viewer

CHAIN3 = SCENARIOS / "chain3.toml"


def _files(folder: Path) -> list[Path]:
    return sorted(folder.rglob("*"))


def _one_line(err: str, *fragments: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("qcontrol: error: ") and "; " in lines[0] and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def _refused_and_nothing_made(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str],
                              *fragments: str) -> str:
    """Run ``argv`` in ``tmp_path`` (outputs under new folders there): exit 2, one line, and the
    folder as it was."""
    before = _files(tmp_path)
    assert main(argv) == 2
    line = _one_line(capsys.readouterr().err, *fragments)
    assert _files(tmp_path) == before, f"created: {set(_files(tmp_path)) - set(before)}"
    return line


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _mismatched_physics(tmp_path: Path) -> Path:
    """Example 2 whose theta disagrees with the MJCF: refused when the MuJoCo plant is built."""
    text = EX2.read_text().replace('"qcontrol:models/', f'"{ROOT}/models/')
    path = tmp_path / "inputs" / "bad.toml"
    path.parent.mkdir()
    path.write_text(text.replace("theta = [-1.0, -3.5, -34.3]", "theta = [-1.0, -3.5, -20.0]"))
    return path


def test_run_creates_nothing_on_bad_input(here: Path, capsys: pytest.CaptureFixture[str]) -> None:
    outputs = ["--out", "runs/a/b", "--rrd", "recs/c/run.rrd", "-q"]
    _refused_and_nothing_made(here, capsys, ["run", str(EX2), "--set", "controller.kapa=0.1", *outputs],
                              "controller.kapa")
    _refused_and_nothing_made(here, capsys, ["run", str(_mismatched_physics(here)), *outputs],
                              "plant.mujoco", "differs")
    _refused_and_nothing_made(here, capsys, ["run", str(CHAIN3), "--backend", "mujoco", *outputs],
                              "[plant.mujoco]")


def test_compare_creates_nothing_on_bad_input(here: Path, capsys: pytest.CaptureFixture[str]) -> None:
    outputs = ["--out", "runs/cmp", "--rrd", "recs/cmp.rrd", "-q"]
    _refused_and_nothing_made(here, capsys, ["compare", str(EX2), "--dt", "0.003", *outputs],
                              "not a whole number of steps")
    _refused_and_nothing_made(here, capsys, ["compare", str(CHAIN3), *outputs], "[plant.mujoco]")
    _refused_and_nothing_made(here, capsys, ["compare", str(_mismatched_physics(here)), *outputs], "differs")


def test_sweep_creates_nothing_on_bad_input(here: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The finding: `--grid controller.kapa=0.1 --out runs/sw6` left an empty runs/sw6/. A bad value
    in a later grid point is found before anything is made too."""
    _refused_and_nothing_made(here, capsys, ["sweep", str(EX2), "--grid", "controller.kapa=0.1", "--out",
                                             "runs/sw6", "-q"], "controller.kapa")
    _refused_and_nothing_made(here, capsys, ["sweep", str(EX2), "--grid", "controller.kappa_margin=0.1,-1",
                                             "--out", "runs/sw7", "-q"],
                              "--grid controller.kappa_margin=-1: must be > 0")
    _refused_and_nothing_made(here, capsys, ["sweep", str(EX2), "--grid", "controller.kappa_margin=0.1",
                                             "--unset", "reference.phase", "--out", "runs/sw8", "-q"],
                              "--unset reference.phase")


def test_reproduce_creates_nothing_on_bad_input(here: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The finding: `--scenarios /nonexistent --out runs/bad3` left an empty runs/bad3/. A folder
    missing only the last scenario the reproduction uses is refused before anything is made."""
    _refused_and_nothing_made(here, capsys, ["reproduce", "--scenarios", "/nonexistent", "--out", "runs/bad3",
                                             "-q"], "--scenarios /nonexistent", "does not exist")
    partial = here / "partial"
    partial.mkdir()
    for name in ("example1.toml", "example2.toml"):
        text = (SCENARIOS / name).read_text().replace('"qcontrol:models/', f'"{ROOT}/models/')
        (partial / name).write_text(text)
    _refused_and_nothing_made(here, capsys, ["reproduce", "--scenarios", str(partial), "--out", "runs/bad4",
                                             "-q"], "example2-rigid.toml", "not found")
    _refused_and_nothing_made(here, capsys, ["reproduce", "--backend", "mujoco", "--duration", "0.0035",
                                             "--out", "runs/bad5", "-q"], "not a whole number of steps")


def test_check_creates_nothing(here: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _refused_and_nothing_made(here, capsys, ["check", str(EX2), "--set", "controller.kapa=0.1"],
                              "controller.kapa")
    assert main(["check", str(EX2)]) == 0
    assert _files(here) == []


# --------------------------------------------------------------------------------------------
# qcontrol check


@pytest.mark.parametrize("name", ["example1", "example2", "example2-rigid", "chain3"])
def test_check_passes_the_shipped_scenarios(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    path = SCENARIOS / f"{name}.toml"
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith(f"ok: {path} ({name}): ") and len(out.splitlines()) == 1
    assert "10000 steps of 0.001 s" in out
    if name != "chain3":  # the MuJoCo model was built and compared with eq. (1)
        assert "mujoco: the model compiled and agrees with eq. (1) at 300 sampled states" in out


@pytest.mark.parametrize(("overrides", "expected"), [
    (["--set", 'plant.phi=["x2", "x2**2*cos(x1)", "sin(x1) + __import__(1)"]'],
     "unknown function '__import__'"),
    (["--set", "plant.theta=[-1.0, -3.5, -20.0]"], "plant.mujoco: MuJoCo's acceleration differs"),
    (["--set", "controller.kappa=0.01"], "must exceed L"),
    (["--set", 'controller.proposed.r=["1 + q2**2", "q2**2", "1"]'], "must be finite and >= 1"),
    (["--unset", "plant.mujoco"], "simulation.backend: is 'mujoco' but the plant has no [plant.mujoco]"),
    (["--set", "simulation.dt=0.003"], "not a whole number of steps"),
])
def test_check_refuses_bad_files(overrides: list[str], expected: str,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(EX2), *overrides]) == 2
    _one_line(capsys.readouterr().err, expected)


def test_check_a_file_with_realism_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Realism options make MuJoCo differ from eq. (1) on purpose: check reports it, exit 0."""
    assert main(["check", str(EX2), "--set", "plant.mujoco.frictionloss=0.5"]) == 0
    assert "as its realism options (frictionloss) make it" in capsys.readouterr().out


# --------------------------------------------------------------------------------------------
# --spawn without a display


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def no_display(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(viewer, "PORT", _free_port())  # no viewer listens there


@pytest.mark.parametrize("command", ["run", "compare"])
def test_spawn_without_a_display_is_one_line_before_the_run(here: Path, capsys: pytest.CaptureFixture[str],
                                                            no_display: None, command: str) -> None:
    if sys.platform != "linux":
        pytest.skip("the display check concerns X11 and Wayland")
    argv = [command, str(EX2), "--spawn", "--out", "runs/x", "--rrd", "recs/x.rrd"]
    before = _files(here)
    assert main(argv) == 2
    captured = capsys.readouterr()
    _one_line(captured.err, "--spawn: cannot open the rerun viewer: no display (DISPLAY and WAYLAND_DISPLAY "
              "are unset)", "--rrd FILE")
    assert captured.out == ""  # the run never started
    assert _files(here) == before


def test_spawn_without_a_display_in_a_real_interpreter(tmp_path: Path) -> None:
    """Through the console entry: stderr is the one line, none of the viewer's own logs."""
    if sys.platform != "linux" or viewer.listening(viewer.PORT):
        pytest.skip("needs Linux and no viewer listening on rerun's port")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")}
    proc = subprocess.run([sys.executable, "-m", "qcontrol.cli", "run", str(EX2), "--spawn"],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path,
                          env=env | {"HOME": str(tmp_path)})
    assert proc.returncode == 2 and proc.stdout == ""
    _one_line(proc.stderr, "--spawn", "no display")
    assert list(tmp_path.iterdir()) == []


def test_a_display_that_cannot_be_reached_is_no_display(tmp_path: Path) -> None:
    missing = next(n for n in range(90, 200) if not Path(f"/tmp/.X11-unix/X{n}").exists())
    problem = viewer.display_problem({"DISPLAY": f":{missing}"}, "linux")
    assert problem == f"the display DISPLAY=:{missing} cannot be reached"
    assert viewer.display_problem({"WAYLAND_DISPLAY": "wayland-9"}, "linux") is not None
    assert viewer.display_problem({}, "linux") == "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    assert viewer.display_problem({}, "darwin") is None


def test_a_viewer_that_exits_at_once_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A reachable display but a viewer that cannot open its window: one line naming --spawn."""
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(tmp_path / "wayland-0"))
    listener.listen(1)
    fake = tmp_path / "rerun"
    fake.write_text("#!/bin/sh\necho 'viewer log line' >&2\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setenv("WAYLAND_DISPLAY", str(tmp_path / "wayland-0"))
    refused = pytest.raises(QcontrolInputError, match=r"--spawn: the rerun viewer exited at once \(status 3")
    with listener, refused:
        viewer.start_viewer(_free_port(), executable=str(fake))


def test_a_listening_viewer_is_reused_without_a_display(no_display: None) -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen(1)
        assert viewer.start_viewer(sock.getsockname()[1]) is None
