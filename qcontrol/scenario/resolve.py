"""A scenario as it was run: the TOML after overrides (with its name written out and file paths
made absolute, or ``qcontrol:models/...`` for a model shipped with qcontrol, so the text reproduces
the run from any folder), and the provenance of an output."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import tomli_w

from ..plants.backends import BACKENDS
from ..provenance import provenance, sha256
from ..resources import resolve_file, shipped_label
from .load import Scenario, plain_data


def resolved_toml(sc: Scenario) -> str:
    """The scenario after its overrides, as TOML: running it gives the same run."""
    data = plain_data(sc.data)
    data.setdefault("scenario", {})["name"] = sc.name
    plant = data.get("plant", {})
    for name, backend in BACKENDS.items():
        section = plant.get(name)
        if backend.section is None or not isinstance(section, dict):
            continue
        for key in backend.section.keys:
            if key.type.path and isinstance(section.get(key.name), str):
                section[key.name] = _portable(resolve_file(section[key.name], sc.base_dir))
    return tomli_w.dumps(data)


def overrides_as_given(sc: Scenario) -> list[Any]:
    """The overrides as the user gave them: ``{"unset": key}`` for each key removed (``--unset``,
    applied first), then ``"key=value"`` strings and ``{key: value}`` for a dict's entries."""
    return [{"unset": key} for key in sc.unset] + [
        item if isinstance(item, str) else {item[0]: item[1]} for item in sc.overrides]


def _portable(path: Path) -> str:
    """A file as provenance names it: ``qcontrol:<kind>/<file>`` if it ships with qcontrol (the
    same on every machine), else its absolute path."""
    return shipped_label(path) or str(path.resolve())


def scenario_file(sc: Scenario) -> str:
    """The scenario's file (see :func:`_portable`), or its source label (e.g. ``<string>``)."""
    path = Path(sc.source)
    return _portable(path) if path.is_file() else sc.source


def scenario_provenance(sc: Scenario, command: str) -> dict[str, Any]:
    """The ``provenance`` object of an output made from the one scenario ``sc``."""
    return provenance(command, scenario_file(sc), sha256(sc.text), overrides_as_given(sc), resolved_toml(sc))


def scenarios_provenance(scenarios: dict[str, Scenario], command: str) -> dict[str, Any]:
    """The ``provenance`` of an output made from several scenarios: each scenario field maps the
    scenarios' labels to their values."""
    return provenance(
        command,
        {label: scenario_file(sc) for label, sc in scenarios.items()},
        {label: sha256(sc.text) for label, sc in scenarios.items()},
        {label: overrides_as_given(sc) for label, sc in scenarios.items()},
        {label: resolved_toml(sc) for label, sc in scenarios.items()},
    )
