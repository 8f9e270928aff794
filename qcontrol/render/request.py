"""What ``--video`` asks for, checked before the run: the file and its format, the frame rate
(within :data:`FPS_RANGE`), the frame size and the frame count (at most :data:`MAX_FRAMES`). No
MuJoCo here: the command line's options and the checks before a run need none of the rendering
(:mod:`.video`, :mod:`.frames`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import QcontrolInputError, shown
from ..outputs import check_output_file

DEFAULT_FPS = 30.0
VIDEO_FORMATS = (".mp4", ".gif")
SIZES = {".mp4": (640, 480), ".gif": (400, 300)}  # a GIF is for a web page: smaller
FPS_RANGE = (1.0, 240.0)  # frames per second of simulated time a video may ask for
MAX_FRAMES = 36_000  # 20 minutes of simulated time at 30 fps: about 10-20 hours of rendering on a CPU


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


def frame_count(duration: float, fps: float) -> int:
    """How many frames a run of ``duration`` simulated seconds gives at ``fps`` (:func:`frame_rows`)."""
    return int(np.floor(duration * fps + 1e-9)) + 1


def check_video_request(path: str | Path, fps: float, camera: str | None = None,
                        size: tuple[int, int] | None = None, duration: float | None = None) -> VideoRequest:
    """One line (a :class:`QcontrolInputError`) for a video that cannot be written, before the run:
    its format, its folder, the frame rate (within :data:`FPS_RANGE`) and, for a run of
    ``duration`` seconds, the frame count (at most :data:`MAX_FRAMES`)."""
    path = check_output_file(path, "--video")
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise QcontrolInputError(f"--video {shown(path)}: unknown format {path.suffix!r}; "
                                 "give a .mp4 or .gif file")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not np.isfinite(fps) or fps <= 0:
        raise QcontrolInputError(f"--video-fps must be > 0, got {fps!r}")
    low, high = FPS_RANGE
    if not low <= fps <= high:
        raise QcontrolInputError(f"--video-fps {fps!r}: must be {low:g} to {high:g} frames per simulated "
                                 f"second; e.g. --video-fps {DEFAULT_FPS:g}")
    if duration is not None and frame_count(duration, fps) > MAX_FRAMES:
        raise QcontrolInputError(
            f"--video: {duration:g} s at {fps:g} fps is {frame_count(duration, fps):,} frames, more than the "
            f"{MAX_FRAMES:,} a video may have; lower --video-fps or --duration")
    return VideoRequest(path, float(fps), camera, size)
