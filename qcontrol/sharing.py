"""Many variants of one scenario loaded together: what they share is read and checked once.

A sweep, a region map or a study loads hundreds of variants of one file, each the file with its
own ``--set`` overrides. Loading one (:func:`~qcontrol.scenario.load.parse_scenario`) is a
sequence of stages: the plant's terms, the simulation settings, the backends' sections (a MuJoCo
model compiled), the quantizer, the controller, the reference, the metrics, the loads, the terms
checked at x(0). Each stage is a function of a few tables of the data alone (and of the stages
before it, themselves functions of their tables). While :func:`sharing` is on, each stage's result
is kept under the exact value of the tables it reads, types and the bits of every float included
(``1`` and ``1.0``, ``0.0`` and ``-0.0`` differ): a variant whose tables equal an earlier variant's
takes that result instead of computing it again. A sweep over ``controller.kappa_margin`` so
checks the plant, its model and the simulation settings once and only the controller for each
variant; variants that differ in ``plant.x0`` share the plant's terms, its backends and the
controller, which do not read it.

Nothing else changes: every stage runs in its order, a stage whose tables are new runs as it
always does, and a stage that fails raises its one line and keeps nothing. So a variant is exactly
what loading it alone gives, and bad input is refused alike. Outside :func:`sharing` nothing is
kept: a single load reads its files afresh (a model file edited between two loads is read again).
Results are shared between variants, which is safe because a scenario and its parts are immutable.
"""

from __future__ import annotations

import datetime
from collections.abc import Callable, Hashable, Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from functools import partial
from pathlib import PurePath
from typing import Any, TypeVar

T = TypeVar("T")
_KEPT: ContextVar[dict | None] = ContextVar("qcontrol_shared_stages", default=None)
# values a key holds as they are: immutable, and equal only when they are the same value
_AS_THEY_ARE = (str, int, type(None), datetime.date, datetime.time, PurePath)
# [plant] but its x0: all that the plant's terms, the backends' sections and the law read of it
# (x0 is read for each variant, and the check of the terms at x0 reads the whole table)
WITHOUT_X0 = "plant without x0"
_NUMBERS = object()  # where the kept results' dict numbers the exact values met (see Stages)


class _NoKey(Exception):
    """A value with no exact key (e.g. an object an API override gave): its stage is not kept."""


@contextmanager
def sharing() -> Iterator[None]:
    """Keep each loading stage's result for the variants loaded inside (see the module docstring);
    nested uses share the outermost's. Per thread: a Dask worker's threads keep their own."""
    if _KEPT.get() is not None:
        yield
        return
    token = _KEPT.set({})
    try:
        yield
    finally:
        _KEPT.reset(token)


def exact(value: Any) -> Hashable:
    """A hashable key equal for two values only if they are the same data: tables and lists by
    their entries in order, each scalar with its type, a float by its bits (``float.hex``)."""
    kind = type(value)
    if kind is dict:  # (the usual types first: this runs over every table of every variant)
        return (dict, tuple([(k, _entry(v)) for k, v in value.items()]))
    if kind is float:
        return (float, float.hex(value))
    if kind is str or kind is int or kind is bool or kind is list or kind is tuple or value is None:
        return (kind, tuple([_entry(v) for v in value])) if kind is list or kind is tuple else (kind, value)
    if isinstance(value, Mapping):
        return (dict, tuple([(k, exact(v)) for k, v in value.items()]))
    if isinstance(value, list | tuple):
        return (kind, tuple([exact(v) for v in value]))
    if isinstance(value, float):
        return (kind, float.hex(value))
    if isinstance(value, _AS_THEY_ARE) and kind.__hash__ is not None:
        return (kind, value)
    raise _NoKey


def _entry(value: Any) -> Hashable:
    """:func:`exact` of an entry; while :func:`sharing` is on, a table's or a list's is its number
    (:func:`numbered`, made once per object: an override copies the tables along its key, the
    others stay the file's), so that a key holds no deep copy of what it names."""
    if (type(value) is dict or type(value) is list) and _KEPT.get() is not None:
        return (numbered, per_object(numbered, value))
    return exact(value)


def numbered(value: Any) -> int:
    """While :func:`sharing` is on: a number for ``value``'s :func:`exact` value, the same for
    every equal value."""
    numbers = _KEPT.get().setdefault(_NUMBERS, {})
    return numbers.setdefault(exact(value), len(numbers))


def _without_x0(plant: Any) -> int:
    """:func:`numbered` of ``[plant]`` without its ``x0``."""
    return numbered({k: v for k, v in plant.items() if k != "x0"} if isinstance(plant, dict) else plant)


def kept(key: Hashable, compute: Callable[[], T]) -> T:
    """``compute()``, or while :func:`sharing` is on, its result kept under ``key``."""
    store = _KEPT.get()
    if store is None:
        return compute()
    if key not in store:
        store[key] = compute()
    return store[key]


def per_object(make: Callable[[Any], T], value: Any) -> T:
    """``make(value)``, made once per object ``value`` while :func:`sharing` is on: the tables of a
    file read once are shared by the variants that do not write into them (the object is kept with
    what was made of it, so that its id names no other object meanwhile)."""
    store = _KEPT.get()
    if store is None:
        return make(value)
    made = store.setdefault(make, {})
    known = made.get(id(value))
    if known is None or known[0] is not value:
        known = made[id(value)] = (value, make(value))
    return known[1]


def kept_for(name: str, values: tuple, compute: Callable[..., T], *args: Any) -> T:
    """``compute(*args)``, or while :func:`sharing` is on, its result kept under ``name`` and the
    exact ``values`` it depends on (:func:`exact`; computed when one has no exact key)."""
    if _KEPT.get() is None:
        return compute(*args)
    try:
        key = (name, exact(values))
    except _NoKey:
        return compute(*args)
    return kept(key, partial(compute, *args))


class Stages:
    """The stages of one load: ``run(name, tables, compute)`` gives ``compute()``, or (while
    :func:`sharing` is on) the result kept for the same stage, ``fixed`` values (the file's
    source, its folder) and the exact values of ``tables`` (top-level tables of ``data`` by name,
    or :data:`WITHOUT_X0`; each made once per load, again after :meth:`changed`). Equal exact
    values are numbered alike, so that a stage's key is a few small numbers."""

    def __init__(self, data: dict, *fixed: Any) -> None:
        self.data = data
        self.kept = _KEPT.get()
        self.keys: dict[str, int] = {}
        try:
            self.fixed = numbered(fixed) if self.kept is not None else None
        except _NoKey:
            self.kept = None

    def key(self, name: str) -> int:
        """The number of a top-level table's exact value (:data:`WITHOUT_X0`: ``[plant]`` but its
        ``x0``), made once per table object."""
        if name not in self.keys:
            if name == WITHOUT_X0:
                self.keys[name] = per_object(_without_x0, self.data.get("plant"))
            else:
                self.keys[name] = per_object(numbered, self.data.get(name))
        return self.keys[name]

    def changed(self, name: str) -> None:
        """The load wrote into table ``name``: later stages read its new value."""
        self.keys.pop(name, None)
        if name == "plant":
            self.keys.pop(WITHOUT_X0, None)

    def run(self, stage: str, tables: tuple[str, ...], compute: Callable[..., T], *args: Any,
            also: tuple = ()) -> T:
        """``compute(*args)``, kept under the stage's name, the fixed values, ``tables`` and the
        exact values ``also`` (what else it reads: ``args`` are derived from these)."""
        if self.kept is None:
            return compute(*args)
        try:
            key = (stage, self.fixed, tuple([self.key(t) for t in tables]), exact(also) if also else None)
        except _NoKey:
            return compute(*args)
        return kept(key, partial(compute, *args))
