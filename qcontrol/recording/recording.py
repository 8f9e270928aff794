"""Rerun recordings of closed-loop runs: 3-D motion, every signal, Lemma 2 margins, a default layout.

A :class:`Recording` writes one ``.rrd`` file while runs go on. Each run streams into it through an
engine observer (:meth:`Recording.observer`, see :func:`qcontrol.engine.simulate`; the streamer is
in :mod:`.streamer`): every call sends the rows that became final as columns (``send_columns``) on
the duration timeline ``sim_time`` and starts writing them to disk, which goes on on another
core while the run continues (the next call first waits until they are written), so an
interrupted or diverged run leaves a readable recording up to its last chunk. The series come
from the signal table (:mod:`.series`), the 3-D bodies from the MuJoCo model (:mod:`.scene`); the
static entities are ``info/scenario``, ``info/constants`` and ``info/version``. Times are integer nanoseconds
``round(t * 1e9)``. Only ``runs[0]`` of a batch is streamed.

The layout (:mod:`.layout`, with the fixed camera of :mod:`.camera`) is sent active and default,
so every viewer (native, ``--web-viewer``, one already open) shows it. Streaming to a viewer, it
is sent when the first run starts and again only when it changes: a twin run adds its difference
panels, and a slide that travels beyond what its camera framed gets a camera that frames the
whole run when the recording is closed. A recording that only writes a file sends it once, when
it is closed (also when a run was interrupted: the partial file has it too); nobody looks at
the file before then, and a layout costs a recording of a fast run as much as its series.

File handling (:mod:`.rrd_file`): data goes to a temporary file of its own beside ``path``
(``.NAME.<random>.tmp``) while the recording is open. When the ``with`` block ends cleanly the
stream is flushed and closed, the file is checked (it reads back, footer included) and moved to
``path``. On an exception (an error, ``KeyboardInterrupt``, SIGTERM) what was recorded up to the
last chunk is kept as ``NAME.partial.rrd`` and ``path`` is left as it was. Only a killed process
leaves its temporary file (readable up to its last chunk but one at least). A blocking flush waits
only while rerun's writer makes progress (:meth:`Recording.flush`): a stream whose writer stopped
(a full disk) is given up on, never flushed or closed again, and its file is judged as it is.
"""

from __future__ import annotations

import errno
import json
import os
import re
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np

from ..engine import Observer, Trajectory
from ..errors import QcontrolInputError
from ..outputs import clean, output_error
from .camera import TRAVEL_MARGIN, Camera, fixed_camera
from .layout import default_blueprint
from .rrd_file import RrdFile, quiet_rerun_logging
from .scene import Scene
from .series import COMPARISON_COLORS, RED, TWIN_COLORS, Panel, Series, shade_of
from .streamer import RunStreamer
from .viewer import start_viewer, viewer_url

if TYPE_CHECKING:
    import mujoco
    import rerun as rr

_COMPARISON_ALPHA = 90
FLUSH_SLICE = 0.25  # s: a blocking flush waits on rerun this long at a time, then checks the sink's progress
FLUSH_STALL = 30.0  # s: a sink that took nothing for this long while a flush waited is given up on
_MAIN_RUN_TAKEN = "a main (non-ghost) run is already being recorded into this file"


def _label_suffix(label: str) -> str:
    cleaned = re.sub(r"[^A-Za-z0-9_\-]", "_", label)
    if not cleaned:
        raise ValueError("a ghost run needs a non-empty label (it names its entities, e.g. 'ode')")
    return cleaned


def _ignore(start: int, stop: int, runs: list[Trajectory]) -> None:
    """The observer of a recording that has nowhere to write (its viewer could not start)."""


class Recording:
    """A rerun recording of one or more closed-loop runs, written while they go on.

    Use as a context manager; see the module docstring for the entity layout and file handling.
    ``path`` is the file to write, ``spawn=True`` opens a viewer (when one can be started) and
    streams to it as well; at least one of them must be given.
    """

    def __init__(self, path: Path | None, *, spawn: bool = False, application_id: str = "qcontrol") -> None:
        if path is None and not spawn:
            raise ValueError("a recording needs a file (path) or a viewer (spawn=True)")
        self.path = None if path is None else Path(path)
        self.spawn = spawn
        self._file: RrdFile | None = None
        self.application_id = application_id
        self._stream: rr.RecordingStream | None = None
        self._main_taken = False
        self._ghosts: set[str] = set()
        self._fixed_logged = False
        self._panels: set[Panel] = set()
        self._scene: Scene | None = None  # the first run's scene: the camera's model
        self._scenes: dict[tuple[int, str | None], Scene] = {}  # by model and joint (scene_of)
        self._travel = (np.inf, -np.inf)  # joint positions (and reference) seen so far
        self._framed: tuple[float, float] | None = None  # what the camera sent frames
        self._camera: Camera | None = None
        self._layout_sent: tuple[Any, ...] | None = None
        self._camera_view: str | None = None  # the entity of MuJoCo's rendered frames, if any
        self._spans: dict[Panel, tuple[float, float]] = {}  # each panel's finite values so far
        self.main_series: list[Series] = []  # the main run's, restyled once a twin is drawn on them
        self.main_label = "main"
        self._flush_error: str | None = None  # the first failure to flush, reported at close
        self._given_up: str | None = None  # why the stream was given up on (its sink stopped answering)
        self._live = False  # streaming to a viewer (the layout is then sent as the runs go on)
        self._open()

    @property
    def enabled(self) -> bool:
        """Whether this recording logs anything (it is open, with a file, a viewer or both)."""
        return self._stream is not None

    @property
    def stream(self) -> rr.RecordingStream | None:
        """The open rerun stream (None once closed, or when there is nowhere to write), for
        modules that log more than runs (e.g. :mod:`.disturbances`)."""
        return self._stream

    @property
    def temporary(self) -> Path | None:
        """The file rerun writes while the recording is open (None without a file)."""
        return None if self._file is None else self._file.temporary

    def _open(self) -> None:
        quiet_rerun_logging()
        import rerun as rr

        stream = rr.RecordingStream(self.application_id)
        sinks: list[Any] = []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = RrdFile(self.path)
            sinks.append(rr.FileSink(str(self._file.temporary)))
        if self.spawn:
            try:
                start_viewer()  # reuses the viewer the command line started before the run
                sinks.append(rr.GrpcSink(viewer_url()))
                self._live = True
            except QcontrolInputError as exc:  # no viewer available: keep the file, if any
                warnings.warn(
                    f"could not start a rerun viewer ({exc}); not streaming to a viewer", stacklevel=3
                )
        if not sinks:  # nowhere to write: stay inert rather than buffer the run in memory
            return
        try:
            stream.set_sinks(*sinks)  # writes the file's header: a disk with no space left fails here
        except RuntimeError as exc:
            if self._file is None:
                raise
            self._file.discard()
            code = errno.ENOSPC if "No space left" in str(exc) else errno.EIO
            raise output_error(self.path, OSError(code, os.strerror(code))) from None
        stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._stream = stream

    def __enter__(self) -> Recording:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close(complete=exc_type is None)

    def close(self, complete: bool = True) -> None:
        """Flush and close the stream; a ``complete`` recording's file is checked and moved to its
        final name, any other is kept under its partial name (see the module docstring; idempotent).
        A stream given up on (:meth:`flush`) is not touched again: its file is judged as it is."""
        if self._stream is None and self._given_up is None:
            if self._file is not None:  # nowhere to write after all (no sink): nothing to keep
                self._file.discard()
                self._file = None
            return
        try:
            self.update_layout(final=True)
            self.flush()
            if self._stream is not None:  # the sink answered every flush: rerun can close it
                self._stream.disconnect()  # closes the file: writes rerun's footer
        except BaseException:
            complete = False
            raise
        finally:
            self._stream = None
            if self._file is not None:
                file, self._file = self._file, None
                file.finish(complete, self._given_up)  # a file that was not written whole raises here
            elif self._given_up is not None:
                warnings.warn(f"the rerun viewer stopped taking the recording ({self._given_up}); the rest "
                              "of the run was not streamed", stacklevel=3)
            if self._flush_error is not None:
                warnings.warn(f"rerun could not flush the recording: {self._flush_error}", stacklevel=3)

    def flush(self, wait: bool = True) -> None:
        """Write everything logged so far: block until it is written, or (``wait=False``) start
        writing it and return, so that the run goes on while rerun encodes and writes on another
        core. A failure does not stop the run: a file that could not be written is reported when
        the recording closes (it is checked then), any other failure (e.g. a viewer that went away)
        as one warning then.

        A blocking flush waits in slices of :data:`FLUSH_SLICE` s and only while the sink makes
        progress. rerun's file sink whose writer stopped on a write error (a full disk) while a
        flush was queued behind the failed write never answers that flush, and from then on no
        flush or close of the stream ever returns. So when the file did not grow during a slice and
        its disk has no space left, or nothing answered and nothing was written for
        :data:`FLUSH_STALL` s, the stream is given up on (:meth:`_give_up`): the recording logs
        nothing more and its file is judged as it is when it closes."""
        if self._stream is None:
            return
        written, quiet = self._written(), 0.0
        while self._stream is not None:
            started = time.monotonic()
            error = self._flush_once(FLUSH_SLICE if wait else 0.0)
            if error is None or not wait or time.monotonic() - started < FLUSH_SLICE:
                # written (or started), or failed before its time: the flush ended, the sink answered
                self._flush_error = self._flush_error or error
                return
            now = self._written()
            quiet = 0.0 if now != written else quiet + FLUSH_SLICE
            written = now
            full = self._file is not None and not self._file.space_left()
            if quiet and (full or quiet >= FLUSH_STALL):
                self._give_up("no space left on the device" if full else
                              f"rerun's writer took nothing for {FLUSH_STALL:g} s")

    def _flush_once(self, timeout: float) -> str | None:
        """One rerun flush waiting at most ``timeout`` s (0: started, not waited for); its error,
        if any (a timeout is one)."""
        try:
            self._stream.flush(timeout_sec=timeout)  # type: ignore[union-attr]
        except RuntimeError as exc:
            return str(exc)
        return None

    def _written(self) -> int:
        return -1 if self._file is None else self._file.written()

    def _give_up(self, why: str) -> None:
        """Stop using a stream whose sink no longer answers. rerun's own pipeline waits for that
        sink forever, so would anything that flushes or closes the stream: rerun's exit hook
        (it closes every stream) and the stream's release (it closes streams nobody holds). The
        stream is kept for the life of the process and rerun's exit hook is turned off (qcontrol
        closes its own recordings itself), so that the process can end."""
        import ctypes

        import rerun as rr

        stream, self._stream = self._stream, None
        self._given_up = why
        self._flush_error = None  # the timeouts that led here: the file (or the warning) says why
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(stream))  # never released: releasing it would hang
        rr.unregister_shutdown()

    # -- static content -------------------------------------------------------------------

    def log_static(
        self, scenario_text: str, constants: Mapping[str, float | Sequence[float]], version: str,
        provenance: Mapping[str, Any] | None = None,
    ) -> None:
        """Log the scenario's text, the controller constants, the package version and, when given,
        the provenance (``info/provenance``: the versions, the command, the overrides)."""
        if self._stream is None:
            return
        import rerun as rr

        markdown = rr.components.MediaType.MARKDOWN
        self._stream.log(
            "info/scenario",
            rr.TextDocument(f"```toml\n{scenario_text}\n```", media_type=markdown),
            static=True,
        )
        rows = "\n".join(f"| {key} | {_format_constant(value)} |" for key, value in constants.items())
        values = {key: np.atleast_1d(np.asarray(value, dtype=float)) for key, value in constants.items()}
        self._stream.log(
            "info/constants",
            rr.TextDocument(f"| constant | value |\n|---|---|\n{rows}\n", media_type=markdown),
            rr.AnyValues(**values),
            static=True,
        )
        self._stream.log(
            "info/version", rr.TextDocument(f"qcontrol {version}"), rr.AnyValues(version=version), static=True
        )
        if provenance is not None:
            text = json.dumps(clean(provenance), indent=2)
            self._stream.log("info/provenance", rr.TextDocument(f"```json\n{text}\n```", media_type=markdown),
                             static=True)

    # -- runs ------------------------------------------------------------------------------

    def observer(
        self,
        label: str,
        model: mujoco.MjModel | None = None,
        joint: str | None = None,
        ghost: bool = False,
        twin_of: Trajectory | None = None,
    ) -> Observer:
        """An engine observer streaming ``runs[0]`` of a :func:`~qcontrol.engine.simulate` call.

        ``label`` names the run ("mujoco", "ode"): it tags the main run's series names and, for a
        ghost, its entity paths (``world/{label}_ghost``, ``signals/tracking/y_{label}``, ...).
        With ``model`` the bodies are drawn and posed by replaying x1 into ``joint`` (a hinge or
        slide; may be omitted when the model has one joint). One main run per recording; a ghost
        run adds its body and its y, z1, u. A ghost with ``twin_of`` (the main run's trajectory,
        the same closed loop on another backend) is the main run's twin: drawn thin on top of the
        main run's wide series, as an outline around its body, with ``|main - twin|`` recorded;
        any other ghost (another controller) is drawn in its own colour.
        """
        if twin_of is not None and not ghost:
            raise ValueError("twin_of names the main run a ghost run is the twin of: pass ghost=True")
        if self._stream is None:
            return _ignore
        shade = len(self._ghosts)  # the how-many-th ghost this run is (its colour)
        if ghost:
            suffix = _label_suffix(label)
            if suffix in self._ghosts:
                raise ValueError(f"a ghost run labelled {label!r} is already being recorded")
            self._ghosts.add(suffix)
            world, role = f"world/{suffix}_ghost", "twin" if twin_of is not None else "comparison"
        else:
            if self._main_taken:
                raise ValueError(_MAIN_RUN_TAKEN)
            self._main_taken = True
            suffix, world, role = "", "world/bodies", "main"
        scene = None if model is None else self.scene_of(model, joint)
        if scene is not None:
            self._log_scene(scene, world, role, shade)
            self._scene = self._scene or scene
        return RunStreamer(self, label, suffix, role, scene, world, twin_of, shade)

    def scene_of(self, model: mujoco.MjModel, joint: str | None) -> Scene:
        """The model's :class:`Scene` for ``joint``, made once per recording (the main run, its
        twin and the disturbance arrows draw the same model; a scene only reads its reference
        pose once made)."""
        key = (id(model), joint)
        if key not in self._scenes:
            self._scenes[key] = Scene(model, joint)
        return self._scenes[key]

    def _log_scene(self, scene: Scene, world: str, role: str, shade: int = 0) -> None:
        """The static geometry: shapes in their bodies, world-body geoms, the target marker."""
        import rerun as rr

        stream = self._stream
        for geom in scene.geoms:
            if geom.body == 0 and self._fixed_logged:
                continue
            parent = "world/fixed" if geom.body == 0 else f"{world}/{scene.body_names[geom.body]}"
            moving = geom.body != 0  # a ghost's look is for its bodies; the world's geoms are shared
            looks = {"main": geom.rgba, "twin": (*shade_of(TWIN_COLORS, shade), 255),
                     "comparison": (*shade_of(COMPARISON_COLORS, shade), _COMPARISON_ALPHA)}
            rgba = looks[role if moving else "main"]
            stream.log(
                f"{parent}/{geom.name}",
                rr.Transform3D(translation=geom.pos, quaternion=rr.Quaternion(xyzw=geom.quat_xyzw)),
                geom.shape(rgba, role == "twin" and moving),
                static=True,
            )
        self._fixed_logged = True
        if role == "main":
            radius = 1.3 * max(scene.tip_radius, 0.01)
            stream.log(
                "world/target",
                rr.Ellipsoids3D(
                    half_sizes=[[radius] * 3],
                    colors=[(*RED, 255)],
                    fill_mode=rr.components.FillMode.MajorWireframe,
                ),
                static=True,
            )

    def log_camera_frames(self, name: str, times: np.ndarray, jpegs: Sequence[bytes]) -> None:
        """MuJoCo's rendered frames (JPEG files' bytes) at simulated ``times`` [s], under
        ``camera/<name>``, shown beside the 3-D view in the layout."""
        if self._stream is None or not len(jpegs):
            return
        import rerun as rr

        from .streamer import time_column

        entity = f"camera/{_label_suffix(name)}"
        self._stream.send_columns(entity, indexes=[time_column(np.asarray(times, dtype=float))],
                                  columns=rr.EncodedImage.columns(blob=list(jpegs),
                                                                  media_type=["image/jpeg"] * len(jpegs)))
        self._camera_view = entity
        self.update_layout()

    # -- layout ----------------------------------------------------------------------------

    def add_panels(self, panels: list[Panel]) -> None:
        """Panels a run's series fill; the layout shows them from its next update."""
        self._panels.update(panels)

    def see_values(self, panel: Panel, values: np.ndarray) -> None:
        """Values a panel shows: a panel whose values are all one number gets a fixed range
        around it when the recording closes (rerun would label its axis with that one tick)."""
        if not values.size:
            return
        least, most = float(values.min()), float(values.max())
        if not (np.isfinite(least) and np.isfinite(most)):  # NaN or inf among them: the finite ones
            finite = values[np.isfinite(values)]
            if not finite.size:
                return
            least, most = float(finite.min()), float(finite.max())
        low, high = self._spans.get(panel, (np.inf, -np.inf))
        self._spans[panel] = (min(low, least), max(high, most))

    def _flat_ranges(self) -> dict[Panel, tuple[float, float]]:
        """``value -+ 1`` (or -+ 10 % of it, if larger) for the panels whose values are all one number."""
        ranges = {}
        for panel, (low, high) in self._spans.items():
            if high - low <= 1e-12 * max(1.0, abs(high)):
                half = max(1.0, 0.1 * abs(high))
                ranges[panel] = (low - half, high + half)
        return ranges

    def see_motion(self, positions: np.ndarray) -> None:
        """Joint positions (and reference positions) drawn in 3-D: the camera frames them."""
        finite = positions[np.isfinite(positions)]
        if finite.size:
            low, high = self._travel
            self._travel = (min(low, float(finite.min())), max(high, float(finite.max())))

    def _current_camera(self) -> Camera | None:
        """The camera for what was seen so far; kept while the travel stays inside what it framed."""
        if self._scene is None:
            return None
        low, high = self._travel
        framed = self._framed
        outside = framed is None or not framed[0] <= low <= high <= framed[1]
        if self._camera is None or (np.isfinite(low) and outside):
            self._camera = fixed_camera(self._scene, low, high)
            margin = TRAVEL_MARGIN * (high - low)
            self._framed = (low - margin, high + margin) if np.isfinite(low) else None
        return self._camera

    def update_layout(self, final: bool = False) -> None:
        """Send the layout (active and default) if it differs from the one sent last. The camera
        is re-made only for the closing update (``final``) or the first one, so that a live viewer
        does not jump while a run goes on; the closing update also fixes the range of panels whose
        values are all one number. Without a viewer only the closing update sends it."""
        if self._stream is None or not self._panels or not (final or self._live):
            return
        camera = self._current_camera() if final or self._layout_sent is None else self._camera
        ranges = self._flat_ranges() if final else {}
        layout = (frozenset(self._panels), camera, self._camera_view, tuple(sorted(ranges.items(), key=str)))
        if layout != self._layout_sent:
            blueprint = default_blueprint(list(self._panels), camera, self._camera_view, ranges)
            self._stream.send_blueprint(blueprint, make_active=True, make_default=True)
            self._layout_sent = layout


def _format_constant(value: float | Sequence[float]) -> str:
    values = np.atleast_1d(np.asarray(value, dtype=float))
    text = ", ".join(f"{v:.6g}" for v in values)
    return text if np.ndim(value) == 0 else f"[{text}]"
