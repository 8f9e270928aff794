"""Starting a rerun viewer for ``--spawn``: is there a display to open it on, and did it start?

Both are answered before a run starts, so that ``--spawn`` without a usable display is one line
and exit status 2 within a second or two, never a run that streams into nothing. The viewer is
started as its own detached process with its output sent to /dev/null: its logs never reach the
user's terminal, and it stays open after the run ends. A viewer already listening on the port
(e.g. one the user opened) is reused. This module does not import rerun.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path

from ..errors import QcontrolInputError

PORT = 9876  # rerun's default viewer port
START_TIMEOUT = 2.0  # seconds for the viewer to listen on its port
SETTLE = 0.3  # seconds the viewer must stay up after it listens (it opens its window then)
CONNECT_TIMEOUT = 0.5  # seconds to reach a display or a port
NO_VIEWER_FIX = "write the recording with --rrd FILE and open it with `rerun FILE` where there is a display"


def viewer_url() -> str:
    """Where a recording streams to the viewer (port :data:`PORT`)."""
    return f"rerun+http://127.0.0.1:{PORT}/proxy"


def viewer_executable() -> str | None:
    """The rerun viewer: on PATH, else beside this interpreter (a venv not on PATH), else None."""
    found = shutil.which("rerun")
    if found is None:
        beside = Path(sys.executable).with_name("rerun")
        found = str(beside) if beside.exists() else None
    return found


def display_problem(env: Mapping[str, str] | None = None, platform: str = sys.platform) -> str | None:
    """Why no window can be opened here (X11 or Wayland on Linux and the BSDs), or None.

    A display named in ``DISPLAY`` or ``WAYLAND_DISPLAY`` must accept a connection: a variable left
    over from another session is no display."""
    env = os.environ if env is None else env
    if not platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return None  # macOS and Windows always have a window system
    if env.get("WAYLAND_SOCKET"):
        return None
    wayland, x11 = env.get("WAYLAND_DISPLAY", ""), env.get("DISPLAY", "")
    if not wayland and not x11:
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    if wayland and _wayland_reachable(wayland, env.get("XDG_RUNTIME_DIR", "")):
        return None
    if x11 and _x11_reachable(x11):
        return None
    named = " or ".join(f"{name}={value}" for name, value in (("DISPLAY", x11), ("WAYLAND_DISPLAY", wayland))
                        if value)
    return f"the display {named} cannot be reached"


def _connects(family: int, address: str | tuple[str, int]) -> bool:
    try:
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            sock.settimeout(CONNECT_TIMEOUT)
            sock.connect(address)
        return True
    except OSError:
        return False


def _x11_reachable(display: str) -> bool:
    """``:0``, ``unix:0`` (a local socket) or ``host:10.0`` (TCP port 6000 + 10)."""
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return False
    if host in ("", "unix"):
        path = f"/tmp/.X11-unix/X{number}"
        return _connects(socket.AF_UNIX, path) or _connects(socket.AF_UNIX, "\0" + path)
    return _connects(socket.AF_INET, (host, 6000 + int(number)))


def _wayland_reachable(name: str, runtime_dir: str) -> bool:
    path = name if name.startswith("/") else os.path.join(runtime_dir, name)
    return bool(runtime_dir or name.startswith("/")) and _connects(socket.AF_UNIX, path)


def listening(port: int) -> bool:
    """Whether something (a viewer) accepts connections on ``port`` on this machine."""
    return _connects(socket.AF_INET, ("127.0.0.1", port))


def start_viewer(port: int | None = None, executable: str | None = None) -> subprocess.Popen | None:
    """Make sure a viewer listens on ``port`` (default :data:`PORT`): reuse one that does, or
    start one (detached, its output discarded) and wait until it listens and stays up. Returns the
    started process (None when one was reused); any failure is one :class:`QcontrolInputError`
    line naming ``--spawn``."""
    port = PORT if port is None else port
    if listening(port):
        return None
    problem = display_problem()
    if problem is not None:
        raise QcontrolInputError(f"--spawn: cannot open the rerun viewer: {problem}; {NO_VIEWER_FIX}")
    executable = executable or viewer_executable()
    if executable is None:
        raise QcontrolInputError("--spawn: the rerun viewer is not installed (no `rerun` on PATH or beside "
                                 f"this Python); install rerun-sdk, or {NO_VIEWER_FIX}")
    command = [executable, "--port", str(port), "--memory-limit", "75%", "--expect-data-soon"]
    try:
        process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError as exc:
        raise QcontrolInputError(f"--spawn: cannot start {executable} ({exc.strerror or exc}); "
                                 f"{NO_VIEWER_FIX}") from None
    _wait_until_up(process, port)
    return process


def _wait_until_up(process: subprocess.Popen, port: int) -> None:
    """Wait for the viewer to listen and to stay up for :data:`SETTLE` s; stop it on failure."""
    deadline = time.monotonic() + START_TIMEOUT
    up_since = None
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise QcontrolInputError(f"--spawn: the rerun viewer exited at once (status "
                                     f"{process.returncode}: it could not open a window); {NO_VIEWER_FIX}")
        if up_since is None and listening(port):
            up_since = time.monotonic()
        if up_since is not None and time.monotonic() - up_since >= SETTLE:
            return
        time.sleep(0.05)
    process.kill()
    process.wait()
    raise QcontrolInputError(f"--spawn: the rerun viewer did not start within {START_TIMEOUT:g} s; "
                             f"{NO_VIEWER_FIX}")
