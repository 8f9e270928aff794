"""Shared test set-up: nothing may write under the real HOME (the rerun SDK keeps analytics there)."""

import os
import pathlib
import tempfile

_HOME = tempfile.mkdtemp(prefix="qcontrol-test-home-")
os.environ["HOME"] = _HOME
os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")
os.environ.setdefault("MPLBACKEND", "Agg")
# compiled code is cached beside pytest's own cache, so later sessions load it instead of compiling
_ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("QCONTROL_CACHE_DIR", str(_ROOT / ".pytest_cache" / "qcontrol-compiled"))
