"""Compiled (numba) versions of qcontrol's hot loops, with the Python loops as the fallback.

Every compiled path gives the same numbers, to the last bit, as the Python code it replaces (it
is generated from the same expression trees, evaluates the same operations in the same order,
without fast-math contraction, with numpy's error model). It is on by default;
``QCONTROL_COMPILE=0`` in the environment turns every compiled path off. Where it cannot be used
(numba missing or refusing to compile), the Python path runs instead and a warning says so once.

Generated code is kept on disk in the user's cache folder (:mod:`.cache`), so a process compiles a
callback once and later processes (worker processes included) load it in a fraction of a second.

Ctrl-C (or SIGTERM) while numba compiles or loads code stops the command once numba has finished
(:mod:`.compiling`): raised inside numba's work, it would leave llvmlite's objects half updated.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

ENVIRONMENT_SWITCH = "QCONTROL_COMPILE"
# generated code's decorators: numpy's error model, no fast-math (the Python form's numbers); no
# cfunc wrapper (nothing calls the functions from C); no_rewrites: numba's IR rewrites (constant
# indices made static, dead branches pruned, array expressions fused) are for code that generated
# scalar code has none of, and skipping them cuts about 8 % of a module's compile (the same
# operations in the same order: the same numbers); CALLED for a function only compiled code calls
# (no wrapper for calls from Python either: less to compile)
JIT = '@numba.njit(cache=True, error_model="numpy", nogil=True, no_rewrites=True, no_cfunc_wrapper=True)'
CALLED = JIT[:-1] + ", no_cpython_wrapper=True)"
_SAID: set[str] = set()
_NOT_NEEDED: list[None] = []  # one entry per open not_needed() block


def requested() -> bool:
    """Whether the environment allows compiled paths (``QCONTROL_COMPILE=0`` forbids them) and no
    :func:`not_needed` block is open."""
    if _NOT_NEEDED:
        return False
    return os.environ.get(ENVIRONMENT_SWITCH, "1").strip().lower() not in ("0", "false", "no", "off")


@contextmanager
def not_needed() -> Iterator[None]:
    """Compiled paths off while the block is open, silently: for work that runs nothing (building
    a plant only to check it) or too little to pay for numba's start (a short single run in a
    fresh process), so that it neither imports numba nor loads compiled code. The same numbers
    either way: every compiled path is bit-identical to its Python form."""
    _NOT_NEEDED.append(None)
    try:
        yield
    finally:
        _NOT_NEEDED.pop()


def numba_missing() -> str | None:
    """Why numba cannot be used here, or None when it can."""
    try:
        import numba  # noqa: F401
    except Exception as exc:  # ImportError, or a broken install (llvmlite's shared library)
        return f"numba cannot be imported ({type(exc).__name__}: {exc})"
    return None


def enabled() -> bool:
    """Compiled paths are on: requested and numba importable (a warning, once, when it is not);
    then numba's compiles hold Ctrl-C (:func:`.compiling.hold_while_compiling`)."""
    if not requested():
        return False
    missing = numba_missing()
    if missing is not None:
        fallback("compiled paths", missing)
        return False
    from .compiling import hold_while_compiling

    hold_while_compiling()
    return True


def fallback(what: str, why: str) -> None:
    """Say once per process that ``what`` runs in Python instead of compiled code, and why."""
    if what in _SAID:
        return
    _SAID.add(what)
    warnings.warn(f"qcontrol: {what} run in Python, not compiled: {why} (same numbers, slower; "
                  f"{ENVIRONMENT_SWITCH}=0 silences this by choosing Python)", RuntimeWarning, stacklevel=3)


def started() -> bool:
    """:func:`enabled`, with numba's compiler started in this process (its typing and target
    registries loaded), so that worker processes forked next inherit it rather than each paying
    for it (about 0.3-0.9 s of CPU a worker)."""
    if not enabled():
        return False
    try:  # (numba's own registry: where a version moved it, each worker starts numba as before)
        from numba.core.registry import cpu_target

        cpu_target.typing_context.refresh()
        cpu_target.target_context.refresh()
    except (ImportError, AttributeError):
        pass
    return True
