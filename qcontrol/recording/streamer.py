"""The observer of one run in a recording: it sends each batch of final rows as columns.

What it sends per batch of rows: every series of the run (:func:`.series.run_series`); for the
main run, with its first rows, the guides' constant lines (the Lemma 2 bound, the quantization
band) from the first instant to the run's horizon; for a twin, ``|main - twin|`` of its
twin-drawn series, against the main run's rows at the same instants; and, with a scene, the pose
of every body (and, for the main run, of the target marker) every 10 ms of simulated time.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import ArrayLike

from ..engine import Trajectory
from .scene import Scene
from .series import RED, TIMELINE, GuideLine, Panel, Series, differences, guide_lines, run_series

if TYPE_CHECKING:
    import rerun as rr


class StreamTarget(Protocol):
    """What a run's streamer uses of its recording (:class:`~.recording.Recording` is one): the
    open stream, flushing, the camera's view of the motion, the layout's panels, and the main
    run's series and label (a twin restyles the first and names the second in its differences)."""

    main_series: list[Series]
    main_label: str

    @property
    def stream(self) -> Any: ...  # rr.RecordingStream, or None once closed

    def flush(self, wait: bool = True) -> None: ...

    def see_motion(self, positions: np.ndarray) -> None: ...

    def update_layout(self, final: bool = False) -> None: ...

    def add_panels(self, panels: list[Panel]) -> None: ...


def time_nanoseconds(t: ArrayLike) -> np.ndarray:
    """The ``sim_time`` values logged for times ``t`` (seconds): ``round(t * 1e9)`` as int64 ns."""
    return np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def time_column(t: ArrayLike) -> rr.TimeColumn:
    """The ``sim_time`` index column of rows at times ``t`` (seconds)."""
    import rerun as rr

    return rr.TimeColumn(TIMELINE, duration=time_nanoseconds(t).view("timedelta64[ns]"))


def scalar_column(values: np.ndarray) -> list[rr.ComponentColumn]:
    """``values`` (rows,) or (rows, k) as the ``Scalars`` column of ``rows`` rows of k instances:
    what ``rr.Scalars.columns(scalars=values)`` makes, built directly from one contiguous copy and
    the rows' offsets (a third of its cost; a recording sends a column per series and batch)."""
    import rerun as rr

    flat = np.ascontiguousarray(values, dtype=np.float64)
    width = 1 if flat.ndim == 1 else flat.shape[1]
    offsets = np.arange(0, width * len(flat) + 1, width, dtype=np.int32)
    return [rr.ComponentColumn(rr.Scalars.descriptor_scalars(), rr.components.ScalarBatch(flat.reshape(-1)),
                               offsets=offsets)]


# A twin's differences are recorded as log10 |main - twin| (a linear axis would label 5e-14 as
# "0.000 000 000 000 05"), floored at this value: -16 on the plot means equal to double rounding.
DIFFERENCE_FLOOR = 1e-16
POSE_PERIOD = 0.01  # s of simulated time between the 3-D view's poses (a display shows 60 frames a second)


def pose_rows(rows: slice, dt: float) -> np.ndarray:
    """The rows of ``rows`` at which the 3-D view is posed: every row whose time is a multiple of
    :data:`POSE_PERIOD` (every row when ``dt`` is that long or longer). The series keep every row;
    the bodies need no more than a display can show, and a pose costs a recording as much as
    three series."""
    stride = max(1, round(POSE_PERIOD / dt))
    first = -(-rows.start // stride) * stride
    return np.arange(first, rows.stop, stride)


def log_style(stream: rr.RecordingStream, series: Series) -> None:
    """A series' static look: its legend name, colour, width, steps for held signals. Zoomed out
    (more rows than pixels) the viewer draws each pixel column's minimum and maximum, not their
    average: a quantization error's sawtooth, u's chattering and Lemma 2's peaks keep their size."""
    import rerun as rr

    mode = "StepAfter" if series.step else "Linear"
    widths = None if series.width is None else [series.width] * len(series.labels)
    stream.log(series.path, rr.SeriesLines(names=series.names, colors=list(series.colors), widths=widths,
                                           interpolation_mode=mode, aggregation_policy="MinMax"),
               static=True)


class RunStreamer:
    """The observer of one run (``role``: "main", "twin" or "comparison"); see the module docstring."""

    def __init__(self, recording: StreamTarget, label: str, suffix: str, role: str, scene: Scene | None,
                 world: str, twin_of: Trajectory | None, shade: int = 0) -> None:
        self.recording = recording
        self.shade = shade  # the how-many-th ghost run of the recording (its colour)
        self.label = label
        self.suffix = suffix
        self.role = role
        self.scene = scene
        self.world = world
        self.twin_of = twin_of
        self.series: list[Series] | None = None
        self.guides: list[GuideLine] = []
        self.differences: list[Series] = []

    def __call__(self, start: int, stop: int, runs: list[Trajectory]) -> None:
        stream = self.recording.stream
        if stream is None or not runs:
            return
        run = runs[0]
        stop = min(stop, len(run.t))
        if start >= stop:
            return
        self.recording.flush()  # the previous rows are on disk (written while the run went on)
        stream = self.recording.stream
        if stream is None:  # that flush gave the stream up (its sink stopped answering)
            return
        rows = slice(start, stop)
        first = self.series is None
        if first:
            self._start(run)
        if self.scene is not None:
            self.recording.see_motion(run.x[rows, 0])
            if self.role == "main":
                self.recording.see_motion(run.yd[rows, 0])
        if first:
            self.recording.update_layout()
        times = time_column(run.t[rows])
        for s in self.series:
            values = s.values(run, rows)
            self.recording.see_values(s.panel, values)
            stream.send_columns(s.path, indexes=[times], columns=scalar_column(values))
        if first and self.guides:  # constant over the run: its two ends, once
            ends = time_column(np.array([run.t[start], max(run.duration, run.t[stop - 1])]))
            for g in self.guides:
                stream.send_columns(g.path, indexes=[ends], columns=scalar_column(np.array([g.levels] * 2)))
        if self.differences:
            self._send_differences(run, rows, times)
        if self.scene is not None:
            self._send_poses(run, rows)
        self.recording.flush(wait=False)

    def _start(self, run: Trajectory) -> None:
        """On the first rows: the series styles (static), the panels they fill; a twin restyles
        the main run's series it is drawn on (wide) and adds its differences."""
        import rerun as rr

        stream, recording = self.recording.stream, self.recording
        self.series = run_series(run, self.label, self.role, self.suffix, self.shade)
        for s in self.series:
            log_style(stream, s)
        if self.role == "main":
            recording.main_series, recording.main_label = self.series, self.label
            self.guides = guide_lines(run)
            for g in self.guides:
                lines = rr.SeriesLines(names=list(g.names), colors=[RED] * len(g.names))
                stream.log(g.path, lines, static=True)
        if self.role == "twin":
            for s in recording.main_series:
                if s.drawn_for_twin:
                    log_style(stream, s.beside_twin())
            self.differences = differences(run, recording.main_label, self.label, self.suffix, self.shade)
            for d in self.differences:
                log_style(stream, d)
        recording.add_panels([s.panel for s in self.series] + [d.panel for d in self.differences])

    def _send_differences(self, run: Trajectory, rows: slice, times: rr.TimeColumn) -> None:
        """``|main - twin|`` at the twin's rows: the main run's row at the same instant, NaN where
        the main run has none (it stopped earlier, or its step differs)."""
        main = self.twin_of
        index = np.rint(run.t[rows] / main.dt).astype(np.int64)
        same = (index < len(main.t)) & np.isclose(main.t[np.minimum(index, len(main.t) - 1)], run.t[rows],
                                                 rtol=0.0, atol=1e-9)
        for d in self.differences:
            against = np.full(len(index), np.nan)
            against[same] = d.values(main, index[same])
            with np.errstate(invalid="ignore", divide="ignore"):
                gap = np.log10(np.maximum(np.abs(against - d.values(run, rows)), DIFFERENCE_FLOOR))
            self.recording.stream.send_columns(d.path, indexes=[times], columns=scalar_column(gap))

    def _send_poses(self, run: Trajectory, rows: slice) -> None:
        """The bodies' poses (and the target's, for the main run) at the rows of ``rows`` that
        fall on the pose grid (:func:`pose_rows`)."""
        import rerun as rr

        stream, scene = self.recording.stream, self.scene
        picked = pose_rows(rows, run.dt)
        if not len(picked):
            return
        times = time_column(run.t[picked])
        pos, quat = scene.replay(run.x[picked, 0])
        for j, body in enumerate(scene.bodies):
            stream.send_columns(
                f"{self.world}/{scene.body_names[body]}",
                indexes=[times],
                columns=rr.Transform3D.columns(translation=pos[:, j], quaternion=quat[:, j]),
            )
        if self.role == "main":
            target = scene.tip_positions(run.yd[picked, 0])
            stream.send_columns("world/target", indexes=[times],
                                columns=rr.Transform3D.columns(translation=target))
