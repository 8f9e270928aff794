"""`qcontrol reproduce --law-module FILE --law KIND`: a law of one's own studied beside the paper's
law and the comparison law (Table 1's json, the region study, the robustness study), the built-in
laws' entries exactly those of a reproduction without it; a kind that is not registered is one
line and nothing written."""

import json
import math
from pathlib import Path

import pytest
from conftest import INTEGRAL_LAW_METHODS, QUICK_REPRODUCE

import qcontrol
from qcontrol.cli import main
from qcontrol.reproduce.reproduction import SCENARIO_DIR

KIND = "repro-integral"  # the integral-action law of docs/laws.md, section 4, under a name of its own
LAW_MODULE = f'''
import numpy as np
import qcontrol


class IntegralBackstepping:
    state_size = 1

    def __init__(self, table, n):
        qcontrol.check_keys(table, ["k_i"])
        self.c, self.k_i = table["c"], float(table.get("k_i", 1.0))

{INTEGRAL_LAW_METHODS}

qcontrol.register_law("{KIND}", IntegralBackstepping, state_name="integral")
'''
OMEGAS = ["0.100", "0.125", "0.150", "0.175", "0.200"]


@pytest.fixture(scope="module")
def law_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("laws") / "mylaws.py"
    path.write_text(LAW_MODULE)
    qcontrol.load_law_module(path)  # as the command line loads it (a file runs once per process)
    return path


def _without_timing(value):
    """A json value without what differs between any two runs: wall times."""
    if isinstance(value, dict):
        return {k: _without_timing(v) for k, v in value.items() if k != "wall_time_s"}
    if isinstance(value, list):
        return [_without_timing(v) for v in value]
    return value


def _json(path: Path) -> dict:
    return _without_timing(json.loads(path.read_text()))


def _finite_rates(rates: dict) -> bool:
    return list(rates) == OMEGAS and all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in rates.values())


def test_quick_reproduce_adds_the_law_to_table1_and_leaves_the_rest(tmp_path, law_file, capsys,
                                                                   quick_reproduction) -> None:
    """The same quick reproduction (0.3 s ODE runs) with the law, through the command line, and
    without it: the session's shared run, through qcontrol.reproduce (conftest.py). The command
    line's ``--quick`` is checked here: its progress printed, no region or robustness study."""
    (plain_rep, _), more = quick_reproduction, tmp_path / "more"
    plain = plain_rep.out
    assert QUICK_REPRODUCE == ["reproduce", "--quick", "--backend", "ode", "--duration", "0.3"]
    with_law = ["--law-module", str(law_file), "--law", KIND, "--out", str(more)]
    assert main([*QUICK_REPRODUCE, *with_law]) == 0
    assert "no region or robustness study (--quick)" in capsys.readouterr().out
    assert not (more / "robustness.json").exists() and not (more / "study_margins.png").exists()
    assert "Not run here (`qcontrol reproduce --quick`)" in (more / "REPORT.md").read_text()
    table, base = _json(more / "table1.json"), _json(plain / "table1.json")
    extra = table.pop("beyond_the_paper")
    assert "Not from the paper" in extra["note"] and list(extra["ours"]) == ["ode"]
    rates = extra["ours"]["ode"][KIND]
    assert _finite_rates(rates)
    # the same law's run through the API, independently: the same numbers
    sc = qcontrol.load_scenario("example2", {"controller.kind": KIND, "simulation.duration": 0.3})
    assert rates == qcontrol.run(sc, backend="ode").summary["error_rate"]
    assert rates != table["ours"]["ode"]["proposed"]
    provenance, base_provenance = table.pop("provenance"), base.pop("provenance")
    assert table == base  # the paper's two methods, their differences and notes: as without --law
    assert provenance["overrides"][KIND] == [f"controller.kind='{KIND}'", "simulation.duration=0.3"]
    for key in ("scenario_file", "scenario_sha256", "overrides", "resolved_scenario"):
        assert {k: v for k, v in provenance[key].items() if k != KIND} == base_provenance[key]
    assert _json(more / "studies.json")["kappa_margin"] == _json(plain / "studies.json")["kappa_margin"]
    markdown, base_markdown = (more / "table1.md").read_text(), (plain / "table1.md").read_text()
    added = [line for line in markdown.splitlines() if line not in base_markdown.splitlines()]
    assert len(added) == 1 and added[0].startswith(f"| {KIND} (--law; not in the paper) | ours, ode | ")
    assert f"| {KIND} (--law; not in the paper) |" in (more / "REPORT.md").read_text()


@pytest.mark.usefixtures("python_loop")
def test_the_region_study_maps_the_law_beside_the_built_in_ones(law_file) -> None:
    from qcontrol.reproduce.region_study import LAWS, region_study
    quiet = lambda _: None  # noqa: E731
    base = region_study(SCENARIO_DIR, 0.05, quiet)
    more = region_study(SCENARIO_DIR, 0.05, quiet, (*LAWS, KIND))
    assert more["laws"] == [*LAWS, KIND]
    assert [r for r in more["rows"] if r["law"] != KIND] == base["rows"]
    own = [r for r in more["rows"] if r["law"] == KIND]
    assert {(r["example"], r["control_period"]) for r in own} == {
        (e, p) for e in ("example1", "example2") for p in (1e-3, 5e-4)}
    for r in own:
        assert r["points_in_box"] == 81 and 0 <= r["failing_in_box"] <= 81 and _finite_rates(r["error_rate"])
    assert [len(region.maps()) for region in more["regions"]] == [4] * 4


def test_the_robustness_study_runs_the_law_on_both_examples(law_file) -> None:
    """Beside the comparison law (the paper's law behaves alike; the full study is the reproduce
    tests' own): its rows, margins and disturbance cases exactly those of a study without the law."""
    from qcontrol.reproduce.robustness_study import LAWS, robustness_study, study_law
    quiet = lambda _: None  # noqa: E731
    comparison = [law for law in LAWS if law[0] == "comparison"]
    base = robustness_study(SCENARIO_DIR, 0.05, 1, quiet, comparison)
    more = robustness_study(SCENARIO_DIR, 0.05, 1, quiet, [*comparison, study_law(KIND)])
    for part in ("rows", "margins", "disturbances"):
        assert [r for r in more[part] if r["law"] != KIND] == base[part]
        assert len([r for r in more[part] if r["law"] == KIND]) == len(base[part])
    own = [r for r in more["rows"] if r["law"] == KIND]
    assert {r["example"] for r in own} == {"example1", "example2"}
    for r in own:
        assert r["mujoco"]["diverged"] == 0 and r["ode"]["diverged"] == 0
        assert all(_finite_rates({w: s["median"] for w, s in r[b]["error_rate"].items()})
                   for b in ("mujoco", "ode"))
        assert math.isfinite(r["mujoco"]["max_abs_u_applied"]["median"])


@pytest.mark.parametrize(("args", "message"), [
    (["--law", "nope"], "--law 'nope': unknown controller kind; known kinds: proposed, comparison"),
    (["--law", "comparison"], "the paper's law and the comparison law are in every study already"),
    (["--law", KIND, "--law", KIND], f"--law {KIND}: given twice"),
])
def test_a_bad_law_is_one_line_and_writes_nothing(tmp_path, law_file, capsys, args, message) -> None:
    out = tmp_path / "out"
    assert main(["reproduce", "--quick", "--backend", "ode", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and KIND in err  # it names the kinds registered
    assert not out.exists()
