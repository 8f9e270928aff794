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
from conftest import EX2

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
