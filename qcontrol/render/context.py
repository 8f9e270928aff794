"""An offscreen OpenGL context for MuJoCo's renderer, headless: EGL first, then OSMesa.

``MUJOCO_GL=egl`` or ``MUJOCO_GL=osmesa`` picks one. Otherwise EGL is used when its library is
installed (Mesa's software rasterizer is enough: no GPU, no display), else OSMesa. PyOpenGL chooses
its platform once per process, so the choice is made once and kept. Without either library the
caller gets one line naming the Debian/Ubuntu packages to install.
"""

from __future__ import annotations

import ctypes.util
import os
from functools import lru_cache
from typing import Any

from ..errors import QcontrolInputError

INSTALL_HINT = ("install the system packages libegl1, libegl-mesa0 and libgl1-mesa-dri (Debian/Ubuntu: "
                "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri), or libosmesa6 and set "
                "MUJOCO_GL=osmesa")
_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}


def _candidates() -> list[str]:
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if chosen in _LIBRARIES:
        return [chosen]
    return [name for name, library in _LIBRARIES.items() if ctypes.util.find_library(library)]


@lru_cache(maxsize=1)
def _context_class() -> tuple[str, Any]:
    """The platform in use and its GLContext class (imported once: PyOpenGL binds one platform)."""
    candidates = _candidates()
    if not candidates:
        raise QcontrolInputError(f"--video needs an offscreen OpenGL library and none was found: "
                                 f"{INSTALL_HINT}")
    name = candidates[0]
    try:
        if name == "egl":
            from mujoco.egl import GLContext
        else:
            from mujoco.osmesa import GLContext
    except (ImportError, OSError, AttributeError) as exc:
        raise QcontrolInputError(f"--video: the {name.upper()} OpenGL platform cannot be loaded ({exc}); "
                                 f"{INSTALL_HINT}") from None
    return name, GLContext


def open_context(width: int, height: int) -> Any:
    """A current offscreen GL context of at least ``width`` x ``height`` (free it with ``.free()``)."""
    name, context_class = _context_class()
    try:
        context = context_class(width, height)
        context.make_current()
    except Exception as exc:  # EGL/OSMesa report a missing driver as assorted errors
        raise QcontrolInputError(f"--video: could not open an offscreen {name.upper()} context ({exc}); "
                                 f"{INSTALL_HINT}") from None
    return context


def require_offscreen_gl() -> str:
    """Check, before a run starts, that an offscreen context opens; the platform's name."""
    open_context(16, 16).free()
    return _context_class()[0]
