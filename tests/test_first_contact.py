"""The rough edges a new user meets first: law settings on `qcontrol laws`, the paper line of a run
that sets a law's key directly, a stateless law's summary, units on every axis, region titles that
fit whatever the laws' labels."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import EX1, EX2

import qcontrol
from qcontrol.cli import main
from qcontrol.cli.printing import format_summary
from qcontrol.explain import paper_setting_differences
from qcontrol.plots.region import PANEL_CHARACTERS, _title, _ylabel


def test_laws_takes_settings_like_region_and_says_no_internal_name(tmp_path: Path, capsys) -> None:
    argv = ["laws", str(EX2), "--law", "proposed", "--law", "proposed:hold=exact", "--backend", "ode",
            "--duration", "0.5", "--out", str(tmp_path)]
    assert main(argv) == 0
    table = json.loads((tmp_path / "laws.json").read_text())["table"]
    assert [row["kind"] for row in table] == ["proposed", "proposed:hold=exact"]
    # the exact hold replaces K by (1 - exp(-K T)) / T < K: a different input, never a larger one
    paper, exact = table
    assert paper["max_abs_u"] >= exact["max_abs_u"] and paper != exact
    capsys.readouterr()
    for second in ("proposed:nonesuch", "proposed"):
        assert main(["laws", str(EX2), "--law", "proposed", "--law", second, "--backend", "ode"]) == 2
    err = capsys.readouterr().err
    assert "--law 'proposed:nonesuch'" in err and "compare_laws" not in err


def test_a_direct_controller_key_is_compared_with_the_files_sub_table() -> None:
    sc = qcontrol.load_scenario(EX2, ["controller.kappa_margin=0.1"])
    assert paper_setting_differences(sc) == ["controller.kappa_margin = 0.1 (example2.toml: 1.1)"]
    same = qcontrol.load_scenario(EX2, ["controller.kappa_margin=1.1"])
    assert paper_setting_differences(same) == []  # the file's own value, given directly: the paper's setting


class Stateless:
    state_size = 0

    def initial_state(self):
        return np.zeros(0)

    def control(self, t, x_q, yd, state):
        return -5.0 * (x_q[0] - yd[0]) - 3.0 * x_q[1] + yd[2]

    def state_rate(self, t, x_q, yd, state):
        return np.zeros(0)


def test_a_stateless_law_prints_no_final_state() -> None:
    qcontrol.register_law("first-contact-pd", lambda table, n: Stateless(), replace=True)
    sc = qcontrol.load_scenario(EX1, {"controller.kind": "first-contact-pd", "simulation.duration": 0.2})
    res = qcontrol.run(sc, backend="ode")
    assert res.adaptive.shape == (201, 0)
    assert "final" not in format_summary(res.summary, sc)
    assert "final eps_hat: [" in format_summary(qcontrol.run(sc.with_overrides(
        {"controller.kind": "proposed"}), backend="ode").summary, sc)


@pytest.mark.parametrize(("scenario", "y", "u"), [(EX2, "[rad]", "[rad/s$^2$]"), (EX1, "[m]", "[N/kg]"),
                                                  ("chain3", "[x$_1$ unit]", "[x$_1$ unit/s$^3$]")])
def test_every_axis_has_its_unit(scenario: str, y: str, u: str) -> None:
    from qcontrol.plots import scenario_units
    from qcontrol.plots.common import unit

    units = scenario_units(qcontrol.load_scenario(scenario))
    assert (unit(units.y), unit(units.u), unit(units.t)) == (f" {y}", f" {u}", " [s]")


def test_the_figures_axes_carry_units(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from matplotlib.figure import Figure

    labels: list[str] = []
    real = Figure.savefig

    def spy(fig, *args, **kwargs):
        labels.extend(ax.get_ylabel() for ax in fig.axes if ax.get_ylabel())
        return real(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", spy)
    sc = qcontrol.load_scenario(EX2, {"simulation.duration": 0.2})
    qcontrol.run(sc, backend="ode").plot(tmp_path / "run.png")
    qcontrol.compare_laws(sc, ["proposed", "comparison"], backend="ode").plot(tmp_path / "laws.png")
    assert len(labels) == 5 + 3 and all(label.endswith("]") for label in labels), labels
    assert "u [rad/s$^2$]" in labels


@pytest.mark.parametrize("columns", [1, 2, 3, 4, 6])
def test_region_titles_fit_their_panel(columns: int) -> None:
    width = max(12, PANEL_CHARACTERS // columns)
    label = "proposed:kappa_margin=0.5,hold=exact,r_scale=30"
    title = _title(f"{label}: 3 of 441 fail in |x_i| <= 10", columns)
    *law_lines, counts = title.split("\n")
    assert "".join(law_lines) == label and counts == "3 of 441 fail in |x_i| <= 10"  # nothing lost
    assert all(len(line) <= width for line in law_lines if ":" in line[:-1] or "," in line[:-1])
    assert _title("proposed: 0 of 9 fail in |x_i| <= 10", columns) == "proposed\n0 of 9 fail in |x_i| <= 10"


def test_a_region_rows_label_has_two_lines() -> None:
    assert _ylabel("example2\nT = 1 ms\nx2(0)") == "example2, T = 1 ms\nx2(0)"
    assert _ylabel("x2(0)") == "x2(0)"
