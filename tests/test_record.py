"""Rerun recordings: what is logged is read back from the .rrd file and compared with the run."""

from __future__ import annotations

import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

import qcontrol
from qcontrol.controller import PaperLaw
from qcontrol.engine import RunSpec, Trajectory, simulate
from qcontrol.errors import QcontrolInputError
from qcontrol.expr import compile_expression as C
from qcontrol.outputs import partial_path
from qcontrol.plants.ode import ChainPlant
from qcontrol.quantizer import UniformQuantizer
from qcontrol.recording import Recording
from qcontrol.recording import recording as recording_module
from qcontrol.recording.streamer import pose_rows
from qcontrol.reference import Sine
from qcontrol.timegrid import TimeGrid

X, Q = ["x1", "x2"], ["q1", "q2"]
RERUN_CLI = Path(sys.executable).with_name("rerun")

PENDULUM = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="arm" pos="0 0 1">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom name="rod" type="capsule" fromto="0 0 0 0 0 -0.5" size="0.02"/>
      <geom name="bob" type="sphere" pos="0 0 -0.5" size="0.05" rgba="0.8 0.2 0.2 1"/>
    </body>
  </worldbody>
</mujoco>
"""

SLIDER = """
<mujoco>
  <worldbody>
    <geom name="rail" type="box" size="2 0.01 0.01"/>
    <body name="cart" pos="0 0 0.05">
      <joint name="slide" type="slide" axis="1 0 0"/>
      <geom name="cart" type="box" size="0.1 0.05 0.04"/>
    </body>
  </worldbody>
</mujoco>
"""


def example2(
    duration: float, observer=None, observe_every: int = 500, psi: str | None = None, state_bound: float = 1e6
) -> Trajectory:
    """Example 2 of the paper on the ODE backend (optionally with an extra psi to make it diverge)."""
    plant = ChainPlant(
        2,
        None if psi is None else C(psi, X),
        [C("x2", X), C("x2**2*cos(x1)", X), C("sin(x1)", X)],
        [-1, -3.5, -34.3],
    )
    q = UniformQuantizer(0.01)
    ctrl = PaperLaw(
        [4, 3], q.max_error, 1.125, 1, 1, [C("1+q2**2", Q), C("1+2*q2**2", Q), C("1", Q)]
    )
    (run,) = simulate(RunSpec(plant=plant, law=ctrl, quantizer=q, reference=Sine(1, 1.5), x0=[0.3, 0.3],
                              grid=TimeGrid.of(duration, 1e-3), state_bound=state_bound, observer=observer,
                              observe_every=observe_every))
    return run


def read_entities(path: Path) -> dict[str, list[pa.RecordBatch]]:
    """Every chunk of the recording store, grouped by entity path (without the leading slash)."""
    entities: dict[str, list[pa.RecordBatch]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        entities[chunk.entity_path.lstrip("/")].append(chunk.to_record_batch())
    return entities


def temporal(batches: list[pa.RecordBatch], component: str) -> tuple[np.ndarray, np.ndarray]:
    """Times (int64 ns) and values (one row per time) of a component over ``sim_time``, time-sorted."""
    times, values = [], []
    for batch in batches:
        if "sim_time" not in batch.column_names or component not in batch.column_names:
            continue
        times.append(batch.column("sim_time").cast(pa.int64()).to_numpy())
        column = batch.column(component)
        flat = column.flatten()
        while pa.types.is_list(flat.type) or pa.types.is_fixed_size_list(flat.type):
            flat = flat.flatten()
        values.append(flat.to_numpy(zero_copy_only=False).reshape(len(column), -1))
    t = np.concatenate(times)
    order = np.argsort(t, kind="stable")
    return t[order], np.concatenate(values)[order]


def static_values(batches: list[pa.RecordBatch], component: str) -> list[list]:
    """Every static value logged for ``component``, in the order of the file."""
    return [batch.column(component).to_pylist()[0] for batch in batches
            if "sim_time" not in batch.column_names and component in batch.column_names]


def static_value(batches: list[pa.RecordBatch], component: str) -> list:
    values = static_values(batches, component)
    if not values:
        raise AssertionError(f"no static {component}")
    return values[0]


def bits(a: np.ndarray) -> np.ndarray:
    """Bit patterns of float64 values: equality of these is exact equality, NaN included."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


def sim_time_ns(t: np.ndarray) -> np.ndarray:
    """The sim_time expected for a run at dt = 1 ms: row k is exactly k ms."""
    k = np.arange(len(t))
    np.testing.assert_array_equal(t, k * 1e-3)
    return k * 1_000_000


def assert_scalars_exact(entities, path: str, expected: np.ndarray, t: np.ndarray) -> None:
    """The entity's scalars are exactly ``expected``: ``(rows,)``, or ``(rows, k)`` for k instances."""
    times, values = temporal(entities[path], "Scalars:scalars")
    np.testing.assert_array_equal(times, sim_time_ns(t), err_msg=path)
    want = np.asarray(expected).reshape(len(t), -1)
    np.testing.assert_array_equal(bits(values), bits(want), err_msg=path)


def rrd_verify(path: Path) -> None:
    if not RERUN_CLI.exists():
        pytest.skip("the rerun CLI is not installed in this environment")
    result = subprocess.run(
        [str(RERUN_CLI), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.fixture(scope="module")
def compare_recording(tmp_path_factory) -> tuple[Path, Trajectory, Trajectory, mujoco.MjModel]:
    """A 2 s Example 2 run with the pendulum drawn, plus its twin (a slightly different plant, so
    that the two differ), streamed in 500-row chunks."""
    path = tmp_path_factory.mktemp("rrd") / "compare.rrd"
    model = mujoco.MjModel.from_xml_string(PENDULUM)
    with Recording(path) as rec:
        rec.log_static("[plant]\norder = 2\n", {"kappa": 1.125, "c": [4.0, 3.0]}, qcontrol.__version__)
        main = example2(2.0, rec.observer("mujoco", model, "hinge"))
        ghost = example2(2.0, rec.observer("ode", model, "hinge", ghost=True, twin_of=main), psi="0.01*x2")
    return path, main, ghost, model


def test_clean_run_renames_the_temporary_file(compare_recording):
    path = compare_recording[0]
    assert list(path.parent.iterdir()) == [path]  # no temporary file left


@pytest.mark.filterwarnings("error:RRD file has no footer")
def test_closed_file_has_a_footer(compare_recording):
    """Closing writes rerun's footer (the chunk manifest) before the file gets its final name."""
    store = RrdReader(compare_recording[0]).store()
    assert store is not None


def test_signals_equal_the_run_bitwise(compare_recording):
    path, main, ghost, _ = compare_recording
    entities = read_entities(path)
    assert_scalars_exact(entities, "signals/tracking/y", main.y, main.t)
    assert_scalars_exact(entities, "signals/tracking/y_d", main.yd[:, 0], main.t)
    assert_scalars_exact(entities, "signals/error/z1", main.z[:, 0], main.t)
    assert_scalars_exact(entities, "signals/input/u", main.u, main.t)
    assert main.adaptive.shape[1] == 3  # one entity, one instance per estimate
    assert_scalars_exact(entities, "signals/adaptive/eps_hat", main.adaptive, main.t)
    for i in range(2):
        assert_scalars_exact(entities, f"signals/state/x{i + 1}/x", main.x[:, i], main.t)
        assert_scalars_exact(entities, f"signals/state/x{i + 1}/q", main.x_q[:, i], main.t)
    ratios = np.stack([main.e_z[:, i] / main.L_z[i] for i in range(2)], axis=1)
    assert_scalars_exact(entities, "theory/lemma2/ratios", ratios, main.t)
    assert_scalars_exact(entities, "theory/law/gain_period", main.diagnostics[:, 0], main.t)  # K T
    # the main run's legend names its run (the twin's K T is drawn thin beside it, and says so)
    assert static_value(entities["theory/law/gain_period"], "SeriesLines:names") == ["gain_period (mujoco)"]
    twin_legend = static_value(entities["theory/law/gain_period_ode"], "SeriesLines:names")
    assert twin_legend == ["gain_period (ode, thin)"]
    assert_scalars_exact(entities, "theory/law/gain_period_ode", ghost.diagnostics[:, 0], ghost.t)
    legend = static_value(entities["theory/lemma2/ratios"], "SeriesLines:names")
    assert legend == ["|e_z1| / L_z1", "|e_z2| / L_z2"]
    assert_scalars_exact(entities, "signals/tracking/y_ode", ghost.y, ghost.t)
    assert_scalars_exact(entities, "signals/input/u_ode", ghost.u, ghost.t)
    assert not np.array_equal(main.u, ghost.u)  # the two runs really are different data


def test_quantization_error_and_its_band(compare_recording):
    """x_meas - q(x_meas) per state, inside the band +-delta/2 drawn beside it (delta = 0.01)."""
    path, main, _, _ = compare_recording
    entities = read_entities(path)
    for i in range(2):
        error = main.x_meas[:, i] - main.x_q[:, i]
        assert_scalars_exact(entities, f"signals/quantization/x{i + 1}/error", error, main.t)
        assert np.max(np.abs(error)) <= 0.005 and np.max(np.abs(error)) > 0.004  # the band, nearly reached
        times, band = temporal(entities[f"signals/quantization/x{i + 1}/band"], "Scalars:scalars")
        np.testing.assert_array_equal(band, [[0.005, -0.005]] * 2)  # +-delta/2 ...
        assert times[0] == 0 and times[-1] == sim_time_ns(main.t)[-1]  # ... across the whole run


def test_twin_differences_equal_the_runs(compare_recording):
    """|y_main - y_twin| and |u_main - u_twin| at every row, as series of their own."""
    path, main, ghost, _ = compare_recording
    entities = read_entities(path)
    def logged(a, b):  # log10 |a - b|, floored at 1e-16 (equal to rounding)
        return np.log10(np.maximum(np.abs(a - b), 1e-16))

    assert_scalars_exact(entities, "signals/difference/y/ode", logged(main.y, ghost.y), main.t)
    assert_scalars_exact(entities, "signals/difference/u/ode", logged(main.u, ghost.u), main.t)
    assert np.max(np.abs(main.y - ghost.y)) > 0


def test_main_series_drawn_wide_under_the_thin_twin(compare_recording):
    """Where MuJoCo and its twin coincide, both show: the main run wide, the twin thin on top, and
    the legend says which is which."""
    entities = read_entities(compare_recording[0])
    for signal in ("tracking/y", "error/z1", "input/u"):
        main, twin = entities[f"signals/{signal}"], entities[f"signals/{signal}_ode"]
        name = signal.split("/")[1]
        # the main run's style was logged twice (before and after the twin joined): the last holds
        assert static_values(main, "SeriesLines:names")[-1] == [f"{name} (mujoco, wide)"]
        assert static_value(twin, "SeriesLines:names") == [f"{name} (ode, thin)"]
        wide = static_values(main, "SeriesLines:widths")[-1][0]
        assert wide >= 3 * static_value(twin, "SeriesLines:widths")[0]


def test_expected_entities_and_static_content(compare_recording):
    path, main, _, _ = compare_recording
    entities = read_entities(path)
    expected = {
        "world",
        "world/fixed/floor",
        "world/bodies/arm",
        "world/bodies/arm/rod",
        "world/bodies/arm/bob",
        "world/ode_ghost/arm",
        "world/ode_ghost/arm/rod",
        "world/ode_ghost/arm/bob",
        "world/target",
        "signals/quantization/x1/error",
        "signals/quantization/x1/band",
        "signals/quantization/x2/band",
        "signals/difference/y/ode",
        "signals/difference/u/ode",
        "signals/tracking/y",
        "signals/tracking/y_d",
        "signals/tracking/y_ode",
        "signals/error/z1",
        "signals/error/z1_ode",
        "signals/input/u",
        "signals/input/u_ode",
        "signals/adaptive/eps_hat",
        "signals/state/x1/x",
        "signals/state/x1/q",
        "signals/state/x2/x",
        "signals/state/x2/q",
        "theory/lemma2/ratios",
        "theory/lemma2/bound",
        "theory/law/gain_period",
        "info/scenario",
        "info/constants",
        "info/version",
    }
    assert expected <= set(entities), expected - set(entities)
    assert "signals/input/u_applied" not in entities  # no actuator limit: the applied input is u itself
    assert "order = 2" in static_value(entities["info/scenario"], "TextDocument:text")[0]
    assert static_value(entities["info/constants"], "c") == [4.0, 3.0]
    assert static_value(entities["info/version"], "TextDocument:text") == [f"qcontrol {qcontrol.__version__}"]
    _, bound = temporal(entities["theory/lemma2/bound"], "Scalars:scalars")
    assert np.all(bound == 1.0)
    # A stream of transforms for each moving body of both runs, every 10 ms of simulated time
    # (every 10th row at dt = 1 ms: the series keep every row); shapes are static.
    rows = pose_rows(slice(0, len(main.t)), main.dt)
    np.testing.assert_array_equal(rows, np.arange(0, len(main.t), 10))
    for body in ("world/bodies/arm", "world/ode_ghost/arm", "world/target"):
        times, _ = temporal(entities[body], "Transform3D:translation")
        np.testing.assert_array_equal(times, sim_time_ns(main.t)[rows])
    assert "Capsules3D:lengths" in entities["world/bodies/arm/rod"][0].column_names
    assert "Ellipsoids3D:half_sizes" in entities["world/bodies/arm/bob"][0].column_names


def test_held_and_quantized_series_step(compare_recording):
    entities = read_entities(compare_recording[0])
    step, linear = 2, 1  # rerun.components.InterpolationMode: Linear = 1, StepAfter = 2
    assert rr.components.InterpolationMode.StepAfter.value == step
    for path in ("signals/input/u", "signals/input/u_ode", "signals/state/x1/q", "signals/state/x2/q"):
        assert static_value(entities[path], "SeriesLines:interpolation_mode") == [step], path
    for path in ("signals/tracking/y", "signals/state/x1/x"):
        assert static_value(entities[path], "SeriesLines:interpolation_mode") == [linear], path


def test_bodies_follow_the_joint_and_target_follows_the_reference(compare_recording):
    path, main, _, model = compare_recording
    entities = read_entities(path)
    _, translation = temporal(entities["world/bodies/arm"], "Transform3D:translation")
    _, quaternion = temporal(entities["world/bodies/arm"], "Transform3D:quaternion")
    _, target = temporal(entities["world/target"], "Transform3D:translation")
    data = mujoco.MjData(model)
    body = model.body("arm").id
    bob = model.geom("bob").id
    rows = pose_rows(slice(0, len(main.t)), main.dt)
    for j in (0, 13, len(rows) - 1):
        k = rows[j]
        data.qpos[0] = main.y[k]
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(translation[j], data.xpos[body], atol=1e-6)
        np.testing.assert_allclose(quaternion[j], data.xquat[body][[1, 2, 3, 0]], atol=1e-6)  # xyzw
        data.qpos[0] = main.yd[k, 0]
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(target[j], data.geom_xpos[bob], atol=1e-6)


def test_twin_body_is_an_outline_around_the_main_body(compare_recording):
    """The twin's bodies are wireframes 15 % larger than the main run's, so they show where the
    two coincide."""
    entities = read_entities(compare_recording[0])
    transparent_fill_wireframe = 4  # rerun.components.FillMode
    assert rr.components.FillMode.TransparentFillMajorWireframe.value == transparent_fill_wireframe
    body = static_value(entities["world/bodies/arm/bob"], "Ellipsoids3D:half_sizes")
    ghost = static_value(entities["world/ode_ghost/arm/bob"], "Ellipsoids3D:half_sizes")
    np.testing.assert_allclose(ghost, 1.15 * np.asarray(body), rtol=1e-6)
    assert static_value(entities["world/ode_ghost/arm/bob"], "Ellipsoids3D:fill_mode") == [
        transparent_fill_wireframe]
    assert static_value(entities["world/bodies/arm/bob"], "Ellipsoids3D:fill_mode") == [
        rr.components.FillMode.Solid.value]


def test_rerun_cli_accepts_the_file(compare_recording):
    rrd_verify(compare_recording[0])


@pytest.mark.usefixtures("python_loop")
def test_diverging_run_ends_at_the_divergence_time(tmp_path):
    path = tmp_path / "diverged.rrd"
    with Recording(path) as rec:
        run = example2(5.0, rec.observer("ode"), psi="100*x2**3")
    assert run.diverged and run.diverged_time < 5.0
    assert list(tmp_path.iterdir()) == [path]  # a diverged run is a finished run: its final name
    entities = read_entities(path)
    times, _ = temporal(entities["signals/tracking/y"], "Scalars:scalars")
    assert times[-1] == round(run.diverged_time * 1e9) == (len(run.t) - 1) * 1_000_000
    assert_scalars_exact(entities, "signals/tracking/y", run.y, run.t)  # the non-finite last row too
    assert_scalars_exact(entities, "signals/input/u", run.u, run.t)
    rrd_verify(path)


def _rows_on_disk(part: Path, entity: str, expected: int, timeout: float = 10.0) -> int:
    """The rows of ``entity`` in the file being written, once they reach ``expected`` (rerun
    writes on its own thread: the file may end in a frame being written; read it again)."""
    deadline = time.monotonic() + timeout
    rows = -1
    while time.monotonic() < deadline:
        try:
            rows = len(temporal(read_entities(part)[entity], "Scalars:scalars")[0])
        except (RuntimeError, KeyError, ValueError):  # a frame being written, the entity not there
            rows = -1  # yet, or only its static style there yet (no timed rows to concatenate)
        if rows == expected:
            break
        time.sleep(0.01)
    return rows


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # the temporary file is read while open
@pytest.mark.filterwarnings("ignore:the run did not finish")
def test_interrupted_run_keeps_the_flushed_chunks(tmp_path, monkeypatch):
    """A KeyboardInterrupt mid-run still leaves a complete file with every chunk streamed so far,
    under the partial name (the final name is left as it was: here, absent);
    chunks are on disk (readable) while the run goes on, not left in rerun's batcher: each call
    starts writing its chunk and the next call waits until it is written."""
    monkeypatch.setenv("RERUN_FLUSH_TICK_SECS", "1000")  # the batcher alone would keep everything
    monkeypatch.setenv("RERUN_FLUSH_NUM_BYTES", str(10**12))
    path = tmp_path / "interrupted.rrd"
    seen: list[int] = []
    flushes: list[int] = []
    flush = rr.RecordingStream.flush
    monkeypatch.setattr(
        rr.RecordingStream, "flush", lambda self, **kw: (flushes.append(1), flush(self, **kw))[1]
    )

    with pytest.raises(KeyboardInterrupt), Recording(path) as rec:
        inner = rec.observer("ode")

        def observer(start: int, stop: int, runs: list[Trajectory]) -> None:
            before = len(flushes)
            inner(start, stop, runs)
            assert len(flushes) > before, "the chunk was not flushed to disk"
            seen.append(_rows_on_disk(rec.temporary, "signals/input/u", stop))
            if len(seen) == 2:
                raise KeyboardInterrupt

        example2(2.0, observer)
    assert seen == [500, 1000]
    partial = partial_path(path)
    assert list(tmp_path.iterdir()) == [partial]
    times, _ = temporal(read_entities(partial)["signals/input/u"], "Scalars:scalars")
    np.testing.assert_array_equal(times, np.arange(1000) * 1_000_000)
    rrd_verify(partial)


def test_slider_target_is_at_the_reference_position(tmp_path):
    path = tmp_path / "slider.rrd"
    model = mujoco.MjModel.from_xml_string(SLIDER)
    with Recording(path) as rec:
        run = example2(0.2, rec.observer("mujoco", model))
    entities = read_entities(path)
    _, target = temporal(entities["world/target"], "Transform3D:translation")
    _, cart = temporal(entities["world/bodies/cart"], "Transform3D:translation")
    rows = pose_rows(slice(0, len(run.t)), run.dt)
    np.testing.assert_allclose(target[:, 0], run.yd[rows, 0], atol=1e-6)
    np.testing.assert_allclose(cart[:, 0], run.y[rows], atol=1e-6)
    np.testing.assert_allclose(cart[:, 1:], np.tile([0.0, 0.05], (len(rows), 1)), atol=1e-7)
    assert "Boxes3D:half_sizes" in entities["world/fixed/rail"][0].column_names


def test_one_main_run_per_recording_and_unique_ghost_labels(tmp_path):
    with Recording(tmp_path / "x.rrd") as rec:
        rec.observer("mujoco")
        with pytest.raises(ValueError, match="main"):
            rec.observer("again")
        rec.observer("ode", ghost=True)
        with pytest.raises(ValueError, match="ode"):
            rec.observer("ode", ghost=True)
    model = mujoco.MjModel.from_xml_string(
        PENDULUM.replace("</body>", "</body><body><joint/><geom size='1'/></body>")
    )
    with Recording(tmp_path / "y.rrd") as rec, pytest.raises(ValueError, match="joint"):
        rec.observer("mujoco", model)


def test_no_viewer_available_warns_and_keeps_the_file(tmp_path, monkeypatch):
    def no_viewer(*args, **kwargs):
        raise QcontrolInputError("--spawn: the rerun viewer is not installed; write the recording with --rrd")

    monkeypatch.setattr(recording_module, "start_viewer", no_viewer)
    with pytest.warns(UserWarning, match="viewer"), Recording(None, spawn=True) as rec:
        assert not rec.enabled
    path = tmp_path / "file.rrd"
    with pytest.warns(UserWarning, match="viewer"), Recording(path, spawn=True) as rec:
        run = example2(0.1, rec.observer("ode"))
    assert_scalars_exact(read_entities(path), "signals/input/u", run.u, run.t)
    assert list(tmp_path.iterdir()) == [path]


def test_a_recording_needs_a_file_or_a_viewer_and_opening_none_imports_nothing(tmp_path):
    """Without --rrd or --spawn the command line makes no recording; asking for one with neither is
    a programming error. Importing the package does not import rerun."""
    code = (
        "import sys\n"
        "from qcontrol.recording import Recording\n"
        "assert 'rerun' not in sys.modules, 'importing qcontrol.recording imported rerun'\n"
        "try:\n"
        "    Recording(None)\n"
        "except ValueError as exc:\n"
        "    assert 'file' in str(exc)\n"
        "else:\n"
        "    raise AssertionError('Recording(None) was accepted')\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert list(tmp_path.iterdir()) == []


def test_each_law_of_a_law_comparison_has_a_colour_of_its_own(tmp_path):
    """Three laws in one recording: the two drawn on the main one are told apart by colour, in
    their series and in their differences from it (they were both white, both blue)."""
    sc = qcontrol.load_scenario("example1", {"simulation.duration": 0.3})
    qcontrol.register_law("same-paper-again", type("SamePaper", (qcontrol.PaperLaw,), {}),
                                extends="proposed", replace=True)
    qcontrol.compare_laws(sc, ["proposed", "comparison", "same-paper-again"], backend="ode",
                          rrd=tmp_path / "laws.rrd")
    entities = read_entities(tmp_path / "laws.rrd")
    for family in ("signals/tracking/y", "signals/input/u", "signals/difference/y"):
        ghosts = [f"{family}_comparison", f"{family}_same-paper-again"]
        if family.endswith("difference/y"):
            ghosts = [f"{family}/comparison", f"{family}/same-paper-again"]
        colors = [static_value(entities[path], "SeriesLines:colors") for path in ghosts]
        assert colors[0] != colors[1], (family, colors)
    # each law's own diagnostics are drawn too: the third law's K T beside the first's; law (46) has none
    assert "theory/law/gain_period_same-paper-again" in entities
    assert not any(path.startswith("theory/law/") and path.endswith("_comparison") for path in entities)
