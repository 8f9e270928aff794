"""The documents ship with the code and agree with it: docs/scenarios.md is made from the key
declarations (and is in sync), its examples are valid scenarios, every reference to a section of
docs/math.md names a section that exists, and nothing cites a document outside the repository."""

from __future__ import annotations

import itertools
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from qcontrol.controller import LAW_KINDS
from qcontrol.reference import REFERENCE_KINDS
from qcontrol.scenario import parse_scenario
from qcontrol.scenario.document import scenarios_markdown
from qcontrol.scenario.keys import TOP, top_sections
from qcontrol.schema import REQUIRED

DOCS = ROOT / "docs"


def test_scenarios_md_is_in_sync_with_the_declarations() -> None:
    """Fails when a key, kind or backend changed and the document was not regenerated. The check
    runs in a fresh interpreter, as the tool does: laws other tests register are not shipped."""
    check = subprocess.run([sys.executable, str(ROOT / "tools" / "make_scenarios_doc.py"), "--check"],
                           capture_output=True, text=True, check=False)
    assert check.returncode == 0, "docs/scenarios.md is stale: run python tools/make_scenarios_doc.py"


def test_every_table_is_documented_and_every_required_key_has_an_example() -> None:
    sections = top_sections()
    assert [s.name for s in sections] == list(TOP), "declare every top-level table in top_sections()"
    kinds = [k for s in sections for k in s.kinds.values() if k is not None]
    for key in [*(k for s in sections for k in s.keys), *(k for kind in kinds for k in kind.keys)]:
        assert key.meaning, key.name
        assert key.default is not REQUIRED or key.example, f"required key {key.name} needs an example"


def _blocks(markdown: str) -> dict[str, str]:
    """The document's TOML examples, keyed by their first line (a table header) and, for a kinded
    table, the kind."""
    blocks = {}
    for text in re.findall(r"```toml\n(.*?)```", markdown, flags=re.S):
        header = text.splitlines()[0]
        kind = re.search(r'^kind = "(.+)"$', text, flags=re.M)
        blocks[header + (f" {kind.group(1)}" if kind else "")] = text
    return blocks


@pytest.mark.parametrize(("law", "reference"), list(itertools.product(
    [k for k, kind in LAW_KINDS.items() if kind.keys is not None], REFERENCE_KINDS)))
def test_the_documents_examples_make_a_valid_scenario(law: str, reference: str) -> None:
    blocks = _blocks(scenarios_markdown())
    names = ["[scenario]", "[plant]", "[plant.mujoco]", f"[controller] {law}", f"[reference] {reference}",
             "[simulation]"]
    text = "\n".join(blocks[name] for name in names)
    sc = parse_scenario(text, source="docs/scenarios.md", base_dir=ROOT / "scenarios")
    assert (sc.controller.kind, sc.reference.kind, sc.simulation.backend) == (law, reference, "mujoco")


MATH_REFERENCE = re.compile(r"docs/math\.md, (?:section )?'(.+?)'(?=[).;,:\s]|$)")


def _headings(path: Path) -> set[str]:
    lines = path.read_text(encoding="utf-8").splitlines()
    return {line[3:].strip() for line in lines if line.startswith("## ")}


TEXT = (".py", ".md", ".toml", ".xml", ".json", ".txt", ".cfg", ".yml", ".yaml", "")


def _tracked(*patterns: str) -> list[Path]:
    """The repository's text files (under ``patterns``), as git knows them."""
    names = subprocess.run(["git", "ls-files", *patterns], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    return [ROOT / name for name in names if (ROOT / name).suffix in TEXT and (ROOT / name).is_file()]


def test_every_reference_to_math_md_names_a_section() -> None:
    headings = _headings(DOCS / "math.md")
    texts = {path: path.read_text(encoding="utf-8") for path in _tracked("qcontrol", "README.md", "scenarios",
                                                                       "models", "tools", "docs")}
    found = {(path.name, name) for path, text in texts.items() for name in MATH_REFERENCE.findall(
        re.sub(r'"\s*\n\s*"', "", text))}  # Python's implicit concatenation of strings across lines
    assert found, "no reference found: the pattern is wrong"
    missing = {(where, name) for where, name in found if name not in headings}
    assert not missing, f"references to sections docs/math.md does not have: {sorted(missing)}"


def test_every_document_a_text_points_to_exists() -> None:
    for path in _tracked("qcontrol", "README.md", "docs", "tools"):
        for name in re.findall(r"\bdocs/[\w/.-]+\.(?:md|png|json)", path.read_text(encoding="utf-8")):
            assert (ROOT / name).exists(), f"{path.name} points to {name}, which does not exist"


def test_nothing_cites_a_document_outside_the_repository() -> None:
    # the bracketed letters keep this line from matching itself
    outside = re.compile(r"\bS[P]EC\b|\bD[E]SIGN\b|/w[o]rk/|\.\./sh[a]red|\b[Ii]ssue [0-9]+")
    # every match holds one of these: a text without any is read no further (the pattern's
    # alternatives tried at each of 2.8 MB of characters take 0.2 s of CPU; these searches, 10 ms)
    needles = ("S" "PEC", "D" "ESIGN", "/w" "ork/", "../sh" "ared", "ssue ")
    for path in _tracked():
        text = path.read_text(encoding="utf-8", errors="replace")
        if not any(needle in text for needle in needles):
            continue
        for number, line in enumerate(text.splitlines(), 1):
            assert not outside.search(line), f"{path.relative_to(ROOT)}:{number}: {line.strip()}"


def test_the_scenario_guides_example_is_valid() -> None:
    guide = (DOCS / "writing-scenarios.md").read_text(encoding="utf-8")
    block = re.search(r"## Writing a scenario\n\n```toml\n(.*?)```", guide, flags=re.S).group(1)
    sc = parse_scenario(block, source="docs/writing-scenarios.md")
    assert (sc.name, sc.order, sc.controller.kind, sc.reference.kind) == ("my-plant", 2, "proposed", "sine")


def test_licence_and_citation_agree_with_the_package() -> None:
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == {"text": "MIT"}
    licence = (ROOT / "LICENSE").read_text()
    assert licence.startswith("MIT License") and "the qcontrol authors" in licence
    citation = (ROOT / "CITATION.cff").read_text()
    from qcontrol import __version__

    assert f'version: "{__version__}"' in citation and "license: MIT" in citation
    assert citation.count("doi: 10.3390/electronics11193160") == 2  # the paper: preferred and referenced
    assert "Global Adaptive Control for Uncertain Nonlinear Systems under Non-Lipschitz Condition" in citation


def test_every_page_of_the_site_is_in_its_navigation() -> None:
    """mkdocs builds the site from docs/ (CI: mkdocs build --strict, which also fails on a broken link
    or reference); a page left out of the navigation is found here without the docs extra."""
    config = (ROOT / "mkdocs.yml").read_text()
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*") if p.suffix in (".md", ".ipynb")}
    listed = set(re.findall(r"^\s+- (?:[^:\n]+: )?([\w/.-]+\.(?:md|ipynb))$", config, flags=re.M))
    not_in_nav = set(re.findall(r"^  ([\w/.-]+\.md)$", config, flags=re.M))
    assert pages == listed | not_in_nav, sorted(pages ^ (listed | not_in_nav))
