"""Shared test set-up: the repository's paths and shipped scenarios (as constants, ``from conftest
import EX2``, and as fixtures), and nothing may write under the real HOME (the rerun SDK keeps
analytics there)."""

import contextlib
import fcntl
import io
import json
import os
import re
import select
import subprocess
import sys
import tempfile
import time
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
# what tests/test_architecture.py reads from each module's syntax tree, kept by the module's text
# (the copies of the repository tests/test_recipes.py makes are given the same folder)
os.environ.setdefault("QCONTROL_TEST_FACTS_DIR", str(ROOT / ".pytest_cache" / "architecture-facts"))
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


# The files that take longest (about 1.5 s of CPU or more, children included, measured on a fresh
# clone, an empty compiled-code cache), heaviest first. With `--dist loadfile` a file runs whole on
# one worker, so a long file handed out last leaves the other worker idle at the end; the rest, each
# shorter than that, keep their order and end the run. A file that grows past that belongs here. xdist's
# own reordering (files with the most tests first) is turned off for that. test_reproduce.py leads
# and test_readme.py comes a few files later: the full reproduction they share (made by the first
# to ask, about 16 s) is ready before the README's command asks for it, not waited for.
HEAVY_FIRST = ("test_reproduce.py", "test_compiled_loop.py", "test_one_definition.py",
               "test_output_safety.py", "test_recipes.py", "test_laws_doc.py", "test_readme.py",
               "test_plots.py", "test_sweep.py", "test_compiled_batch.py", "test_reliability.py",
               "test_reproduce_laws.py", "test_tuning.py", "test_user_law_compiled.py", "test_cli.py",
               "test_video.py", "test_fastpath.py", "test_failures.py", "test_law_api.py",
               "test_bad_input.py", "test_commands_api.py", "test_mujoco_compiled_batch.py",
               "test_native_passive.py", "test_expr_fuzz.py", "test_compiled_folds.py", "test_api.py",
               "test_sensors.py", "test_core_plant.py", "test_closed_loop.py", "test_laws_by_hand.py",
               "test_physics.py", "test_sampled.py", "test_mujoco_plant.py", "test_model_command.py")


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist's --no-loadscope-reorder
        config.option.loadscopereorder = False
    _rewrite_a_share_of_the_test_files(config)


def _rewrite_a_share_of_the_test_files(config: pytest.Config) -> None:
    """Under pytest-xdist every worker imports every test module, and pytest rewrites a module's
    asserts on import unless it finds the rewritten code cached (in ``__pycache__``): on a fresh
    clone both workers rewrite all of them at once, about 1.9 s of CPU each. Here worker k of n
    rewrites and caches every n-th file before collecting, with pytest's own functions and config,
    so each finds the others' share cached (the same code: the cache pytest writes and checks).
    Nothing changes where these internals are missing, bytecode is not written or asserts are
    not rewritten."""
    worker, count = os.environ.get("PYTEST_XDIST_WORKER"), os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if not worker or not count or sys.dont_write_bytecode or config.getoption("assertmode") != "rewrite":
        return
    try:
        from _pytest.assertion import rewrite
        state = config.stash[rewrite.assertstate_key]
        files = sorted(Path(__file__).parent.glob("test_*.py"))[int(worker.removeprefix("gw"))::int(count)]
        for file in files:
            pyc = rewrite.get_cache_dir(file) / (file.name[:-3] + rewrite.PYC_TAIL)
            if rewrite._read_pyc(file, pyc) is None and rewrite.try_makedirs(pyc.parent):
                source_hash, code = rewrite._rewrite_test(file, config)
                rewrite._write_pyc(state, code, source_hash, pyc)
    except (AttributeError, ImportError, KeyError, ValueError):  # another pytest: it rewrites them all
        return


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def _once_per_session(tmp_path_factory: pytest.TempPathFactory, name: str, make) -> Path:
    """The folder ``make(folder)`` fills, made once per test session: under pytest-xdist the first
    worker to ask makes it (the others wait on a lock, then read it). ``make`` leaves a file
    ``done`` last, so a folder without it (its maker failed) is made again."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the session's folder, shared by its workers
    folder = root / f"shared-{name}"
    with open(root / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (folder / "done").is_file():
            if folder.exists():
                import shutil

                shutil.rmtree(folder)
            folder.mkdir()
            make(folder)
            (folder / "done").write_text("")
    return folder


# A quick reproduction on 0.3 s ODE runs, as a call of qcontrol.reproduce and as its command line
QUICK_REPRODUCE_CALL = {"quick": True, "backend": "ode", "duration": 0.3}
QUICK_REPRODUCE = ["reproduce", "--quick", "--backend", "ode", "--duration", "0.3"]
# The README's `qcontrol reproduce --out results/` (every study, every figure) on 0.5 s horizons
# instead of the paper's 10 s: what tests/test_reproduce.py reads, and the README's command itself
FULL_REPRODUCE = ["reproduce", "--out", "results/", "--duration", "0.5", "-q"]


def _reproduction(folder: Path, argv: list[str]) -> None:
    """``argv`` with its ``--out`` inside ``folder``: the exit status and what it printed, kept
    in ``folder/run.json``."""
    from qcontrol.cli import main

    argv = list(argv)
    argv[argv.index("--out") + 1] = str(folder / "out")
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        status = main(argv)
    (folder / "run.json").write_text(json.dumps({"status": status, "stdout": printed.getvalue()}))


def _shared_reproduction(tmp_path_factory: pytest.TempPathFactory, name: str,
                         argv: list[str]) -> tuple[Path, int, str]:
    folder = _once_per_session(tmp_path_factory, name, lambda folder: _reproduction(folder, argv))
    run = json.loads((folder / "run.json").read_text())
    return folder / "out", run["status"], run["stdout"]


def _api_reproduction(folder: Path) -> None:
    """``qcontrol.reproduce(folder / "out", **QUICK_REPRODUCE_CALL)``: the Reproduction it returned
    and the lines it logged, pickled in ``folder/run.pickle``: the other workers read the very
    object it returned (a tuple stays a tuple, a Path a Path: JSON would change them)."""
    import pickle

    import qcontrol

    lines: list[str] = []
    rep = qcontrol.reproduce(folder / "out", **QUICK_REPRODUCE_CALL, log=lines.append)
    (folder / "run.pickle").write_bytes(pickle.dumps((rep, "\n".join(lines))))


@pytest.fixture(scope="session")
def quick_reproduction(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    """``qcontrol.reproduce(FOLDER, **QUICK_REPRODUCE_CALL)``, run once for the session through the
    API (the test files that read a quick reproduction share it; tests/test_reproduce_laws.py runs
    the same reproduction, with a law more, through the command line): the
    :class:`qcontrol.Reproduction` it returned and what it logged."""
    import pickle

    folder = _once_per_session(tmp_path_factory, "quick-reproduce", _api_reproduction)
    return pickle.loads((folder / "run.pickle").read_bytes())


@pytest.fixture(scope="session")
def full_reproduction(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int, str]:
    """``qcontrol FULL_REPRODUCE`` with its ``--out`` in a folder of the session, run once (the
    README's command and tests/test_reproduce.py share it): the folder, the exit status and what
    it printed."""
    return _shared_reproduction(tmp_path_factory, "full-reproduce", FULL_REPRODUCE)


# Runs the commands of argv[1] (a JSON list of argv lists, ["python", "-c", text] for a script; an
# item {"argv": [...], "cwd": folder} runs in a folder of its own) each as the process it names
# would: `qcontrol ...` through the console script's entry point, `python FILE`, `python -m
# MODULE` and `python -c TEXT` as the interpreter runs them, anything
# else (git) as a subprocess. A command runs in a fork of this interpreter, which has imported
# the package (the one on its PYTHONPATH: a recipe's copy, as the recipe left it) and run nothing,
# not numba either: what a fresh process is once it has imported the package, without starting an
# interpreter per command. Prints one JSON line per command: its exit status, stdout and stderr.
FORKING_RUNNER = """
import json, os, runpy, subprocess, sys, tempfile
import qcontrol, qcontrol._entry, qcontrol.cli


def child(argv):
    if argv[0] == "qcontrol":
        sys.argv = argv
        sys.exit(qcontrol._entry.main())
    if argv[1] == "-c":
        sys.argv, sys.path[0] = ["-c", *argv[3:]], ""
        exec(compile(argv[2], "<string>", "exec"), {"__name__": "__main__", "__builtins__": __builtins__})
    elif argv[1] == "-m":
        sys.argv, sys.path[0] = argv[2:], os.getcwd()
        runpy.run_module(argv[2], run_name="__main__", alter_sys=True)
    else:
        sys.argv, sys.path[0] = argv[1:], os.path.dirname(os.path.abspath(argv[1]))
        runpy.run_path(argv[1], run_name="__main__")
    sys.exit(0)


folder = tempfile.mkdtemp()
for argv in json.loads(sys.argv[1]):
    cwd = None
    if isinstance(argv, dict):
        argv, cwd = argv["argv"], argv["cwd"]
    if argv[0] not in ("python", "qcontrol"):
        done = subprocess.run(argv, capture_output=True, text=True, cwd=cwd)
        print(json.dumps([done.returncode, done.stdout, done.stderr]), flush=True)
        continue
    out, err = os.path.join(folder, "out"), os.path.join(folder, "err")
    sys.stdout.flush()
    pid = os.fork()
    if pid == 0:
        os.dup2(os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), 1)
        os.dup2(os.open(err, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), 2)
        if cwd is not None:
            os.chdir(cwd)
        child(argv)
    status = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    print(json.dumps([status, open(out).read(), open(err).read()]), flush=True)
"""


def run_forked(commands: list, cwd: Path, env: dict,
               timeout: float = 600) -> list[tuple[int, str, str]]:
    """Each command's exit status, stdout and stderr, run in ``cwd`` by :data:`FORKING_RUNNER`."""
    done = subprocess.run([sys.executable, "-c", FORKING_RUNNER, json.dumps(commands)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)
    results = [tuple(json.loads(line)) for line in done.stdout.splitlines()]
    assert done.returncode == 0 and len(results) == len(commands), done.stderr
    return results


def progress_past_zero(master: int, proc: subprocess.Popen, timeout: float = 60.0) -> str:
    """What command ``proc`` printed on its stderr, the pseudo-terminal whose other end is
    ``master``, read until its progress line (``label:  42%``) is past 0 %: its loop is running, a
    part of the run done and the next under way (its checks, a compile, a recording's set-up all
    behind it). A condition to wait on before signalling a run, instead of a fixed sleep;
    ``timeout`` bounds only a command that hangs or shows no progress (the test then fails)."""
    deadline, shown = time.monotonic() + timeout, ""
    while not re.search(r"[1-9]\d*%", shown) and proc.poll() is None and time.monotonic() < deadline:
        if select.select([master], [], [], 0.05)[0]:
            shown += os.read(master, 4096).decode(errors="replace")
    assert re.search(r"[1-9]\d*%", shown), f"no progress past 0 % shown: {shown!r}"
    return shown


def drain_terminal(master: int) -> str:
    """Everything left on a pseudo-terminal whose other end has closed."""
    text = ""
    while select.select([master], [], [], 0.5)[0]:
        try:
            chunk = os.read(master, 4096)
        except OSError:  # EIO: the other end is closed
            break
        if not chunk:
            break
        text += chunk.decode(errors="replace")
    return text


def process_fields(pid: int) -> list[str] | None:
    """The fields of ``/proc/PID/stat`` after the command's name (0 the state, "Z" a zombie; 1 the
    parent; 2 the process group; 11 and 12 the user and system clock ticks), or None once the
    process is gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def processes() -> list[int]:
    """Every process's id (read from /proc)."""
    return [int(entry.name) for entry in Path("/proc").iterdir() if entry.name.isdigit()]


def cpu_seconds(pid: int) -> float:
    """The CPU seconds (user + system) process ``pid`` used so far (0 once it is gone)."""
    fields = process_fields(pid)
    return 0.0 if fields is None else (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def children_of(pid: int) -> list[int]:
    """The processes whose parent is ``pid``."""
    return [child for child in processes() if (fields := process_fields(child)) and int(fields[1]) == pid]


def forks_of(pid: int) -> list[int]:
    """The children of ``pid`` that are forks of it (the same command line): its workers, not a
    helper program a library starts for a moment (importing MuJoCo runs ``python -c`` to ask
    GLFW's version; matplotlib runs ``fc-list``)."""
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return []
    found = []
    for child in children_of(pid):
        try:
            if Path(f"/proc/{child}/cmdline").read_bytes() == command:
                found.append(child)
        except OSError:
            continue
    return found


def busy(pid: int, seconds: float = 0.05, timeout: float = 60.0) -> bool:
    """Whether process ``pid`` has used ``seconds`` of CPU (it is working on its runs), asked until
    then, for at most ``timeout`` seconds (a bound on a worker that never runs, not a wait)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and process_fields(pid) is not None:
        if cpu_seconds(pid) >= seconds:
            return True
        time.sleep(0.01)
    return False


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
def python_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs in the Python loop and the array form (``QCONTROL_COMPILE=0``), for a test of what a
    run does rather than of its compiled form whose scenario (a plant term, a bounding function of
    its own) would be one more generated module to compile: seconds on an empty cache against a
    fraction of a second in Python. The compiled forms give the Python loop's numbers to the last
    bit (tests/test_compiled_loop.py, tests/test_compiled_batch.py)."""
    monkeypatch.setenv("QCONTROL_COMPILE", "0")


@pytest.fixture
def figure_not_drawn(monkeypatch) -> list:
    """For a test of a sweep's table and record: the sweep command's figure (about 0.3 s of
    matplotlib a sweep) is not drawn; tests/test_sweep.py's figure tests draw and check it, diverged
    runs, random initial states and the partial name among them. The paths it would have been
    drawn to."""
    from qcontrol.plots import sweeps as sweep_plots

    paths = []
    monkeypatch.setattr(sweep_plots, "fig_sweep", lambda rows, keys, metrics, path, title: paths.append(path))
    return paths


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
