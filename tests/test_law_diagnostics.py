"""A user's law declares diagnostics of its own (qcontrol.Diagnostic), and they land wherever a
run's signals land: the Result, the --save files (npz and csv, by name), summary.json and the
printed summary (``max_<name>`` / ``last_<name>``), and the rerun recording (the entities and a law
panel titled by the law's own diagnostics). Each is checked against a computation of its own from
the saved arrays."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import EX1, EX2, INTEGRAL_LAW_METHODS
from test_record import assert_scalars_exact, read_entities, static_value
from test_record_layout import active_blueprint, views

import qcontrol
from qcontrol.cli import main
from qcontrol.sweep.runs import run_batch

KIND = "integral-diag"
LAW_FILE = '''
import numpy as np
import qcontrol


def abs_integral(x_q, yd, state):
    """|integral| at every row: one copy's rows, (rows,)."""
    return np.abs(state[:, 0])


def error_and_sign(x_q, yd, state):
    """(q1 - y_d, sign(integral)): (rows, 2)."""
    return np.stack([x_q[:, 0] - yd[:, 0], np.sign(state[:, 0])], axis=1)


class IntegralDiag:
    state_size = 1

    def __init__(self, table, n):
        qcontrol.check_keys(table, ["k_i"])
        self.c, self.k_i = table["c"], float(table.get("k_i", 1.0))
        self.diagnostics = (
            qcontrol.Diagnostic("abs_integral", 1, "-", "max", "|integral of q1 - y_d|", abs_integral),
            qcontrol.Diagnostic("err_sign", 2, "-", "last", "q1 - y_d and the integral's sign",
                                error_and_sign),
            qcontrol.Diagnostic("ki_integral", 1, "-", "max", "k_i |integral|: this copy's own k_i",
                                self.ki_integral),
        )

    def ki_integral(self, x_q, yd, state):
        return self.k_i * np.abs(state[:, 0])

INTEGRAL_LAW_METHODS

qcontrol.register_law("KIND", IntegralDiag, state_name="integral", replace=True)
'''.replace("KIND", KIND).replace("INTEGRAL_LAW_METHODS", INTEGRAL_LAW_METHODS)


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory) -> dict:
    """One CLI run of the law (npz + rrd + summary), and one more saving csv."""
    folder = tmp_path_factory.mktemp("diag")
    law = folder / "diaglaw.py"
    law.write_text(LAW_FILE)
    common = [str(EX1), "--law-module", str(law), "--set", f"controller.kind={KIND}", "--set",
              "controller.k_i=2.0", "--backend", "ode", "--duration", "1"]
    assert main(["run", *common, "--save", str(folder / "out.npz"), "--rrd", str(folder / "out.rrd"),
                 "--out", str(folder / "run")]) == 0
    assert main(["run", *common, "--save", str(folder / "out.csv"), "--out", str(folder / "csv"), "-q"]) == 0
    return {"folder": folder, "summary": json.loads((folder / "run" / "summary.json").read_text()),
            "npz": dict(np.load(folder / "out.npz")), "law": law}


def test_the_summary_reduces_each_diagnostic_as_it_declares(cli_run: dict) -> None:
    s, saved = cli_run["summary"], cli_run["npz"]
    assert qcontrol.load_scenario(EX1).simulation.control_period is None  # every row is a control sample
    integral = saved["adaptive"][:, 0]
    assert s["max_abs_integral"] == float(np.max(np.abs(integral)))  # max over the rows
    assert s["max_abs_integral"] == s["final_integral"][0] > 0.1  # here the integral only grows
    assert s["max_ki_integral"] == pytest.approx(2.0 * s["max_abs_integral"], rel=1e-15)  # k_i = 2
    last = [saved["x_q"][-1, 0] - saved["yd"][-1, 0], float(np.sign(integral[-1]))]
    assert s["last_err_sign"] == last  # width 2, "last": the last row's two columns
    assert "max_gain_period" not in s  # the paper's diagnostic is the paper's law's


def test_the_npz_holds_each_diagnostic_by_its_name(cli_run: dict) -> None:
    saved = cli_run["npz"]
    integral = saved["adaptive"][:, 0]
    np.testing.assert_array_equal(saved["abs_integral"], np.abs(integral))
    assert saved["err_sign"].shape == (len(saved["t"]), 2)
    np.testing.assert_array_equal(saved["err_sign"][:, 0], saved["x_q"][:, 0] - saved["yd"][:, 0])
    np.testing.assert_array_equal(saved["err_sign"][:, 1], np.sign(integral))
    np.testing.assert_array_equal(saved["diagnostics"][:, 0], saved["abs_integral"])  # the signal, in order


def test_the_csv_has_a_column_per_diagnostic_component(cli_run: dict) -> None:
    with open(cli_run["folder"] / "out.csv") as f:
        rows = list(csv.DictReader(f))
    column = {name: np.array([float(r[name]) for r in rows]) for name in
              ("abs_integral", "err_sign_1", "err_sign_2", "ki_integral", "integral_1", "x_q1", "yd_0")}
    np.testing.assert_array_equal(column["abs_integral"], np.abs(column["integral_1"]))
    np.testing.assert_array_equal(column["err_sign_1"], column["x_q1"] - column["yd_0"])
    np.testing.assert_array_equal(column["err_sign_2"], np.sign(column["integral_1"]))
    np.testing.assert_array_equal(column["ki_integral"], 2.0 * column["abs_integral"])
    np.testing.assert_array_equal(column["abs_integral"], cli_run["npz"]["abs_integral"])  # same run


def test_the_printed_summary_reports_them(tmp_path: Path, capsys: pytest.CaptureFixture,
                                          cli_run: dict) -> None:
    assert main(["run", str(EX1), "--law-module", str(cli_run["law"]), "--set", f"controller.kind={KIND}",
                 "--backend", "ode", "--duration", "0.2", "--out", str(tmp_path)]) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    (line,) = [x for x in capsys.readouterr().out.splitlines() if "law diagnostics" in x]
    assert f"max_abs_integral = {s['max_abs_integral']:.4g}" in line
    assert f"last_err_sign = [{s['last_err_sign'][0]:.4g}, {s['last_err_sign'][1]:.4g}]" in line


def test_the_recording_draws_them_in_a_panel_titled_by_them(cli_run: dict) -> None:
    saved, rrd = cli_run["npz"], cli_run["folder"] / "out.rrd"
    entities = read_entities(rrd)
    assert_scalars_exact(entities, "theory/law/abs_integral", saved["abs_integral"], saved["t"])
    assert_scalars_exact(entities, "theory/law/err_sign_1", saved["err_sign"][:, 0], saved["t"])
    assert_scalars_exact(entities, "theory/law/err_sign_2", saved["err_sign"][:, 1], saved["t"])
    assert static_value(entities["theory/law/err_sign_2"], "SeriesLines:names") == ["err_sign_2 (ode)"]
    assert "theory/law/gain_period" not in entities
    shown = views(active_blueprint(rrd))
    title = "law diagnostics: abs_integral; err_sign; ki_integral"
    assert shown[title][2] == "theory/law"
    assert not any("gain_period" in name for name in shown)


def _scenario(**overrides: object) -> qcontrol.Scenario:
    return qcontrol.load_scenario(EX1, {"controller.kind": KIND, "simulation.duration": 0.3, **overrides})


@pytest.fixture()
def law_registered(cli_run: dict) -> None:
    qcontrol.load_law_module(cli_run["law"])


def test_result_diagnostic_gives_each_by_name(law_registered: None) -> None:
    res = qcontrol.run(_scenario(), backend="ode")
    np.testing.assert_array_equal(res.diagnostic("abs_integral"), np.abs(res.adaptive[:, 0]))
    assert res.diagnostic("err_sign").shape == (len(res.t), 2)
    np.testing.assert_array_equal(res.diagnostic("err_sign")[:, 1], np.sign(res.adaptive[:, 0]))
    with pytest.raises(qcontrol.QcontrolInputError, match=r"diagnostic 'nope': the law declares no "
                       r"diagnostic of that name \(its diagnostics: abs_integral, err_sign, ki_integral\)"):
        res.diagnostic("nope")
    metrics = qcontrol.run(_scenario(), backend="ode", record="metrics").summary  # reduced chunk by chunk
    for key in ("max_abs_integral", "last_err_sign", "max_ki_integral"):
        assert metrics[key] == res.summary[key]


def test_each_copy_of_a_batch_is_evaluated_with_its_own_law(law_registered: None) -> None:
    variants = [_scenario(**{"controller.k_i": k}) for k in (0.5, 3.0)]
    batched = run_batch(variants, "ode")  # one batch of two copies
    for sc, s in zip(variants, batched, strict=True):
        single = qcontrol.run(sc, backend="ode").summary
        assert s.law_diagnostics == {k: single[k] for k in ("max_abs_integral", "last_err_sign",
                                                             "max_ki_integral")}
        k_i = sc.controller.settings.table["k_i"]
        assert single["max_ki_integral"] == pytest.approx(k_i * single["max_abs_integral"], rel=1e-15)
    assert batched[0].law_diagnostics["max_abs_integral"] != batched[1].law_diagnostics["max_abs_integral"]


class _Declares:
    """A law that declares whatever it is given (its control: plain backstepping)."""

    state_size = 1

    def __init__(self, table: dict, diagnostics: object) -> None:
        self.c, self.diagnostics = table["c"], diagnostics

    def initial_state(self) -> np.ndarray:
        return np.zeros(1)

    def control(self, t, x_q, yd, state) -> float:
        return float(qcontrol.quantized_backstepping(self.c, x_q, yd)[1][-1])

    def state_rate(self, t, x_q, yd, state) -> np.ndarray:
        return np.array([x_q[0] - yd[0]])


def _state(x_q, yd, state):
    return state[:, 0]


def _diagnostic(name: str, width: int = 1, reduce: str = "max", evaluate=_state) -> qcontrol.Diagnostic:
    return qcontrol.Diagnostic(name, width, "-", reduce, "a test diagnostic", evaluate)


BAD = "controller kind 'diag-bad': "


def _run_declaring(diagnostics: object, record: str = "full") -> qcontrol.Result:
    qcontrol.register_law("diag-bad", lambda table, n: _Declares(table, diagnostics), state_name="integral",
                          replace=True)
    sc = qcontrol.load_scenario(EX1, {"controller.kind": "diag-bad", "simulation.duration": 0.05})
    return qcontrol.run(sc, backend="ode", record=record)


@pytest.mark.parametrize(("declared", "message"), [
    ("abs", f"{BAD}diagnostics must be a list or tuple of qcontrol.Diagnostic, got str; fix the law"),
    ([_diagnostic("a"), "b"], f"{BAD}diagnostics[1] is str 'b', not a qcontrol.Diagnostic; fix the law"),
    ([_diagnostic("a"), _diagnostic("a", reduce="last")],
     f"{BAD}diagnostic 'a' gives a second column named 'a'; give each diagnostic its own name"),
    ([_diagnostic("a", 2), _diagnostic("a_2")], f"{BAD}diagnostic 'a_2' gives a second column named 'a_2'"),
    ([_diagnostic("u")], f"{BAD}diagnostic 'u': 'u' already names a recorded signal or its column in the "
                         "saved files; rename the diagnostic"),
    ([_diagnostic("x1")], "diagnostic 'x1': 'x1' already names a recorded signal"),
    ([_diagnostic("integral_1")], "diagnostic 'integral_1': 'integral_1' already names"),  # a state column
    ([_diagnostic("yd", 2)], "diagnostic 'yd': 'yd' already names"),
    ([_diagnostic("t")], "diagnostic 't': 't' already names"),
    ([_diagnostic("allow_pickle")], "diagnostic 'allow_pickle': 'allow_pickle' already names"),  # np.savez's
    ([_diagnostic("abs_u")], f"{BAD}diagnostic 'abs_u': its summary key 'max_abs_u' is already a summary "
                             "field; rename the diagnostic"),
])
def test_a_bad_declaration_is_refused_in_one_line(declared: object, message: str) -> None:
    with pytest.raises(qcontrol.QcontrolInputError) as refused:
        _run_declaring(declared)
    assert message in str(refused.value) and "\n" not in str(refused.value)


def _scalar(x_q, yd, state):
    return 1.0


def _too_wide(x_q, yd, state):
    return np.zeros((len(x_q), 3))


def _text(x_q, yd, state):
    return "high"


@pytest.mark.parametrize(("diagnostic", "message"), [
    (_diagnostic("level", evaluate=_scalar), f"{BAD}diagnostic 'level': evaluate(x_q, yd, state) must return "
     "shape (51,) or (51, 1) for 51 rows (width 1), got shape (); fix the law"),
    (_diagnostic("pair", 2, evaluate=_too_wide), "diagnostic 'pair': evaluate(x_q, yd, state) must return "
     "shape (51, 2) for 51 rows (width 2), got shape (51, 3)"),
    (_diagnostic("word", evaluate=_text), f"{BAD}diagnostic 'word': evaluate(x_q, yd, state) must return an "
     "array of real numbers, got str; fix the law"),
])
@pytest.mark.parametrize("record", ["full", "metrics"])
def test_a_wrong_result_names_the_law_and_the_diagnostic(diagnostic, message: str, record: str) -> None:
    with pytest.raises(qcontrol.QcontrolInputError) as refused:
        _run_declaring([diagnostic], record)
    assert message in str(refused.value) and "\n" not in str(refused.value)


def test_a_wrong_result_on_the_command_line_is_exit_2_one_line(tmp_path: Path, capsys) -> None:
    law = tmp_path / "wrong.py"
    law.write_text(LAW_FILE.replace("np.abs(state[:, 0])", "np.abs(state)[:, :, None]"))
    assert main(["run", str(EX1), "--law-module", str(law), "--set", f"controller.kind={KIND}",
                 "--backend", "ode", "--duration", "0.05", "--out", str(tmp_path / "o"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"controller kind '{KIND}': diagnostic 'abs_integral': evaluate(x_q, yd, state) must return" in err


# a law class: a subclass of the paper's law adds a diagnostic beside gain_period

def _eps_sum(q, yd, eps_hat):
    """The sum of the estimates eps_hat (columns (rows, batch) each)."""
    return sum(eps_hat)


class EpsSumPaperLaw(qcontrol.PaperLaw):
    """Law (44)-(45) unchanged, declaring one more diagnostic: the sum of its estimates."""

    diagnostics = (qcontrol.Diagnostic("eps_sum", 1, "-", "last", "sum of eps_hat", _eps_sum),)


def test_a_paper_law_subclass_adds_a_diagnostic_beside_gain_period(tmp_path: Path) -> None:
    qcontrol.register_law("paper-eps-sum", EpsSumPaperLaw, extends="proposed", replace=True)
    base = qcontrol.load_scenario(EX2, {"simulation.duration": 1.0})
    paper = qcontrol.run(base, backend="ode")
    mine = qcontrol.run(base.with_overrides({"controller.kind": "paper-eps-sum"}), backend="ode",
                        rrd=tmp_path / "class.rrd")
    assert mine.summary["max_gain_period"] == paper.summary["max_gain_period"]  # the same law, bit for bit
    np.testing.assert_array_equal(mine.u, paper.u)
    assert mine.summary["last_eps_sum"] == float(np.sum(mine.adaptive[-1]))  # from the saved state
    np.testing.assert_array_equal(mine.diagnostic("eps_sum"), mine.adaptive.sum(axis=1))
    np.testing.assert_array_equal(mine.diagnostic("gain_period"), paper.diagnostic("gain_period"))
    entities = read_entities(tmp_path / "class.rrd")
    assert_scalars_exact(entities, "theory/law/eps_sum", mine.diagnostic("eps_sum"), mine.t)
    shown = views(active_blueprint(tmp_path / "class.rrd"))
    title = "law diagnostics: gain_period = K T of (44) (> 1: the held input overshoots); eps_sum"
    assert shown[title][2] == "theory/law"


class _NotDeclaring(qcontrol.PaperLaw):
    diagnostics = ("eps_sum",)


def test_a_law_classes_bad_declaration_is_refused_when_the_scenario_loads() -> None:
    qcontrol.register_law("paper-bad-diag", _NotDeclaring, extends="proposed", replace=True)
    with pytest.raises(qcontrol.QcontrolInputError) as refused:
        qcontrol.load_scenario(EX2, {"controller.kind": "paper-bad-diag"})
    assert str(refused.value).endswith("controller kind 'paper-bad-diag': diagnostics[1] is str 'eps_sum', "
                                       "not a qcontrol.Diagnostic; fix the law")
