"""What run and compare share for MuJoCo's own picture of a run: ``--video`` (a file), its frame
rate, size and camera, and ``--camera-view`` (the frames in the recording); each checked before
the run, the video written after it with a progress bar on a terminal."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from .. import api
from ..assembly import Assembly
from ..errors import QcontrolInputError
from ..progress import ProgressLine
from ..render.request import DEFAULT_FPS, FPS_RANGE, MAX_FRAMES, parse_size


def _video_size(text: str) -> tuple[int, int]:
    try:
        return parse_size(text)
    except QcontrolInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_rendering_options(p: argparse.ArgumentParser) -> None:
    """``--camera-view``, ``--video`` and its ``--video-fps``, ``--video-size``, ``--video-camera``."""
    p.add_argument("--camera-view", action="store_true",
                   help="with --rrd or --spawn: put MuJoCo's own rendering of the run beside the 3-D view "
                   "(JPEG frames, 15 per simulated second, 320x240: about 1.5 MB per 10 s)")
    p.add_argument("--video", type=Path, metavar="FILE",
                   help="render the run as MuJoCo draws it to FILE.mp4 or FILE.gif, headless (EGL or "
                   "OSMesa), after the run: about 1-2 s per simulated second at 30 fps on a CPU")
    p.add_argument("--video-fps", type=float, default=DEFAULT_FPS, metavar="N",
                   help=f"video frames per second of simulated time, {FPS_RANGE[0]:g} to {FPS_RANGE[1]:g} "
                   f"(default {DEFAULT_FPS:g}); a video has at most {MAX_FRAMES:,} frames")
    p.add_argument("--video-size", type=_video_size, metavar="WxH",
                   help="video frame size in pixels (default 640x480 for .mp4, 400x300 for .gif)")
    p.add_argument("--video-camera", metavar="NAME",
                   help="the model's camera to render from (default: its first named camera)")


def check_rendering(args: argparse.Namespace, run: Assembly) -> None:
    """Before the run ``run``: that --video and --camera-view can be made (one line and exit status 2)."""
    if args.video is not None:
        api.check_video(run, args.video, args.video_fps, args.video_camera, args.video_size)
    if args.camera_view:
        if args.rrd is None and not args.spawn:
            raise QcontrolInputError("--camera-view puts the rendering in a recording: add --rrd FILE "
                                     "(or --spawn)")
        api.check_camera_view(run)


def write_video(args: argparse.Namespace, result: api.Result, twin: api.Result | None = None) -> None:
    """Render ``--video`` (with ``twin`` as a ghost) and say what it cost."""
    if args.video is None:
        return
    progress = ProgressLine(f"video {args.video.name}", not args.quiet, unit="frames")
    started = time.perf_counter()
    path = api.video(result, args.video, fps=args.video_fps, camera=args.video_camera,
                     size=args.video_size, twin=twin, progress=progress)
    progress.finish()
    seconds = time.perf_counter() - started
    run = result.typed_summary
    simulated = max(run.steps * run.dt, 1e-9)
    print(f"  wrote {path} ({path.stat().st_size / 1e6:.2f} MB, rendered in {seconds:.1f} s: "
          f"{seconds / simulated:.2f} s per simulated second)")
