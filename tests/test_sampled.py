"""Law (44) in the sampled loop: the exact hold of its robust term, the gain-period monitor K T,
and the region command that maps where a law holds (docs/math.md, 'Sampling the law')."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import EX1, EX2
from hypothesis import given, settings
from hypothesis import strategies as st

from qcontrol.assembly import build_controller, run_scenario, run_variants
from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError
from qcontrol.metrics import summary
from qcontrol.quantizer import UniformQuantizer, quantize
from qcontrol.scenario import load_scenario

ODE = "simulation.backend='ode'"


def _run(path: Path, *overrides: str, backend: str = "ode", record: str = "full"):
    return run_scenario(load_scenario(path, [ODE, *overrides]), backend, record=record)


def test_the_exact_hold_gives_table_1_of_the_paper_law_to_four_decimals() -> None:
    """From the paper's x(0), K T stays near 0.011: the two holds give the same E(omega) to 4
    decimals, yet the runs differ (the option is not a no-op)."""
    paper, exact = _run(EX2), _run(EX2, 'controller.hold="exact"')
    e_paper, e_exact = summary(paper, "ex2", "ode")["error_rate"], summary(exact, "ex2", "ode")["error_rate"]
    assert e_paper.keys() == e_exact.keys()
    for omega in e_paper:
        assert round(e_paper[omega], 4) == round(e_exact[omega], 4), omega
    assert not np.array_equal(paper.u, exact.u)


def test_the_default_hold_is_the_paper_law_bit_for_bit() -> None:
    """hold = "paper" is the default: giving it changes no number."""
    a = _run(EX1, "simulation.duration=1.0")
    b = _run(EX1, "simulation.duration=1.0", 'controller.hold="paper"')
    for name in a.signals:
        np.testing.assert_array_equal(a.signals[name], b.signals[name], err_msg=name)


def _gain_and_input(sc_overrides: list[str], x: np.ndarray, eps: np.ndarray):
    """K T from the law's own formula and the u it returns, for a batch of readings."""
    sc = load_scenario(EX2, [ODE, *sc_overrides])
    law = build_controller(sc)
    reading = quantize(UniformQuantizer(sc.controller.delta), x)
    yd = [0.0] * (sc.order + 1)
    out = law.control(reading, yd, tuple(eps.T))
    q = reading.columns
    zbar, alphabar = law.recursion(q, yd)
    kt = np.asarray(law.robust_gain(q, yd, tuple(eps.T))) * law.period
    return kt, zbar[-1], alphabar[-1], np.asarray(out.u), law


@settings(max_examples=40, derandomize=True, database=None, deadline=None)
@given(scale=st.floats(1e-3, 1e3), spread=st.floats(0.0, 1e4), seed=st.integers(0, 2**16))
def test_the_exact_hold_factor_is_always_in_the_unit_interval(scale: float, spread: float, seed: int) -> None:
    """For any state and any estimate, the held robust term maps zbar_n by exp(-K T), in (0, 1]
    (the paper's law by 1 - K T, outside it once K T > 1), read back from the u the law returns."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-scale, scale, size=(64, 2))
    eps = rng.uniform(0.0, spread, size=(64, 3))
    kt, zn, alphabar, u, law = _gain_and_input(['controller.hold="exact"'], x, eps)
    assert np.all(kt >= 0)
    factor = law.held_factor(kt)
    assert np.all((factor >= 0) & (factor <= 1))
    assert np.all(factor[kt < 700] > 0)  # > 0 wherever exp(-K T) does not underflow (K T > 745)
    moved = np.abs(zn) > 1e-9
    implied = 1.0 - (alphabar - u)[moved] / zn[moved] * law.period  # 1 - K_T T, from the law's u
    np.testing.assert_allclose(implied, factor[moved], rtol=1e-9, atol=1e-12)
    _, _, _, u_paper, paper = _gain_and_input([], x, eps)
    np.testing.assert_allclose(1.0 - (alphabar - u_paper)[moved] / zn[moved] * paper.period,
                               paper.held_factor(kt[moved]), rtol=1e-9, atol=1e-9)


def test_the_monitor_on_the_paper_run_and_before_a_divergence() -> None:
    """max_gain_period is the largest K T over the control samples, recomputed here from the
    record by (44)'s formula; 0.011 on the paper's Example 2 run, beyond 1e5 before a divergence."""
    traj = _run(EX2)
    s = summary(traj, "ex2", "ode")
    law = build_controller(load_scenario(EX2, [ODE]))
    zbar = law.quantized_errors(traj.x_q, traj.yd)[0][:, -1]
    r = np.column_stack([e(traj.x_q) for e in law.r])
    kappa = law.kappa
    gain = (zbar**2 / kappa + law.L) * (traj.adaptive * r).sum(axis=1) / (kappa * (kappa - law.L))
    assert s["max_gain_period"] == pytest.approx(float(gain.max() * 1e-3), rel=1e-12)
    assert s["max_gain_period"] == pytest.approx(0.0112, abs=5e-4)
    np.testing.assert_allclose(traj.diagnostics[:, 0], gain * 1e-3, rtol=1e-12)
    diverged = summary(_run(EX2, "plant.x0=[10.0, 10.0]"), "ex2", "ode")
    assert diverged["diverged"] and diverged["max_gain_period"] > 1e5


def test_the_monitor_counts_only_control_samples() -> None:
    """With a control period of 5 steps the monitor reads the samples' rows only, and a metrics-only
    run reports the same value as a full record."""
    overrides = ["simulation.control_period=0.005", "simulation.duration=2.0"]
    full, metrics = _run(EX2, *overrides), _run(EX2, *overrides, record="metrics")
    samples = full.diagnostics[::5, 0]
    assert summary(full, "a", "ode")["max_gain_period"] == float(samples.max())
    assert summary(metrics, "a", "ode")["max_gain_period"] == float(samples.max())


def test_the_comparison_law_declares_no_gain() -> None:
    s = summary(_run(EX2, "controller.kind='comparison'", "simulation.duration=0.5"), "b", "ode")
    assert "max_gain_period" not in s


def test_the_exact_hold_runs_in_a_batch_as_single_runs_do() -> None:
    """Two starts as one batch give the numbers of two single runs (per-copy columns)."""
    starts = ["plant.x0=[10.0, -10.0]", "plant.x0=[-5.0, 7.5]"]
    scs = [load_scenario(EX2, [ODE, 'controller.hold="exact"', "simulation.duration=1.0", x]) for x in starts]
    batch = run_variants(scs, "ode", record="metrics")
    for sc, run in zip(scs, batch, strict=True):
        single = run_scenario(sc, "ode", record="metrics")
        same = {"wall_time_s": 0}
        assert summary(run, "a", "ode") | same == summary(single, "a", "ode") | same
        assert not run.diverged


def test_the_exact_hold_on_mujoco() -> None:
    run = _run(EX2, 'controller.hold="exact"', "plant.x0=[5.0, 5.0]", "simulation.duration=0.5",
               backend="mujoco", record="metrics")
    assert not run.diverged
    assert summary(run, "m", "mujoco")["max_gain_period"] > 1  # far from the reference: K T large


def test_a_bad_hold_is_one_line() -> None:
    with pytest.raises(QcontrolInputError, match=r"hold.*paper.*exact"):
        load_scenario(EX2, ['controller.hold="fast"'])


def test_the_region_command_writes_its_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "region"
    assert main(["region", str(EX2), "--resolution", "3", "--duration", "0.5", "--law", "proposed",
                 "--law", "proposed:hold=exact", "--law", "comparison", "--out", str(out), "-q"]) == 0
    rows = list(csv.DictReader((out / "region.csv").open()))
    assert len(rows) == 27 and {r["law"] for r in rows} == {"proposed", "proposed:hold=exact", "comparison"}
    corner = {r["law"]: r for r in rows if r["x1"] == "10.0" and r["x2"] == "10.0"}
    assert corner["proposed"]["outcome"] == "diverged" and float(corner["proposed"]["diverged_time"]) < 0.01
    assert corner["proposed:hold=exact"]["outcome"] == "bounded"
    assert corner["comparison"]["max_gain_period"] == ""
    record = json.loads((out / "region.json").read_text())
    assert record["axes"] == ["x1", "x2"] and record["resolution"] == 3 and record["control_period"] == 0.001
    assert "provenance" in record and record["provenance"]["scenario_sha256"]
    laws = {law["law"]: law for law in record["laws"]}
    assert laws["proposed:hold=exact"]["failing_in_box"] == 0 and laws["proposed"]["failing_in_box"] > 0
    assert (out / "region.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "proposed:hold=exact: 0 of 9 points fail in |x_i| <= 10" in printed


@pytest.mark.parametrize("argv, message", [
    (["--law", "nope"], "unknown controller kind 'nope'"),
    (["--axes", "1,1"], "--axes '1,1'"),
    (["--box", "5,1"], "--box '5,1'"),
    (["--resolution", "1"], "--resolution 1"),
    (["--law", "proposed:hold=fast"], "hold"),
])
def test_the_region_command_refuses_bad_input_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                          argv: list[str], message: str) -> None:
    out = tmp_path / "region"
    assert main(["region", str(EX2), "--out", str(out), "-q", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_the_largest_working_scale_per_direction() -> None:
    """On the grid's rays: the largest scale before the first failure, per direction."""
    from qcontrol.region import RegionGrid, measure_region, parse_law

    region = measure_region(EX2, RegionGrid((0, 1), (-10.0, -10.0), (10.0, 10.0), 5), [parse_law("proposed")],
                            overrides=["simulation.duration=0.5"])
    directions = {tuple(d["direction"]): d for d in region.law_summary(region.laws[0])["directions"]}
    assert len(directions) == 8 and all(d["points"] == 2 for d in directions.values())
    along_x1 = directions[(1, 0)]
    assert along_x1["first_fail"] == 5.0 and along_x1["largest_ok"] == 0.0
    assert math.isclose(max(p.x0[0] for p in region.points), 10.0)


def test_the_region_is_the_same_in_process_and_on_workers(monkeypatch) -> None:
    """In this process a law's scenario is loaded once and its starts batched as the sweep batches
    them; on local workers every start goes through the sweep's executor: the same points."""
    from qcontrol.region import RegionGrid, measure_region, parse_law
    from qcontrol.sweep import runs

    grid = RegionGrid((0, 1), (-10.0, -2.0), (10.0, 6.0), 3)
    laws = [parse_law("proposed"), parse_law("proposed:hold=exact")]
    here = measure_region(EX2, grid, laws, overrides=["simulation.duration=0.3"])
    monkeypatch.setattr(runs, "SPREAD_MIN_WORK", {})  # workers however little the work
    there = measure_region(EX2, grid, laws, overrides=["simulation.duration=0.3"], workers=2)
    assert here.points == there.points and len(here.points) == 18
    assert {p.x0 for p in here.points} == {(a, b) for a in (-10.0, 0.0, 10.0) for b in (-2.0, 2.0, 6.0)}


class _CertaintyEquivalence:
    """u = alphabar_n (no robust term, no adaptation): a law registered from Python."""

    state_size = 0

    def __init__(self, c):
        self.c = c

    def initial_state(self):
        return np.zeros(0)

    def control(self, t, x_q, yd, state):
        import qcontrol

        return qcontrol.quantized_backstepping(self.c, x_q, yd)[1][-1]

    def state_rate(self, t, x_q, yd, state):
        return np.zeros(0)


def test_a_law_registered_from_python_is_mapped_like_a_built_in_one(tmp_path: Path) -> None:
    import qcontrol
    from qcontrol.controller import LAW_KINDS

    if "region_ce" not in LAW_KINDS:
        qcontrol.register_law("region_ce", lambda table, n: _CertaintyEquivalence(table["c"]))
    out = tmp_path / "r"
    assert main(["region", str(EX2), "--law", "region_ce", "--law", "proposed", "--resolution", "3",
                 "--duration", "0.2", "--out", str(out), "-q"]) == 0
    laws = {law["law"]: law for law in json.loads((out / "region.json").read_text())["laws"]}
    assert laws["region_ce"]["points"] == 9 and laws["region_ce"]["max_gain_period"] is None
    assert laws["proposed"]["max_gain_period"] is not None


def test_the_law_diagnostics_land_in_the_saved_files(tmp_path: Path) -> None:
    """--save writes the diagnostic under its own name, a column in CSV and an array in npz."""
    out = tmp_path / "r"
    short = ["run", str(EX2), "--backend", "ode", "--duration", "0.2", "-q"]
    assert main([*short, "--save", str(tmp_path / "run.csv"), "--out", str(out)]) == 0
    rows = list(csv.DictReader((tmp_path / "run.csv").open()))
    column = np.array([float(r["gain_period"]) for r in rows])
    assert column.max() == json.loads((out / "summary.json").read_text())["max_gain_period"]
    assert main([*short, "--save", str(tmp_path / "run.npz")]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "run.npz")["diagnostics"][:, 0], column)
