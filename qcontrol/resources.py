"""Where the shipped example scenarios and MJCF models are: inside the installed package
(``qcontrol/data/``, mapped there when the wheel is built), or, in a source checkout or an
editable install, the repository's top-level ``scenarios/`` and ``models/``."""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def shipped_dir(kind: str) -> Path:
    """The folder of the shipped ``"scenarios"`` or ``"models"``."""
    installed = _PACKAGE / "data" / kind
    return installed if installed.is_dir() else _PACKAGE.parent / kind


def shipped_scenarios() -> dict[str, Path]:
    """The shipped scenarios by name (the file name without ``.toml``)."""
    folder = shipped_dir("scenarios")
    if not folder.is_dir():
        return {}
    return {path.stem: path for path in sorted(folder.glob("*.toml"), key=lambda p: p.stem)}


def scenario_path(name_or_path: str | Path) -> Path:
    """A scenario file: ``name_or_path`` if it names a file (or anything but a bare name), else
    the shipped scenario of that name (``example2`` -> the shipped ``example2.toml``)."""
    path = Path(name_or_path)
    if path.exists() or path.suffix or len(path.parts) > 1:
        return path
    return shipped_scenarios().get(str(name_or_path), path)


SHIPPED = "qcontrol:"  # prefix of a file shipped with qcontrol: "qcontrol:models/pendulum.xml"


def shipped_label(path: Path) -> str | None:
    """``qcontrol:<kind>/<file>`` for a shipped scenario or model (the same on every machine and
    install), None for any other file."""
    path = Path(path).resolve()
    for kind in ("scenarios", "models"):
        folder = shipped_dir(kind).resolve()
        if path.parent == folder:
            return f"{SHIPPED}{kind}/{path.name}"
    return None


def resolve_file(value: str, base_dir: Path) -> Path:
    """A file a scenario names: ``qcontrol:models/<file>`` is a shipped model, anything else a
    path relative to the scenario file's folder ``base_dir``."""
    if value.startswith(SHIPPED):
        kind, _, name = value[len(SHIPPED):].partition("/")
        return (shipped_dir(kind) / name).resolve()
    return (Path(base_dir) / value).resolve()
