"""Writing results: every file qcontrol writes goes through this module.

The guarantees (docs/reliability.md, 'What qcontrol does with its outputs', states them for users):

* An output name must be a regular file or a new name. A folder, a device, a FIFO, a socket or
  a symbolic-link loop at an output name is refused before the run (:func:`check_output_file`),
  so is a name that no file system takes (a NUL byte, a component over 255 bytes).
* A file is written under a temporary name of its own in the target folder
  (``.NAME.<random>.tmp``, created exclusively with ``O_EXCL | O_NOFOLLOW``: never an existing
  file, never through a symbolic link), flushed and fsynced, then moved over the final name with
  ``os.replace`` only when it is complete (a recording: only once it reads back, footer
  included). A reader never sees half a file under the final name.
* A write that fails (no space left, an I/O error, no permission) is a
  :class:`~qcontrol.errors.QcontrolOutputError` naming the file and the cause; the temporary file
  is removed and the previous file at that name is untouched.
* Every exit path (success, error, Ctrl-C, SIGTERM) removes the temporaries it made and nothing
  else; what an interrupted recording holds is kept under its partial name (:func:`partial_path`).
"""

from __future__ import annotations

import atexit
import errno
import json
import math
import os
import secrets
import stat
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np

from .errors import QcontrolInputError, QcontrolOutputError, shown
from .interrupts import stop_if_asked

MAX_NAME_BYTES = 255  # one path component, as Linux, macOS and Windows file systems take it
MAX_PATH_BYTES = 4096
FIGURE_FORMATS = (".png", ".pdf", ".svg")  # what a figure's suffix may be (matplotlib writes each)
_LIVE: set[Path] = set()  # temporaries made by this process and not yet moved or removed
_STAGING = threading.local()  # .files: this thread's files written inside staged(), moved at its end


def check_name(path: str | Path, option: str) -> Path:
    """Refuse, as one line naming ``option``, a path no file system takes: a NUL byte, a
    component longer than :data:`MAX_NAME_BYTES` bytes, or a path longer than :data:`MAX_PATH_BYTES`."""
    text = os.fspath(path)
    if "\0" in text:
        raise QcontrolInputError(f"{option} {shown(text)}: the path contains a NUL byte; remove it")
    encoded = os.fsencode(text)
    if len(encoded) > MAX_PATH_BYTES:
        raise QcontrolInputError(f"{option} {shown(text[:60])}...: the path is longer than {MAX_PATH_BYTES} "
                                 "bytes; choose a shorter one")
    for part in encoded.split(b"/"):
        if len(part) > MAX_NAME_BYTES:
            raise QcontrolInputError(
                f"{option} {shown(text[:60])}...: a name in the path is {len(part)} bytes, longer than the "
                f"{MAX_NAME_BYTES} a file system takes; choose a shorter name")
    return Path(path)


def path_kind(path: str | Path) -> str | None:
    """What is at ``path`` when it is not a regular file: "a folder", "a character device", "a
    FIFO (named pipe)", ...; None for a regular file or a name where nothing is (symbolic links
    followed; a dangling one is nothing)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symbolic link loop"
        if exc.errno == errno.ENOTDIR:
            return "inside something that is not a folder"
        return f"unreadable ({exc.strerror})"
    if stat.S_ISREG(mode):
        return None
    kinds = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
             (stat.S_ISSOCK, "a socket"))
    return next((name for test, name in kinds if test(mode)), "not a regular file")


def check_output_dir(path: str | Path, option: str = "--out") -> Path:
    """Check, without creating anything, that ``path`` is a writable folder or can be made one
    (its nearest existing ancestor is a writable folder); bad paths are input errors naming the
    command-line ``option`` they came from. Commands call this before they run and create the
    folder only when they write into it, so bad input leaves nothing behind."""
    path = check_name(path, option)
    existing = path
    while not existing.exists() and existing != existing.parent:
        if existing.is_symlink():  # a dangling link (or a loop): mkdir would fail on it
            break
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        raise QcontrolInputError(
            f"{option} {shown(path)}: cannot create the folder ({shown(existing)} is {path_kind(existing)}, "
            "not a folder); choose a writable folder"
        )
    if not existing.exists():
        what = path_kind(existing) or "a broken link"
        raise QcontrolInputError(f"{option} {shown(path)}: cannot create the folder ({shown(existing)} is "
                                 f"{what}); choose a writable folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "folder is not writable" if existing == path else f"{shown(existing)} is not writable"
        raise QcontrolInputError(f"{option} {shown(path)}: {what}; choose a writable folder")
    return path


def prepare_output_dir(path: str | Path, option: str = "--out") -> Path:
    """Create ``path`` (and parents) and check it is writable; bad paths are input errors
    naming the command-line ``option`` they came from."""
    path = check_output_dir(path, option)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise QcontrolInputError(
            f"{option} {shown(path)}: cannot create the folder ({exc.strerror}); choose a writable folder"
        ) from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise QcontrolInputError(f"{option} {shown(path)}: folder is not writable; choose a writable folder")
    return path


@contextmanager
def output_dir(path: str | Path, option: str = "--out") -> Iterator[Path]:
    """:func:`prepare_output_dir` for a block that writes into the folder: when the block fails
    (bad input found only while running, a write error, Ctrl-C) the folders it made are removed
    again if they hold nothing, so a command that fails leaves nothing behind."""
    path = Path(path)
    made = []
    missing = path
    while not missing.exists() and missing != missing.parent:
        made.append(missing)
        missing = missing.parent
    folder = prepare_output_dir(path, option)
    try:
        yield folder
    except BaseException:
        for created in made:  # innermost first
            try:
                created.rmdir()
            except OSError:
                break
        raise


def check_output_file(path: str | Path, option: str, example: str | None = None,
                      fix: str | None = None) -> Path:
    """Check, without creating anything, that an output file can be written: its name is a
    regular file or free (not a folder, a device, a FIFO, a socket, a link loop) and its folder
    exists or can be made, writable."""
    path = check_name(path, option)
    kind = path_kind(path)
    if kind is not None:
        fix = fix or f"give a file name such as {example or 'run' + (path.suffix or '.rrd')}"
        raise QcontrolInputError(f"{option} {shown(path)}: is {kind}, not a regular file; qcontrol writes "
                                 f"only regular files: {fix}")
    check_output_dir(path.parent if str(path.parent) else Path("."), option)
    return path


def check_figure_file(path: str | Path, option: str) -> Path:
    """:func:`check_output_file` for a figure, whose suffix must be one of :data:`FIGURE_FORMATS`."""
    path = check_output_file(path, option, "run.png")  # a folder there is named as one first
    if path.suffix.lower() not in FIGURE_FORMATS:
        suffix = path.suffix or "(none)"
        raise QcontrolInputError(f"{option} {shown(path)}: unknown figure format {suffix!r}; "
                                 f"give a file ending in {', '.join(FIGURE_FORMATS)}")
    return path


def partial_path(path: str | Path) -> Path:
    """Where an interrupted or failed output keeps what it holds: ``r.rrd`` -> ``r.partial.rrd``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.partial{path.suffix}")


def output_error(path: str | Path, exc: OSError) -> QcontrolOutputError:
    """One line naming the file, the cause and the fix."""
    code = exc.errno
    if code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        cause, fix = "no space left on the device", "free some space or write elsewhere"
    elif code == errno.EIO:
        cause, fix = "input/output error", "check the disk or write elsewhere"
    elif code in (errno.EACCES, errno.EPERM, errno.EROFS):
        cause, fix = exc.strerror or "permission denied", "choose a writable folder"
    else:
        cause, fix = exc.strerror or str(exc), "choose another folder"
    error = QcontrolOutputError(code, f"{shown(path)}: cannot write ({cause}); {fix} (nothing was replaced)")
    error.filename = str(path)
    return error


def _create_temporary(path: Path) -> tuple[Path, int]:
    """A new file beside ``path`` (``.NAME.<random>.tmp``), created exclusively and never through a
    symbolic link, with the permissions an ordinary ``open()`` gives."""
    folder = path.parent if str(path.parent) else Path(".")
    stem = os.fsencode(path.name)[:200].decode(errors="ignore")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
    for _ in range(100):
        temporary = folder / f".{stem}.{secrets.token_hex(6)}.tmp"
        try:
            fd = os.open(temporary, flags, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise output_error(path, exc) from None
        _LIVE.add(temporary)
        return temporary, fd
    raise QcontrolOutputError(errno.EEXIST, f"{shown(path)}: cannot make a temporary name beside it; "
                                            "clean the folder of .*.tmp files")


@atexit.register
def _remove_live_temporaries() -> None:
    """On the interpreter's exit: remove temporaries an unusual exit path left (e.g. a thread)."""
    for temporary in list(_LIVE):
        temporary.unlink(missing_ok=True)
    _LIVE.clear()


class AtomicFile:
    """A result written under a temporary name of its own in its folder, then moved into place
    with ``os.replace`` (see the module docstring). ``open()`` gives the temporary file for
    writing; a writer that opens the file itself (rerun) writes to ``temporary``."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.temporary, self._fd = _create_temporary(self.path)

    def open(self) -> IO[bytes]:
        """The temporary file, open for writing (once)."""
        fd, self._fd = self._fd, -1
        return os.fdopen(fd, "wb")

    def release(self) -> None:
        """Close the descriptor made with the file (for writers that open it by name)."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def commit(self) -> Path:
        """fsync the written file and move it over the final name; the final name must still be a
        regular file or free."""
        self.release()
        try:
            kind = path_kind(self.path)
            if kind is not None:
                message = f"{shown(self.path)}: is {kind} now, not a regular file; nothing was replaced"
                raise QcontrolOutputError(errno.EEXIST, f"{message}: remove it or choose another name")
            _fsync(self.temporary)
            os.replace(self.temporary, self.path)
            _LIVE.discard(self.temporary)
        except QcontrolOutputError:
            self.discard()
            raise
        except OSError as exc:
            self.discard()
            raise output_error(self.path, exc) from None
        _fsync_folder(self.path.parent if str(self.path.parent) else Path("."))
        return self.path

    def keep_partial(self) -> Path | None:
        """Move what was written to :func:`partial_path` (never over the final name); None when
        nothing was written or the partial name is taken by something other than a file."""
        self.release()
        partial = partial_path(self.path)
        try:
            if self.temporary.stat().st_size == 0 or path_kind(partial) is not None:
                self.discard()
                return None
            _fsync(self.temporary)
            os.replace(self.temporary, partial)
            _LIVE.discard(self.temporary)
        except OSError:
            self.discard()
            return None
        return partial

    def discard(self) -> None:
        self.release()
        self.temporary.unlink(missing_ok=True)
        _LIVE.discard(self.temporary)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Make the rename durable (best effort: not every file system lets a folder be fsynced)."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def finish(file: AtomicFile) -> Path:
    """Move a complete file into place now or, inside :func:`staged`, with the others at its end;
    once a stop was asked for whose exception was lost (:func:`~qcontrol.interrupts.stop_if_asked`)
    the file is removed and the stop raised."""
    try:
        stop_if_asked()
    except BaseException:
        file.discard()
        raise
    files = getattr(_STAGING, "files", None)
    if files is None:
        return file.commit()
    files.append(file)
    return file.path


@contextmanager
def staged() -> Iterator[None]:
    """Write a set of files as one: every file finished inside the block keeps its temporary name
    until the block ends cleanly; then each final name is checked (a regular file or free) and
    only then are all moved into place. On an exception (Ctrl-C included), or a stop asked for
    whose exception was lost (:func:`~qcontrol.interrupts.stop_if_asked`), every one is removed,
    so the folder keeps its previous files, none mixed with new ones. Inside another
    :func:`staged` block the files join the outer set. The set is the calling thread's: another
    thread's files are its own."""
    if getattr(_STAGING, "files", None) is not None:
        yield
        return
    files: list[AtomicFile] = []
    _STAGING.files = files
    try:
        yield
        stop_if_asked()  # (a SIGTERM whose exception was lost: nothing put in place)
        _STAGING.files = None
        for file in files:
            kind = path_kind(file.path)
            if kind is not None:
                raise QcontrolOutputError(errno.EEXIST, f"{shown(file.path)}: is {kind}, not a regular file; "
                                          "none of the new files was put in place: remove it and run again")
        while files:
            files[0].commit()
            files.pop(0)
    finally:
        _STAGING.files = None
        for file in files:
            file.discard()


@contextmanager
def unstaged() -> Iterator[None]:
    """Inside the block the calling thread's files go straight into place, outside any
    :func:`staged` set it is in (a forked process writing files for its parent, which stages what
    it takes of them)."""
    files = getattr(_STAGING, "files", None)
    _STAGING.files = None
    try:
        yield
    finally:
        _STAGING.files = files


def write_file(path: str | Path, write: Callable[[IO[bytes]], Any]) -> Path:
    """Write a file atomically: ``write(file)`` fills the temporary file, which is then flushed,
    fsynced and moved into place (:func:`finish`). A failed write is a
    :class:`QcontrolOutputError`; whatever fails, the temporary is removed."""
    path = Path(path)
    file = AtomicFile(path)
    try:
        with file.open() as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        return finish(file)
    except QcontrolOutputError:
        file.discard()
        raise
    except OSError as exc:
        file.discard()
        raise output_error(path, exc) from None
    except BaseException:
        file.discard()
        raise


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for a writer that opens it by name; on success it
    replaces ``path``, on an exception it is removed."""
    file = AtomicFile(path)
    file.release()
    try:
        yield file.temporary
        file.commit()
    except QcontrolOutputError:
        raise
    except OSError as exc:
        raise output_error(path, exc) from None
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
    return write_text(path, json.dumps(clean(obj), indent=2, allow_nan=False) + "\n")


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) atomically."""
    data = text.encode("utf-8")
    return write_file(path, lambda handle: handle.write(data))


def _identity(path: str | Path) -> str:
    """The file a path names, for comparing outputs (links and ``..`` resolved)."""
    return os.path.realpath(os.path.abspath(path))


def check_distinct(files: dict[str, Path], inputs: dict[str, Path] | None = None,
                   folders: dict[str, Path] | None = None) -> None:
    """Refuse, before the run, outputs that clash: two outputs (``files``: label -> path, the label
    names the option) at one path, an output at an input's path (``inputs``), or an output file
    that is an output folder (``folders``) or holds one."""
    seen: dict[str, str] = {}
    for label, path in files.items():
        key = _identity(path)
        if key in seen:
            raise QcontrolInputError(f"{label} {shown(path)}: the same file as {seen[key]}; one would "
                                     "destroy the other: give each output its own name")
        seen[key] = f"{label} {shown(path)}"
    for label, path in (inputs or {}).items():
        key = _identity(path)
        if key in seen:
            raise QcontrolInputError(f"{seen[key]}: is the {label} ({shown(path)}); writing it would destroy "
                                     "the input: give the output another name")
    for option, folder in (folders or {}).items():
        inside = _identity(folder)
        for key, label in seen.items():
            if inside == key or inside.startswith(key + os.sep):
                raise QcontrolInputError(f"{option} {shown(folder)}: the folder would be where {label} is "
                                         "written; give the folder and the file different names")
