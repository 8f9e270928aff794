"""Laws from outside the package: a Python file that registers laws (``--law-module mylaws.py``)
and installed plugin packages, found through the entry-point group ``qcontrol.laws``.

A plugin package declares, in its ``pyproject.toml``::

    [project.entry-points."qcontrol.laws"]
    mylaws = "mylaws:register"      # a function called with no arguments, or a module: "mylaws"

and its function (or the module, as it is imported) calls :func:`qcontrol.register_law`. The
command line loads every installed plugin before it reads a scenario; from Python,
:func:`load_law_plugins` does the same.
"""

from __future__ import annotations

import importlib.util
import sys
from importlib.metadata import entry_points
from pathlib import Path

from ..errors import QcontrolInputError

ENTRY_POINT_GROUP = "qcontrol.laws"

_loaded_files: dict[Path, str] = {}  # file -> its module name, so a file given twice runs once
_loaded_plugins: set[str] = set()


def load_law_module(path: str | Path, option: str = "--law-module") -> str:
    """Run the Python file ``path`` (it registers laws with :func:`qcontrol.register_law`) as a
    module; its failures become one line naming the file. Returns the module's name. A file
    already loaded in this process is not run again."""
    if not isinstance(path, (str, Path)):
        raise QcontrolInputError(f"{option}: expected the path of a Python file, got {type(path).__name__}")
    file = Path(path).resolve()
    if file in _loaded_files:
        return _loaded_files[file]
    if not file.is_file() or file.suffix != ".py":
        raise QcontrolInputError(f"{option} {path}: no such Python file; give a .py file that registers laws "
                                 "with qcontrol.register_law")
    name = f"qcontrol_law_module_{len(_loaded_files)}_{file.stem}"
    spec = importlib.util.spec_from_file_location(name, file)
    assert spec is not None and spec.loader is not None  # a .py file always has a source loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look the module up by name
    try:
        spec.loader.exec_module(module)
    except QcontrolInputError as exc:
        del sys.modules[name]
        raise QcontrolInputError(f"{option} {path}: {exc}") from None
    except SystemExit as exc:  # sys.exit() at import: nothing was registered, and nothing is run
        del sys.modules[name]
        raise QcontrolInputError(f"{option} {path}: the file called sys.exit({exc.code!r}) while it was "
                                 f"imported{_line_of(exc, file)}; a law module only registers laws: remove "
                                 "the call") from None
    except Exception as exc:  # noqa: BLE001 -- any failure of the user's file is reported in one line
        del sys.modules[name]
        raise QcontrolInputError(f"{option} {path}: importing it failed ({type(exc).__name__}: {exc}"
                                 f"{_line_of(exc, file)}); fix the file") from None
    _loaded_files[file] = name
    return name


def _line_of(exc: BaseException, file: Path) -> str:
    tb, line = exc.__traceback__, None
    while tb is not None:
        if Path(tb.tb_frame.f_code.co_filename).resolve() == file:
            line = tb.tb_lineno
        tb = tb.tb_next
    return "" if line is None else f", line {line}"


def load_law_plugins() -> list[str]:
    """Load every installed plugin of the entry-point group ``qcontrol.laws`` (once per process):
    a module is imported, a function called with no arguments. Returns the names loaded now."""
    loaded = []
    for point in entry_points(group=ENTRY_POINT_GROUP):
        if point.name in _loaded_plugins:
            continue
        try:
            target = point.load()
            if callable(target):
                target()
        except QcontrolInputError as exc:
            raise QcontrolInputError(f"law plugin {point.name!r} ({point.value}): {exc}") from None
        except Exception as exc:  # noqa: BLE001 -- a broken plugin is reported in one line
            raise QcontrolInputError(f"law plugin {point.name!r} ({point.value}) failed to load "
                                     f"({type(exc).__name__}: {exc}); fix or uninstall it") from None
        _loaded_plugins.add(point.name)
        loaded.append(point.name)
    return loaded
