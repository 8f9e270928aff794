"""Messages that tell the truth: a diverged run says when and why it stopped and what usually
helps; the step limit says what `run` keeps; a dt that does not divide the duration gets steps and
durations that work (checked by using them); every TOML hint is TOML; a run of a paper scenario
says what the paper reports and where the difference is explained.
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import pytest
from conftest import EX1, EX2, ROOT

from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError
from qcontrol.explain import README_SECTION, SAMPLED_WARNING
from qcontrol.paper import PAPER_TABLE1
from qcontrol.scenario import load_scenario
from qcontrol.timegrid import step_count

CHAIN3 = ROOT / "scenarios" / "chain3.toml"


def toml_hints(line: str) -> list[str]:
    """The snippets a message offers to be written into a scenario: what follows ``write`` (and
    ``e.g.``) up to the end of its clause, when it looks like TOML rather than words, an option or
    an expression; and every table header in the fix (after the first ``; ``)."""
    snippets = []
    for match in re.finditer(r"\bwrite (?:e\.g\. )?(.+?)(?=; |, or | or | \(|$)", line):
        snippet = match.group(1).strip()
        if snippet.startswith("--") or re.match(r"^[a-z]+\(", snippet):
            continue  # a command-line option, or an expression over x1..xn
        if re.match(r"^[A-Za-z]+ [a-z]+", snippet):
            continue  # words
        snippets.append(snippet)
    fix = line.split("; ", 1)[-1]
    snippets += re.findall(r"\[\[?[\w.<>]+(?:\[\d+\])*\]?\]", fix)
    return snippets


def is_toml(snippet: str) -> bool:
    """A header, ``key = value`` lines, or a value."""
    for text in (snippet + "\n", f"v = {snippet}\n"):
        try:
            tomllib.loads(text)
            return True
        except tomllib.TOMLDecodeError:
            pass
    return False


def assert_toml_hints(line: str) -> None:
    bad = [hint for hint in toml_hints(line) if not is_toml(hint)]
    assert not bad, f"hints that are not TOML: {bad} in {line!r}"


def test_the_toml_hint_checker_catches_the_finding() -> None:
    """The finding: a hint `write [reference.terms[0]]`, which is not TOML."""
    assert "[reference.terms[0]]" in toml_hints("x: must be a table; write [reference.terms[0]]")
    assert "[controller.<kind>]" in toml_hints("x: y; settings go in a sub-table, e.g. [controller.<kind>]")
    assert not is_toml("[controller.<kind>]")
    assert not is_toml("[reference.terms[0]]")
    assert is_toml("[[reference.terms]]") and is_toml("parameters = {mass = 1.0}") and is_toml("[1.0, 2.0]")


@pytest.mark.parametrize("text", [
    '[reference]\nkind = "sum_of_sines"\nterms = [1.0]\n',
    '[reference]\nkind = "sum_of_sines"\nterms = 3\n',
])
def test_a_hint_about_a_list_of_tables_is_toml(tmp_path: Path, text: str) -> None:
    base = EX2.read_text().replace('"qcontrol:models/', f'"{ROOT}/models/')
    base = base.replace('kind = "sine"          # y_d = sin(1.5 t)\namplitude = 1.0\nfrequency = 1.5\n', "")
    path = tmp_path / "bad.toml"
    path.write_text(base.replace("[reference]\n", text))
    with pytest.raises(QcontrolInputError) as exc:
        load_scenario(path)
    assert toml_hints(str(exc.value)), str(exc.value)
    assert_toml_hints(str(exc.value))


# --------------------------------------------------------------------------------------------
# a diverged run


def test_a_diverged_run_says_when_why_and_what_helps(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Example 1 from x(0) = [30, 0] at dt = 1 ms: outside the measured region, it blows up in 7 steps."""
    out = tmp_path / "out"
    assert main(["run", str(EX1), "--backend", "ode", "--set", "plant.x0=[30.0, 0.0]", "--out", str(out),
                 "-q"]) == 1
    printed = capsys.readouterr().out
    s = json.loads((out / "summary.json").read_text())
    steps, t = s["steps"], s["diverged_time"]
    assert steps == round(t / 0.001) and 0 < t < 0.05
    assert f"stopped after {steps} of 10000 steps of 0.001 s ({t:g} s of 10 s simulated)" in printed
    assert f"  DIVERGED: stopped at t = {t:g} s of 10 s: {s['divergence_reason']}" in printed
    assert re.fullmatch(r"x[12] = \S+ left the bound \|x_i\| <= 1e\+06", s["divergence_reason"])
    helps = next(line for line in printed.splitlines() if line.startswith("  what usually helps: "))
    assert "a smaller --dt or simulation.control_period" in helps and "eq. (44)" in helps
    assert "max |x_i(0)| = 30" in helps and "measure it with 'qcontrol region " in helps
    assert 'hold = "exact"' in helps
    kt = s["max_gain_period"]
    assert kt > 1 and f"  warning: K T reached {kt:.4g} > 1: {SAMPLED_WARNING}" in printed


def test_the_gain_period_monitor_is_printed_without_a_warning_on_the_paper_run(capsys, tmp_path) -> None:
    """Example 2 as shipped: K T stays near 0.011, printed, and no sampled-loop warning."""
    assert main(["run", str(EX2), "--backend", "ode", "--set", "simulation.duration=2.0",
                 "--out", str(tmp_path / "r"), "-q"]) == 0
    printed = capsys.readouterr().out
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert 0.005 < s["max_gain_period"] < 0.02
    assert f"sampled loop: max K T = {s['max_gain_period']:.4g}" in printed
    assert SAMPLED_WARNING not in printed


@pytest.mark.usefixtures("python_loop")
def test_the_diverged_reason_names_a_nan_state() -> None:
    from qcontrol.assembly import run_scenario

    sc = load_scenario(EX1, ['plant.psi="exp(x2)**2"', "plant.x0=[0.8, 3.0]", "simulation.backend='ode'"])
    run = run_scenario(sc, "ode", record="metrics")
    assert run.diverged and re.fullmatch(r"x2 became NaN/Inf", run.divergence_reason)


# --------------------------------------------------------------------------------------------
# the time grid and the step limit


def test_the_step_limit_says_what_run_keeps(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(EX2), "--duration", "1e6", "-q"]) == 2
    err = capsys.readouterr().err
    assert "more than the limit of 20,000,000 steps per run" in err
    assert "qcontrol run keeps only its metrics" in err and "compare and reproduce keep every step" in err


@pytest.mark.parametrize(("duration", "dt"), [(10.0, 0.003), (10.0, 0.0007), (2.0, 0.3), (1.0, 0.00123)])
def test_a_dt_that_does_not_divide_the_duration_gets_values_that_work(duration: float, dt: float) -> None:
    with pytest.raises(QcontrolInputError) as exc:
        step_count(duration, dt)
    message = str(exc.value)
    steps, durations = re.search(r"the nearest that work are dt = (.+) for this duration, or duration = (.+) "
                                 r"for this dt$", message).groups()
    for step in re.findall(r"([0-9.e+-]+) s", steps):
        assert step_count(duration, float(step)) >= 1  # each suggested step divides the duration
    for nearest in re.findall(r"([0-9.e+-]+) s", durations):
        assert step_count(float(nearest), dt) >= 1  # each suggested duration is whole steps of dt
    assert abs(float(re.findall(r"([0-9.e+-]+) s", durations)[0]) - duration) < dt


def test_the_finding_dt_0_003_names_the_nearest_values(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(EX2), "--dt", "0.003", "-q"]) == 2
    err = capsys.readouterr().err
    assert "dt = 0.0025 s or 0.0032 s for this duration, or duration = 9.999 s or 10.002 s for this dt" in err


# --------------------------------------------------------------------------------------------
# the first run tells the story


@pytest.mark.parametrize(("overrides", "row"), [((), "proposed"), (("--set", "controller.kind=comparison"),
                                                                   "comparison")])
def test_a_paper_scenario_prints_the_papers_value(capsys: pytest.CaptureFixture[str],
                                                  overrides: tuple[str, ...], row: str) -> None:
    assert main(["run", str(EX2), "--backend", "ode", "-q", *overrides]) == 0
    lines = capsys.readouterr().out.splitlines()
    told = [line for line in lines if "paper, Table 1" in line]
    assert len(told) == 1 and lines.index(told[0]) == len(lines) - 1  # under the summary
    rates = "  ".join(f"E({w})={v:.4f}" for w, v in PAPER_TABLE1[row].items())
    assert told[0] == f"  paper, Table 1, {row} law: {rates}; why ours differs: {README_SECTION}"


@pytest.mark.parametrize(("scenario", "args", "differs"), [
    (EX2, ("--duration", "1"), "simulation.duration = 1.0 (example2.toml: 10.0)"),
    (EX2, ("--set", "controller.delta=0.02"), "controller.delta = 0.02 (example2.toml: 0.01)"),
    (EX2, ("--unset", "reference.amplitude", "--unset", "reference.frequency",
           "--set", "reference.kind=constant", "--set", "reference.value=0.2"),
     "reference.kind = 'constant' (example2.toml: 'sine')"),
    (EX1, ("--set", 'plant.psi="-0.1*x2**2"'), "plant.psi = '-0.1*x2**2' (example1.toml: '0.1*x2**2')"),
])
def test_a_run_outside_the_papers_setting_gets_no_paper_numbers(capsys: pytest.CaptureFixture[str],
                                                                 scenario: Path, args: tuple[str, ...],
                                                                 differs: str) -> None:
    assert main(["run", str(scenario), "--backend", "ode", "--duration", "1", "-q", *args]) == 0
    out = capsys.readouterr().out
    assert "paper, Table 1" not in out and "Figs. 1-4" not in out
    line = next(line for line in out.splitlines() if line.startswith("  paper:"))
    assert line.startswith(f"  paper: no numbers to compare: this run leaves the setting of the paper's "
                           f"Example {2 if scenario == EX2 else 1} in ") and differs in line


def test_a_copied_paper_scenario_naming_the_shipped_model_is_the_papers_setting(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = tmp_path / "example2.toml"
    copy.write_text(EX2.read_text())  # the shipped file names its model qcontrol:models/pendulum.xml
    assert main(["run", str(copy), "--backend", "ode", "-q"]) == 0
    assert "paper, Table 1, proposed law" in capsys.readouterr().out


def test_the_readme_has_the_section_the_line_names() -> None:
    section = re.search(r"section '(.+)'", README_SECTION).group(1)
    assert f"\n## {section}\n" in (ROOT / "README.md").read_text()


def test_example1_and_other_scenarios(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(EX1), "--backend", "ode", "-q"]) == 0
    assert "paper: Example 1 is shown in Figs. 1-4 without numbers" in capsys.readouterr().out
    assert main(["run", str(CHAIN3), "--duration", "0.5", "-q"]) == 0
    assert "paper" not in capsys.readouterr().out


def test_a_kind_switched_on_the_command_line_names_the_unset_fix(capsys: pytest.CaptureFixture[str]) -> None:
    switched = ["--set", "reference.kind=constant", "--set", "reference.value=0.2"]
    assert main(["run", str(EX2), "-q", *switched]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "reference.amplitude: does not apply to kind 'constant'" in err
    assert err.endswith("as the kind came from --set, remove the file's key: --unset reference.amplitude")
    assert main(["run", str(EX2), "-q", "--set", "controller.gain=2"]) == 2
    assert capsys.readouterr().err.strip().endswith("or leave out --set controller.gain=...")
