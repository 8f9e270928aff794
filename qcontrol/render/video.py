"""A run as a video: the finished trajectory sampled at a rate of simulated time, rendered by
:mod:`.frames`, encoded to MP4 (H.264) or GIF by the ffmpeg that the imageio-ffmpeg wheel ships.

imageio-ffmpeg is a small wrapper around a static ffmpeg binary in its wheel (no system codec, no
download at run time); frames are piped to it as raw RGB. A GIF gets its own 256-colour palette
(ffmpeg's palettegen/paletteuse), which keeps the README's animation small and sharp.

The video is an output like the others (:mod:`qcontrol.outputs`): written under a temporary name
of its own, checked complete (the encoder's exit status and its errors, then the container read
back and its frames counted) and only then moved over the final name. An encoder that fails (a
full disk among others) is a :class:`~qcontrol.errors.QcontrolOutputError` naming the file and
the cause; an interrupted render leaves nothing under the final name, and a previous video there
is never touched. The frame rate and the frame count are bounded before the run
(:mod:`.request`).
"""

from __future__ import annotations

import errno
import os
import subprocess
import tempfile
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import IO

import numpy as np

from ..engine import Trajectory
from ..errors import QcontrolOutputError, shown
from ..outputs import atomic_path, output_dir, output_error
from .frames import DEFAULT_CAMERA, DEFAULT_CAMERA_NAME, FrameRenderer, Instant, camera_id
from .request import VideoRequest, frame_count


def frame_rows(traj: Trajectory, fps: float) -> np.ndarray:
    """The rows shown: the one at or just before each instant i / fps of simulated time, up to
    the run's last row (a diverged run's video ends where it stopped)."""
    dt = float(traj.t[1] - traj.t[0]) if len(traj.t) > 1 else 1.0
    count = frame_count(float(traj.t[-1]), fps)
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


def _encoder_command(path: Path, suffix: str, size: tuple[int, int], fps: float) -> list[str]:
    """The ffmpeg command that reads raw RGB frames on its stdin and writes ``path`` in the format
    of ``suffix`` (the final name's: ``path`` is a temporary one)."""
    import imageio_ffmpeg

    width, height = size
    rate = str(Fraction(fps).limit_denominator())
    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-f", "rawvideo", "-vcodec", "rawvideo",
               "-s", f"{width:d}x{height:d}", "-pix_fmt", "rgb24", "-r", rate, "-i", "-", "-an"]
    if suffix == ".gif":
        palette = ("split[a][b];[a]palettegen=stats_mode=diff[p];"
                   "[b][p]paletteuse=dither=none:diff_mode=rectangle")
        return [*command, "-vcodec", "gif", "-pix_fmt", "pal8", "-v", "error",
                "-filter_complex", palette, "-f", "gif", str(path)]
    command += ["-vcodec", "libx264", "-pix_fmt", "yuv420p"]
    if width % 16 or height % 16:  # H.264 players want whole macro blocks: scale up to them
        command += ["-vf", f"scale={width + -width % 16}:{height + -height % 16}"]
    return [*command, "-v", "error", "-crf", "26", "-preset", "fast", "-movflags", "+faststart",
            "-f", "mp4", str(path)]


def _encoder_failure(path: Path, log: IO[bytes], what: str) -> QcontrolOutputError:
    """The encoder's failure as one line naming the final file: a full disk as the other outputs
    name it, anything else with the encoder's last message."""
    log.seek(0)
    lines = [line.strip() for line in log.read().decode(errors="replace").splitlines() if line.strip()]
    if any("No space left" in line or "Disk quota" in line for line in lines):
        return output_error(path, OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))
    last = shown(lines[-1][:200]) if lines else "no message"
    return QcontrolOutputError(errno.EIO, f"{shown(path)}: cannot write the video ({what}: {last}); "
                                          "check the disk or write elsewhere (nothing was replaced)")


class _Encoder:
    """ffmpeg fed frames on its stdin; :meth:`finish` waits for it and checks its exit status and
    the file it wrote. Every exit path ends the process."""

    def __init__(self, path: Path, final: Path, size: tuple[int, int], fps: float) -> None:
        self.path, self.final = path, final
        self.log = tempfile.TemporaryFile()
        self.process = subprocess.Popen(_encoder_command(path, final.suffix.lower(), size, fps),
                                        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self.log,
                                        start_new_session=True)  # Ctrl-C reaches qcontrol, which ends it

    def send(self, frame: np.ndarray) -> None:
        try:
            self.process.stdin.write(np.ascontiguousarray(frame).data)  # type: ignore[union-attr]
        except (BrokenPipeError, OSError):
            self.process.wait()
            raise _encoder_failure(self.final, self.log, f"the encoder stopped, exit status "
                                   f"{self.process.returncode}") from None

    def finish(self, frames: int) -> None:
        """Close the input, wait, and check the exit status and that the file holds ``frames``."""
        try:
            self.process.stdin.close()  # type: ignore[union-attr]
        except OSError:
            pass
        status = self.process.wait()
        if status != 0:
            raise _encoder_failure(self.final, self.log, f"the encoder's exit status {status}")
        counted = _frames_in(self.path)
        if counted != frames:
            raise QcontrolOutputError(errno.EIO, f"{shown(self.final)}: the video written holds {counted} "
                                      f"frames of {frames}; check the disk or write elsewhere "
                                      "(nothing was replaced)")

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.log.close()


def _frames_in(path: Path) -> int:
    """The frames of the video at ``path`` as ffmpeg reads its container back (its packets, not
    decoded); -1 when it cannot be read."""
    import imageio_ffmpeg

    try:
        return int(imageio_ffmpeg.count_frames_and_secs(str(path))[0])
    except (RuntimeError, OSError, ValueError, subprocess.CalledProcessError):
        return -1


CAMERA_VIEW_FPS = 15.0  # a recording's rendered frames per second of simulated time
CAMERA_VIEW_SIZE = (320, 240)
JPEG_QUALITY = 80  # about 10 kB a frame: a 10 s recording's camera view is about 1.5 MB


def camera_view_frames(traj: Trajectory, model: object, joint: str, source: str, camera: str | None = None,
                       twin: Trajectory | None = None, order: int = 2,
                       input_gain: float = 1.0) -> tuple[str, np.ndarray, list[bytes]]:
    """MuJoCo's rendered frames of ``traj`` for a recording: the camera's name, the frames'
    simulated times and the JPEG files' bytes (``CAMERA_VIEW_FPS``, ``CAMERA_VIEW_SIZE``);
    ``order`` and ``input_gain``: the plant's, for the overlay's unit of u."""
    import io

    import mujoco
    from PIL import Image

    cid = camera_id(model, camera, source)  # type: ignore[arg-type]
    name = (DEFAULT_CAMERA_NAME if cid == DEFAULT_CAMERA
            else mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, cid) or f"camera{cid}")
    instants = _instants(traj, CAMERA_VIEW_FPS, twin)
    jpegs = []
    with FrameRenderer(model, joint, cid, *CAMERA_VIEW_SIZE,  # type: ignore[arg-type]
                       positions=_positions(instants), order=order, input_gain=input_gain) as renderer:
        for instant in instants:
            buffer = io.BytesIO()
            Image.fromarray(renderer.render(instant)).save(buffer, format="JPEG", quality=JPEG_QUALITY)
            jpegs.append(buffer.getvalue())
    return name, np.array([i.t for i in instants]), jpegs


def write_video(request: VideoRequest, traj: Trajectory, model: object, joint: str, source: str,
                twin: Trajectory | None = None,
                progress: Callable[[int, int], None] | None = None, order: int = 2,
                input_gain: float = 1.0) -> Path:
    """Render ``traj`` (posing ``joint`` of ``model``) and, with ``twin``, its ODE twin as a ghost,
    to ``request.path``; ``progress(done, total)`` after each frame; ``order`` and ``input_gain``:
    the plant's, for the overlay's unit of u. Returns the path."""
    cid = camera_id(model, request.camera, source)  # type: ignore[arg-type]
    instants = _instants(traj, request.fps, twin)
    width, height = request.frame_size
    folder = request.path.parent if str(request.path.parent) else Path(".")
    renderer = FrameRenderer(model, joint, cid, width, height,  # type: ignore[arg-type]
                             positions=_positions(instants), order=order, input_gain=input_gain)
    with output_dir(folder, "--video"), atomic_path(request.path) as tmp, renderer:
        encoder = _Encoder(tmp, request.path, (width, height), request.fps)
        try:
            for done, instant in enumerate(instants, start=1):
                encoder.send(renderer.render(instant))
                if progress is not None:
                    progress(done, len(instants))
            encoder.finish(len(instants))
        finally:
            encoder.close()
    return request.path
