"""Every code block of docs/laws.md runs, in a folder holding the scenarios and models: the Python
blocks in order in one process, then every ``qcontrol`` command of its shell blocks there, each in
a process of its own. Each process is a fork of one interpreter that has imported the command line
and the plotting library the figures are drawn with, and run nothing (what a fresh interpreter is
once it has imported them, without importing them eleven times), so a command sees nothing the
blocks or another command registered or loaded. (Not numba: a process that has started it
compiles shorter runs.)"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from conftest import ROOT

DOC = (ROOT / "docs" / "laws.md").read_text()
PYTHON_BLOCKS = re.findall(r"```python\n(.*?)```", DOC, re.S)
COMMANDS = [line.strip() for block in re.findall(r"```bash\n(.*?)```", DOC, re.S)
            for line in block.splitlines() if line.strip().startswith("qcontrol ")]
# argv[1] is a JSON pair: Python text and a list of commands. Runs the text in a fork of itself as
# `python -c` would and prints one JSON line, its exit status and stdout; then runs each command in
# a fork and prints one JSON line per command: the command and its exit status. Anything else a
# fork writes goes to stderr. A fork that ends normally leaves as the interpreter's exit does (its
# threads waited for, its atexit functions run, its output flushed) but without tearing its objects
# down one by one, which in a fork touches every page it shares with its parent: about 0.15 s of
# CPU a process (an exception still ends it the interpreter's way, with exit status 1). The
# commands run with QCONTROL_COMPILE=0, as tests/test_readme.py's: what a command does, not its
# compiled form, which the region map would otherwise compile for the integral law (a batch of two
# laws: about 1.5 s of numba on an empty cache, for numbers the array form gives to the last bit;
# tests/test_user_law_compiled.py compiles a user law's batch and checks it against its Python run).
FORKING_RUNNER = """
import atexit, json, os, shlex, sys, tempfile, threading
import matplotlib.backends.backend_agg, matplotlib.figure
from qcontrol.cli import main


def leave(status):
    sys.stdout.flush()
    getattr(threading, "_shutdown", lambda: None)()  # the non-daemon threads are waited for
    atexit._run_exitfuncs()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


text, commands = json.loads(sys.argv[1])
printed = tempfile.mkstemp()[1]
sys.stdout.flush()
pid = os.fork()
if pid == 0:
    os.dup2(os.open(printed, os.O_WRONLY | os.O_TRUNC), 1)
    exec(compile(text, "<string>", "exec"), {"__name__": "__main__", "__builtins__": __builtins__})
    leave(0)
status = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
print(json.dumps([status, open(printed).read()]), flush=True)
os.remove(printed)
os.environ["QCONTROL_COMPILE"] = "0"
for command in commands:
    sys.stdout.flush()
    pid = os.fork()
    if pid == 0:
        os.dup2(2, 1)
        leave(main(shlex.split(command)[1:]))
    status = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    print(json.dumps([command, status]), flush=True)
"""


def test_the_laws_tutorial_runs(tmp_path: Path) -> None:
    for name in ("scenarios", "models"):
        (tmp_path / name).symlink_to(ROOT / name)
    assert len(PYTHON_BLOCKS) >= 5 and len(COMMANDS) == 10
    work = json.dumps(["\n".join(PYTHON_BLOCKS), COMMANDS])
    ran = subprocess.run([sys.executable, "-c", FORKING_RUNNER, work], cwd=tmp_path, capture_output=True,
                         text=True, timeout=600)
    (status, printed), *statuses = [json.loads(line) for line in ran.stdout.splitlines()]
    assert status == 0, ran.stderr
    assert "integral [" in printed and "-5.0" in printed
    (largest,) = [line.split()[1:] for line in printed.splitlines() if line.startswith("max_abs_integral")]
    assert largest[0] == largest[1] and float(largest[0]) > 0  # the summary's max is the array's
    assert (tmp_path / "integral.png").stat().st_size > 10_000
    assert ran.returncode == 0 and statuses == [[command, 0] for command in COMMANDS], ran.stderr
    sweep = (tmp_path / "sweep-laws" / "sweep.csv").read_text()
    assert "integral-bs" in sweep and "comparison" in sweep
    assert (tmp_path / "region-laws" / "region.csv").is_file()
    table1 = (tmp_path / "reproduce-laws" / "table1.json").read_text()
    assert '"beyond_the_paper"' in table1 and '"integral-bs"' in table1
    # --quick without --duration: 1 s horizons, for the law as for the paper's two methods
    assert json.loads(table1)["provenance"]["overrides"]["integral-bs"] == [
        "controller.kind='integral-bs'", "simulation.duration=1.0"]
    assert "paper-integral [" in printed
    compared = (tmp_path / "laws-cmp" / "laws.json").read_text()
    assert all(kind in compared for kind in ("proposed", "comparison", "paper-integral"))
    assert (tmp_path / "sweep-ki" / "sweep.csv").read_text().count("\n") == 4  # a header and 3 runs
