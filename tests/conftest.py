"""Shared test set-up: nothing may write under the real HOME (the rerun SDK keeps analytics there)."""

import os
import tempfile

_HOME = tempfile.mkdtemp(prefix="qcontrol-test-home-")
os.environ["HOME"] = _HOME
os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")
os.environ.setdefault("MPLBACKEND", "Agg")
