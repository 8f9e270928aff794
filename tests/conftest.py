"""Shared test set-up: the repository's paths and shipped scenarios (as constants, ``from conftest
import EX2``, and as fixtures), and nothing may write under the real HOME (the rerun SDK keeps
analytics there)."""

import os
import subprocess
import tempfile
from pathlib import Path

import pytest

_HOME = tempfile.mkdtemp(prefix="qcontrol-test-home-")
os.environ["HOME"] = _HOME
os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")
os.environ.setdefault("MPLBACKEND", "Agg")

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "qcontrol"
# compiled code is cached beside pytest's own cache, so later sessions load it instead of compiling
os.environ.setdefault("QCONTROL_CACHE_DIR", str(ROOT / ".pytest_cache" / "qcontrol-compiled"))
SCENARIOS = ROOT / "scenarios"
MODELS = ROOT / "models"
EX1 = SCENARIOS / "example1.toml"
EX2 = SCENARIOS / "example2.toml"

# The integral-action user law of docs/laws.md, section 4 (u = backstepping - k_i * integral of
# q1 - y_d): its methods, for test files that write the law into a module of their own.
INTEGRAL_LAW_METHODS = """
    def initial_state(self):
        return np.zeros(1)

    def control(self, t, x_q, yd, state):
        return float(qcontrol.quantized_backstepping(self.c, x_q, yd)[1][-1] - self.k_i * state[0])

    def state_rate(self, t, x_q, yd, state):
        return np.array([x_q[0] - yd[0]])
"""


@pytest.fixture
def ex1() -> Path:
    """Example 1's scenario file (the cart of eq. (47))."""
    return EX1


@pytest.fixture
def ex2() -> Path:
    """Example 2's scenario file (the pendulum of eq. (48))."""
    return EX2


@pytest.fixture
def short_example2():
    """Example 2 loaded with a 0.2 s horizon: a real closed loop in a fraction of a second."""
    from qcontrol.scenario import load_scenario

    return load_scenario(EX2, ["simulation.duration=0.2"])


@pytest.fixture
def ctrl_c_on_second_chunk(monkeypatch):
    """Call it to make the sweeps that follow run one run per chunk and be interrupted
    (KeyboardInterrupt, as Ctrl-C) when their second chunk starts: the first chunk's rows are
    finished, the rest are not."""
    from qcontrol.sweep import runs

    def arm() -> None:
        original, calls = runs._run_chunk, []

        def stop_on_the_second_chunk(*args):
            calls.append(1)
            if len(calls) == 2:
                raise KeyboardInterrupt
            return original(*args)

        monkeypatch.setattr(runs, "CHUNK", 1)
        monkeypatch.setattr(runs, "_run_chunk", stop_on_the_second_chunk)

    return arm


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs (root only): a disk that fills up."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root; the injected write errors cover the same paths")
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)],
                             capture_output=True, text=True, check=False)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    yield disk
    subprocess.run(["umount", str(disk)], check=False)
