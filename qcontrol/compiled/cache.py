"""Generated modules of numba code, kept in the user's cache folder.

A generated module's file name is a hash of its source text and of the versions that shape the
machine code (Python, numba, numpy, MuJoCo, qcontrol): the same text on the same versions is the
same file, and numba's own cache (``cache=True``) keeps the compiled code next to it, in its
``__pycache__``. Nothing is written into site-packages. ``QCONTROL_CACHE_DIR`` moves the folder.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import re
import sys
import tempfile
from pathlib import Path
from types import ModuleType

_LOADED: dict[str, ModuleType] = {}


def cache_folder() -> Path:
    """``$QCONTROL_CACHE_DIR``, else the platform's user cache folder + ``qcontrol/compiled``."""
    override = os.environ.get("QCONTROL_CACHE_DIR")
    if override:
        return Path(override)
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "qcontrol" / "compiled"


def versions() -> str:
    """The versions the generated code depends on, one line."""
    import mujoco
    import numba
    import numpy

    from .._version import __version__

    return (f"python {sys.version.split()[0]} numba {numba.__version__} numpy {numpy.__version__} "
            f"mujoco {mujoco.__version__} qcontrol {__version__}")


def _name(kind: str, source: str) -> str:
    """The module name of ``source``: its kind and a hash of the text and the versions."""
    key = hashlib.sha256(f"# {versions()}\n{source}".encode()).hexdigest()[:24]
    return f"qcontrol_{kind}_{key}"


def _atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a concurrent process sees the old file or the new one."""
    with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp", delete=False) as tmp:
        tmp.write(text)
    os.replace(tmp.name, path)


def generated_module(kind: str, source: str) -> ModuleType:
    """The module of ``source`` (written to the cache folder once, then imported from there)."""
    name = _name(kind, source)
    if name in _LOADED:
        return _LOADED[name]
    folder = cache_folder()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.py"
    if not path.is_file() or path.read_text() != source:
        _atomic(path, source)
    (folder / f"{name}.rows").unlink(missing_ok=True)  # compiled from now on (uncompiled_rows)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # numba's cache pickles references to the module by name
    spec.loader.exec_module(module)
    _LOADED[name] = module
    return module


def uncompiled_rows(kind: str, source: str) -> int | None:
    """The rows run so far without the module of ``source`` (0 when it was never met), kept in the
    cache folder by :func:`count_uncompiled`; None where it was compiled before (loaded in this
    process, or its text in the cache folder: numba's code beside it). Nothing is compiled or
    imported to tell."""
    name = _name(kind, source)
    if name in _LOADED:
        return None
    folder = cache_folder()
    try:
        return int((folder / f"{name}.rows").read_text())
    except FileNotFoundError:
        return None if (folder / f"{name}.py").is_file() else 0
    except ValueError:  # (not a count: counted afresh)
        return 0


def count_uncompiled(kind: str, source: str, rows: int) -> None:
    """Keep ``rows``, the rows run so far without the module of ``source``, in the cache folder."""
    folder = cache_folder()
    folder.mkdir(parents=True, exist_ok=True)
    _atomic(folder / f"{_name(kind, source)}.rows", str(rows))


def shared(kind: str, source: str) -> str:
    """The line importing the functions of ``source`` (module-level text of decorated functions)
    from a generated module of their own, compiled once and kept in the cache like any other,
    then linked into each generated module that imports them instead of compiled again in each.
    Its name is the hash of its text, so an importer's text (and its cache entry) changes with it."""
    names = re.findall(r"^def (\w+)\(", source, flags=re.MULTILINE)
    module = generated_module(kind, "import math\n\nimport numba\nimport numpy as np\n\n"
                                    f"from qcontrol.compiled.pointers import opaque\n\n{source}")
    return f"from {module.__name__} import {', '.join(names)}"
