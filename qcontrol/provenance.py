"""Where an output came from: the versions, the command, the scenario file and its digest, the
overrides as given and the resolved scenario (the TOML that reproduces the run)."""

from __future__ import annotations

import hashlib
import platform
import shlex
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from ._version import __version__

_PACKAGES = ("mujoco", "rerun-sdk")


def versions() -> dict[str, str]:
    """The versions of qcontrol's scientific dependencies and of Python."""
    from importlib import metadata  # 10 ms to import: only when an output is written

    found = {"numpy": np.__version__, "python": platform.python_version()}
    for name in _PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return dict(sorted(found.items()))


def command_line(argv: Sequence[str] | None = None) -> str:
    """The command as a user would type it: ``qcontrol`` and its arguments (``argv``, or this
    process's)."""
    return shlex.join(["qcontrol", *(sys.argv[1:] if argv is None else argv)])


def sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def provenance(command: str, scenario_file: Any, scenario_sha256: Any, overrides: Any,
               resolved_scenario: Any) -> dict[str, Any]:
    """The ``provenance`` object of an output (for outputs of several scenarios the scenario
    fields map each scenario's name to its value)."""
    return {
        "qcontrol_version": __version__,
        "versions": versions(),
        "command": command,
        "scenario_file": scenario_file,
        "scenario_sha256": scenario_sha256,
        "overrides": overrides,
        "resolved_scenario": resolved_scenario,
    }
