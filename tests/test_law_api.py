"""The public API around laws: qcontrol.sweep's table equals the command's sweep.csv, Result.plot
draws --plot's figure, register_law(replace=True) and hyphenated kinds, the summary's final state
under the law's own name, and misuse of the API refused in one line."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from conftest import EX1

import qcontrol
from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError

SHORT = {"simulation.duration": 0.5}


class Proportional:
    """u = alpha_n of the backstepping (no robust term) times a gain: stateless."""

    state_size = 0

    def __init__(self, c: list[float], gain: float) -> None:
        self.c, self.gain = c, gain

    def initial_state(self) -> np.ndarray:
        return np.zeros(0)

    def control(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> float:
        return self.gain * float(qcontrol.quantized_backstepping(self.c, x_q, yd)[1][-1])

    def state_rate(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> np.ndarray:
        return np.zeros(0)


def test_sweep_returns_the_table_the_command_writes(tmp_path: Path, figure_not_drawn: list) -> None:
    sc = qcontrol.load_scenario(EX1, SHORT)
    rows = qcontrol.sweep(sc, grid={"controller.delta": [0.05, 0.1],
                                    "controller.kind": ["proposed", "comparison"]}, backend="ode")
    assert [(r["controller.delta"], r["controller.kind"]) for r in rows] == [
        (0.05, "proposed"), (0.05, "comparison"), (0.1, "proposed"), (0.1, "comparison")]
    assert main(["sweep", str(EX1), "--set", "simulation.duration=0.5", "--grid",
                 "controller.delta=0.05,0.1", "--grid", "controller.kind=proposed,comparison",
                 "--backend", "ode", "--out", str(tmp_path / "sw"), "--quiet"]) == 0
    with open(tmp_path / "sw" / "sweep.csv") as file:
        written = list(csv.DictReader(file))
    for row, line in zip(rows, written, strict=True):
        assert repr(row["error_rate_0.100"]) == line["error_rate_0.100"]
        assert repr(row["lemma2_max_ratio"]) == line["lemma2_max_ratio"]
    assert rows[0]["max_abs_z1_last_half"] != rows[2]["max_abs_z1_last_half"]  # delta really varied
    assert figure_not_drawn == [tmp_path / "sw" / "sweep.png"]


def test_qcontrol_sweep_is_the_function_and_the_package_stays_importable() -> None:
    import qcontrol.sweep.runs  # noqa: F401  (importing a submodule must not rebind qcontrol.sweep)
    from qcontrol.sweep import sweep_summaries

    assert callable(qcontrol.sweep) and qcontrol.sweep is qcontrol.api.sweep and callable(sweep_summaries)


@pytest.mark.parametrize(("call", "message"), [
    (lambda: qcontrol.sweep("example1", grid={"controller.kappa_margin": [0.1]}),
     "sweep: expected a Scenario (from qcontrol.load_scenario), got str"),
    (lambda: qcontrol.sweep(qcontrol.load_scenario(EX1), grid={"controller.kappa_margin": 0.1}),
     "sweep: grid['controller.kappa_margin'] must be a non-empty list of values, got 0.1"),
    (lambda: qcontrol.sweep(qcontrol.load_scenario(EX1), grid={}),
     "sweep: grid must be a non-empty dict {key: [values]}, got {}"),
    (lambda: qcontrol.register_law("bad name", Proportional),
     "register_law: kind 'bad name' must be letters, digits, _ and -, starting with a letter or _"),
    (lambda: qcontrol.register_law("k_none", None),
     "register_law: factory for 'k_none' must be callable as factory(table, n), got NoneType"),
    (lambda: qcontrol.register_law("proposed", Proportional),
     "controller kind 'proposed' is built in and cannot be replaced; choose another name"),
    (lambda: qcontrol.run("example1"), "run: expected a Scenario (from qcontrol.load_scenario), got str"),
    (lambda: qcontrol.run(qcontrol.load_scenario(EX1), backend=3),
     "run: backend must be str or None, got int 3"),
    (lambda: qcontrol.run(qcontrol.load_scenario(EX1), record="all"),
     'run: record must be "full" or "metrics", got \'all\''),
    (lambda: qcontrol.compare(None),
     "compare: expected a Scenario (from qcontrol.load_scenario), got NoneType"),
    (lambda: qcontrol.load_scenario(3), "load_scenario: path must be a file path (str or Path)"),
    (lambda: qcontrol.load_scenario(EX1, "controller.delta=1"),
     'load_scenario: overrides must be a dict {"key": value} or a list of "key=value" strings'),
    (lambda: qcontrol.load_scenario(EX1).with_overrides(5), "with_overrides: overrides must be a dict"),
])
def test_api_misuse_is_refused_in_one_line(call, message: str) -> None:
    with pytest.raises(QcontrolInputError) as err:
        call()
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_register_law_replace_and_a_hyphenated_kind() -> None:
    qcontrol.register_law("held-p", lambda table, n: Proportional(table["c"], 1.0))
    sc = qcontrol.load_scenario(EX1, SHORT | {"controller.kind": "held-p"})
    first = qcontrol.run(sc, backend="ode").summary
    with pytest.raises(QcontrolInputError, match="already registered; choose another name or pass replace"):
        qcontrol.register_law("held-p", lambda table, n: Proportional(table["c"], 2.0))
    qcontrol.register_law("held-p", lambda table, n: Proportional(table["c"], 2.0), replace=True)
    second = qcontrol.run(qcontrol.load_scenario(EX1, SHORT | {"controller.kind": "held-p"}), backend="ode")
    assert second.summary["max_abs_u"] > first["max_abs_u"]  # the edited law ran, without a restart
    assert second.summary["final_state"] == [] and second.summary["final_eps_hat"] == []


def test_the_summary_names_the_final_state_by_the_laws_name() -> None:
    base = qcontrol.run(qcontrol.load_scenario(EX1, SHORT | {"controller.kind": "comparison"}), backend="ode")
    s = base.summary
    assert s["adaptive_state"] == "theta_hat"
    assert s["final_theta_hat"] == s["final_eps_hat"] == [float(v) for v in base.adaptive[-1]]
    paper = qcontrol.run(qcontrol.load_scenario(EX1, SHORT), backend="ode").summary
    assert paper["adaptive_state"] == "eps_hat" and "final_eps_hat" in paper


def test_result_plot_draws_the_run_figure(tmp_path: Path) -> None:
    res = qcontrol.run(qcontrol.load_scenario(EX1, SHORT), backend="ode")
    out = res.plot(tmp_path / "run.png")
    assert out == tmp_path / "run.png" and out.stat().st_size > 10_000
    assert main(["run", str(EX1), "--set", "simulation.duration=0.5", "--backend", "ode",
                 "--plot", str(tmp_path / "cli.png")]) == 0
    assert (tmp_path / "cli.png").stat().st_size > 10_000
    with pytest.raises(QcontrolInputError, match="is a folder"):
        res.plot(tmp_path)


# ---------------------------------------------------------------------------------------------
# laws from a file (--law-module) and from installed plugin packages (entry points qcontrol.laws)

LAW_FILE = '''
import numpy as np
import qcontrol


class Scaled:
    state_size = 1

    def __init__(self, table, n):
        qcontrol.check_keys(table, ["gain"])
        self.c, self.gain = table["c"], table.get("gain", 1.0)

    def initial_state(self):
        return np.zeros(1)

    def control(self, t, x_q, yd, state):
        return self.gain * float(qcontrol.quantized_backstepping(self.c, x_q, yd)[1][-1])

    def state_rate(self, t, x_q, yd, state):
        return np.array([x_q[0] - yd[0]])


qcontrol.register_law("{kind}", Scaled, state_name="integral")
'''


def test_a_law_module_on_run_compare_sweep_and_region(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    laws = tmp_path / "mylaws.py"
    laws.write_text(LAW_FILE.replace("{kind}", "file-law"))
    common = ["--law-module", str(laws), "--set", "controller.kind=file-law",
              "--set", "simulation.duration=0.3"]
    assert main(["run", str(EX1), "--backend", "ode", "--out", str(tmp_path / "run"), *common]) == 0
    assert '"final_integral"' in (tmp_path / "run" / "summary.json").read_text()
    assert main(["compare", str(EX1), "--out", str(tmp_path / "cmp"), *common]) == 0
    assert main(["sweep", str(EX1), "--backend", "ode", "--grid", "controller.gain=0.5,1.0", "--quiet",
                 "--out", str(tmp_path / "sw"), *common]) == 0
    assert main(["region", str(EX1), "--law", "file-law", "--resolution", "3", "--box", "1", "--quiet",
                 "--out", str(tmp_path / "reg"), *common]) == 0
    assert (tmp_path / "reg" / "region.csv").is_file()


def test_a_broken_or_missing_law_module_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    broken = tmp_path / "broken.py"
    broken.write_text("import qcontrol\n\nraise RuntimeError('not yet')\n")
    assert main(["run", str(EX1), "--law-module", str(broken)]) == 2
    err = capsys.readouterr().err
    assert err == (f"qcontrol: error: --law-module {broken}: importing it failed (RuntimeError: not yet, "
                   "line 3); fix the file\n")
    assert main(["run", str(EX1), "--law-module", str(tmp_path / "none.py")]) == 2
    assert "--law-module" in capsys.readouterr().err


def test_an_installed_plugin_package_registers_its_law(tmp_path: Path) -> None:
    """A tiny plugin package built and installed (into a folder of its own, not this venv) with
    pip; a fresh interpreter with that folder on its path runs the plugin's law by name."""
    import subprocess
    import sys

    pkg = tmp_path / "tinylaw"
    (pkg / "tinylaw").mkdir(parents=True)
    (pkg / "tinylaw" / "__init__.py").write_text(
        LAW_FILE.replace("{kind}", "tiny-law").replace('qcontrol.register_law(', 'def register():\n    '
                                                                                   'qcontrol.register_law('))
    (pkg / "pyproject.toml").write_text(
        '[build-system]\nrequires = ["hatchling"]\nbuild-backend = "hatchling.build"\n\n'
        '[project]\nname = "tinylaw"\nversion = "0.1"\n\n'
        '[project.entry-points."qcontrol.laws"]\ntiny = "tinylaw:register"\n')
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--no-index", "--target", str(target), str(pkg)], check=True, capture_output=True)
    env = {**__import__("os").environ, "PYTHONPATH": str(target)}
    done = subprocess.run([sys.executable, "-m", "qcontrol.cli", "run", str(EX1), "--backend", "ode",
                           "--set", "controller.kind=tiny-law", "--set", "simulation.duration=0.2"],
                          capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    assert "final integral" in done.stdout


# ---------------------------------------------------------------------------------------------
# API input checked like file input


def test_a_scenario_is_read_only() -> None:
    sc = qcontrol.load_scenario(EX1)
    with pytest.raises(TypeError):
        sc.data["controller"]["delta"] = 0.5  # type: ignore[index]
    with pytest.raises(TypeError):
        sc.backends["ode"] = None  # type: ignore[index]
    assert "delta = 0.1" in qcontrol.api.scenario_provenance(sc, "x")["resolved_scenario"]


class _Bad(Proportional):
    """A law whose output ``field`` is replaced by ``value``."""

    def __init__(self, table: dict, field: str, value: object) -> None:
        super().__init__(table["c"], 1.0)
        self.field, self.value, self.state_size = field, value, 1

    def initial_state(self) -> object:
        return self.value if self.field == "initial_state" else np.zeros(1)

    def control(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> object:
        return self.value if self.field == "control" else 0.0

    def state_rate(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> object:
        return self.value if self.field == "state_rate" else np.zeros(1)


K = "controller kind 'bad-out': "


@pytest.mark.parametrize(("field", "value", "message"), [
    ("control", "1.5", K + "control() must return a real number u, got str '1.5'; fix the law"),
    ("control", float("nan"), K + "control() returned nan at the first control sample"),
    ("initial_state", [0.0, 0.0], K + "initial_state() must return shape (1,) (the law's state_size), "
                                      "got shape (2,)"),
    ("state_rate", [float("inf")], K + "state_rate() returned a value that is not finite"),
    ("state_rate", None, K + "state_rate() must return an array of 1 real numbers, got NoneType None"),
])
def test_a_laws_outputs_are_checked_naming_the_law_and_field(field: str, value: object, message: str) -> None:
    qcontrol.register_law("bad-out", lambda table, n: _Bad(table, field, value), replace=True)
    sc = qcontrol.load_scenario(EX1, SHORT | {"controller.kind": "bad-out"})
    with pytest.raises(QcontrolInputError) as err:
        qcontrol.run(sc, backend="ode")
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


# ---------------------------------------------------------------------------------------------
# the public expression compiler, cbrt and spow, and a NaN reported with its term


def test_the_public_expression_compiler_on_arrays_and_floats() -> None:
    r = qcontrol.expression("1 + q2**2", variables=("q1", "q2"))
    np.testing.assert_array_equal(r(np.array([[0.0, 1.0], [0.0, 2.0]])), [2.0, 5.0])
    assert r.on_floats([0.0, 3.0]) == 10.0
    root = qcontrol.expression("cbrt(x1) + spow(x2, 1/3)")
    assert root.on_floats([-8.0, -27.0]) == pytest.approx(-5.0, abs=1e-12)
    assert float(root(np.array([-8.0, -27.0]))) == pytest.approx(-5.0, abs=1e-12)
    assert np.isnan(qcontrol.expression("x2**(1/3)").on_floats([0.0, -27.0]))  # why spow exists
    with pytest.raises(QcontrolInputError, match="^expression: unknown function '__import__'"):
        qcontrol.expression("__import__('os')")
    with pytest.raises(QcontrolInputError, match="^expression: variables must be a list of names"):
        qcontrol.expression("x1", variables="x1")


def test_a_nan_from_an_expressions_domain_names_the_term(capsys: pytest.CaptureFixture) -> None:
    assert main(["run", str(EX1), "--backend", "ode", "--duration", "2", "-q",
                 "--set", 'plant.psi="0.1*x2**(1/3)"']) == 1
    out = capsys.readouterr().out
    assert "plant.psi = '0.1*x2**(1/3)' is NaN at x1 = " in out and "x2 = -" in out
    assert "write cbrt(x) or spow(x, p)" in out and "a smaller --dt" not in out
    fixed = qcontrol.run(qcontrol.load_scenario(EX1, {"plant.psi": "0.1*spow(x2, 1/3)",
                                                       "simulation.duration": 2.0}), backend="ode")
    assert not fixed.summary["diverged"]


def test_a_sweep_over_kinds_draws_categories_not_a_trend() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from qcontrol.plots.sweeps import _line, _Points

    rows = [{"controller.kind": kind, "max_abs_u": u, "diverged": False}
            for kind, u in (("proposed", 3.0), ("comparison", 2.0), ("proposed", 4.0))]
    points = _Points(rows, ["controller.kind"])
    for categories, style in ((True, "None"), (False, "-")):
        fig, ax = plt.subplots()
        _line(ax, points, ["proposed", "comparison"], np.arange(2.0), "max_abs_u", "max |u|", "C0",
              categories)
        assert {line.get_linestyle() for line in ax.lines} == {style}  # no line joins two kinds
        plt.close(fig)


# ---------------------------------------------------------------------------------------------
# several laws side by side


def test_compare_laws_equals_the_single_runs_and_records_every_law(tmp_path: Path) -> None:
    sc = qcontrol.load_scenario(EX1, SHORT)
    cmp = qcontrol.compare_laws(sc, ["proposed", "comparison"], backend="ode", rrd=tmp_path / "laws.rrd")
    assert [row["kind"] for row in cmp.table] == ["proposed", "comparison"]
    for row in cmp.table:
        alone = qcontrol.run(sc.with_overrides({"controller.kind": row["kind"]}), backend="ode").summary
        assert row["error_rate_0.100"] == alone["error_rate"]["0.100"]
        assert row["max_abs_u"] == alone["max_abs_u"]
    assert cmp.runs["comparison"].summary["adaptive_state"] == "theta_hat"
    assert (tmp_path / "laws.rrd").stat().st_size > 10_000
    assert cmp.plot(tmp_path / "laws.png").stat().st_size > 10_000
    with pytest.raises(QcontrolInputError, match=r"^compare_laws: kinds \['proposed', 'nope'\] must be"):
        qcontrol.compare_laws(sc, ["proposed", "nope"])


def test_the_laws_command_with_a_law_module(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    laws = tmp_path / "mylaws.py"
    laws.write_text(LAW_FILE.replace("{kind}", "cli-law"))
    assert main(["laws", str(EX1), "--law-module", str(laws), "--law", "proposed", "--law", "cli-law",
                 "--backend", "ode", "--duration", "0.5", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "  proposed " in out and "  cli-law " in out
    import json

    record = json.loads((tmp_path / "out" / "laws.json").read_text())
    assert [row["kind"] for row in record["table"]] == ["proposed", "cli-law"]
    assert "final_integral" in record["runs"]["cli-law"]
    assert (tmp_path / "out" / "laws.png").is_file()


def test_an_unknown_kind_on_the_command_line_says_how_to_register_one() -> None:
    """``python -m qcontrol`` is the command; an unknown kind is refused with one line that names
    the registered kinds and the ways to add one (--law-module first)."""
    import subprocess
    import sys

    command = [sys.executable, "-m", "qcontrol", "run", "example2", "--set", "controller.kind=bs_pi"]
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert "'bs_pi' is not allowed; use one of proposed, comparison" in line
    assert "--law-module FILE" in line and "Traceback" not in done.stderr
