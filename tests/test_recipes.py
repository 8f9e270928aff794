"""The recipes of docs/architecture.md ("How to add ..."), each performed exactly as the page writes
it: the page's code blocks are read from the page, written into a copy of the repository where
their first line says, and every command the recipe gives is run there (`qcontrol check`,
`qcontrol run`, a `qcontrol.run` script, and the tests the recipe names). Then this file checks
the result against an independent computation: the law's u against eqs. (31)-(34), the plant's
states against an Euler step of eq. (1), the signal against x_meas - x, the command's output."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, run_forked

PAGE = ROOT / "docs" / "architecture.md"
RECIPES = {"law": "**A control law in the package**", "backend": "**A plant backend**",
           "signal": "**A recorded signal**", "command": "**A command**"}
COPIED = ("qcontrol", "tests", "tools", "docs", "scenarios", "models", "pyproject.toml", "README.md",
          "mkdocs.yml", "LICENSE", "CITATION.cff", ".gitignore")
PLACE = re.compile(r"# (?:(new file|at the end of):? (\S+)|in (\S+), (after|before|replace) the line: (.*))$")
TIMEOUT = 600


def recipe_blocks(name: str) -> list[tuple[str, str]]:
    """The recipe's code blocks, in order: ``(language, text)``."""
    page = PAGE.read_text()
    start = page.index(RECIPES[name])
    end = page.find("\n**A ", start + 1)
    return re.findall(r"```(\w+)\n(.*?)```", page[start:end], flags=re.DOTALL)


def place(text: str, root: Path) -> bool:
    """Put a block where its first line says; False when it says nothing (a script to run)."""
    first, *body = text.splitlines()
    match = PLACE.match(first)
    if match is None:
        return False
    how, path, in_path, where, line = match.groups()
    target = root / (path or in_path)
    if how == "new file":
        assert not target.exists(), f"{target} exists already"
        target.write_text("\n".join(body) + "\n")
        return True
    if how == "at the end of":
        target.write_text(target.read_text() + "\n".join(body) + "\n")
        return True
    lines = target.read_text().splitlines()
    found = [i for i, old in enumerate(lines) if old.strip() == line.strip()]
    assert len(found) == 1, f"{in_path}: the line {line!r} is there {len(found)} times, not once"
    i = found[0]
    lines[i:i + 1] = {"after": [lines[i], *body], "before": [*body, lines[i]], "replace": body}[where]
    target.write_text("\n".join(lines) + "\n")
    return True


def run(commands: list[list[str]], root: Path, env: dict, unchecked: set[int]) -> list:
    """Each command's stdout; every command must exit 0, but those whose index is in ``unchecked``,
    which give their exit status, stdout and stderr."""
    outputs = []
    for i, (command, (status, out, err)) in enumerate(zip(commands, run_forked(commands, root, env, TIMEOUT),
                                                          strict=True)):
        if i in unchecked:
            outputs.append((status, out, err))
            continue
        assert status == 0, f"{shlex.join(command)}: {status}\n{out}\n{err}"
        outputs.append(out)
    return outputs


def perform(name: str, root: Path, then: tuple[str | list[str], ...] = ()) -> dict:
    """Every step of the recipe, in a copy of the repository at ``root``: each command's output.
    ``then``: what runs in the copy once the recipe is done, each in a fork of the interpreter that
    ran the recipe's last commands: a Python script (as ``python -c``; its stdout is the output
    named ``then i``) or a command (an argv list, which may fail: its exit status, stdout and
    stderr are the output named ``then i``)."""
    # The compiled bytecode comes along (copies keep their sources' times, so Python and pytest
    # take a module's from its __pycache__ only while its source is unchanged: a file the recipe
    # edits is compiled again); otherwise each recipe compiles the whole package and the tests it
    # runs once more, about 0.5 s of CPU a recipe. .gitignore keeps them out of the copy's git.
    for item in COPIED:
        source = ROOT / item
        if source.is_dir():
            shutil.copytree(source, root / item, ignore=shutil.ignore_patterns(".*cache"))
        else:
            shutil.copy2(source, root / item)
    env = dict(os.environ, PYTHONPATH=str(root), HOME=str(root / "home"),
               PATH=os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]))
    env.pop("PYTEST_XDIST_WORKER", None)
    # the tests a recipe names use no hypothesis: without its plugin their pytest does not import
    # hypothesis to end the session (~0.15 s of CPU a recipe)
    env["PYTEST_ADDOPTS"] = f"{os.environ.get('PYTEST_ADDOPTS', '')} -p no:hypothesispytest".strip()
    # The tests list the files with git (`git ls-files`): each step's files are added to the index
    # as intent-to-add entries, listed as added files are, without hashing and writing every file
    # of the copy into git's object store (about 0.4 s of CPU a recipe, the copy's 9 MB)
    subprocess.run(["git", "init", "-q"], cwd=root, env=env, check=True)
    outputs, names, commands = {}, [], []  # the commands since the last block placed, in order
    commands_that_may_fail = {f"then {i}" for i, item in enumerate(then) if isinstance(item, list)}

    def run_pending() -> None:
        if not commands:
            return
        unchecked = {i for i, key in enumerate(names) if key in commands_that_may_fail}
        for key, out in zip(names, run(commands, root, env, unchecked), strict=True):
            if key is not None:
                outputs[key] = out
        names.clear()
        commands.clear()

    for language, text in recipe_blocks(name):
        if place(text, root):
            run_pending()  # what ran before a block is placed ran without it
            continue
        names.append(None)
        commands.append(["git", "add", "--all", "--intent-to-add"])
        if language == "bash":
            for line in filter(None, text.splitlines()):
                names.append(line)
                commands.append(shlex.split(line))
        elif language == "python":
            names.append("python")
            commands.append(["python", "-c", text])
    for i, item in enumerate(then):
        names.append(f"then {i}")
        commands.append(item if isinstance(item, list) else ["python", "-c", item])
    run_pending()
    return outputs


def test_every_recipe_names_where_each_block_goes() -> None:
    for name in RECIPES:
        blocks = recipe_blocks(name)
        assert any(language == "bash" for language, _ in blocks), name
        for language, text in blocks:
            first = text.splitlines()[0]
            assert PLACE.match(first) or language in ("bash", "python"), (name, first)


def test_recipe_a_control_law(tmp_path) -> None:
    outputs = perform("law", tmp_path, then=("""
import json
import numpy as np
import qcontrol
sc = qcontrol.load_scenario("example2", {"controller.kind": "damped", "controller.damped.gain": 2.0,
                                         "simulation.duration": 0.3})
res = qcontrol.run(sc, backend="ode")
print(json.dumps({"c": list(sc.controller.c), "x_q": res.x_q.tolist(), "yd": res.yd.tolist(),
                  "u": res.u.tolist()}))
""",))
    assert "ok" in next(out for line, out in outputs.items() if line.startswith("qcontrol check"))
    assert '### [controller] kind = "damped"' in (tmp_path / "docs" / "scenarios.md").read_text()
    seen = json.loads(outputs["then 0"])
    for k in (0, 100, 300):  # u = alphabar_n - gain zbar_n from eqs. (31)-(34), computed here
        import qcontrol

        x_q, yd = np.array(seen["x_q"][k]), np.array(seen["yd"][k])
        zbar, alphabar = qcontrol.quantized_backstepping(seen["c"], x_q, yd)
        assert seen["u"][k] == pytest.approx(alphabar[-1] - 2.0 * zbar[-1], rel=1e-12, abs=1e-12)


def _optional_parts_default() -> bool:
    from qcontrol.plants import base

    return "physics_report" in vars(base)


@pytest.mark.skipif(not _optional_parts_default(), reason="a plant's optional parts have no defaults yet: "
                    "run and check read PhysicsReport unguarded")
def test_recipe_a_plant_backend(tmp_path) -> None:
    outputs = perform("backend", tmp_path, then=("""
import json
import qcontrol
res = qcontrol.run(qcontrol.load_scenario("example2", {"simulation.duration": 0.3}), backend="euler")
print(json.dumps({"x": res.x.tolist(), "u": res.u.tolist(), "dt": res.summary["dt"]}))
""",))
    seen = json.loads(outputs["then 0"])
    x, u, h = np.array(seen["x"]), np.array(seen["u"]), seen["dt"]
    theta = (-1.0, -3.5, -34.3)  # example2.toml: phi = [x2, x2**2 cos(x1), sin(x1)], no psi
    phi = np.column_stack([x[:-1, 1], x[:-1, 1] ** 2 * np.cos(x[:-1, 0]), np.sin(x[:-1, 0])])
    euler = x[:-1] + h * np.column_stack([x[:-1, 1], u[:-1] + phi @ theta])
    np.testing.assert_allclose(x[1:], euler, rtol=1e-12, atol=1e-12)


def test_recipe_a_recorded_signal(tmp_path) -> None:
    outputs = perform("signal", tmp_path, then=("""
import json
import qcontrol
from qcontrol.recording import series
noisy = {"simulation.duration": 0.2, "plant.mujoco.sensor_noise": [0.01, 0.0], "plant.mujoco.noise_seed": 3}
sc = qcontrol.load_scenario("example2", noisy)
res = qcontrol.run(sc, backend="mujoco")
old = qcontrol.Summary.from_json(json.loads(open("tests/data/summary-0.2.json").read()))
rows = qcontrol.sweep(sc, grid={"controller.delta": [0.01, 0.02]}, backend="mujoco")
print(json.dumps({"error": res.sensor_error.tolist(), "x": res.x.tolist(), "x_meas": res.x_meas.tolist(),
                  "old": old.max_abs_sensor_error, "sweep": [r["max_abs_sensor_error"] for r in rows],
                  "paths": sorted({s.path for s in series.run_series(res.trajectory, "mujoco")})}))
""",))
    assert "ok" in next(out for line, out in outputs.items() if line.startswith("qcontrol check"))
    written = json.loads((tmp_path / "sensor-run" / "summary.json").read_text())
    assert list(written).index("max_abs_sensor_error") == list(written).index("saturated_fraction") + 1
    largest, independent = (float(v) for v in outputs["python"].split())
    assert largest == independent > 0.0  # the reduction is the largest |x_meas - x|, computed here too
    seen = json.loads(outputs["then 0"])
    np.testing.assert_array_equal(seen["error"], np.array(seen["x_meas"]) - np.array(seen["x"]))
    assert np.abs(np.array(seen["error"])[:, 1]).max() == 0.0  # noise on x1 only
    assert seen["old"] is None and all(v > 0 for v in seen["sweep"])
    assert {"signals/sensor/x1", "signals/sensor/x2"} <= set(seen["paths"])


def test_recipe_a_command(tmp_path) -> None:
    refused = ["python", "-m", "qcontrol", "steps", "example2", "--set", "controller.c=1"]
    outputs = perform("command", tmp_path, then=(refused,))
    steps = next(out for line, out in outputs.items() if line.startswith("qcontrol steps"))
    assert steps == "example2: 250 steps\n"
    status, _, err = outputs["then 0"]  # bad input: one line, exit status 2
    assert status == 2 and err.count("\n") == 1 and "controller" in err


def test_the_concepts_are_listed_once_at_most_twenty_and_all_exist() -> None:
    page = PAGE.read_text()
    table = page[page.index("## The concepts, once each"):page.index("## One step of the loop")]
    rows = [line.split("|") for line in table.splitlines() if re.match(r"\| \d+ \|", line)]
    assert [int(row[1]) for row in rows] == list(range(1, len(rows) + 1)) and len(rows) <= 20
    source = "\n".join(path.read_text() for path in (ROOT / "qcontrol").rglob("*.py"))
    for row in rows:  # every concept, and every class or table a sentence names, is defined in the package
        for name in re.findall(r"`([A-Za-z_]+)`", row[2]) + re.findall(r"`([A-Z][A-Za-z_]*)`", row[3]):
            assert re.search(rf"^\s*(class|def) {name}\b|^{name}\b.*=", source, flags=re.MULTILINE), name
