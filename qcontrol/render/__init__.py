"""MuJoCo's own picture of a run: the model rendered offscreen, headless, frame by frame.

:mod:`.request` checks what ``--video`` asks for before the run (no MuJoCo: importing this
package imports none); :mod:`.context` opens an offscreen OpenGL context (EGL, then OSMesa) or says
which system package is missing; :mod:`.frames` poses the model at the recorded states and renders
it from the model's named camera with an overlay (t, q(x1), u) and, for a comparison, the ODE twin
as a translucent ghost; :mod:`.video` samples a finished run at a rate of simulated time and
encodes the frames (MP4 or GIF) through imageio-ffmpeg. Rendering only reads a run's trajectory:
the physics never sees it.
"""

from .context import require_offscreen_gl
from .request import DEFAULT_FPS, VIDEO_FORMATS, check_video_request

__all__ = ["DEFAULT_FPS", "VIDEO_FORMATS", "check_video_request", "require_offscreen_gl"]
