"""`qcontrol reproduce` end to end on a shortened horizon: every file, valid contents."""

import json
import struct

import numpy as np
import pytest
from conftest import FULL_REPRODUCE, QUICK_REPRODUCE_CALL

from qcontrol.paper import PAPER_TABLE1
from qcontrol.plots import FIG_HEIGHT_PX, FIG_WIDTH_PX

FIGURES = [
    "fig1_output.png", "fig2_tracking_error.png", "fig3_xi_hat.png", "fig4_input.png",
    "fig5_outputs.png", "fig6_tracking_errors.png", "fig7_eps_hat.png", "fig8_input.png",
    "fig_example1_mujoco_vs_ode.png", "fig_example2_mujoco_vs_ode.png", "table1.png",
    "study_kappa.png", "study_r_scale.png", "study_plant_variants.png", "study_robustness.png",
    "study_margins.png", "study_region.png", "study_tradeoff.png",
]
OMEGAS = ["0.100", "0.125", "0.150", "0.175", "0.200"]


@pytest.fixture(scope="module")
def reproduction(full_reproduction):
    """``reproduce --out FOLDER --duration 0.5 -q`` (the session's shared run, conftest.py)."""
    out, status, _ = full_reproduction
    assert FULL_REPRODUCE == ["reproduce", "--out", "results/", "--duration", "0.5", "-q"]
    assert status == 0
    return out


def test_every_file_is_written(reproduction):
    names = {p.name for p in reproduction.iterdir()}
    expected = set(FIGURES) | {"table1.md", "table1.json", "studies.json", "robustness.json", "REPORT.md",
                               "example1.rrd", "example2.rrd", "region.json", "tradeoff.json"}
    assert expected <= names
    assert not [n for n in names if n.endswith((".part", ".tmp"))]


def test_table1_json(reproduction):
    table = json.loads((reproduction / "table1.json").read_text())
    assert table["omegas"] == OMEGAS
    assert table["paper"] == PAPER_TABLE1  # verbatim
    assert table["paper"]["proposed"]["0.100"] == 0.0253
    assert table["paper"]["comparison"]["0.200"] == 0.8679
    assert set(table["ours"]) == {"mujoco", "ode"}
    for methods in table["ours"].values():
        assert set(methods) == {"proposed", "comparison"}
        for rates in methods.values():
            assert list(rates) == OMEGAS
            for v in rates.values():
                assert 0.0 <= v <= 1.0 and np.isfinite(v)
            values = list(rates.values())  # E(omega) cannot grow with omega
            assert all(a >= b for a, b in zip(values, values[1:], strict=False))


def test_runs_shorter_than_the_papers_are_not_compared_with_it(reproduction):
    """0.5 s runs against the paper's 10 s: no difference anywhere, and the outputs say why."""
    table = json.loads((reproduction / "table1.json").read_text())
    assert "difference" not in table and "0.5 s long, the paper's 10 s" in table["not_compared"]
    md = (reproduction / "table1.md").read_text()
    assert "ours - paper" not in md and "Not compared with the paper" in md
    report = (reproduction / "REPORT.md").read_text()
    assert "Nothing is compared with the paper here" in report
    assert "Not reproduced" not in report and "qualitative picture" not in report


def test_runs_of_the_papers_horizon_are_compared_with_it():
    from qcontrol.reproduce.report import table1, table1_markdown

    ours = {"ode": {m: {w: 0.5 for w in OMEGAS} for m in ("proposed", "comparison")}}
    for horizon in (None, 10.0):
        table = table1(ours, horizon)
        assert "not_compared" not in table
        for method in ("proposed", "comparison"):
            for w in OMEGAS:
                assert table["difference"]["ode"][method][w] == 0.5 - PAPER_TABLE1[method][w]
        assert "| proposed (44)-(45) | ours - paper (ode) | +0.4747 |" in table1_markdown(table)
    assert "difference" not in table1(ours, 9.0)


def test_table1_markdown_and_report(reproduction):
    md = (reproduction / "table1.md").read_text()
    assert "| proposed (44)-(45) | paper | 0.0253 | 0.0223 | 0.0200 | 0.0177 | 0.0161 |" in md
    assert "| comparison [20], eq. (46) | paper | 0.9570 | 0.9339 | 0.9132 | 0.8925 | 0.8679 |" in md
    report = (reproduction / "REPORT.md").read_text()
    needles = ("Lemma 2", "kappa - L", "scale of r", "MuJoCo vs ODE", "fig5_outputs.png",
               "## Robustness on realistic hardware", "study_robustness.png", "### Reading", "Saturation",
               "Velocity from the encoder", "Friction", "## The sampled loop: region of attraction",
               "study_region.png", "The cost of safety", "## The trade-off", "study_tradeoff.png")
    for needle in needles:
        assert needle in report


def test_table1_json_carries_the_provenance(reproduction):
    table = json.loads((reproduction / "table1.json").read_text())
    provenance = table["provenance"]
    assert set(provenance["scenario_file"]) == {"proposed", "comparison"}
    assert provenance["overrides"]["comparison"][0] == "controller.kind=comparison"
    assert "[controller.comparison]" in provenance["resolved_scenario"]["comparison"]


def test_studies_cover_the_paper_values(reproduction):
    studies = json.loads((reproduction / "studies.json").read_text())
    assert 1.1 in studies["kappa_margin"]["values"] and 0.1 in studies["kappa_margin"]["values"]
    assert studies["r_scale"]["values"][0] == 1.0
    provenance = studies.pop("provenance")
    assert set(provenance["scenario_file"]) == {"example2", "example2-rigid"}
    for study in studies.values():
        assert len(study["values"]) == len(study["summaries"])
        for s in study["summaries"]:
            assert s["lemma2_max_ratio"] <= 1 + 1e-9


@pytest.mark.parametrize("name", FIGURES)
def test_figures_are_pngs_of_the_stated_size(reproduction, name):
    data = (reproduction / name).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (FIG_WIDTH_PX, FIG_HEIGHT_PX)
    assert len(data) > 10_000


ROBUSTNESS_ROWS = {  # every imperfection of the realistic scenarios, alone, then all together
    "example2": ["ideal", "torque limit", "friction", "rotor inertia (armature)", "link mass (rod)",
                 "sensor noise", "sensor delay", "control period", "x2 differenced", "all together"],
    "example1": ["ideal", "force limit", "friction", "rotor inertia (armature)", "sensor noise",
                 "sensor delay", "control period", "x2 differenced", "all together"],
}
ROW_NUMBERS = ("max_abs_z1_last_half", "max_abs_u_applied", "saturated_fraction")


def test_robustness_json_holds_every_row(reproduction):
    study = json.loads((reproduction / "robustness.json").read_text())
    assert len(study["seeds"]) >= 20
    for example, labels in ROBUSTNESS_ROWS.items():
        for law in ("proposed", "comparison"):
            rows = [r for r in study["rows"] if r["example"] == example and r["law"] == law]
            assert [r["imperfection"] for r in rows] == labels
            for r in rows:
                noisy = r["imperfection"] in ("sensor noise", "all together")
                assert r["mujoco"]["runs"] == (len(study["seeds"]) if noisy else 1) and r["ode"]["runs"] == 1
                for backend in ("mujoco", "ode"):
                    cell = r[backend]
                    assert list(cell["error_rate"]) == OMEGAS and 0 <= cell["diverged"] <= cell["runs"]
                    for key in ROW_NUMBERS:
                        spread = cell[key]
                        assert set(spread) == {"median", "min", "max"}
                        if spread["median"] is not None:
                            assert spread["min"] <= spread["median"] <= spread["max"]
                    assert 0.0 <= cell["saturated_fraction"]["max"] <= 1.0
    kinds = {(c["plant"], c["disturbance"], c["law"], c["backend"]) for c in study["disturbances"]}
    assert kinds == {(p, d, law, b) for p in ("ideal arm", "realistic arm") for d in ("impulse", "load step")
                     for law in ("proposed", "comparison") for b in ("mujoco", "ode")}
    for c in study["disturbances"]:
        keys = {"peak_abs_z1", "peak_deviation", "recovery_time_s", "recovery_to_undisturbed_s"}
        assert keys <= set(c["result"])
    assert {m["example"] for m in study["margins"]} == {"example1", "example2"}


def test_quick_reproduce_skips_the_robustness_study(quick_reproduction):
    """A quick reproduction on 0.3 s ODE runs (the session's shared run, made through
    qcontrol.reproduce: conftest.py; tests/test_reproduce_laws.py checks the same of the command
    line's ``reproduce --quick``)."""
    rep, logged = quick_reproduction
    out = rep.out
    assert QUICK_REPRODUCE_CALL == {"quick": True, "backend": "ode", "duration": 0.3}
    assert "no region or robustness study (--quick)" in logged
    assert (out / "table1.json").is_file() and (out / "REPORT.md").is_file()
    assert not (out / "robustness.json").exists() and not (out / "study_margins.png").exists()
    report = (out / "REPORT.md").read_text()
    assert "Not run here (`qcontrol reproduce --quick`)" in report


def test_the_region_study_compares_the_three_laws_at_two_rates(reproduction):
    """Both examples at 1 kHz and 2 kHz: the paper's law, its exact hold and the comparison law; the
    exact hold fails nowhere in the box, the paper's law somewhere on Example 2, and from x(0) the
    two holds give the same error rates to 4 decimals."""
    study = json.loads((reproduction / "region.json").read_text())
    assert "provenance" in study and study["resolution"] == 9
    rows = {(r["example"], r["control_period"], r["law"]): r for r in study["rows"]}
    assert len(rows) == 12
    for example in ("example1", "example2"):
        for period in (0.001, 0.0005):
            paper, exact = rows[(example, period, "proposed")], rows[(example, period, "proposed:hold=exact")]
            assert exact["failing_in_box"] == 0 and exact["points_in_box"] == 81
            assert {w: round(v, 4) for w, v in paper["error_rate"].items()} == {
                w: round(v, 4) for w, v in exact["error_rate"].items()}
            assert rows[(example, period, "comparison")]["max_gain_period_from_x0"] is None
    assert rows[("example2", 0.001, "proposed")]["failing_in_box"] > 0


def test_the_robustness_study_batches_each_rows_seeds(monkeypatch, tmp_path):
    """Each row's sensor-noise seeds share everything else: one job per row (8 of the study's
    rows); the other runs alone, in jobs of one scenario file and backend each, at most
    ALONE_PER_JOB runs a job. A run asked for twice is planned once: the seed the scenario
    file has already (1) is the row's run without the override, and the disturbance cases' quiet
    runs (the ideal and the realistic arm, each law, each backend) are rows' runs."""
    from pathlib import Path

    from qcontrol.reproduce import robustness_study as study

    planned = {}

    def capture(tasks, full):
        planned["batches"] = study.batches(tasks)
        planned["files"] = [{(tasks[i].path, tasks[i].backend) for i in b} for b in planned["batches"]]
        seed = lambda task: next((o for o in task.overrides if o.startswith(study.SEED_OVERRIDE)), "own")  # noqa: E731
        planned["seeds"] = [{seed(tasks[i]) for i in b} for b in planned["batches"][:8]]
        planned["shared"] = [t for t in full if t in set(tasks)]
        raise KeyboardInterrupt

    monkeypatch.setattr(study, "_execute", capture)
    with pytest.raises(KeyboardInterrupt):
        scenarios = Path(__file__).resolve().parent.parent / "scenarios"
        study.robustness_study(scenarios, 0.5, 1, log=lambda _: None)
    sizes = sorted((len(b) for b in planned["batches"]), reverse=True)
    assert sizes[:8] == [len(study.SEEDS)] * 8 and max(sizes[8:]) == study.ALONE_PER_JOB
    assert all(len(files) == 1 for files in planned["files"])  # one file and backend a job
    every = {f"plant.mujoco.noise_seed={s}" for s in study.SEEDS}
    own = {"own", *(f"plant.mujoco.noise_seed={s}" for s in study.SEEDS[1:])}  # the realistic files' rows
    matched = [seeds == own for seeds in planned["seeds"] if seeds in (every, own)]
    assert len(matched) == 8 and sum(matched) == 4
    quiet = [t for t in planned["shared"] if "disturbance=[]" in t.overrides]  # the realistic arm's
    assert len(planned["shared"]) == 8 and len(quiet) == 4 and {t.backend for t in quiet} == {"mujoco", "ode"}
    assert sorted(i for b in planned["batches"] for i in b) == list(range(sum(sizes)))


def test_figures_drawn_apart_are_the_figures_drawn_here(tmp_path):
    """A forked worker draws the very bytes this process draws, its files are staged with the
    others, and its failure reaches the caller."""
    from qcontrol.outputs import staged
    from qcontrol.plots.common import new_figure, save
    from qcontrol.reproduce.drawing import Apart

    def figures(folder):
        fig, axes = new_figure()
        axes[0, 0].plot([0.0, 1.0, 2.0], [1.0, -0.5, 2.0], label="a line")
        axes[0, 0].legend()
        save(fig, folder / "f.png")

    def broken(folder):
        raise ValueError("no figure")

    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    Apart(here, forked=False).draw(figures)
    with staged(), Apart(there, forked=True) as apart:
        apart.draw(figures)
        apart.wait()
        assert not (there / "f.png").exists()  # staged: in place with the set, at its end
    assert (there / "f.png").read_bytes() == (here / "f.png").read_bytes()
    with pytest.raises(ValueError, match="no figure"), Apart(there, forked=True) as apart:
        apart.draw(broken)
        apart.wait()


def test_a_study_of_long_runs_runs_them_alone_with_the_batchs_numbers(monkeypatch, tmp_path):
    """A sensitivity study whose runs take the compiled loop runs them one by one (each its own
    batch of one), in input order, with the numbers of the same variants stepped as one batch in
    the array form."""
    from qcontrol import compiled as compiled_paths
    from qcontrol.reproduce import reproduction
    from qcontrol.sweep import runs

    sets = [[f"controller.kappa_margin={m!r}"] for m in (0.1, 0.5, 1.1, 2.0, 5.0)]  # (a sweep batches 5)
    rep = reproduction.Reproduction(tmp_path, duration=5.0, log=lambda _: None)
    batches, original = [], runs.run_batch
    monkeypatch.setattr(runs, "run_batch", lambda scs, backend: batches.append(len(scs)) or
                        original(scs, backend))
    alone = rep.study("kappa", "example2", sets) if compiled_paths.enabled() else None
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    batched = rep.study("kappa", "example2", sets)
    if alone is not None:
        assert batches == [1] * len(sets) + [len(sets)]
        assert [s.error_rate for s in alone] == [s.error_rate for s in batched]
        assert [s.max_abs_z1_last_half for s in alone] == [s.max_abs_z1_last_half for s in batched]
    assert len({s.error_rate["0.100"] for s in batched}) == len(sets)  # (every kappa its own numbers)
