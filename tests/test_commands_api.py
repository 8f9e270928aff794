"""The command line's other commands as functions: qcontrol.check, qcontrol.region and
qcontrol.reproduce return typed results holding what the commands print and write."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import EX2, QUICK_REPRODUCE_CALL

import qcontrol
from qcontrol.cli import main
from qcontrol.paper import PAPER_TABLE1
from qcontrol.region import OUTCOMES, Region


def test_check_reports_the_models_agreement_and_prints_the_commands_line(capsys) -> None:
    report = qcontrol.check(qcontrol.load_scenario("example2"))
    assert isinstance(report, qcontrol.CheckReport)
    assert (report.scenario, report.backend, report.law) == ("example2", "mujoco", "proposed")
    assert report.steps == 10000
    mujoco = report.backends["mujoco"]
    assert mujoco["samples"] == 300 and mujoco["max_abs_mismatch"] < 1e-9  # MuJoCo realises eq. (1)
    assert main(["check", "example2"]) == 0
    assert capsys.readouterr().out.strip() == report.line()
    ode = qcontrol.check(qcontrol.load_scenario("chain3"))
    assert ode.backends == {"ode": {}} and ode.line().endswith("ode: the plant of eq. (1) built")


def test_check_refuses_what_a_run_refuses() -> None:
    sc = qcontrol.load_scenario("example2", {"plant.theta": [-1.0, -3.5, -30.0]})  # the model's is -34.3
    with pytest.raises(qcontrol.QcontrolInputError, match="-34.3"):
        qcontrol.check(sc)
    with pytest.raises(qcontrol.QcontrolInputError, match="check: expected a Scenario"):
        qcontrol.check("example2")


def test_region_is_the_commands_table_and_the_exact_hold_holds_the_box(tmp_path: Path) -> None:
    sc = qcontrol.load_scenario(EX2, {"simulation.duration": 0.5})
    found = qcontrol.region(sc, ["proposed", "proposed:hold=exact"], resolution=5, out=tmp_path / "api")
    assert isinstance(found, Region)
    assert [law.label for law in found.laws] == ["proposed", "proposed:hold=exact"]
    assert len(found.points) == 2 * 25 and {p.outcome for p in found.points} <= set(OUTCOMES)
    paper, exact = (found.law_summary(law) for law in found.laws)
    assert exact["failing_in_box"] == 0 and exact["points_in_box"] == 25  # bounded from the whole box
    assert paper["failing_in_box"] > 0  # law (44) as printed, held over 1 ms, loses the box's corners
    origin = [p for p in found.points if p.x0 == (0.0, 0.0)]
    assert [p.outcome for p in origin] == ["bounded", "bounded"]
    assert found.outcomes(found.laws[1]).shape == (5, 5)
    cli = tmp_path / "cli"
    assert main(["region", str(EX2), "--set", "simulation.duration=0.5", "--law", "proposed", "--law",
                 "proposed:hold=exact", "--resolution", "5", "--out", str(cli), "-q"]) == 0
    assert (tmp_path / "api" / "region.csv").read_text() == (cli / "region.csv").read_text()
    api_json, cli_json = (json.loads((d / "region.json").read_text()) for d in (tmp_path / "api", cli))
    assert api_json["laws"] == cli_json["laws"]


def test_region_refuses_bad_arguments_in_one_line() -> None:
    sc = qcontrol.load_scenario("example2")
    for kwargs, needle in (({"laws": "proposed"}, "laws must be a list"), ({"box": "ten"}, "box must be"),
                           ({"laws": ["nonesuch"]}, "unknown controller kind"),
                           ({"resolution": 1}, "at least 2 points")):
        with pytest.raises(qcontrol.QcontrolInputError, match=needle):
            qcontrol.region(sc, **kwargs)


def test_quick_reproduce_returns_table1_and_compares_nothing(quick_reproduction) -> None:
    """What ``qcontrol.reproduce(OUT, quick=True, backend="ode", duration=0.3)`` returned (the
    session's shared quick reproduction, made through this function: conftest.py)."""
    rep, _ = quick_reproduction
    assert QUICK_REPRODUCE_CALL == {"quick": True, "backend": "ode", "duration": 0.3}
    assert isinstance(rep, qcontrol.Reproduction) and rep.quick
    assert rep.files == tuple(sorted(p.name for p in rep.out.iterdir() if p.is_file()))
    assert {"REPORT.md", "table1.json", "table1.md", "table1.png", "studies.json"} <= set(rep.files)
    assert "region.json" not in rep.files and "robustness.json" not in rep.files
    written = json.loads((rep.out / "table1.json").read_text())
    assert rep.table1["ours"] == written["ours"] and rep.table1["paper"] == PAPER_TABLE1
    assert "difference" not in rep.table1
    proposed = rep.table1["ours"]["ode"]["proposed"]
    assert list(proposed) == ["0.100", "0.125", "0.150", "0.175", "0.200"]
    assert np.all(np.diff(list(proposed.values())) <= 0)  # E(omega) cannot grow with omega
    assert "Nothing is compared with the paper here" in rep.report


def test_reproduce_checks_its_arguments_before_making_the_folder(tmp_path: Path) -> None:
    for kwargs, needle in (({"duration": -1.0}, "duration must be"), ({"workers": 0}, "workers must be"),
                           ({"laws": "mine"}, "laws must be a list"),
                           ({"scenarios": tmp_path / "no"}, "not a folder")):
        with pytest.raises(qcontrol.QcontrolInputError, match=needle):
            qcontrol.reproduce(tmp_path / "out", quick=True, **kwargs)
    assert not (tmp_path / "out").exists()
