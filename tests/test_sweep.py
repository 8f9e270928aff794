"""``qcontrol sweep``: the table, diverged grid points, bad input, and the executors."""

import argparse
import csv
import json
import os
import signal
import struct
from pathlib import Path

import pytest
from conftest import EX2 as EXAMPLE2

from qcontrol.cli.sweep_command import add_sweep_parser, cmd_sweep
from qcontrol.errors import QcontrolInputError
from qcontrol.sweep import CSV_METRICS, sweep_summaries
from qcontrol.sweep import runs as sweep

SHORT = "simulation.duration=1.0"


def _sweep(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    add_sweep_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["sweep", *argv])
    return cmd_sweep(args)


def _table(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_sweep_csv_has_one_row_per_grid_point(tmp_path):
    assert _sweep(str(EXAMPLE2), "--grid", "controller.kappa_margin=0.1,1.1", "--grid",
                  "controller.r_scale=1,2,4", "--set", SHORT, "--out", str(tmp_path), "-q") == 0
    rows = _table(tmp_path / "sweep.csv")
    keys = ["controller.kappa_margin", "controller.r_scale"]
    assert list(rows[0]) == keys + CSV_METRICS + ["max_gain_period"]  # the law's diagnostic last
    assert [(r["controller.kappa_margin"], r["controller.r_scale"]) for r in rows] == [
        (k, s) for k in ("0.1", "1.1") for s in ("1", "2", "4")]
    assert {r["diverged"] for r in rows} == {"False"}
    assert all(0.0 <= float(r["error_rate_0.100"]) <= 1.0 for r in rows)
    assert all(float(r["lemma2_max_ratio"]) <= 1.0 + 1e-9 for r in rows)
    assert (tmp_path / "sweep.png").stat().st_size > 1000
    assert not list(tmp_path.glob(".*part"))  # atomic writes leave no temporaries


def test_the_laws_diagnostics_are_columns_equal_to_each_runs_summary(tmp_path):
    """A batched sweep's max_gain_period equals the run's alone; a law without the diagnostic (the
    comparison law) leaves the cell empty."""
    import qcontrol

    assert _sweep(str(EXAMPLE2), "--grid", "controller.kind=proposed,comparison", "--grid",
                  "controller.proposed.kappa_margin=0.1,0.3,0.5,0.7,0.9", "--set", SHORT, "--backend", "ode",
                  "--out", str(tmp_path), "-q") == 0
    rows = _table(tmp_path / "sweep.csv")
    for row in rows:
        if row["controller.kind"] == "comparison":
            assert row["max_gain_period"] == ""
            continue
        alone = qcontrol.run(qcontrol.load_scenario(EXAMPLE2, {"controller.kappa_margin": float(
            row["controller.proposed.kappa_margin"]), "simulation.duration": 1.0}), backend="ode")
        assert float(row["max_gain_period"]) == alone.summary["max_gain_period"] > 0


def test_a_diverging_grid_point_is_a_row_not_a_stop(tmp_path):
    # the first point's state bound is left within 0.1 s: a diverged run among finished ones
    assert _sweep(str(EXAMPLE2), "--grid", "simulation.state_bound=0.35,1e6", "--grid",
                  "controller.gamma=1,2", "--set", SHORT, "--out", str(tmp_path), "-q") == 0
    rows = _table(tmp_path / "sweep.csv")
    assert len(rows) == 4
    assert [r["diverged"] for r in rows] == ["True", "True", "False", "False"]
    assert all(float(r["max_abs_u"]) > 0 for r in rows)  # the later points ran to the end


def test_random_initial_states(tmp_path):
    assert _sweep(str(EXAMPLE2), "--grid", "controller.gamma=1,2", "--random-initial", "2", "--seed", "7",
                  "--set", "simulation.duration=0.2", "--out", str(tmp_path), "-q") == 0
    rows = _table(tmp_path / "sweep.csv")
    assert len(rows) == 4 and len({r["plant.x0"] for r in rows}) == 2


@pytest.mark.parametrize("argv, message", [
    (["--grid", "controller.gamma"], "expected KEY=V1,V2"),
    (["--grid", "controller.gamma=1,,2"], "empty value"),
    (["--grid", "controller.kappa_margin=-1"], "kappa_margin"),
    (["--grid", "controller.nonsense=1"], "unknown key"),
    (["--workers", "0"], "--workers"),
])
def test_bad_input_is_an_input_error(tmp_path, argv, message):
    with pytest.raises(QcontrolInputError, match=message):
        _sweep(str(EXAMPLE2), *argv, "--set", SHORT, "--out", str(tmp_path / "out"), "-q")
    assert not (tmp_path / "out" / "sweep.csv").exists()


SETS = [[SHORT, f"controller.kappa_margin={k}", f"controller.gamma={g}"]
        for k in (0.1, 1.1) for g in (1.0, 3.0)]


def _comparable(summaries):
    return [{k: v for k, v in s.to_json().items() if k != "wall_time_s"} for s in summaries]


def test_local_workers_give_the_in_process_table(monkeypatch):
    monkeypatch.setattr(sweep, "CHUNK", 2)  # two batches, so both workers get one
    monkeypatch.setattr(sweep, "SPREAD_MIN_WORK", {})  # workers however little the work
    local = sweep_summaries(EXAMPLE2, SETS)
    assert _comparable(sweep_summaries(EXAMPLE2, SETS, workers=2)) == _comparable(local)


_COMMAND = os.getpid()  # (the process the tests run in: a sweep's workers are its forks)
_RUN_CHUNK = sweep._run_chunk
_HERE: list[list[int]] = []  # the chunks this process ran (a fork's appends stay in the fork)


def _noting_this_process(*task):
    if os.getpid() == _COMMAND:
        _HERE.append(task[5])
    return _RUN_CHUNK(*task)


def _failing_in_a_fork(*task):
    if os.getpid() != _COMMAND:
        raise QcontrolInputError("failed in a fork")
    return _RUN_CHUNK(*task)


def test_this_process_is_one_of_the_workers(monkeypatch):
    """Two workers: this process runs the first chunk, its one fork the second, the others go to
    whichever is free; the table is this process's alone, and a fork's error reaches this process."""
    monkeypatch.setattr(sweep, "CHUNK", 2)
    monkeypatch.setattr(sweep, "SPREAD_MIN_WORK", {})
    local = sweep_summaries(EXAMPLE2, SETS)
    monkeypatch.setattr(sweep, "_run_chunk", _noting_this_process)
    _HERE.clear()
    assert _comparable(sweep_summaries(EXAMPLE2, SETS, workers=2)) == _comparable(local)
    assert _HERE[0] == [0] and [1] not in _HERE  # (four runs, run by run: four chunks)
    monkeypatch.setattr(sweep, "_run_chunk", _failing_in_a_fork)
    with pytest.raises(QcontrolInputError, match="failed in a fork"):
        sweep_summaries(EXAMPLE2, SETS, workers=2)


def _square_and_where(i: int) -> tuple[int, int]:
    return i * i, os.getpid()


def _ending_in_a_fork(i: int) -> int:
    if os.getpid() != _COMMAND:
        os.kill(os.getpid(), signal.SIGKILL)
    return i


def test_share_runs_every_task_once_here_and_on_the_forks():
    """workers.share: every index run once, its result handed to ``done`` in this process (task 0
    run here, task 1 on the fork); a fork killed mid-task is an error here, not a wait forever."""
    from qcontrol.workers import WorkerDied, share

    got: dict[int, tuple[int, int]] = {}
    share(2, 7, _square_and_where, got.__setitem__)
    assert sorted(got) == list(range(7)) and all(got[i][0] == i * i for i in got)
    assert got[0][1] == _COMMAND and got[1][1] != _COMMAND
    with pytest.raises(WorkerDied):
        share(2, 3, _ending_in_a_fork, lambda i, r: None)


def test_a_sweep_forks_workers_only_for_work_enough(monkeypatch):
    """runs x rows against the backend's least work for workers: 49 runs of 10,001 rows on the
    ODE stay in this process, 50 go to workers (500,050 copy-steps), on MuJoCo 2 runs already; a
    small sweep with ``workers=2`` never forks and gives the in-process table."""
    def variants(runs: int) -> list:
        return sweep.planned(EXAMPLE2, [["simulation.duration=10.0"]] * runs, "ode")[1]

    assert sweep.SPREAD_MIN_WORK["ode"] == 500_000
    assert not sweep.worth_spreading(variants(49), "ode")
    assert sweep.worth_spreading(variants(50), "ode")
    assert sweep.SPREAD_MIN_WORK["mujoco"] == 20_000  # a MuJoCo copy-step costs some 40x an ODE one
    assert not sweep.worth_spreading(variants(1), "mujoco") and sweep.worth_spreading(variants(2), "mujoco")
    assert sweep.worth_spreading(None, "ode")  # variants loaded elsewhere: as asked

    def no_fork(*args: object) -> None:
        raise AssertionError("forked workers for a small sweep")

    monkeypatch.setattr(sweep, "share", no_fork)
    here = sweep_summaries(EXAMPLE2, SETS)
    assert _comparable(sweep_summaries(EXAMPLE2, SETS, workers=2)) == _comparable(here)


def test_dask_cluster_gives_the_local_table(monkeypatch):
    distributed = pytest.importorskip("distributed")
    monkeypatch.setattr(sweep, "CHUNK", 2)
    local = sweep_summaries(EXAMPLE2, SETS)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        remote = sweep_summaries(EXAMPLE2, SETS, scheduler=cluster.scheduler_address)
    assert _comparable(remote) == _comparable(local)


def test_unreachable_scheduler_is_an_input_error(monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(sweep, "DASK_CONNECT_TIMEOUT", 1.0)
    with pytest.raises(QcontrolInputError, match="--scheduler"):
        sweep_summaries(EXAMPLE2, SETS[:1], scheduler="tcp://127.0.0.1:9")


def test_sweep_json_records_the_sweep_with_provenance(tmp_path, figure_not_drawn):
    assert _sweep(str(EXAMPLE2), "--grid", "controller.gamma=1,2", "--set", SHORT, "--backend", "ode",
                  "--out", str(tmp_path), "-q") == 0
    record = json.loads((tmp_path / "sweep.json").read_text())
    assert record["grid"] == {"controller.gamma": ["1", "2"]} and record["backend"] == "ode"
    assert record["runs"] == record["runs_finished"] == 2 and not record["interrupted"]
    assert record["provenance"]["overrides"] == [SHORT]
    assert "[controller.proposed]" in record["provenance"]["resolved_scenario"]
    rows = _table(tmp_path / "sweep.csv")
    assert [r["diverged_time"] for r in rows] == ["", ""]
    assert figure_not_drawn == [tmp_path / "sweep.png"]


def test_the_scenarios_backend_is_the_default(tmp_path, capsys, figure_not_drawn):
    assert _sweep(str(EXAMPLE2), "--grid", "controller.gamma=1,2", "--set", "simulation.duration=0.1",
                  "--out", str(tmp_path)) == 0
    assert json.loads((tmp_path / "sweep.json").read_text())["backend"] == "mujoco"
    assert "--backend ode steps the runs together" in capsys.readouterr().out


def test_ctrl_c_keeps_the_finished_rows(tmp_path, ctrl_c_on_second_chunk):
    ctrl_c_on_second_chunk()
    (tmp_path / "sweep.csv").write_text("a complete sweep's table\n")
    with pytest.raises(KeyboardInterrupt):
        _sweep(str(EXAMPLE2), "--grid", "controller.gamma=1,2,3", "--set", SHORT, "--backend", "ode",
               "--out", str(tmp_path), "-q")
    rows = _table(tmp_path / "sweep.partial.csv")  # the finished rows, under the partial names
    assert [r["controller.gamma"] for r in rows] == ["1"]
    record = json.loads((tmp_path / "sweep.partial.json").read_text())
    assert record["interrupted"] and record["runs"] == 3 and record["runs_finished"] == 1
    assert record["csv"] == "sweep.partial.csv"
    assert (tmp_path / "sweep.csv").read_text() == "a complete sweep's table\n"  # left as it was
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["sweep.csv", "sweep.partial.csv", "sweep.partial.json", "sweep.partial.png"]


GRIDS = [["controller.gamma=1,2,3"], ["controller.gamma=1,2", "controller.sigma=1,2"],
         ["controller.gamma=1,2", "controller.sigma=1,2", "controller.r_scale=1,2"]]


@pytest.mark.parametrize("grids", GRIDS)
def test_a_figure_for_each_grid_dimension(tmp_path, grids):
    from qcontrol.plots import FIG_HEIGHT_PX, FIG_WIDTH_PX

    argv = [str(EXAMPLE2), "--set", "simulation.duration=0.5", "--backend", "ode", "--out", str(tmp_path),
            "-q"]
    for grid in grids:
        argv += ["--grid", grid]
    assert _sweep(*argv) == 0
    data = (tmp_path / "sweep.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert struct.unpack(">II", data[16:24]) == (FIG_WIDTH_PX, FIG_HEIGHT_PX)


def test_a_diverged_cell_is_marked_and_does_not_set_the_colour_scale():
    """A run that diverged has an enormous max |u|: its cell is left blank (marked x), and the
    colours span the other cells only."""
    import matplotlib.pyplot as plt

    from qcontrol.plots.sweeps import _heatmap, _Points

    rows = [{"a": a, "b": b, "max_abs_u": u, "diverged": str(d)}
            for a, b, u, d in [("1", "1", 20.0, False), ("2", "1", 30.0, False),
                               ("1", "2", 40.0, False), ("2", "2", 2e17, True)]]
    fig, ax = plt.subplots()
    _heatmap(ax, rows, _Points(rows, ["a", "b"]), ["a", "b"], (), "max_abs_u", "max |u|")
    (image,) = ax.get_images()
    cells = image.get_array()
    assert cells.mask.tolist() == [[False, False], [False, True]]  # rows: b = 1, 2; columns: a = 1, 2
    assert (image.norm.vmin, image.norm.vmax) == (20.0, 40.0)
    assert "x" in [t.get_text() for t in ax.texts]
    plt.close(fig)


def test_small_groups_run_run_by_run_and_large_ones_in_even_chunks(monkeypatch):
    monkeypatch.setattr(sweep, "CHUNK", 4)
    groups = [list(range(9)), [9, 10], [11, 12, 13, 14, 15]]
    assert sweep.chunks_of(groups) == [[0, 1, 2], [3, 4, 5], [6, 7, 8], [9], [10], [11, 12], [13, 14, 15]]


def test_chunks_are_cut_so_that_every_worker_gets_one():
    """200 runs on 2 workers: two batches of 100 (not one of 200); 1000: four of 250."""
    assert [len(c) for c in sweep.chunks_of([list(range(200))], workers=2)] == [100, 100]
    assert [len(c) for c in sweep.for_workers([list(range(200))], 2)] == [100, 100]
    assert [len(c) for c in sweep.chunks_of([list(range(1000))], workers=2)] == [250] * 4
    assert [len(c) for c in sweep.chunks_of([list(range(6))], workers=3)] == [6]  # no batch below MIN_BATCH
    assert sweep.for_workers([[0, 1], [2, 3]], 2) == [[0, 1], [2, 3]]  # short chunks are left whole
    # 600 runs: as many runs per worker (not 3 of 200: one worker's 400 against the other's 200)
    assert [len(c) for c in sweep.for_workers(sweep.chunks_of([list(range(600))]), 2)] == [100] * 6
    # three groups of 100 on 2 workers: six of 50, the largest first; every run once
    cut = sweep.for_workers([list(range(k, k + 100)) for k in (0, 100, 200)], 2)
    assert [len(c) for c in cut] == [50] * 6 and sorted(i for c in cut for i in c) == list(range(300))
    assert [len(c) for c in sweep.for_workers([list(range(10)), list(range(10, 40))], 2)] == [10] * 4


@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_the_table_is_the_same_however_the_runs_are_chunked(tmp_path, monkeypatch, backend, figure_not_drawn):
    """sweep.csv (wall time aside) from one batch in this process, from two workers (a batch each),
    and from batches of 6: a copy's numbers do not depend on its batch."""
    argv = [str(EXAMPLE2), "--grid", "controller.gamma=1,2,3", "--random-initial", "4", "--seed", "3",
            "--set", "simulation.duration=0.5", "--backend", backend, "-q"]
    tables = []
    monkeypatch.setattr(sweep, "SPREAD_MIN_WORK", {})  # workers however little the work
    for chunk, workers in ((250, 1), (250, 2), (6, 1)):
        monkeypatch.setattr(sweep, "CHUNK", chunk)
        out = tmp_path / f"{chunk}-{workers}"
        assert _sweep(*argv, "--workers", str(workers), "--out", str(out)) == 0
        rows = _table(out / "sweep.csv")
        tables.append([{k: v for k, v in row.items() if k != "wall_time_s"} for row in rows])
    assert len(tables[0]) == 12 and len({row["plant.x0"] for row in tables[0]}) == 4
    assert tables[1] == tables[0] and tables[2] == tables[0]


def test_a_sweep_over_theta_and_noise_seeds_on_mujoco_is_one_batch():
    """theta2 (the passive callback's term) and the noise seed go per copy: one chunk of 6."""
    sets = [[SHORT, f"plant.theta=[-1.0, {t}, -34.3]", "plant.mujoco.sensor_noise=0.001",
             f"plant.mujoco.noise_seed={seed}"] for t in (-3.5, 3.5) for seed in (1, 2, 3)]
    assert sweep.plan(EXAMPLE2, sets, "mujoco") == [[0, 1, 2, 3, 4, 5]]
    other_damping = [[*s, "plant.theta=[-2.0, -3.5, -34.3]", "plant.mujoco.parameters={damping = 2.0}"]
                     for s in sets[:1]]
    assert len(sweep.plan(EXAMPLE2, sets + other_damping, "mujoco")) == 2


def test_a_region_map_is_the_same_on_one_and_two_workers():
    """The 25 starts of a 5 x 5 map: in this process (one batch) and cut in two for two workers;
    every point's outcome and figures are the same, bit for bit (diverging starts included)."""
    from qcontrol.region import RegionGrid, measure_region, parse_law

    grid = RegionGrid((0, 1), (-10.0, -10.0), (10.0, 10.0), 5)
    maps = [measure_region(EXAMPLE2, grid, [parse_law("proposed")], overrides=["simulation.duration=0.5"],
                           workers=w).points for w in (1, 2)]
    assert len(maps[0]) == 25 and {p.outcome for p in maps[0]} >= {"bounded", "diverged"}
    assert [repr(p) for p in maps[1]] == [repr(p) for p in maps[0]]


@pytest.mark.parametrize("backend", ["ode", "mujoco"])
def test_a_batched_copy_has_its_single_runs_summary_key_for_key(backend):
    """The separation (37)-(43) is checked along every copy of a batch as along the run alone:
    ``bound_constants`` and every other key (wall time aside) equal, the diverging start's too."""
    from qcontrol.scenario import load_scenario

    sets = [["simulation.duration=0.3", f"controller.kappa_margin={k}", f"plant.x0=[{x}, 0.0]"]
            for k, x in ((0.1, 0.3), (1.1, -0.5), (0.6, 12.0), (0.8, 1.0), (1.1, 2.0))]
    scs = [load_scenario(EXAMPLE2, s) for s in sets]
    batched = _comparable(sweep.run_batch(scs, backend))
    alone = [_comparable(sweep.run_batch([sc], backend))[0] for sc in scs]
    assert all(s["bound_constants"] for s in alone)
    assert batched == alone


def test_a_worker_killed_from_outside_ends_the_command_with_one_line(monkeypatch, tmp_path, capsys):
    """A fork of the sweep killed mid-run (the system's out-of-memory killer, a kill -9) is one line
    naming it and the fix, exit status 1, no traceback; this process's own runs are not waited for
    forever."""
    from qcontrol.cli.dispatch import main

    real_share, parent = sweep.share, os.getpid()

    def killed_in_the_fork(workers, count, run, done):
        def run_or_die(i):
            if os.getpid() != parent:
                os.kill(os.getpid(), signal.SIGKILL)
            return run(i)
        real_share(workers, count, run_or_die, done)

    monkeypatch.setattr(sweep, "share", killed_in_the_fork)
    status = main(["sweep", str(EXAMPLE2), "--backend", "mujoco", "--set", "simulation.duration=10.0",
                   "--random-initial", "2", "--seed", "1", "--workers", "2", "-q",
                   "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert status == 1 and "Traceback" not in err, err
    assert err.strip().splitlines() == ["qcontrol: error: a worker process ended before it finished its runs "
                                        "(killed from outside, e.g. by the system when memory ran out); run "
                                        "again, with fewer --workers if memory is short"]
