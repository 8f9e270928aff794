"""Control laws written by users, one copy at a time: the :class:`Law` protocol, the adapter that
lets the engine drive such a law like a built-in one, and the kind :func:`qcontrol.register_law`
makes of it (:class:`UserKind`).

A user law sees, at each control sample ``t_k``, the quantized reading ``x_q`` (shape ``(n,)``),
``yd = [y_d, y_d', ..., y_d^(n)]`` and its own state (shape ``(m,)``), and returns the input ``u``,
which is held over the control period like any law's. Between samples its state moves on every
step ``h`` (the simulation step dt) with the sample (``t_k``, ``x_q``, ``yd``) held, in one of two
ways the law chooses:

* ``state_rate(t_k, x_q, yd, state)``: the engine takes one classical RK4 step of it (four calls
  per step);
* ``advance(t_k, x_q, yd, state, h)`` in its place: the state one step on, its own update (an
  exact solution, a discrete-time law, a reset); one call per step. A law with both is advanced
  by ``advance``.

The engine records the law's errors z, zbar and the Lemma 2 check in the backstepping coordinates
of the scenario's ``c`` and ``delta``, as for the built-in laws.

The adapter serves every form the engine drives a law in (:class:`~.law.AnyColumnForm`): it calls
each copy's law in turn with fresh ``(n,)`` arrays made from the reading, and gives ``u`` and the
state back in the reading's form. A law that raises, or returns what its method must not, at any
call stops its copy like a divergence, with one line saying why (:mod:`.user_failure`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from types import MappingProxyType
from typing import Any, NamedTuple, Protocol, runtime_checkable

import numpy as np

from ..columns import ARRAYS, Column, ColumnForm
from ..errors import QcontrolInputError
from ..quantizer import QuantizedReading
from ..schema import Table
from .backstepping import Backstepping, Columns
from .law import LawContext, conforms
from .user_diagnostics import declared_diagnostics
from .user_failure import describe, describe_call, returned

FLOAT = np.dtype(float)


@runtime_checkable
class Law(Protocol):
    """A control law for one copy of the plant (see the module docstring): ``state_size``,
    ``initial_state()``, ``control(t, x_q, yd, state) -> u`` and ``state_rate(t, x_q, yd, state)``,
    or ``advance(t, x_q, yd, state, h)`` in place of ``state_rate``."""

    state_size: int  # m >= 0 states of the law (adaptive estimates, integrators, ...)

    def initial_state(self) -> np.ndarray:
        """The law's state at t = 0, shape ``(m,)``."""

    def control(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> float:
        """The input u at a control sample."""

    def state_rate(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> np.ndarray:
        """``d state / dt``, shape ``(m,)``, with ``x_q``, ``yd`` and ``t`` held until the next sample.
        In its place a law may give ``advance(t, x_q, yd, state, h) -> state`` one step ``h`` on."""


@runtime_checkable
class _Advancing(Protocol):
    """A :class:`Law` that gives ``advance`` in place of ``state_rate`` (not a protocol of its
    own for users: the engine's test of which update a law gives)."""

    state_size: int

    def initial_state(self) -> np.ndarray: ...

    def control(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray) -> float: ...

    def advance(self, t: float, x_q: np.ndarray, yd: np.ndarray, state: np.ndarray,
                h: float) -> np.ndarray: ...


@runtime_checkable
class _FromContext(Protocol):
    """A factory that is a class built from the run's :class:`~.law.LawContext`."""

    def from_context(self, context: LawContext) -> object: ...


LawFactory = Callable[[dict, int], Law]  # (the [controller] table, the plant order n) -> a law


def advances_itself(law: object) -> bool:
    """True when the law gives its own ``advance`` (used in place of RK4 of ``state_rate``)."""
    return conforms(law, _Advancing)


class _Sample(NamedTuple):
    """What one evaluation hands the engine: ``u``, and the sample the state's update holds.
    ``u`` a column in the reading's form, ``x_q`` the readings of the copies (a ``(n,)`` row
    each: a ``(batch, n)`` array, or a list of one row for a single copy)."""

    u: np.ndarray | float
    t: float
    x_q: np.ndarray | list[np.ndarray]
    yd: np.ndarray  # (n + 1,)


sample = partial(tuple.__new__, _Sample)  # _Sample((u, t, x_q, yd)) without NamedTuple's __new__ (hot loop)


class FastCalls(NamedTuple):
    """A law's calls on the Python loop where the engine traced and checked its code
    (:mod:`qcontrol.engine.user_trace`): plain functions on floats, ``control(*q, *yd, *state, t)
    -> u`` and ``advance(*q, *yd, t, *state) -> state``, each None (or raising what ``math``
    raises) where the law's own code is to be called instead."""

    control: Callable[..., Any]
    advance: Callable[..., Any]


class _FastSample(NamedTuple):
    """What :class:`FastCalls` hand the update: ``u``, and the sample as floats."""

    u: float
    t: float
    q: tuple
    yd: list


fast_sample = partial(tuple.__new__, _FastSample)
HANDED_OVER = (ArithmeticError, ValueError)  # what math and float arithmetic raise: the law's own call


def fresh_rows(form: ColumnForm, columns: Sequence[Column], batch: int, size: int
               ) -> list[np.ndarray]:
    """``columns`` (``size`` of them, in ``form``) as a fresh ``(size,)`` array per copy, which a
    law may be given as it is: for a single copy made from its columns (numbers, or one-element
    columns) at once, for a batch copied from the form's ``(batch, size)`` array."""
    if batch != 1:
        return [row.copy() for row in form.array(columns, batch)]
    row = np.array(columns, dtype=float)
    return [row if row.ndim == 1 else row.reshape(size).copy()]


class UserLaw(Backstepping):
    """A batch of user laws (one per copy) driven by the engine (:class:`~.law.BatchLaw`, in any
    column form: :class:`~.law.AnyColumnForm`).

    Each copy's law is called with fresh arrays at every call (it may change or keep them), in
    copy order; what it returns is checked (:meth:`_number`, :meth:`_checked_array`: fully at a
    method's first call, then only what a later call could get wrong)."""

    def __init__(self, laws: Sequence[Law], c: Sequence[float], max_error: float, state_name: str,
                 kind: str = "user law") -> None:
        super().__init__(c, max_error)
        self.laws, self.kind = list(laws), kind
        self._checked: set[str] = set()  # the methods whose output has been checked (at its first call)
        sizes = {_state_size(law) for law in self.laws}
        if len(sizes) != 1:
            raise QcontrolInputError(f"the copies of a user law have different state sizes {sorted(sizes)}")
        self.state_size = sizes.pop()
        self._shape = (self.state_size,)
        self.state_name = state_name
        self.copies = len(self.laws) if len(self.laws) > 1 else None
        self.stepped = all(advances_itself(law) for law in self.laws)
        self.diagnostics = declared_diagnostics(self.laws, kind)  # a law's own, if it declares them
        self.failures: dict[int, tuple[float, str, bool]] = {}  # copy -> (t, the line, in control())
        # "compiled" once the engine has traced and checked the law's code for its compiled loop,
        # else why it runs in Python (None: not asked yet): see qcontrol.engine.compiled_user
        self.compiled_form: str | None = None
        self.fast: FastCalls | None = None  # a single copy's traced calls, set by the engine (or None)

    def initial_state(self, batch: int) -> np.ndarray:
        try:
            rows = [self._checked_array(law.initial_state(), "initial_state()") for law in self.laws]
        except QcontrolInputError:
            raise
        except Exception as exc:
            line = describe(self.kind, "initial_state()", exc, 0.0, self.laws[0].initial_state)
            raise QcontrolInputError(f"{line}; fix the law") from None
        return np.array(rows if len(rows) == batch else rows * batch).reshape(batch, self.state_size)

    def constants(self) -> dict[str, Any]:
        return {}

    def control(self, reading: QuantizedReading, yd: Sequence[float], state: Columns,
                t: float = 0.0) -> _Sample:
        """``u`` of every copy at the sample ``t`` (its law called with that copy's reading), a
        column in the reading's form."""
        if not isinstance(reading, QuantizedReading) or reading.max_error != self.max_error:
            self.check_reading(reading)
        form, batch = reading.form, reading.batch
        if self.fast is not None and batch == 1 and self._first_calls_done():
            u = self._fast_control(reading.columns, yd, state, t)
            if u is not None:
                return fast_sample((u, t, reading.columns, yd))
        yd_row = np.array(yd, dtype=float)
        x_q = fresh_rows(form, reading.columns, 1, self.n) if batch == 1 else reading.values
        states = fresh_rows(form, state, batch, self.state_size)
        laws, failures, number, u = self.copies_laws(batch), self.failures, self._number, [0.0] * batch
        for b in range(batch):
            if failures and b in failures:
                continue  # no input: the engine stopped the copy
            law = laws[b]
            try:
                u[b] = number(law.control(t, x_q[b].copy(), yd_row.copy(), states[b]))
            except QcontrolInputError:
                raise
            except Exception as exc:  # the user's code failed: this copy stops here (see .user_failure)
                failures[b] = (t, describe(self.kind, "control()", exc, t, law.control), True)
        return sample((form.column(u), t, x_q, yd_row))

    def _first_calls_done(self) -> bool:
        """Whether the law's own methods made their first calls (which check what they return)."""
        return "control()" in self._checked and (
            not self.state_size or ("advance()" if self.stepped else "state_rate()") in self._checked)

    def _fast_control(self, q: Sequence[float], yd: Sequence[float], state: Columns,
                      t: float) -> float | None:
        """u by the traced calls (:class:`FastCalls`), or None: the law's own ``control`` then."""
        try:
            u = self.fast.control(*q, *yd, *state, t)  # type: ignore[union-attr]
        except HANDED_OVER:
            return None
        return None if u is None else float(u)

    def copies_laws(self, batch: int) -> list[Law]:
        """Each copy's law: one per copy, or the one law for every copy."""
        return self.laws if len(self.laws) == batch else self.laws * batch

    def step_state(self, law: Law, sample: _Sample, x_q: np.ndarray, state: np.ndarray,
                   h: float, copy: int = 0) -> np.ndarray:
        """One copy's state one step ``h`` on (NaN once its law failed: see :mod:`.user_failure`):
        its own ``advance``, else one classical RK4 step of its ``state_rate``
        (``s + h/6 (k1 + 2 (k2 + k3) + k4)``), with the sample held. ``state`` is a fresh array
        (:func:`fresh_rows`), the law's to have."""
        if self.failures and copy in self.failures:
            return np.full(self.state_size, math.nan)
        t, yd, checked = sample.t, sample.yd, self._checked_array
        try:
            if self.stepped:
                return checked(law.advance(t, x_q.copy(), yd.copy(), state, h), "advance()")
            rate, half = law.state_rate, 0.5 * h
            k1 = checked(rate(t, x_q.copy(), yd.copy(), state.copy()), "state_rate()")
            k2 = checked(rate(t, x_q.copy(), yd.copy(), state + half * k1), "state_rate()")
            k3 = checked(rate(t, x_q.copy(), yd.copy(), state + half * k2), "state_rate()")
            k4 = checked(rate(t, x_q.copy(), yd.copy(), state + h * k3), "state_rate()")
            return state + h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
        except QcontrolInputError:
            raise
        except Exception as exc:  # the user's code failed: this copy stops here (see .user_failure)
            method = "advance()" if self.stepped else "state_rate()"
            function = law.advance if self.stepped else law.state_rate  # type: ignore[union-attr]
            self.failures[copy] = (sample.t, describe(self.kind, method, exc, sample.t, function), False)
            return np.full(self.state_size, math.nan)

    def _refuse(self, field: str, problem: str) -> QcontrolInputError:
        return QcontrolInputError(f"controller kind {self.kind!r}: {field} {problem}; fix the law")

    def _number(self, value: object) -> float:
        """``control()``'s u as a float, checked at every call: a real number (a numpy scalar or a
        0-d array too); at the first call also finite, and a refusal there is bad input."""
        if type(value) is float and "control()" in self._checked:  # the common case, at once
            return value
        if "control()" in self._checked:
            if isinstance(value, float):
                return float(value)
            if isinstance(value, bool) or not isinstance(value, int | np.number | np.ndarray) \
                    or np.ndim(value) != 0 or not np.isrealobj(value):
                raise returned(value, "a real number u")
            return float(value)  # type: ignore[arg-type]
        if isinstance(value, bool) or not isinstance(value, int | float | np.number | np.ndarray) \
                or np.ndim(value) != 0 or not np.isrealobj(value):
            raise self._refuse("control()", f"must return a real number u, got {type(value).__name__} "
                                            f"{value!r}")
        if not np.isfinite(float(value)):
            raise self._refuse("control()", f"returned {float(value)} at the first control sample")
        self._checked.add("control()")
        return float(value)

    def _checked_array(self, value: object, field: str) -> np.ndarray:
        """An ``(m,)`` array of finite real numbers from ``initial_state()``, ``state_rate()`` or
        ``advance()``, checked at the method's first call (a refusal there is bad input); at later
        calls an array of m real numbers (else a failure of the law)."""
        if type(value) is np.ndarray and value.dtype is FLOAT and value.shape == self._shape \
                and field in self._checked:  # the common case, at once: the array as it is
            return value
        if field in self._checked:
            if isinstance(value, np.ndarray) and value.dtype.kind in "iuf" and value.size == self.state_size \
                    and value.ndim <= 1:
                return np.asarray(value, dtype=float).reshape(self.state_size)
            array = np.asarray(value) if isinstance(value, list | tuple | float | int | np.number) else None
            if isinstance(value, bool) or array is None or array.dtype.kind not in "iuf" or array.ndim > 1 \
                    or array.size != self.state_size:
                raise returned(value, f"an array of {self.state_size} real numbers")
            return array.astype(float).reshape(self.state_size)
        arrays = np.ndarray | np.number | list | tuple | float
        array = np.asarray(value) if isinstance(value, arrays) else None
        if array is None or array.dtype.kind not in "iuf":
            raise self._refuse(field, f"must return an array of {self.state_size} real numbers, got "
                                      f"{type(value).__name__} {value!r}")
        if array.ndim > 1 or array.size != self.state_size:
            raise self._refuse(field, f"must return shape ({self.state_size},) (the law's state_size), "
                                      f"got shape {array.shape}")
        if not np.all(np.isfinite(array)):
            raise self._refuse(field, f"returned a value that is not finite: {array.tolist()}")
        if field != "initial_state()":
            self._checked.add(field)
        return array.astype(float).reshape(self.state_size)

    def advancer(self, h: float) -> Callable[[Columns, _Sample], Columns]:
        """The state of every copy one step ``h`` on (:meth:`step_state`), in the array form."""
        return self.advancer_in(ARRAYS, h)

    def advancer_in(self, form: ColumnForm, h: float) -> Callable[[Columns, _Sample], Columns]:
        """:meth:`advancer` for a state in ``form``."""
        return StateUpdate(self, form, h).advance


class StateUpdate:
    """The state of a batch of user laws over one step ``h``, copy by copy
    (:meth:`UserLaw.step_state`), its columns in ``form``."""

    def __init__(self, law: UserLaw, form: ColumnForm, h: float) -> None:
        self.law, self.form, self.h = law, form, h

    def advance(self, state: Columns, sample: _Sample) -> Columns:
        law, h, m = self.law, self.h, self.law.state_size
        if not m:
            return state
        if type(sample) is _FastSample:  # a single copy on its traced calls
            try:
                new = law.fast.advance(*sample.q, *sample.yd, sample.t, *state)  # type: ignore[union-attr]
            except HANDED_OVER:
                new = None
            if new is not None:
                return tuple([float(v) for v in new])
            sample = _Sample(sample.u, sample.t, [np.array(sample.q, dtype=float)],
                             np.array(sample.yd, dtype=float))
        x_q = sample.x_q
        batch = len(x_q)
        s, laws, step = fresh_rows(self.form, state, batch, m), law.copies_laws(batch), law.step_state
        if batch == 1:
            return tuple(self.form.columns(step(laws[0], sample, x_q[0], s[0], h, 0).reshape(1, m)))
        return tuple(self.form.columns(np.array([step(laws[b], sample, x_q[b], s[b], h, b)
                                                 for b in range(batch)])))


def _state_size(law: object) -> int:
    if not (conforms(law, Law) or conforms(law, _Advancing)):
        raise QcontrolInputError(
            f"a user law must have state_size, initial_state(), control() and state_rate() or advance() "
            f"(the qcontrol.Law protocol); the factory returned {type(law).__name__}"
        )
    size = law.state_size
    if isinstance(size, bool) or not isinstance(size, int) or size < 0:
        raise QcontrolInputError(f"a user law's state_size must be a whole number >= 0, got {size!r}")
    return size


@dataclass(frozen=True)
class UserSettings:
    """The ``[controller]`` table as the factory received it (kind, delta, c and the law's keys)."""

    items: tuple[tuple[str, Any], ...]

    @property
    def table(self) -> dict:
        return _thaw(self.items)


def _freeze(value: Any) -> Hashable:
    if isinstance(value, Mapping):
        return tuple((k, _freeze(v)) for k, v in value.items())
    if isinstance(value, list):
        return ("__list__", tuple(_freeze(v) for v in value))
    return value


def _thaw(value: Any) -> Any:
    if isinstance(value, tuple) and value[:1] == ("__list__",):
        return [_thaw(v) for v in value[1]]
    if isinstance(value, tuple):
        return {k: _thaw(v) for k, v in value}
    return value


class UserKind:
    """A controller kind of a per-copy :class:`Law` (made by :func:`qcontrol.register_law`): its
    table checked (against the declared ``keys``, else by the factory) when a scenario loads, one
    law per copy built when it runs; variants of it always share a batch."""

    def __init__(self, kind: str, factory: LawFactory, state_name: str,
                 keys: Sequence[str] | None = None) -> None:
        self.kind, self.factory, self.state_name, self.keys = kind, factory, state_name, keys

    def parse(self, table: Table, ctx: LawContext) -> UserSettings:
        given = {"kind": self.kind, "delta": ctx.delta, "c": list(ctx.c)} | table.data
        if self.keys is not None:
            try:
                check_keys(given, self.keys)
            except QcontrolInputError as exc:
                raise QcontrolInputError(f"{ctx.source}: {exc}") from None
        settings = UserSettings(_freeze(given))
        _call(self.factory, settings, ctx)
        return settings

    def build(self, settings: Sequence[UserSettings], ctx: LawContext) -> UserLaw:
        laws = [_call(self.factory, s, ctx) for s in settings]
        return UserLaw(laws, ctx.c, ctx.max_error, self.state_name, self.kind)

    @staticmethod
    def structure(settings: UserSettings, ctx: LawContext) -> Hashable:
        return None


def _call(factory: LawFactory, settings: UserSettings, ctx: LawContext) -> Law:
    """The factory's law: ``factory.from_context(context)`` when it has that class method (the
    context's ``settings``: the law's own keys), else ``factory(table, n)``; its input errors
    become one line naming the file and the table."""
    try:
        if conforms(factory, _FromContext):
            own = {k: v for k, v in settings.table.items() if k not in COMMON_KEYS}
            context = dataclasses.replace(ctx, settings=MappingProxyType(own), controller=None)
            law = factory.from_context(context)
        else:
            law = factory(settings.table, ctx.order)
    except QcontrolInputError as exc:
        raise QcontrolInputError(f"{ctx.source}: {exc}") from None
    except (KeyError, ValueError, TypeError) as exc:
        raise QcontrolInputError(
            f"{ctx.source}: controller: the law's factory refused the table ({type(exc).__name__}: {exc}); "
            "fix the [controller] keys"
        ) from None
    except Exception as exc:  # the user's code failed: one line naming it (see .user_failure)
        raise QcontrolInputError(f"{ctx.source}: controller: the law's factory failed "
                                 f"({describe_call(exc, factory)}); fix the factory") from None
    _state_size(law)
    return law


COMMON_KEYS = ("kind", "delta", "c")  # the keys of every kind's [controller] table


def check_keys(table: Mapping[str, Any], allowed: Sequence[str]) -> None:
    """Refuse a key of a user law's ``[controller]`` table that is not in ``allowed`` (``kind``,
    ``delta`` and ``c`` are always allowed), with the usual one-line message."""
    known = (*COMMON_KEYS, *allowed)
    for key in table:
        if key not in known:
            raise QcontrolInputError(
                f"controller.{key}: unknown key for kind {table.get('kind')!r}; keys of this kind are "
                f"{', '.join(known)} (remove it or check its spelling)"
            )
