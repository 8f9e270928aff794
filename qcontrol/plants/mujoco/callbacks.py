"""MuJoCo's process-global hooks: the passive-force callback and the warning handler.

``mjcb_passive`` is one function for the whole process, installed while plants are in use and
restored after the last (:func:`passive_forces`). Where the plants' terms compile
(:mod:`.native`) and every plant in use shares them, it is the native callback itself; otherwise
one Python dispatcher serves every plant, each ``MjData`` with its own entry. A term of eq. (1)
with no rigid-body counterpart (Example 1's psi, Example 2's theta2 x2^2 cos x1) is added to
``qfrc_passive`` there; MuJoCo's RK4 calls the callback at each of its four stages, so MuJoCo and
the ODE integrate the same vector field with the same scheme.

MuJoCo's default warning handler appends to ``MUJOCO_LOG.TXT`` in the working folder. While a
:func:`collect_warnings` block is open (a plant's run, a model compiled or checked at load:
:func:`kept_aside`) the handler is this module's: a plant collects its run's warnings (a blow-up is
reported as a divergence), and warnings of the model checks are kept in
:data:`UNCLAIMED_WARNINGS`, never written to disk. When the last block closes, the handler found
before the first one is restored: importing this module changes nothing.

MuJoCo's bindings install a profiling timer (``mjcb_time``, read at every one of ``mj_step``'s
timed stages: about 40 % of a step of the paper's models) whenever an ``MjData`` is made. No
number depends on it (it fills ``MjData.timer`` only), so a run steps without it
(:func:`untimed`) unless a timer of the user's own is installed; the timer found is put back
after the last run.

The hooks belong to the whole process, so one lock (:data:`HOOKS`, reentrant) is held by
whatever uses them, from a plant's ``with`` block (its run) and a model's compilation or check to
their end: runs in several threads of one process take turns on MuJoCo, each with its own
callback and warnings, and give what each gives alone (ODE runs do not take the lock).
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from functools import cache
from typing import Any

import mujoco

from ...expr import Expression, FloatCombination
from ..base import timed
from .native import NativeForce

_ENTRIES: dict[int, Callable[[], None]] = {}  # id(MjData) -> adds the non-native terms to it
_PREVIOUS: list[Any] = []  # the passive callback that was installed before the dispatcher
_NATIVE: list[str] = []  # [key] while a native callback (of that key) is installed directly
UNCLAIMED_WARNINGS: list[str] = []  # warnings while no run collects them (the last 100)
_SINKS: list[list[str]] = []  # the innermost collecting run's list is last
_PREVIOUS_WARNING: list[Any] = []  # the warning handler found when the first block opened
_TIMERS: list[int] = []  # the timer found when the first untimed run started (its address), per run
HOOKS = threading.RLock()  # held while the process's passive callback or warning handler is in use


def _fresh_lock_in_child() -> None:
    """A forked worker starts with the lock free (its parent's holder is not copied into it)."""
    global HOOKS
    HOOKS = threading.RLock()


os.register_at_fork(after_in_child=_fresh_lock_in_child)


class GeneralizedForce:
    """``force(q, v) = I * sum(coefficient * term(q, v))`` on one MjData's floats: the terms of
    eq. (1) MuJoCo's own physics does not produce, as a generalized force on the joint, summed in
    order from 0.0, evaluated through ``math`` with the expression compiler's one fallback rule
    (:class:`~qcontrol.expr.FloatCombination`)."""

    def __init__(self, terms: Sequence[tuple[float, Expression]], inertia: float) -> None:
        self.total = FloatCombination([e for _, e in terms], [inertia * c for c, _ in terms])
        self.timed = any(timed(e) for _, e in terms)  # a term in t: evaluated at MuJoCo's data.time

    def at(self, q: float, v: float) -> float:
        return 0.0 + self.total((q, v))  # = ((0.0 + c1 f1) + c2 f2) ..., sign of zero included

    def at_time(self, q: float, v: float, t: float) -> float:
        """:meth:`at` for terms in t, at time ``t`` (the RK4 stage's, MuJoCo's ``data.time``)."""
        return 0.0 + self.total((q, v, t))


def _dispatch(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """The Python ``mjcb_passive``: MuJoCo passes the very MjData objects the plants own."""
    apply = _ENTRIES.get(id(data))
    if apply is not None:
        apply()
    elif _PREVIOUS and _PREVIOUS[0] is not None:
        _PREVIOUS[0](model, data)


class PassiveApplier:
    """Adds the non-native terms to one MjData's ``qfrc_passive`` (the dispatcher calls
    :meth:`apply` with MuJoCo's every evaluation of the passive forces)."""

    def __init__(self, data: mujoco.MjData, qadr: int, dof: int, force: GeneralizedForce) -> None:
        self.qpos, self.qvel, self.qfrc = data.qpos, data.qvel, data.qfrc_passive  # views, made once
        self.qadr, self.dof, self.force = qadr, dof, force.at

    def apply(self) -> None:
        dof = self.dof
        self.qfrc[dof] += self.force(self.qpos.item(self.qadr), self.qvel.item(dof))


class TimedPassiveApplier(PassiveApplier):
    """:class:`PassiveApplier` for terms in t, evaluated at ``data.time`` (MuJoCo sets it to each
    RK4 stage's time before it evaluates the passive forces)."""

    def __init__(self, data: mujoco.MjData, qadr: int, dof: int, force: GeneralizedForce) -> None:
        super().__init__(data, qadr, dof, force)
        self.data, self.force = data, force.at_time

    def apply(self) -> None:
        dof = self.dof
        self.qfrc[dof] += self.force(self.qpos.item(self.qadr), self.qvel.item(dof), self.data.time)


class NativeApplier:
    """The native callback called from the Python dispatcher for one MjData (when plants of
    different terms, or a foreign callback, share the process's one ``mjcb_passive``)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, native: NativeForce) -> None:
        self.call, self.model, self.data = native.pointer, model._address, data._address

    def apply(self) -> None:
        self.call(self.model, self.data)


def _install(native: NativeForce | None) -> None:
    """Install the callback for the first plant: its native one when it has one and no foreign
    callback must be chained, else the Python dispatcher."""
    previous = mujoco.get_mjcb_passive()
    _PREVIOUS[:] = [None if previous is _dispatch else previous]
    if native is not None and _PREVIOUS[0] is None:
        mujoco.set_mjcb_passive(native.pointer)
        _NATIVE[:] = [native.key]
    else:
        mujoco.set_mjcb_passive(_dispatch)


@contextmanager
def passive_forces(model: mujoco.MjModel, datas: Sequence[mujoco.MjData], qadr: int, dof: int,
                   forces: Sequence[GeneralizedForce] | None,
                   native: NativeForce | None = None) -> Iterator[None]:
    """Register ``datas`` for the passive force (``forces``: one per data), installing the
    callback if needed; undo everything on exit. With ``native`` (whose numbers the caller keeps
    in each copy's userdata) MuJoCo calls compiled code directly while every plant in use shares
    its terms; otherwise the Python dispatcher serves every plant, calling the native callbacks
    through ctypes."""
    with HOOKS:
        if forces is None:
            yield
            return
        with _registered(model, datas, qadr, dof, forces, native):
            yield


@contextmanager
def _registered(model: mujoco.MjModel, datas: Sequence[mujoco.MjData], qadr: int, dof: int,
                forces: Sequence[GeneralizedForce], native: NativeForce | None) -> Iterator[None]:
    """:func:`passive_forces`' work, with :data:`HOOKS` held."""
    if not _ENTRIES:
        _install(native)
    elif _NATIVE and (native is None or native.key != _NATIVE[0]):
        mujoco.set_mjcb_passive(_dispatch)
        _NATIVE.clear()
    keys = []
    try:
        for data, force in zip(datas, forces, strict=True):
            applier = TimedPassiveApplier if force.timed else PassiveApplier
            _ENTRIES[id(data)] = (NativeApplier(model, data, native).apply if native is not None
                                  else applier(data, qadr, dof, force).apply)
            keys.append(id(data))
        yield
    finally:
        for key in keys:
            _ENTRIES.pop(key, None)
        if not _ENTRIES:
            mujoco.set_mjcb_passive(_PREVIOUS[0] if _PREVIOUS else None)
            _PREVIOUS.clear()
            _NATIVE.clear()


def python_callback_installed() -> bool:
    """Whether ``mjcb_passive`` is a Python function now (which ``mujoco.batch`` refuses)."""
    installed = mujoco.get_mjcb_passive()
    return installed is not None and not isinstance(installed, ctypes._CFuncPtr)


def _warn(message: str) -> None:
    """MuJoCo's warning handler while a block is open: into the innermost block's list."""
    sink = _SINKS[-1] if _SINKS else UNCLAIMED_WARNINGS
    sink.append(message)
    if sink is UNCLAIMED_WARNINGS:
        del UNCLAIMED_WARNINGS[:-100]


@contextmanager
def collect_warnings(sink: list[str]) -> Iterator[None]:
    """MuJoCo's warnings go to ``sink`` inside the block (nested blocks: the innermost); the
    handler is installed by the first block and the previous one restored after the last."""
    with HOOKS, _collecting(sink):
        yield


@contextmanager
def _collecting(sink: list[str]) -> Iterator[None]:
    """:func:`collect_warnings`' work, with :data:`HOOKS` held."""
    if not _SINKS:
        _PREVIOUS_WARNING[:] = [mujoco.get_mju_user_warning()]
        mujoco.set_mju_user_warning(_warn)
    _SINKS.append(sink)
    try:
        yield
    finally:  # by identity: two sinks may be equal lists
        del _SINKS[max(i for i, open_sink in enumerate(_SINKS) if open_sink is sink)]
        if not _SINKS:
            mujoco.set_mju_user_warning(_PREVIOUS_WARNING[0] if _PREVIOUS_WARNING else None)
            _PREVIOUS_WARNING.clear()


def kept_aside() -> contextlib.AbstractContextManager[None]:
    """A block whose MuJoCo warnings (compiling or checking a model outside any run) are kept in
    :data:`UNCLAIMED_WARNINGS` (the last 100), not written to disk."""
    return collect_warnings(UNCLAIMED_WARNINGS)


@cache
def mujoco_library_path() -> str:
    """The path of MuJoCo's C library the bindings loaded, in the mujoco package."""
    found = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*"))
                   + glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco*.dylib"))
                   + glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "mujoco*.dll")))
    if not found:
        raise LookupError("MuJoCo's C library was not found beside its Python bindings")
    return found[0]


@cache
def _timer_slot() -> ctypes.c_void_p | None:
    """MuJoCo's ``mjcb_time`` (the C variable; the bindings' setter puts their timer back for None)."""
    try:
        return ctypes.c_void_p.in_dll(ctypes.CDLL(mujoco_library_path()), "mjcb_time")
    except (LookupError, OSError, ValueError):
        return None


@contextmanager
def untimed() -> Iterator[None]:
    """MuJoCo's profiling timer off inside the block (a run: the same numbers, about 40 % less
    time per step), unless the user installed a timer of their own (a Python function) or MuJoCo's
    C library cannot be reached; the timer found is restored when the last block closes."""
    slot = _timer_slot()
    with HOOKS:
        if slot is None or mujoco.get_mjcb_time() is not None:
            yield
            return
        _TIMERS.append(slot.value if not _TIMERS else _TIMERS[0])
        slot.value = None
        try:
            yield
        finally:
            found = _TIMERS.pop()
            if not _TIMERS:
                slot.value = found
