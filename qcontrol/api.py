"""The Python API: load a scenario, run it, compare MuJoCo with the ODE, save what a run recorded.

    import qcontrol
    sc = qcontrol.load_scenario("scenarios/example2.toml", overrides={"controller.kappa_margin": 0.1})
    res = qcontrol.run(sc, backend="ode")      # a Result: res.summary is what summary.json holds
    res.t, res.x, res.u                        # numpy arrays, a row per instant t_k = k dt
    res.save("run.npz")

The command line is built on these functions, so a run from Python and from ``qcontrol run`` give
the same summary (apart from ``wall_time_s`` and the ``command`` of the provenance).

Threads: ``run``, ``compare`` and ``sweep`` may be called from several threads of one process at
once; each gives what it gives alone. MuJoCo's passive callback and warning handler belong to the
whole process, so MuJoCo runs take turns on them (ODE runs go side by side).
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import compiled as compiled_paths
from ._version import __version__
from .assembly import Assembly, assemble, runnable_backend
from .attribution import realism_attribution
from .controller import Backstepping
from .controller import lemma2_bounds as _lemma2_bounds
from .engine import SIGNALS, ProgressCallback, RunMetrics, Trajectory
from .engine.signals import column_names
from .errors import QcontrolInputError
from .metrics import backend_deviation, run_summary, summary
from .outputs import check_figure_file, check_output_file, clean, prepare_output_dir, write_file, write_text
from .plants import SceneSource
from .scenario import Scenario, parse_scenario
from .scenario.resolve import scenario_provenance
from .sharing import sharing
from .summary import Summary
from .sweep.grid import MAX_RUNS
from .sweep.runs import run_variants_batched
from .sweep.table import sweep_rows

if TYPE_CHECKING:
    from .plants.mujoco.equation import ModelEquation

SAVE_FORMATS = (".npz", ".csv")


@dataclass(frozen=True)
class Result:
    """One closed-loop run: its ``summary`` (exactly what ``summary.json`` holds) and, unless it
    kept only its metrics, its signals as numpy arrays, a row per instant ``t[k] = k dt``.

    Arrays (from the signal table, :data:`qcontrol.engine.signals.SIGNALS`): ``x`` the true state
    ``(rows, n)``, ``x_meas`` the sensor reading, ``x_q`` its quantization (all the controller
    saw), ``u`` the input held over ``[t_k, t_k + dt)`` ``(rows,)``, ``adaptive`` the law's state
    ``(rows, m)``, ``yd`` the reference and its n derivatives ``(rows, n + 1)``, ``z`` and ``zbar``
    the errors (7)-(8) and (31)-(33), ``e_z`` the Lemma 2 errors, ``bound_ratio`` the separation's
    ratios, ``diagnostics`` the law's own signals (the paper's law: ``gain_period``, K T);
    ``y = x[:, 0]`` and ``t``. A diverged run ends with the row that stopped it. ``assembly`` is
    what the run was put together from (its plant, law, scene; :class:`~qcontrol.assembly.Assembly`).
    """

    summary: dict[str, Any]
    scenario: Scenario
    backend: str
    record: Trajectory | RunMetrics
    assembly: Assembly | None = field(default=None, repr=False, compare=False)

    @property
    def typed_summary(self) -> Summary:
        """:attr:`summary` as a frozen, typed :class:`~qcontrol.summary.Summary`."""
        return Summary.from_json(self.summary)

    @property
    def trajectory(self) -> Trajectory:
        if not isinstance(self.record, Trajectory):
            raise ValueError("this run kept only its metrics; run it with record=\"full\" to get its signals")
        return self.record

    @property
    def t(self) -> np.ndarray:
        return self.trajectory.t

    @property
    def y(self) -> np.ndarray:
        return self.trajectory.y

    def save(self, path: str | Path) -> Path:
        """Write the run's signals, by the file's suffix: ``.npz`` (one array per signal, by its
        name, plus ``t``, the summary as JSON and each of the law's diagnostics by its own name)
        or ``.csv`` (one header row, a column per component: ``t, x1, x2, x_meas1, ...``, the
        diagnostics by name). Written atomically."""
        _check_arguments("save", path=(path, (str, Path), False))
        path = check_output_file(path, "save")
        if path.suffix not in SAVE_FORMATS:
            raise QcontrolInputError(f"{path}: unknown format {path.suffix!r}; save as .npz or .csv")
        traj = self.trajectory
        prepare_output_dir(path.parent if str(path.parent) else Path("."), "save")
        if path.suffix == ".csv":
            return write_text(path, _csv_text(traj))
        meta = np.array(json.dumps(clean(self.summary)))
        named = {d.name: traj.diagnostic(d.name) for d in traj.law_diagnostics}  # each by its own name too
        return write_file(path, lambda file: np.savez(file, t=traj.t, summary=meta, **traj.signals, **named))

    def diagnostic(self, name: str) -> np.ndarray:
        """The law's own diagnostic ``name`` (one it declares, :class:`~qcontrol.Diagnostic`) at
        every row: ``(rows,)`` for a width of 1, else ``(rows, width)``."""
        return self.trajectory.diagnostic(name)

    def plot(self, path: str | Path) -> Path:
        """Draw the run's figure (y and y_d, the errors, u, the law's state; the figure
        ``qcontrol run --plot`` draws) to ``path`` (.png, .pdf or .svg); returns the path."""
        from .plots import fig_run, scenario_units  # matplotlib: imported only when a figure is drawn

        _check_arguments("plot", path=(path, (str, Path), False))
        path = check_figure_file(path, "plot")
        s = self.typed_summary
        notes = [f"{s.scenario} on {s.backend}, {s.duration:g} s, dt = {s.dt:g} s"]
        notes += [f"E({k}) = {v:.4f}" for k, v in s.error_rate.items()]
        notes += [f"max |z1|, last half = {s.max_abs_z1_last_half:.4g}", f"max |u| = {s.max_abs_u:.4g}",
                  f"Lemma 2 ratio = {s.lemma2_max_ratio:.6f}"]
        if s.diverged:
            notes.append(f"diverged at t = {s.diverged_time:g} s")
        return fig_run(self.trajectory, path, f"{s.scenario} ({s.backend})", scenario_units(self.scenario),
                       notes=notes)


for _signal in SIGNALS:
    setattr(Result, _signal.name, property(lambda res, key=_signal.name: res.trajectory.signals[key],
                                           doc=_signal.meaning))
del _signal


def columns(traj: Trajectory) -> list[tuple[str, np.ndarray]]:
    """The run's signals as named columns, in the order of the signal table: ``t``; ``x1 .. xn``;
    ``x_meas1 ..``; ``x_q1 ..``; ``u``; ``<adaptive name>_1 ..``; ``yd_0 .. yd_n`` (y_d and its
    derivatives); ``z1 ..``; ``zbar1 ..``; ``e_z1 ..``; ``bound_ratio_<term> ..``;
    the law's diagnostics by name (``gain_period``)."""
    out = [("t", traj.t)]
    for signal in SIGNALS:
        array = traj.signals[signal.name]
        if array.ndim == 1:
            out.append((signal.name, array))
            continue
        names = column_names(signal, array.shape[1], traj.naming)
        out += [(name, array[:, i]) for i, name in enumerate(names)]
    return out


def _csv_text(traj: Trajectory) -> str:
    named = columns(traj)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow([name for name, _ in named])
    writer.writerows(zip(*[[repr(float(v)) for v in values] for _, values in named], strict=True))
    return buffer.getvalue()


# --------------------------------------------------------------------------------------------
# runs


def _call(name: str, sc: Scenario, **kw: Any) -> str:
    """How an API call is named in the provenance of what it writes."""
    arguments = ", ".join(f"{k}={v!r}" for k, v in kw.items() if v is not None)
    return f"qcontrol.{name}(<scenario {sc.name!r} from {sc.source}>{', ' if arguments else ''}{arguments})"


def run(scenario: Scenario | Assembly, backend: str | None = None, *, rrd: str | Path | None = None,
        spawn: bool = False, record: str = "full", progress: ProgressCallback | None = None,
        command: str | None = None, camera_view: bool = False) -> Result:
    """Run the scenario's closed loop on ``backend`` (None: the scenario's ``simulation.backend``).
    ``scenario`` may also be a run already put together (:func:`~qcontrol.assembly.assemble`,
    as the command line does): its parts are used as they are.

    ``record="full"`` keeps every row (the Result's arrays); ``"metrics"`` only the summary, in
    memory that does not grow with the run. ``rrd`` writes a rerun recording while it runs,
    ``spawn`` streams it to a rerun viewer; with ``camera_view`` the recording also holds
    MuJoCo's own rendering of the run beside its 3-D view (the run keeps every row for it).
    ``command`` is what the provenance names as the command (default: this call).
    """
    asm = scenario if isinstance(scenario, Assembly) else None
    scenario = check_scenario(scenario.scenario if asm else scenario, "run")
    _check_arguments("run", backend=(backend, str, True), rrd=(rrd, (str, Path), True),
                     spawn=(spawn, bool, False), command=(command, str, True),
                     camera_view=(camera_view, bool, False))
    if record not in ("full", "metrics"):
        raise QcontrolInputError(f"run: record must be \"full\" or \"metrics\", got {record!r}")
    if progress is not None and not callable(progress):
        raise QcontrolInputError(f"run: progress must be a callable or None, got {type(progress).__name__}")
    asm = _assembled(asm, scenario, backend, "run")
    backend = asm.backend
    command = command or _call("run", scenario, backend=backend, rrd=None if rrd is None else str(rrd))
    provenance = scenario_provenance(scenario, command)
    with recording_for(rrd, spawn, asm, provenance) as rec:
        observer = None if rec is None else observer_for(rec, asm.scene, backend)
        traj = asm.run("full" if camera_view and rec is not None else record, progress, observer)[0]
        if camera_view and rec is not None:
            _log_camera_view(rec, asm, traj)
    result = replace(run_summary(traj, scenario.name, backend), provenance=provenance,
                     physics_warnings=tuple(asm.report.warnings))
    return Result(result.to_json(), scenario, backend, traj, asm)


def _assembled(asm: Assembly | None, scenario: Scenario, backend: str | None, function: str) -> Assembly:
    """The run put together once: ``asm`` as given (on ``backend`` if one is named), else the
    scenario's on ``backend``."""
    if asm is None:
        return assemble(scenario, backend)
    if backend is not None and runnable_backend(scenario, backend) != asm.backend:
        raise QcontrolInputError(f"{function}: backend={backend!r}, but the run given was put together "
                                 f"on {asm.backend!r}; leave out backend")
    return asm


@dataclass(frozen=True)
class Comparison:
    """The same controller on MuJoCo and on the ODE of eq. (1): ``summary`` is what
    ``compare.json`` holds; ``mujoco`` and ``ode`` are the two runs' :class:`Result`\\ s."""

    summary: dict[str, Any]
    mujoco: Result
    ode: Result


def compare(scenario: Scenario | Assembly, *, rrd: str | Path | None = None, spawn: bool = False,
            progress: Callable[[str], ProgressCallback | None] | None = None,
            command: str | None = None, camera_view: bool = False) -> Comparison:
    """Run the scenario on its MuJoCo model and on the ODE with the same step and hold, and
    measure how far they drift apart (``max_abs_dx``, ``max_abs_dy``, ``max_abs_du``, ...).
    ``progress(backend)`` may give a progress callback per run. ``scenario`` may also be its
    MuJoCo run already put together (:func:`~qcontrol.assembly.assemble`)."""
    given = scenario if isinstance(scenario, Assembly) else None
    scenario = check_scenario(scenario.scenario if given else scenario, "compare")
    _check_arguments("compare", rrd=(rrd, (str, Path), True), spawn=(spawn, bool, False),
                     command=(command, str, True), camera_view=(camera_view, bool, False))
    require_twin(scenario)
    command = command or _call("compare", scenario, rrd=None if rrd is None else str(rrd))
    provenance = scenario_provenance(scenario, command)
    main = given if given is not None else assemble(scenario, "mujoco")
    if main.backend != "mujoco":
        raise QcontrolInputError(f"compare: the run given was put together on {main.backend!r}; give the "
                                 "scenario, or its run on \"mujoco\"")
    assemblies = {"mujoco": main, "ode": assemble(scenario, "ode")}
    runs: dict[str, Result] = {}
    with recording_for(rrd, spawn, main, provenance) as rec:
        for backend, asm in assemblies.items():  # the ODE run is drawn as the MuJoCo run's twin
            twin_of = runs["mujoco"].record if backend == "ode" else None
            observer = None if rec is None else observer_for(rec, main.scene, backend, twin_of)
            traj = asm.run(progress=progress(backend) if progress else None, observer=observer)[0]
            runs[backend] = Result(summary(traj, scenario.name, backend), scenario, backend, traj, asm)
        if camera_view and rec is not None:
            _log_camera_view(rec, main, runs["mujoco"].record, runs["ode"].record)
    report = main.report
    result = {
        "scenario": scenario.name, "integrator": scenario.backends["mujoco"].integrator,
        "dt": scenario.simulation.dt, **backend_deviation(runs["mujoco"].record, runs["ode"].record),
        "consistency": report.consistency_report,
        "realism_alone": realism_attribution(scenario, runs["ode"].record) if report.consistency_report.get(
            "realism") else {},
        "mujoco": runs["mujoco"].summary, "ode": runs["ode"].summary,
        "physics_warnings": list(report.warnings), "provenance": provenance,
    }
    return Comparison(result, runs["mujoco"], runs["ode"])


def sweep(scenario: Scenario, grid: Mapping[str, Sequence[Any]], *, backend: str | None = None) -> list[dict]:
    """Run every point of the product of ``grid`` (``{"controller.kappa_margin": [0.1, 0.5],
    "controller.kind": ["proposed", "comparison"]}``: each key a scenario key, its values as
    ``with_overrides`` takes them) on ``backend`` (None: the scenario's), batched as
    ``qcontrol sweep`` batches them, in this process. Returns the table ``qcontrol sweep`` writes
    to sweep.csv: one dict per run, the grid's keys (the values as given), then the error rate per
    omega (``error_rate_0.100``, ...), ``max_abs_z1_last_half``, ``max_abs_u``, ``diverged``,
    ``diverged_time`` and ``lemma2_max_ratio``."""
    check_scenario(scenario, "sweep")
    _check_arguments("sweep", backend=(backend, str, True))
    if not isinstance(grid, Mapping) or not grid:
        raise QcontrolInputError(f"sweep: grid must be a non-empty dict {{key: [values]}}, got {grid!r}")
    for key, values in grid.items():
        listed = isinstance(values, Sequence) and not isinstance(values, (str, bytes)) and len(values) > 0
        if not isinstance(key, str) or not listed:
            raise QcontrolInputError(f"sweep: grid[{key!r}] must be a non-empty list of values, "
                                     f"got {values!r}")
    runs = math.prod(len(values) for values in grid.values())
    if runs > MAX_RUNS:
        raise QcontrolInputError(f"sweep: {runs:,} runs is more than the {MAX_RUNS:,} a sweep may make; "
                                 "split it into several sweeps")
    backend = runnable_backend(scenario, backend)
    points = [dict(zip(grid, combo, strict=True)) for combo in itertools.product(*grid.values())]
    with sharing():  # (what the variants share is checked once)
        variants = [scenario.with_overrides(point) for point in points]
    return sweep_rows(points, run_variants_batched(variants, backend))


def check_scenario(scenario: object, function: str) -> Scenario:
    """``scenario`` if it is a :class:`Scenario`, else a one-line refusal naming ``function``."""
    if not isinstance(scenario, Scenario):
        raise QcontrolInputError(f"{function}: expected a Scenario (from qcontrol.load_scenario), got "
                                 f"{type(scenario).__name__}")
    return scenario


def _check_arguments(function: str, **given: tuple[Any, type | tuple[type, ...], bool]) -> None:
    """Each argument ``name=(value, types, may_be_none)`` of the types it must have, else one line."""
    for name, (value, types, optional) in given.items():
        if (value is None and optional) or (isinstance(value, types) and not (types is not bool
                                                                               and isinstance(value, bool))):
            continue
        wanted = " or ".join(t.__name__ for t in (types if isinstance(types, tuple) else (types,)))
        raise QcontrolInputError(f"{function}: {name} must be {wanted}{' or None' if optional else ''}, "
                                 f"got {type(value).__name__} {value!r}")


def check_video(run: Assembly, path: str | Path, fps: float = 30.0, camera: str | None = None,
                size: tuple[int, int] | None = None) -> Any:
    """Check, before a run, that its video can be made (:func:`video`): the run's scenario has a
    MuJoCo model (its camera, or a default one framing the body), the format is known, the encoder
    is installed, an offscreen OpenGL context opens. One line (:class:`QcontrolInputError`)
    otherwise. Returns the checked request."""
    drawn, scenario = run.scene, run.scenario
    if drawn is None:
        raise QcontrolInputError(f"--video: {scenario.source} has no MuJoCo model to render; add a "
                                 "[plant.mujoco] table, or leave out --video")
    from .render import check_video_request, require_offscreen_gl
    from .render.frames import camera_id

    camera_id(drawn.model, camera, str(scenario.source))
    request = check_video_request(path, fps, camera, size, scenario.simulation.duration)
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        raise QcontrolInputError("--video needs the video extra (the ffmpeg encoder): "
                                 "pip install 'qcontrol[video]'") from None
    require_offscreen_gl()
    return request


def video(result: Result, path: str | Path, *, fps: float = 30.0, camera: str | None = None,
          size: tuple[int, int] | None = None, twin: Result | None = None,
          progress: ProgressCallback | None = None) -> Path:
    """Render a run (kept with ``record="full"``) as MuJoCo draws it, to ``path`` (.mp4 or .gif):
    ``fps`` frames per second of simulated time, from the model's camera ``camera`` (None: its
    first), ``size`` (width, height) pixels (None: 640 x 480 for MP4, 400 x 300 for GIF), with
    t, q(x1) and u overlaid; ``twin`` (a comparison's ODE run) is drawn as a
    translucent ghost. Only reads the trajectories: the runs' numbers do not change."""
    from .render.video import write_video

    asm = result.assembly if result.assembly is not None else assemble(result.scenario, result.backend)
    request = check_video(asm, path, fps, camera, size)
    drawn = asm.scene
    return write_video(request, result.trajectory, drawn.model, drawn.joint, str(result.scenario.source),
                       None if twin is None else twin.trajectory, progress, order=asm.scenario.order,
                       input_gain=asm.scenario.terms.b)


def _log_camera_view(rec: Any, asm: Assembly, traj: Trajectory, twin: Trajectory | None = None) -> None:
    """MuJoCo's rendering of a finished run (and its twin's ghost) into the recording ``rec``."""
    from .render.video import camera_view_frames

    drawn, source = asm.scene, asm.scenario.source
    if drawn is None:
        raise QcontrolInputError(f"--camera-view: {source} has no MuJoCo model to render")
    name, times, jpegs = camera_view_frames(traj, drawn.model, drawn.joint, str(source), twin=twin,
                                            order=asm.scenario.order, input_gain=asm.scenario.terms.b)
    rec.log_camera_frames(name, times, jpegs)


def check_camera_view(run: Assembly) -> None:
    """Before a run: that its recording can hold MuJoCo's rendering (a MuJoCo model, an
    offscreen OpenGL context); one line otherwise."""
    from .render import require_offscreen_gl
    from .render.frames import camera_id

    drawn, scenario = run.scene, run.scenario
    if drawn is None:
        raise QcontrolInputError(f"--camera-view: {scenario.source} has no MuJoCo model to render; add a "
                                 "[plant.mujoco] table, or leave out --camera-view")
    camera_id(drawn.model, None, str(scenario.source))
    require_offscreen_gl()


def require_twin(scenario: Scenario) -> None:
    """Refuse, in one line, a scenario :func:`compare` cannot run: one without a MuJoCo model."""
    if "mujoco" not in scenario.backends:
        raise QcontrolInputError(
            f"{scenario.source}: compare needs a [plant.mujoco] table (the MuJoCo twin of the ODE); add one"
        )


def recording_for(rrd: str | Path | None, spawn: bool, asm: Assembly, provenance: dict[str, Any]) -> Any:
    """A rerun Recording of the run ``asm`` (its scenario's resolved text, the law's constants,
    ``provenance`` and the disturbances), or nothing without ``rrd`` and ``spawn``."""
    from contextlib import nullcontext

    if rrd is None and not spawn:
        return nullcontext(None)
    if rrd is not None:
        check_output_file(rrd, "--rrd")
    from .recording import Recording  # imports rerun when it opens: only when asked for

    rec = Recording(None if rrd is None else Path(rrd), spawn=spawn)
    rec.log_static(provenance["resolved_scenario"], asm.constants, __version__, provenance=provenance)
    from .recording.disturbances import log_disturbances

    log_disturbances(rec, asm)  # arrows and time markers of the scenario's [[disturbance]]s, if any
    return rec


def observer_for(rec: Any, drawn: SceneSource | None, label: str, twin_of: Trajectory | None = None,
                 ghost: bool | None = None) -> Any:
    """The recording's observer of a run labelled ``label`` (its backend, or e.g. "comparison"),
    drawn in 3-D in the scene ``drawn`` (an :attr:`Assembly.scene <qcontrol.assembly.Assembly.scene>`;
    None: no 3-D view); with ``twin_of`` the run is drawn as that main run's twin (thin lines on its
    wide ones, an outline body, the differences); ``ghost`` (default: whether it is a twin) draws
    another run beside the main one."""
    ghost = twin_of is not None if ghost is None else ghost
    if drawn is None:
        return rec.observer(label, ghost=ghost, twin_of=twin_of)
    return rec.observer(label, drawn.model, drawn.joint, ghost=ghost, twin_of=twin_of)


# --------------------------------------------------------------------------------------------
# helpers for user-defined laws


@lru_cache(maxsize=64)
def _coordinates(c: tuple[float, ...]) -> Backstepping:
    return Backstepping(c, 1.0)  # the quantizer bound matters only for Lemma 2's bounds


def quantized_backstepping(c: Sequence[float], x_q: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray,
                                                                                         np.ndarray]:
    """The quantized backstepping signals for gains ``c`` (eqs. (31)-(34)): ``zbar`` and
    ``alphabar``, each of shape ``(n,)``, from the quantized reading ``x_q`` ``(n,)`` and
    ``yd = [y_d, y_d', ..., y_d^(n)]``. ``alphabar[-1]`` is the backstepping input without any
    robust or adaptive term. Computed by the recursion of eqs. (31)-(34) as written
    (:meth:`~qcontrol.BacksteppingLaw.recursion`), on floats, or column by column for readings of
    shape ``(..., n)``: the same numbers row by row, and a law that calls it has a compiled form."""
    coordinates = _coordinates(tuple(float(v) for v in c))
    q, y = np.asarray(x_q), np.asarray(yd)
    q, y = (a if a.dtype == object else a.astype(float) for a in (q, y))  # object: traced values
    if q.ndim == 1 and y.ndim == 1:
        zbar, alphabar = coordinates.recursion(q.tolist(), y.tolist())
        kind = type(x_q) if q.dtype == object else np.ndarray  # traced: the traced vectors' class
        return np.array(zbar).view(kind), np.array(alphabar).view(kind)
    zbar, alphabar = coordinates.recursion(list(np.moveaxis(q, -1, 0)), list(np.moveaxis(y, -1, 0)))
    shape = np.broadcast_shapes(q.shape[:-1], y.shape[:-1])
    return tuple(np.stack([np.broadcast_to(v, shape) for v in values], axis=-1)
                 for values in (zbar, alphabar))


def lemma2_bounds(c: Sequence[float], delta: float | Sequence[float]) -> np.ndarray:
    """Lemma 2's bounds ``L_z`` (shape ``(n,)``) on ``|z_i - zbar_i|`` for gains ``c`` and the
    uniform quantizer's step ``delta`` (a number, or one step per channel); the paper's ``L`` is
    ``L_z[-1]``."""
    half = delta / 2.0 if np.ndim(delta) == 0 else [d / 2.0 for d in delta]
    return _lemma2_bounds(c, half)[0]


def model_equation(model: str | Path, joint: str | None = None) -> ModelEquation:
    """The equation the one-joint MJCF file ``model`` realises, ``x2' = b u + theta^T phi(x)``: its
    inertia, input gain b = gear / I, each term MuJoCo's physics produces with its coefficient and
    what lies outside that form (``qcontrol model``); ``joint`` names the joint meant (checked)."""
    from .plants.mujoco.equation import model_equation as equation

    _check_arguments("model_equation", model=(model, (str, Path), False), joint=(joint, str, True))
    return equation(model, joint)


def model_scenario(model: str | Path, out: str | Path, joint: str | None = None,
                   command: str | None = None) -> Path:
    """Write at ``out`` a scenario of the model's equation (every term native, the paper's law with a
    bounding function for each, or through a filter actuator the tuning-function law, a reference)
    after loading it and building its law and both plants, MuJoCo's compared with eq. (1) (``qcontrol
    model --scenario``): nothing is written when it would not run. ``command`` is named in its
    header."""
    from .plants.mujoco.model_scenario import scenario_text

    _check_arguments("model_scenario", out=(out, (str, Path), False))
    eq = model_equation(model, joint)
    path = check_output_file(out, "--scenario" if command else "model_scenario", "model.toml")
    if path.suffix != ".toml":
        raise QcontrolInputError(f"{path}: a scenario is a .toml file; e.g. model.toml")
    text = scenario_text(eq, Path(model), path, command or f"qcontrol.model_scenario({str(model)!r})",
                         input_gain=True)
    sc = parse_scenario(text, source=str(path), base_dir=path.parent, default_name=path.stem)
    with compiled_paths.not_needed():
        for backend in ("mujoco", "ode"):
            assemble(sc, backend)  # its law and plant built, MuJoCo's compared with eq. (1)
    return write_text(path, text)
