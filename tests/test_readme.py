"""Every code block of the README and of the user guide's pages that hold code (docs/index.md,
docs/commands.md, docs/python.md) runs: the Python blocks in a fresh process each, and every
``qcontrol`` command of the shell blocks, in a folder holding the scenarios and models (the install
and test commands are what CI itself runs). The README stays one screenful that links into the
documentation, and its headline is the shipped reproduction."""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import pytest
from conftest import FULL_REPRODUCE, ROOT, run_forked

from qcontrol.cli import main

README = (ROOT / "README.md").read_text()
PYTHON_BLOCKS = re.findall(r"```python\n(.*?)```", README, re.S)
GUIDE = {name: (ROOT / "docs" / name).read_text() for name in ("index.md", "commands.md", "python.md")}
GUIDE_PYTHON = [block for text in GUIDE.values() for block in re.findall(r"```python\n(.*?)```", text, re.S)]


def _commands(text: str = README) -> list[str]:
    """The qcontrol commands of the shell blocks (continuations joined, comments dropped)."""
    found = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            for part in line.split("#")[0].split("&&"):
                if part.strip().startswith("qcontrol "):
                    found.append(part.strip())
    return found


@pytest.fixture
def workplace(tmp_path: Path) -> Path:
    for name in ("scenarios", "models"):
        (tmp_path / name).symlink_to(ROOT / name)
    return tmp_path


def test_the_readme_has_code_to_run() -> None:
    assert len(PYTHON_BLOCKS) >= 2 and len(_commands()) >= 8
    commands = {shlex.split(c)[1] for c in _commands()}
    assert {"run", "compare", "laws", "sweep", "region", "reproduce", "check"} <= commands  # one per command


def test_the_readme_is_one_screenful_that_links_into_the_documentation() -> None:
    assert len(README.splitlines()) <= 250
    for target in re.findall(r"\]\(((?!https?:|#)[^)#]+)(?:#[^)]*)?\)", README):
        assert (ROOT / target).exists(), f"README links to {target}, which does not exist"
    for page in ("commands.md", "python.md", "math.md", "architecture.md", "tutorial.ipynb", "paper.md"):
        assert f"(docs/{page})" in README


def test_the_readmes_headline_is_the_shipped_reproduction() -> None:
    """Table 1 in the README: the paper's rows as published, ours as docs/reproduction wrote them."""
    import json

    from qcontrol.paper import PAPER_TABLE1

    shipped = json.loads((ROOT / "docs" / "reproduction" / "table1.json").read_text())
    rows = {line.split("|")[1].strip(): [float(v) for v in line.split("|")[2:7]]
            for line in README.splitlines() if line.startswith(("| paper,", "| ours,"))}
    assert rows["paper, proposed"] == list(PAPER_TABLE1["proposed"].values())
    assert rows["paper, comparison [20]"] == list(PAPER_TABLE1["comparison"].values())
    for label, method in (("ours, proposed, paper's kappa = 1.1 + L", "proposed"),
                          ("ours, comparison [20] (reconstructed law)", "comparison")):
        assert rows[label] == [round(v, 4) for v in shipped["ours"]["mujoco"][method].values()]


BLOCKS = PYTHON_BLOCKS + GUIDE_PYTHON


@pytest.fixture(scope="module")
def block_runs(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[int, str, str]]:
    """Each Python block run as ``python -c BLOCK`` in a folder of its own holding the scenarios and
    models, each in a fresh process (a fork of one interpreter that has imported the package and
    run nothing, conftest's runner): its exit status, stdout and stderr."""
    root = tmp_path_factory.mktemp("blocks")
    commands = []
    for i, block in enumerate(BLOCKS):
        folder = root / f"block{i}"
        folder.mkdir()
        for name in ("scenarios", "models"):
            (folder / name).symlink_to(ROOT / name)
        commands.append({"argv": ["python", "-c", block], "cwd": str(folder)})
    return run_forked(commands, root, dict(os.environ), timeout=300)


@pytest.mark.parametrize("i", range(len(BLOCKS)), ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_python_block_runs(block_runs: list[tuple[int, str, str]], i: int) -> None:
    status, _, err = block_runs[i]
    assert status == 0, err


# Commands run with a shorter horizon: the README's full `qcontrol reproduce` (paper's 10 s horizon,
# the robustness study: minutes of CPU) runs on 0.5 s runs, every study and figure of it: the
# session's shared run (conftest.py), whose files tests/test_reproduce.py reads; its numbers at
# the paper's horizon are the committed docs/reproduction/*.json.
SHORTENED = {"reproduce": ["--duration", "0.5"]}


@pytest.mark.parametrize("command", sorted(set(_commands()).union(*(_commands(t) for t in GUIDE.values()))))
def test_shell_command_runs(workplace: Path, monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest,
                            command: str) -> None:
    monkeypatch.chdir(workplace)
    argv = [*shlex.split(command)[1:], *SHORTENED.get(shlex.split(command)[1], []), "-q"]
    if argv == FULL_REPRODUCE:  # run once for the session, where its files are read
        assert request.getfixturevalue("full_reproduction")[1] == 0
        return
    # what a command does, not its compiled form (tests/test_compiled_*.py): the sweep and the
    # region map would otherwise reach the compile gate and compile their batches (seconds of CPU
    # each on an empty cache) for numbers the array form gives to the last bit
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    assert main(argv) == 0


def test_animation_at_the_top_is_small_and_its_command_is_documented() -> None:
    from PIL import Image

    first_image = re.search(r"!\[[^\]]*\]\(([^)]+)\)", README)
    assert first_image and first_image.start() < README.index("## Quick start")
    gif = ROOT / first_image.group(1)
    assert gif.suffix == ".gif" and gif.stat().st_size < 2_000_000
    with Image.open(gif) as image:
        assert image.n_frames > 100  # an animation of the run, not a still
    made_by = re.search(r"`(qcontrol run example2 --video (\S+) [^`]*)`", README[:first_image.end() + 600])
    assert made_by and made_by.group(2) == first_image.group(1)
    from qcontrol.cli.dispatch import build_parser

    args = build_parser().parse_args(shlex.split(made_by.group(1))[1:])
    assert args.video == Path(first_image.group(1))
