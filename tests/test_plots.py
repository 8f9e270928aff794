"""Figures: every function writes a valid PNG of the stated size, atomically, even for bad runs."""

from __future__ import annotations

import dataclasses
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.image import imread

from qcontrol import plots as P
from qcontrol.controller import ComparisonLaw, PaperLaw
from qcontrol.engine import RunSpec, Trajectory, simulate
from qcontrol.expr import compile_expression as C
from qcontrol.plants.ode import ChainPlant
from qcontrol.plots.common import adaptive_labels
from qcontrol.quantizer import UniformQuantizer
from qcontrol.reference import Sine
from qcontrol.timegrid import TimeGrid

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
X = ["x1", "x2"]
Q = ["q1", "q2"]
OMEGAS = ["0.100", "0.125", "0.150", "0.175", "0.200"]
PAPER_PROPOSED = dict(zip(OMEGAS, [0.0253, 0.0223, 0.0200, 0.0177, 0.0161], strict=True))
PAPER_COMPARISON = dict(zip(OMEGAS, [0.9570, 0.9339, 0.9132, 0.8925, 0.8679], strict=True))


def _example2_runs(duration: float = 2.0, state_bound: float = 1e6) -> tuple[Trajectory, Trajectory]:
    phi = [C("x2", X), C("x2**2*cos(x1)", X), C("sin(x1)", X)]
    plant = ChainPlant(2, None, phi, [-1, -3.5, -34.3])
    q = UniformQuantizer(0.01)
    r = [C("1+q2**2", Q), C("1+2*q2**2", Q), C("1", Q)]
    ctrl = PaperLaw([4, 3], q.max_error, 1.125, 1, 1, r)
    proposed = simulate(RunSpec(plant=plant, law=ctrl, quantizer=q, reference=Sine(1, 1.5), x0=[0.3, 0.3],
                                grid=TimeGrid.of(duration, 1e-3), state_bound=state_bound))[0]
    base_ctrl = ComparisonLaw([4, 3], q.max_error, None, phi)
    base = simulate(RunSpec(plant=plant, law=base_ctrl, quantizer=q, reference=Sine(1, 1.5), x0=[0.3, 0.3],
                            grid=TimeGrid.of(duration, 1e-3), state_bound=state_bound))[0]
    return proposed, base


@pytest.fixture(scope="module")
def runs() -> tuple[Trajectory, Trajectory]:
    return _example2_runs()


@pytest.fixture(scope="module")
def diverged() -> Trajectory:
    """A run stopped early (tight state bound), with NaNs punched into it for good measure."""
    traj, _ = _example2_runs(state_bound=0.5)
    assert traj.diverged and len(traj.t) < 2001
    x = traj.x.copy()
    x[5:9, 0] = np.nan
    u = traj.u.copy()
    u[-1] = np.nan
    return traj.with_signals(x=x, u=u)


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from the IHDR chunk; fails unless the file starts like a PNG."""
    data = path.read_bytes()
    assert len(data) > 1000, f"{path} is (nearly) empty"
    assert data[:8] == PNG_SIGNATURE, f"{path} is not a PNG"
    length, kind = struct.unpack(">I4s", data[8:16])
    assert kind == b"IHDR" and length == 13
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def assert_figure(path: Path, returned: Path) -> None:
    assert Path(returned) == path
    assert path.is_file()
    assert png_size(path) == (P.FIG_WIDTH_PX, P.FIG_HEIGHT_PX)
    pixels = imread(path)
    assert pixels.shape[:2] == (P.FIG_HEIGHT_PX, P.FIG_WIDTH_PX)
    assert float(np.var(pixels[..., :3])) > 1e-3, "the figure is blank"
    leftovers = [p.name for p in path.parent.iterdir() if p.name.startswith(".") or p.suffix == ".tmp"]
    assert leftovers == [], f"temporary files left behind: {leftovers}"


def _run_figures(proposed: Trajectory, base: Trajectory, out: Path) -> dict[str, Path]:
    """Call every figure function that draws trajectories once; name -> returned path."""
    U = P.EXAMPLE2_UNITS
    return {
        "fig1.png": P.fig_output(proposed, out / "fig1.png", P.PAPER_TITLES[1], P.EXAMPLE1_UNITS),
        "fig2.png": P.fig_tracking_error(proposed, out / "fig2.png", P.PAPER_TITLES[2], U, omega=0.1),
        "fig3.png": P.fig_adaptive(proposed, out / "fig3.png", P.PAPER_TITLES[3], U),
        "fig4.png": P.fig_input(proposed, out / "fig4.png", P.PAPER_TITLES[4], U),
        "fig5.png": P.fig_compare_output(proposed, base, out / "fig5.png", P.PAPER_TITLES[5], U),
        "fig6.png": P.fig_compare_error(proposed, base, out / "fig6.png", P.PAPER_TITLES[6], U, omega=0.1),
        "overlay.png": P.fig_backend_overlay(proposed, base, out / "overlay.png", "MuJoCo vs ODE", U),
    }


def _all_figures(proposed: Trajectory, base: Trajectory, out: Path) -> dict[str, Path]:
    """Call every figure function once; name -> returned path. The study and table figures draw
    numbers, not trajectories (NaN and missing rates among them), so the tests of bad
    trajectories draw :func:`_run_figures` only."""
    table = {
        "proposed": {"paper": PAPER_PROPOSED, "ODE": dict.fromkeys(OMEGAS, 0.5) | {"0.150": None}},
        "comparison": {"paper": PAPER_COMPARISON, "ODE": dict.fromkeys(OMEGAS, float("nan"))},
    }
    return {
        **_run_figures(proposed, base, out),
        "sens.png": P.fig_sensitivity(
            [0.1, 0.5, 1.1],
            {"0.100": [0.02, float("nan"), 0.9], "0.200": [0.01, None, 0.8]},
            r"$\kappa - L$",
            out / "sens.png",
            "E vs kappa - L",
            paper_rates=PAPER_PROPOSED,
            markers={"paper: 1.1": 1.1},
        ),
        "table1.png": P.fig_table1(table, out / "table1.png"),
    }


def test_every_figure_is_a_png_of_the_stated_size(runs, tmp_path):
    proposed, base = runs
    written = _all_figures(proposed, base, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(written)
    for name, returned in written.items():
        assert_figure(tmp_path / name, returned)
        assert (os.stat(tmp_path / name).st_mode & 0o777) == 0o644


def test_figures_of_a_diverged_trajectory_with_nans(runs, diverged, tmp_path):
    _, base = runs
    written = _run_figures(diverged, base, tmp_path)
    for name, returned in written.items():
        assert_figure(tmp_path / name, returned)


def test_all_nan_trajectory_still_plots(runs, tmp_path):
    proposed, _ = runs
    nan = proposed.with_signals(
        x=np.full_like(proposed.x, np.nan),
        z=np.full_like(proposed.z, np.nan),
        u=np.full_like(proposed.u, np.nan),
        adaptive=np.full_like(proposed.adaptive, np.nan),
    )
    for name, returned in _run_figures(nan, nan, tmp_path).items():
        assert_figure(tmp_path / name, returned)


def test_log_difference_of_identical_runs(runs, tmp_path):
    proposed, _ = runs
    t, diff = P.output_difference(proposed, proposed)
    assert np.array_equal(t, proposed.t) and np.all(diff == 0.0)
    path = tmp_path / "same.png"
    assert_figure(path, P.fig_backend_overlay(proposed, proposed, path, "identical runs", P.EXAMPLE2_UNITS))


def test_output_difference_on_different_grids_and_lengths(runs, diverged):
    proposed, _ = runs
    # Different lengths on the same grid: compared over the common rows.
    t, diff = P.output_difference(diverged, proposed)
    assert len(t) == len(diverged.t)
    finite = np.isfinite(diff)
    assert finite.any() and np.all(diff[finite] == np.abs(diverged.y - proposed.y[: len(t)])[finite])
    # A coarser grid of the same run: interpolation reproduces it at the shared instants.
    coarse = dataclasses.replace(proposed.with_signals(x=proposed.x[::10]), t=proposed.t[::10])
    t, diff = P.output_difference(proposed, coarse)
    assert len(t) == len(proposed.t)
    assert np.nanmax(diff[::10]) < 1e-12
    assert np.nanmax(diff) < 1e-3


def test_existing_file_is_replaced_and_folders_are_created(runs, tmp_path):
    proposed, _ = runs
    path = tmp_path / "new" / "dir" / "fig.png"
    path.parent.mkdir(parents=True)
    path.write_bytes(b"old")
    P.fig_input(proposed, path, P.PAPER_TITLES[8], P.EXAMPLE2_UNITS)
    assert_figure(path, path)
    deeper = tmp_path / "a" / "b" / "fig.png"
    assert_figure(deeper, P.fig_input(proposed, deeper, P.PAPER_TITLES[8], P.EXAMPLE2_UNITS))


def test_failed_render_leaves_no_temp_file(runs, tmp_path):
    proposed, _ = runs
    with pytest.raises(ValueError):
        P.fig_adaptive(proposed, tmp_path / "bad.png", "Fig. 7", P.EXAMPLE2_UNITS, labels=["only one"])
    with pytest.raises(ValueError):
        P.fig_sensitivity([1.0, 2.0], {"0.100": [0.5]}, "x", tmp_path / "bad.png", "bad")
    assert list(tmp_path.iterdir()) == []


def test_save_failure_cleans_up(runs, tmp_path, monkeypatch):
    proposed, _ = runs

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(Figure, "savefig", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        P.fig_output(proposed, tmp_path / "f.png", P.PAPER_TITLES[1], P.EXAMPLE1_UNITS)
    assert list(tmp_path.iterdir()) == []


def test_sensitivity_with_categories(tmp_path):
    path = tmp_path / "variants.png"
    rates = {"0.100": [0.9, 0.03], "0.200": [0.8, 0.01]}
    returned = P.fig_sensitivity(
        ["canonical", "rigid pendulum"], rates, "plant variant", path, "variants", paper_rates=PAPER_PROPOSED
    )
    assert_figure(path, returned)


def test_adaptive_labels_follow_the_state_name(runs):
    proposed, base = runs
    assert adaptive_labels(proposed, 3) == [rf"$\hat{{\varepsilon}}_{{{i}}}$" for i in (1, 2, 3)]
    assert adaptive_labels(base, 1) == [r"$\hat{\theta}$"]


def test_no_pyplot_state_is_touched(runs, tmp_path):
    import sys

    proposed, _ = runs
    P.fig_output(proposed, tmp_path / "f.png", P.PAPER_TITLES[1], P.EXAMPLE1_UNITS)
    if "matplotlib.pyplot" in sys.modules:
        import matplotlib.pyplot as plt

        assert plt.get_fignums() == []


@pytest.mark.parametrize("number", sorted(P.PAPER_TITLES))
def test_every_paper_title_lies_inside_its_figure(number: int) -> None:
    """Figs. 5 and 6's captions are wider than the figure: they are wrapped, word for word, never
    inside a formula; the short ones stay on one line."""
    from qcontrol.plots.common import fit_titles, new_figure

    fig, axes = new_figure()
    axes[0, 0].set_ylabel("y, $y_d$ [rad]")
    title = axes[0, 0].set_title(P.PAPER_TITLES[number])
    fit_titles(fig)
    fig.draw_without_rendering()
    box = title.get_window_extent(fig.canvas.get_renderer())
    assert 0 <= box.x0 and box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height
    text = title.get_text()
    assert text.replace("\n", " ") == P.PAPER_TITLES[number]
    assert all(line.count("$") % 2 == 0 for line in text.split("\n"))
    assert ("\n" in text) == (number in (5, 6))


def test_a_long_suptitle_is_wrapped_inside_a_grid_of_axes() -> None:
    from qcontrol.plots.common import fit_titles, new_figure

    fig, _ = new_figure(2, 2)
    long = " ".join(["a long title about $|z_1| \\leq \\omega$ and the rest"] * 4)
    sup = fig.suptitle(long)
    fit_titles(fig)
    fig.draw_without_rendering()
    box = sup.get_window_extent(fig.canvas.get_renderer())
    assert 0 <= box.x0 and box.x1 <= fig.bbox.width
    assert sup.get_text().count("\n") >= 1 and sup.get_text().replace("\n", " ") == long
