"""The Python API: results equal the command line's, saved files hold the run's arrays, the
provenance reproduces a run, user laws run everywhere a built-in law does, the separation check,
the [metrics] table, and the package ships its scenarios and models."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import EX1, EX2, ROOT

import qcontrol
from qcontrol.api import columns
from qcontrol.cli import main
from qcontrol.engine import SIGNALS
from qcontrol.errors import QcontrolInputError
from qcontrol.sweep import sweep_summaries

SHORT = {"simulation.duration": 1.0}


def _without_run_specifics(summary: dict) -> dict:
    """A summary without what differs between equal runs: the wall time and the command."""
    s = json.loads(json.dumps(summary))  # as JSON holds it (tuples as lists, NaN as null ...)
    s.pop("wall_time_s")
    s["provenance"].pop("command")
    return s


def _json(summary: dict) -> dict:
    from qcontrol.outputs import clean

    return clean(summary)


@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_the_api_summary_is_the_cli_summary(tmp_path: Path, backend: str) -> None:
    sc = qcontrol.load_scenario(EX2, ["simulation.duration=1.0", "controller.kappa_margin=0.1"])
    res = qcontrol.run(sc, backend=backend)
    argv = ["run", str(EX2), "--backend", backend, "--set", "simulation.duration=1.0",
            "--set", "controller.kappa_margin=0.1", "--out", str(tmp_path), "-q"]
    assert main(argv) == 0
    cli = json.loads((tmp_path / "summary.json").read_text())
    assert _without_run_specifics(_json(res.summary)) == _without_run_specifics(cli)
    assert cli["provenance"]["command"] == "qcontrol " + " ".join(argv)
    assert cli["provenance"]["overrides"] == ["simulation.duration=1.0", "controller.kappa_margin=0.1"]


def test_saved_files_hold_the_runs_arrays(tmp_path: Path) -> None:
    res = qcontrol.run(qcontrol.load_scenario(EX2, SHORT), backend="ode")
    npz = np.load(res.save(tmp_path / "run.npz"))
    np.testing.assert_array_equal(npz["t"], res.t)
    for signal in SIGNALS:
        np.testing.assert_array_equal(npz[signal.name], getattr(res, signal.name), err_msg=signal.name)
    assert json.loads(str(npz["summary"]))["error_rate"] == res.summary["error_rate"]
    with open(res.save(tmp_path / "run.csv"), newline="") as f:
        table = list(csv.reader(f))
    header, body = table[0], np.array(table[1:], dtype=float)
    assert header[:4] == ["t", "x1", "x2", "x_meas1"] and "eps_hat_3" in header and "yd_2" in header
    assert body.shape == (len(res.t), len(header))
    for j, (name, values) in enumerate(columns(res.trajectory)):
        assert header[j] == name
        np.testing.assert_array_equal(body[:, j], values, err_msg=name)  # repr round-trips exactly


def test_a_save_to_an_unknown_format_is_refused(tmp_path: Path) -> None:
    res = qcontrol.run(qcontrol.load_scenario(EX2, SHORT), backend="ode")
    with pytest.raises(QcontrolInputError, match="save as .npz or .csv"):
        res.save(tmp_path / "run.mat")
    assert list(tmp_path.iterdir()) == []


def test_the_resolved_scenario_reruns_to_the_same_summary(tmp_path: Path) -> None:
    sc = qcontrol.load_scenario(EX1, {"simulation.duration": 2.0, "plant.x0": [0.1, -0.2]})
    first = qcontrol.run(sc)  # on the scenario's backend, MuJoCo: the model path must resolve
    elsewhere = tmp_path / "elsewhere" / "again.toml"
    elsewhere.parent.mkdir()
    elsewhere.write_text(first.summary["provenance"]["resolved_scenario"])
    again = qcontrol.run(qcontrol.load_scenario(elsewhere))
    a, b = _without_run_specifics(_json(first.summary)), _without_run_specifics(_json(again.summary))
    for key in ("scenario_file", "scenario_sha256", "overrides"):
        a["provenance"].pop(key), b["provenance"].pop(key)
    assert a == b


def test_scenarios_are_immutable_and_with_overrides_makes_a_new_one() -> None:
    sc = qcontrol.load_scenario("example2")  # a shipped scenario by name
    other = sc.with_overrides({"controller.kind": "baseline"})
    assert sc.controller.kind == "proposed" and other.controller.kind == "comparison"  # its former name
    assert other.overrides == (("controller.kind", "baseline"),)
    with pytest.raises(QcontrolInputError, match="does not apply to kind 'comparison'"):
        sc.with_overrides({"controller.kappa_margin": 0.1}).with_overrides({"controller.kind": "baseline"})


def test_provenance_names_versions_and_the_scenario_file() -> None:
    sc = qcontrol.load_scenario(EX2, SHORT)
    provenance = qcontrol.run(sc, backend="ode").summary["provenance"]
    assert provenance["qcontrol_version"] == qcontrol.__version__
    assert set(provenance["versions"]) == {"mujoco", "numpy", "rerun-sdk", "python"}
    assert provenance["scenario_file"] == "qcontrol:scenarios/example2.toml"  # shipped: no machine path
    assert 'model = "qcontrol:models/pendulum.xml"' in provenance["resolved_scenario"]
    import hashlib

    assert provenance["scenario_sha256"] == hashlib.sha256(EX2.read_bytes()).hexdigest()
    assert provenance["overrides"] == [{"simulation.duration": 1.0}]
    assert "duration = 1.0" in provenance["resolved_scenario"]


def test_a_file_of_ones_own_is_named_by_its_path_and_may_use_a_shipped_model(tmp_path: Path) -> None:
    """Outside the shipped folder the provenance names the absolute path; a copy of a shipped
    scenario keeps working there: it names its model ``qcontrol:models/...``."""
    mine = tmp_path / "mine.toml"
    assert '"qcontrol:models/pendulum.xml"' in EX2.read_text()
    mine.write_text(EX2.read_text())
    ours = qcontrol.run(qcontrol.load_scenario(mine, SHORT), backend="mujoco").summary
    shipped = qcontrol.run(qcontrol.load_scenario(EX2, SHORT), backend="mujoco").summary
    assert ours["provenance"]["scenario_file"] == str(mine.resolve())
    assert ours["error_rate"] == shipped["error_rate"] and ours["final_eps_hat"] == shipped["final_eps_hat"]
    bad = tmp_path / "bad.toml"
    bad.write_text(mine.read_text().replace("qcontrol:models/pendulum.xml", "qcontrol:models/nope.xml"))
    with pytest.raises(QcontrolInputError, match="model: file 'qcontrol:models/nope.xml' not found"):
        qcontrol.load_scenario(bad)


# ---------------------------------------------------------------------------------------------
# a law of one's own: the proposed law (44)-(45) written with the public API


class ProposedAgain:
    """Law (44)-(45) through the Law protocol (its state advanced by the adapter's RK4)."""

    def __init__(self, table: dict, n: int) -> None:
        qcontrol.check_keys(table, ["kappa", "gamma", "sigma"])
        self.c, self.delta = table["c"], table["delta"]
        self.L = float(qcontrol.lemma2_bounds(self.c, self.delta)[-1])
        self.kappa, self.gamma, self.sigma = table["kappa"], table["gamma"], table["sigma"]
        self.state_size = 3

    def initial_state(self) -> np.ndarray:
        return np.zeros(3)

    def r(self, x_q: np.ndarray) -> np.ndarray:
        return np.array([1 + x_q[1] ** 2, 1 + 2 * x_q[1] ** 2, 1.0])

    def _s(self, x_q: np.ndarray, yd: np.ndarray) -> tuple[float, float, float]:
        zbar, alphabar = qcontrol.quantized_backstepping(self.c, x_q, yd)
        return zbar[-1], alphabar[-1], zbar[-1] ** 2 / self.kappa + self.L

    def control(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> float:
        zn, alpha, s = self._s(x_q, yd)
        return alpha - zn / self.kappa / (self.kappa - self.L) * s * float(state @ self.r(x_q))

    def state_rate(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> np.ndarray:
        _, _, s = self._s(x_q, yd)
        return self.gamma * (s * self.r(x_q) - self.sigma * state)


qcontrol.register_law("proposed_again", ProposedAgain, state_name="eps_again")
AGAIN = {"controller.kind": "proposed_again", "controller.kappa": 1.125, "controller.gamma": 1.0,
         "controller.sigma": 1.0, "simulation.duration": 2.0}


@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_a_user_law_matches_the_built_in_law_it_rewrites(backend: str) -> None:
    mine = qcontrol.run(qcontrol.load_scenario(EX2, AGAIN), backend=backend)
    theirs = qcontrol.run(qcontrol.load_scenario(EX2, {"simulation.duration": 2.0}), backend=backend)
    assert mine.summary["adaptive_state"] == "eps_again"
    # eq. (45) advanced by RK4 steps vs exactly: equal to the RK4 error over a step (~1e-12)
    np.testing.assert_allclose(mine.adaptive, theirs.adaptive, rtol=0, atol=1e-8)
    np.testing.assert_allclose(mine.u, theirs.u, rtol=0, atol=1e-7)
    assert mine.summary["error_rate"] == theirs.summary["error_rate"]
    assert mine.summary["lemma2_max_ratio"] <= 1 + 1e-9 and not mine.summary["diverged"]


def test_a_user_law_in_compare_and_in_a_sweep() -> None:
    cmp = qcontrol.compare(qcontrol.load_scenario(EX2, AGAIN | {"simulation.duration": 1.0}))
    assert cmp.summary["max_abs_dy"] < 1e-9 and cmp.mujoco.summary["adaptive_state"] == "eps_again"
    sets = [["controller.kind=proposed_again", "controller.kappa=1.125", "controller.gamma=1.0",
             f"controller.sigma={s}", "simulation.duration=1.0"] for s in (1.0, 2.0)]
    batched = sweep_summaries(EX2, sets)  # one batch of two copies, one law object each
    for overrides, summary in zip(sets, batched, strict=True):
        alone = qcontrol.run(qcontrol.load_scenario(EX2, overrides), backend="ode").summary
        assert summary.error_rate == alone["error_rate"]
        assert summary.final_eps_hat == pytest.approx(alone["final_eps_hat"], rel=1e-12)


def test_a_user_laws_factory_refuses_unknown_keys_in_one_line() -> None:
    with pytest.raises(QcontrolInputError) as err:
        qcontrol.load_scenario(EX2, AGAIN | {"controller.gama": 2.0})
    message = str(err.value)
    # the key came from the dict: the override is named, as given, rather than the file
    assert message.startswith("override controller.gama=2.0: unknown key") and "\n" not in message


def test_a_law_must_follow_the_protocol() -> None:
    qcontrol.register_law("not_a_law", lambda table, n: object())
    with pytest.raises(QcontrolInputError, match="the qcontrol.Law protocol"):
        qcontrol.load_scenario(EX2, {"controller.kind": "not_a_law"})
    with pytest.raises(QcontrolInputError, match="built in and cannot be replaced"):
        qcontrol.register_law("proposed", ProposedAgain)


# ---------------------------------------------------------------------------------------------
# the separation (37)-(43) and the [metrics] table


def test_bound_constants_against_an_independent_computation() -> None:
    res = qcontrol.run(qcontrol.load_scenario(EX2, SHORT), backend="ode")
    x, q = res.x, res.x_q
    phi_x = np.column_stack([np.abs(x[:, 1]), np.abs(x[:, 1] ** 2 * np.cos(x[:, 0])), np.abs(np.sin(x[:,
                                                                                                      0]))])
    phi_q = np.column_stack([np.abs(q[:, 1]), np.abs(q[:, 1] ** 2 * np.cos(q[:, 0])), np.abs(np.sin(q[:,
                                                                                                      0]))])
    r = np.column_stack([1 + q[:, 1] ** 2, 1 + 2 * q[:, 1] ** 2, np.ones(len(q))])
    expected = (np.maximum(phi_x, phi_q) / r).max(axis=0)
    got = res.summary["bound_constants"]
    assert list(got) == ["phi1", "phi2", "phi3"] and not res.summary["warnings"]
    np.testing.assert_allclose([got["phi1"], got["phi2"], got["phi3"]], expected, rtol=1e-12)
    assert got["phi1"] <= 0.5 + 0.01  # |x2| / (1 + q2^2) <= (1 + delta/2) / 2


def test_a_term_its_r_does_not_bound_is_reported(capsys: pytest.CaptureFixture[str]) -> None:
    overrides = ['plant.psi="1/x1"', 'controller.r=["1 + q2**2", "1 + 2*q2**2", "1", "1"]',
                 "simulation.duration=3"]  # 3 s: x1 follows y_d across 0, where psi has no bound
    argv = ["run", str(EX2), "--backend", "ode", "-q"]
    for item in overrides:
        argv += ["--set", item]
    main(argv)
    out = capsys.readouterr().out
    assert "warning: psi is not bounded by its r on this run" in out
    sc = qcontrol.load_scenario(EX2, overrides)
    summary = qcontrol.run(sc, backend="ode").summary
    assert summary["bound_constants"]["psi"] is None and summary["bound_constants"]["phi1"] is not None


def test_the_metrics_table_sets_the_error_rate() -> None:
    sc = qcontrol.load_scenario(EX2, {"metrics.omega": [0.05, 0.0005], "metrics.samples": 11} | SHORT)
    res = qcontrol.run(sc, backend="ode")
    rates = res.summary["error_rate"]
    assert list(rates) == ["0.050", "0.0005"]
    instants = np.arange(11) * (1.0 / 10)
    z1 = np.abs(np.interp(instants, res.t, res.z[:, 0]))
    assert rates["0.050"] == np.count_nonzero(z1 > 0.05) / 11
    with pytest.raises(QcontrolInputError, match="metrics.omega"):
        qcontrol.load_scenario(EX2, {"metrics.omega": [0.1, 0.1]})


# ---------------------------------------------------------------------------------------------
# a real package


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("hatchling")
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                    "-w", str(out), str(ROOT)], check=True, capture_output=True, timeout=300)
    (path,) = out.glob("qcontrol-*.whl")
    return path


def test_the_wheel_ships_the_scenarios_and_the_models(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    for scenario in (ROOT / "scenarios").glob("*.toml"):
        assert f"qcontrol/data/scenarios/{scenario.name}" in names
    for model in (ROOT / "models").glob("*.xml"):
        assert f"qcontrol/data/models/{model.name}" in names
    assert "qcontrol/engine/loop.py" in names and "qcontrol/plants/mujoco/plant.py" in names


def test_shipped_scenarios_run_by_name_from_any_folder(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["run", "example1", "--duration", "0.2", "--out", "here", "-q"]) == 0
    assert json.loads((tmp_path / "here" / "summary.json").read_text())["scenario"] == "example1"
    assert main(["run", "example9", "-q"]) == 2


def test_a_recording_carries_the_provenance_and_the_resolved_scenario(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    sc = qcontrol.load_scenario(EX2, {"simulation.duration": 0.2, "controller.kappa_margin": 0.1})
    res = qcontrol.run(sc, backend="ode", rrd=tmp_path / "run.rrd")
    texts = {}
    for chunk in RrdReader(tmp_path / "run.rrd").stream():
        batch = chunk.to_record_batch()
        if "TextDocument:text" in batch.column_names:
            texts[chunk.entity_path.lstrip("/")] = batch.column("TextDocument:text").to_pylist()[0][0]
    provenance = json.loads(texts["info/provenance"].removeprefix("```json\n").removesuffix("\n```"))
    assert provenance == _json(res.summary["provenance"])
    assert "kappa_margin = 0.1" in texts["info/scenario"]  # the scenario as run, not the file's text


def test_compare_json_and_table1_json_carry_the_provenance(tmp_path: Path) -> None:
    assert main(["compare", str(EX2), "--duration", "0.2", "--out", str(tmp_path / "cmp"), "-q"]) == 0
    compare = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert compare["provenance"]["command"].startswith("qcontrol compare ")
    assert compare["provenance"]["scenario_file"] == "qcontrol:scenarios/example2.toml"
    assert compare["mujoco"]["error_rate"] and compare["ode"]["L"] == compare["mujoco"]["L"]


def test_run_plot_draws_the_run(tmp_path: Path) -> None:
    from qcontrol.plots import FIG_HEIGHT_PX, FIG_WIDTH_PX

    assert main(["run", str(EX1), "--backend", "ode", "--duration", "1", "--plot", str(tmp_path / "run.png"),
                 "--save", str(tmp_path / "run.npz"), "-q"]) == 0
    data = (tmp_path / "run.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    import struct

    assert struct.unpack(">II", data[16:24]) == (FIG_WIDTH_PX, FIG_HEIGHT_PX)
    assert len(np.load(tmp_path / "run.npz")["t"]) == 1001
    assert main(["run", str(EX1), "--save", str(tmp_path / "run.mat"), "-q"]) == 2
