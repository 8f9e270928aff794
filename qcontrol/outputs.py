"""Writing results: output folders checked before anything runs, and every file written atomically
(a temporary name in the same folder, then ``os.replace``)."""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from .errors import QcontrolInputError


def check_output_dir(path: str | Path, option: str = "--out") -> Path:
    """Check, without creating anything, that ``path`` is a writable folder or can be made one
    (its nearest existing ancestor is a writable folder); bad paths are input errors naming the
    command-line ``option`` they came from. Commands call this before they run and create the
    folder only when they write into it, so bad input leaves nothing behind."""
    path = Path(path)
    existing = path
    while not existing.exists() and existing != existing.parent:
        if existing.is_symlink():  # a dangling link: mkdir would fail on it
            break
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        raise QcontrolInputError(
            f"{option} {path}: cannot create the folder ({existing} is a file, not a folder); "
            "choose a writable folder"
        )
    if not existing.exists():
        raise QcontrolInputError(f"{option} {path}: cannot create the folder ({existing} is a broken link); "
                                 "choose a writable folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "folder is not writable" if existing == path else f"{existing} is not writable"
        raise QcontrolInputError(f"{option} {path}: {what}; choose a writable folder")
    return path


def prepare_output_dir(path: str | Path, option: str = "--out") -> Path:
    """Create ``path`` (and parents) and check it is writable; bad paths are input errors
    naming the command-line ``option`` they came from."""
    path = check_output_dir(path, option)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise QcontrolInputError(
            f"{option} {path}: cannot create the folder ({exc.strerror}); choose a writable folder"
        ) from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise QcontrolInputError(f"{option} {path}: folder is not writable; choose a writable folder")
    return path


def check_output_file(path: str | Path, option: str) -> Path:
    """Check, without creating anything, that an output file can be written: it is not a folder
    and its folder exists or can be made, writable."""
    path = Path(path)
    if path.is_dir():
        raise QcontrolInputError(f"{option} {path}: is a folder; give a file name such as run.rrd")
    check_output_dir(path.parent if str(path.parent) else Path("."), option)
    return path


def _umask() -> int:
    """The process umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


class AtomicFile:
    """A result written under a temporary name in its own folder, then moved into place with
    ``os.replace``: a reader never sees half a file under the final name.

    The temporary file is made with the permissions an ordinary ``open()`` would give
    (``mkstemp`` makes it private, 0600), or, with ``temporary``, is left to the writer to create
    (a recording streams to ``<name>.part``). A file that cannot be created or moved into place
    (e.g. the path is a folder, or its folder vanished) is a :class:`QcontrolInputError` naming
    the path, so the command line reports it as one line.
    """

    def __init__(self, path: str | Path, temporary: Path | None = None) -> None:
        self.path = Path(path)
        folder = self.path.parent if str(self.path.parent) else Path(".")
        if temporary is not None:
            self.temporary = temporary
            return
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".part", dir=folder)
        except OSError as exc:
            raise QcontrolInputError(
                f"{self.path}: cannot create a file in {folder} ({exc.strerror or exc}); "
                "choose a writable folder"
            ) from None
        self.temporary = Path(tmp)
        try:
            os.fchmod(fd, 0o666 & ~_umask())
        finally:
            os.close(fd)

    def commit(self) -> None:
        """Move the written file into place."""
        try:
            os.replace(self.temporary, self.path)
        except OSError as exc:
            self.discard()
            raise QcontrolInputError(
                f"{self.path}: cannot write the result ({exc.strerror or exc}); "
                "remove what is in the way or choose another folder"
            ) from None

    def discard(self) -> None:
        self.temporary.unlink(missing_ok=True)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on an exception it
    is removed."""
    file = AtomicFile(path)
    try:
        yield file.temporary
        file.commit()
    finally:
        file.discard()


def clean(value: Any) -> Any:
    """JSON has no NaN/Inf: write them as null. numpy scalars and arrays become plain Python."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    return value


def write_json(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as indented JSON, atomically."""
    path = Path(path)
    return write_text(path, json.dumps(clean(obj), indent=2, allow_nan=False) + "\n")


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        try:
            tmp.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise QcontrolInputError(
                f"{path}: cannot write the result ({exc.strerror or exc}); free some space or choose "
                "another folder"
            ) from None
    return path
