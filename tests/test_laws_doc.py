"""Every code block of docs/laws.md runs: the Python blocks in order in one fresh interpreter, in a
folder holding the scenarios and models, then every ``qcontrol`` command of its shell blocks there,
each in a process of its own: a fork of one interpreter that has imported the command line and the
plotting library its figures are drawn with, and run nothing (what a fresh ``qcontrol`` is once
imported, without importing it ten times), so a command sees nothing another one registered or
loaded. (Not numba: a process that has started it compiles shorter runs.)"""

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
# Runs each command of argv[1] (a JSON list) in a fork of itself and prints one JSON line per
# command: the command and its exit status; a command's own output goes to stderr.
FORKING_RUNNER = """
import json, os, shlex, sys
import matplotlib.backends.backend_agg, matplotlib.figure
from qcontrol.cli import main
for command in json.loads(sys.argv[1]):
    sys.stdout.flush()
    pid = os.fork()
    if pid == 0:
        os.dup2(2, 1)
        sys.exit(main(shlex.split(command)[1:]))
    status = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    print(json.dumps([command, status]), flush=True)
"""


def test_the_laws_tutorial_runs(tmp_path: Path) -> None:
    for name in ("scenarios", "models"):
        (tmp_path / name).symlink_to(ROOT / name)
    assert len(PYTHON_BLOCKS) >= 5 and len(COMMANDS) == 10
    done = subprocess.run([sys.executable, "-c", "\n".join(PYTHON_BLOCKS)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "integral [" in done.stdout and "-5.0" in done.stdout
    (largest,) = [line.split()[1:] for line in done.stdout.splitlines()
                  if line.startswith("max_abs_integral")]
    assert largest[0] == largest[1] and float(largest[0]) > 0  # the summary's max is the array's
    assert (tmp_path / "integral.png").stat().st_size > 10_000
    ran = subprocess.run([sys.executable, "-c", FORKING_RUNNER, json.dumps(COMMANDS)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    statuses = [json.loads(line) for line in ran.stdout.splitlines()]
    assert ran.returncode == 0 and statuses == [[command, 0] for command in COMMANDS], ran.stderr
    sweep = (tmp_path / "sweep-laws" / "sweep.csv").read_text()
    assert "integral-bs" in sweep and "comparison" in sweep
    assert (tmp_path / "region-laws" / "region.csv").is_file()
    table1 = (tmp_path / "reproduce-laws" / "table1.json").read_text()
    assert '"beyond_the_paper"' in table1 and '"integral-bs"' in table1
    # --quick without --duration: 1 s horizons, for the law as for the paper's two methods
    assert json.loads(table1)["provenance"]["overrides"]["integral-bs"] == [
        "controller.kind='integral-bs'", "simulation.duration=1.0"]
    assert "paper-integral [" in done.stdout
    compared = (tmp_path / "laws-cmp" / "laws.json").read_text()
    assert all(kind in compared for kind in ("proposed", "comparison", "paper-integral"))
    assert (tmp_path / "sweep-ki" / "sweep.csv").read_text().count("\n") == 4  # a header and 3 runs
