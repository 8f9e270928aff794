"""A run as a video: the finished trajectory sampled at a rate of simulated time, rendered by
:mod:`.frames`, encoded to MP4 (H.264) or GIF by the ffmpeg that the imageio-ffmpeg wheel ships.

imageio-ffmpeg is a small wrapper around a static ffmpeg binary in its wheel (no system codec, no
download at run time); frames are piped to it as raw RGB. A GIF gets its own 256-colour palette
(ffmpeg's palettegen/paletteuse), which keeps the README's animation small and sharp.

The video is written under a temporary name and moved into place when complete: an interrupted
render leaves nothing under the final name.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..engine import Trajectory
from ..errors import QcontrolInputError
from ..outputs import atomic_path, check_output_file
from .frames import DEFAULT_CAMERA, DEFAULT_CAMERA_NAME, FrameRenderer, Instant, camera_id

DEFAULT_FPS = 30.0
VIDEO_FORMATS = (".mp4", ".gif")
SIZES = {".mp4": (640, 480), ".gif": (400, 300)}  # a GIF is for a web page: smaller


@dataclass(frozen=True)
class VideoRequest:
    """What ``--video`` asked for, checked before the run: the file, the frame rate, the camera."""

    path: Path
    fps: float
    camera: str | None = None
    size: tuple[int, int] | None = None  # width, height; None: by format (SIZES)

    @property
    def frame_size(self) -> tuple[int, int]:
        return self.size or SIZES[self.path.suffix.lower()]


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480); one line for anything else."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise QcontrolInputError(f"--video-size {text}: give WIDTHxHEIGHT, e.g. 640x480") from None
    if not (16 <= width <= 4096 and 16 <= height <= 4096):
        raise QcontrolInputError(f"--video-size {text}: each side must be 16 to 4096 pixels")
    return width, height


def check_video_request(path: str | Path, fps: float, camera: str | None = None,
                        size: tuple[int, int] | None = None) -> VideoRequest:
    """One line (a :class:`QcontrolInputError`) for a video that cannot be written, before the run:
    its format, its folder, the frame rate."""
    path = check_output_file(path, "--video")
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise QcontrolInputError(f"--video {path}: unknown format {path.suffix!r}; give a .mp4 or .gif file")
    if not (np.isfinite(fps) and fps > 0):
        raise QcontrolInputError(f"--video-fps must be > 0, got {fps!r}")
    return VideoRequest(path, float(fps), camera, size)


def frame_rows(traj: Trajectory, fps: float) -> np.ndarray:
    """The rows shown: the one at or just before each instant i / fps of simulated time, up to
    the run's last row (a diverged run's video ends where it stopped)."""
    dt = float(traj.t[1] - traj.t[0]) if len(traj.t) > 1 else 1.0
    count = int(np.floor(traj.t[-1] * fps + 1e-9)) + 1
    rows = np.floor(np.arange(count) / fps / dt + 1e-9).astype(int)
    return np.minimum(rows, len(traj.t) - 1)


def _instants(traj: Trajectory, fps: float, twin: Trajectory | None) -> list[Instant]:
    x, x_q, u, yd = traj.signals["x"], traj.signals["x_q"], traj.signals["u"], traj.signals["yd"]
    instants = []
    for row in frame_rows(traj, fps):
        twin_x1 = None
        if twin is not None:
            twin_x1 = float(twin.signals["x"][min(row, len(twin.t) - 1), 0])
        instants.append(Instant(float(traj.t[row]), float(x[row, 0]), float(x_q[row, 0]), float(u[row]),
                                float(yd[row, 0]), twin_x1))
    return instants


def _positions(instants: list[Instant]) -> np.ndarray:
    """The joint positions the frames show (the run's, its twin's, the reference's), which the
    default camera frames."""
    return np.array([v for i in instants for v in (i.x1, i.yd, i.twin_x1) if v is not None], dtype=float)


def _writer(path: Path, suffix: str, size: tuple[int, int], fps: float) -> Generator[None, np.ndarray, None]:
    """imageio-ffmpeg's frame sink writing ``path`` in the format of ``suffix`` (the final name's:
    ``path`` is a temporary one)."""
    import imageio_ffmpeg

    if suffix == ".gif":
        palette = ("split[a][b];[a]palettegen=stats_mode=diff[p];"
                   "[b][p]paletteuse=dither=none:diff_mode=rectangle")
        return imageio_ffmpeg.write_frames(str(path), size, fps=fps, codec="gif", pix_fmt_out="pal8",
                                           output_params=["-filter_complex", palette, "-f", "gif"],
                                           macro_block_size=1, ffmpeg_log_level="error")
    return imageio_ffmpeg.write_frames(str(path), size, fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                                       quality=None, output_params=["-crf", "26", "-preset", "fast",
                                                                    "-movflags", "+faststart", "-f", "mp4"],
                                       macro_block_size=16, ffmpeg_log_level="error")


CAMERA_VIEW_FPS = 15.0  # a recording's rendered frames per second of simulated time
CAMERA_VIEW_SIZE = (320, 240)
JPEG_QUALITY = 80  # about 10 kB a frame: a 10 s recording's camera view is about 1.5 MB


def camera_view_frames(traj: Trajectory, model: object, joint: str, source: str, camera: str | None = None,
                       twin: Trajectory | None = None) -> tuple[str, np.ndarray, list[bytes]]:
    """MuJoCo's rendered frames of ``traj`` for a recording: the camera's name, the frames'
    simulated times and the JPEG files' bytes (``CAMERA_VIEW_FPS``, ``CAMERA_VIEW_SIZE``)."""
    import io

    import mujoco
    from PIL import Image

    cid = camera_id(model, camera, source)  # type: ignore[arg-type]
    name = (DEFAULT_CAMERA_NAME if cid == DEFAULT_CAMERA
            else mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, cid) or f"camera{cid}")
    instants = _instants(traj, CAMERA_VIEW_FPS, twin)
    jpegs = []
    with FrameRenderer(model, joint, cid, *CAMERA_VIEW_SIZE,  # type: ignore[arg-type]
                       positions=_positions(instants)) as renderer:
        for instant in instants:
            buffer = io.BytesIO()
            Image.fromarray(renderer.render(instant)).save(buffer, format="JPEG", quality=JPEG_QUALITY)
            jpegs.append(buffer.getvalue())
    return name, np.array([i.t for i in instants]), jpegs


def write_video(request: VideoRequest, traj: Trajectory, model: object, joint: str, source: str,
                twin: Trajectory | None = None,
                progress: Callable[[int, int], None] | None = None) -> Path:
    """Render ``traj`` (posing ``joint`` of ``model``) and, with ``twin``, its ODE twin as a ghost,
    to ``request.path``; ``progress(done, total)`` after each frame. Returns the path."""
    cid = camera_id(model, request.camera, source)  # type: ignore[arg-type]
    instants = _instants(traj, request.fps, twin)
    width, height = request.frame_size
    with atomic_path(request.path) as tmp, FrameRenderer(model, joint, cid, width, height,  # type: ignore[arg-type]
                                                         positions=_positions(instants)) as renderer:
        writer = _writer(tmp, request.path.suffix.lower(), (width, height), request.fps)
        writer.send(None)  # start ffmpeg
        try:
            for done, instant in enumerate(instants, start=1):
                writer.send(np.ascontiguousarray(renderer.render(instant)))
                if progress is not None:
                    progress(done, len(instants))
        finally:
            writer.close()
    return request.path
