"""A user law that fails during a run: reported as one line, the copy stopped like a divergence.

A law written in Python (:mod:`.user`) may raise, or return something that is not what its
method promises (None, a string, an array of the wrong shape), at any call. The adapter catches
it for the copy it happened to, stops that copy's law (its u is 0 and its state NaN from then on)
and the engine stops the copy at that row, as a divergence (:mod:`qcontrol.engine.divergence`),
keeps :func:`describe`'s line: the kind, the method, what went wrong and the line of the user's
file. The summary's ``divergence_reason`` and ``law_failure`` hold it; the command line prints it
and exits with its own status (4). The other copies of a batch run on.

The full traceback is printed too (on stderr, at the moment of the failure) when the
environment sets :data:`DEBUG_SWITCH` (``QCONTROL_DEBUG=1``).
"""

from __future__ import annotations

import os
import sys
import sysconfig
import traceback
from pathlib import Path
from types import TracebackType
from typing import Any

DEBUG_SWITCH = "QCONTROL_DEBUG"
_PACKAGE = str(Path(__file__).resolve().parents[1])  # qcontrol's own frames are not the user's line
_LIBRARIES = tuple(str(Path(sysconfig.get_paths()[key]).resolve())  # nor the libraries'
                   for key in ("stdlib", "purelib", "platlib"))


class LawReturned(Exception):
    """A law's method returned what it must not (after its first call, which refuses it as bad
    input): the message says what it returned and what it must return."""


def debugging() -> bool:
    """Whether the environment asks for full tracebacks (:data:`DEBUG_SWITCH`)."""
    return os.environ.get(DEBUG_SWITCH, "").strip().lower() not in ("", "0", "false", "no", "off")


def _one_line(text: object, limit: int = 160) -> str:
    text = " ".join(str(text).split())
    text = text if text.isprintable() else repr(text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _users_frame(tb: TracebackType | None) -> str | None:
    """``file.py, line N``: the innermost frame of the traceback in the user's code (not qcontrol's,
    not the standard library's or an installed package's)."""
    found = None
    for frame in traceback.extract_tb(tb):
        name = str(Path(frame.filename).resolve()) if not frame.filename.startswith("<") else frame.filename
        if not name.startswith(_PACKAGE) and not name.startswith(_LIBRARIES):
            found = f"{Path(frame.filename).name}, line {frame.lineno}"
    return found


def _defined_at(method: Any) -> str | None:
    code = getattr(getattr(method, "__func__", method), "__code__", None)
    return None if code is None else f"{Path(code.co_filename).name}, line {code.co_firstlineno}"


def describe_call(exc: BaseException, function: Any) -> str:
    """``ZeroDivisionError: division by zero, mylaws.py, line 12``: what a call of the user's
    ``function`` raised, and where (the traceback on stderr with :data:`DEBUG_SWITCH` set)."""
    if debugging():
        traceback.print_exception(exc, file=sys.stderr)
    where = _users_frame(exc.__traceback__) or _defined_at(function)
    return f"{type(exc).__name__}: {_one_line(exc)}" + (f", {where}" if where else "")


def describe(kind: str, method: str, exc: BaseException, t: float, function: Any) -> str:
    """One line for a law's failure in ``method`` (e.g. ``"control()"``) at the sample ``t``:
    ``controller kind 'mine': control() raised ZeroDivisionError: division by zero at t = 0.25 s
    (mylaws.py, line 12)``; with :data:`DEBUG_SWITCH` set, the traceback is printed on stderr."""
    if isinstance(exc, LawReturned):
        what, where = str(exc), _defined_at(function)
    else:
        what, where = f"raised {type(exc).__name__}: {_one_line(exc)}", _users_frame(exc.__traceback__)
        where = where or _defined_at(function)
    if debugging():
        traceback.print_exception(exc, file=sys.stderr)
    place = f" ({where})" if where else ""
    return f"controller kind {kind!r}: {method} {what} at t = {t:g} s{place}"


def returned(value: Any, promised: str) -> LawReturned:
    """The failure of a method that returned ``value`` instead of ``promised``."""
    return LawReturned(f"returned {type(value).__name__} {_one_line(repr(value), 60)}, not {promised}")
