"""Diagnostics declared by a user's law: the :class:`LawDiagnostics` capability of a
:class:`~.user.Law`, the checks of what a law declares, and the adapters that give the engine
each diagnostic in its column form.

A law written against the :class:`~.user.Law` protocol declares ``diagnostics``, a sequence of
:class:`~.law.Diagnostic` whose ``evaluate(x_q, yd, state)`` takes ONE copy's record as arrays
(``x_q`` ``(rows, n)``, ``yd`` ``(rows, n + 1)``, ``state`` ``(rows, m)``: the quantized reading,
the reference row and the law's state at each row) and returns ``(rows,)`` or ``(rows, width)``.
Each copy of a batch is evaluated with its own law object (the per-copy parameters of a sweep
differ), after the loop recorded the rows: a run's numbers are the same with or without them.

A law class (registered by :func:`~.kinds.register_law`) declares them in the engine's column form
(:data:`~.law.Evaluate`); its results are checked here too, so that a wrong shape stops the run
with one line naming the law and the diagnostic.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

import numpy as np

from ..errors import QcontrolInputError
from .backstepping import Columns
from .law import Diagnostic, Evaluate, conforms


@runtime_checkable
class LawDiagnostics(Protocol):
    """A capability of a :class:`~.user.Law`: the diagnostics it declares (see the module
    docstring for what their ``evaluate`` receives)."""

    diagnostics: Sequence[Diagnostic]


def diagnostic_columns(diagnostics: Sequence[Diagnostic]) -> tuple[str, ...]:
    """The names of the columns the diagnostics fill: a diagnostic's name for a width of 1, else
    ``name_1 .. name_w``."""
    return tuple(d.name if d.width == 1 else f"{d.name}_{i + 1}" for d in diagnostics for i in range(d.width))


def checked_declarations(declared: object, law: str) -> tuple[Diagnostic, ...]:
    """What a law declares as ``diagnostics``, if it is a list or tuple of distinct
    :class:`~.law.Diagnostic` whose columns have distinct names; else a one-line refusal naming
    ``law`` (none: the caller names it)."""
    law = f"{law}: " if law else ""
    if not isinstance(declared, list | tuple):
        raise QcontrolInputError(f"{law}diagnostics must be a list or tuple of qcontrol.Diagnostic, got "
                                 f"{type(declared).__name__}; fix the law")
    for i, item in enumerate(declared):
        if not isinstance(item, Diagnostic):
            raise QcontrolInputError(f"{law}diagnostics[{i}] is {type(item).__name__} {item!r}, not a "
                                     "qcontrol.Diagnostic; fix the law")
    seen: set[str] = set()
    for item, column in ((d, c) for d in declared for c in diagnostic_columns((d,))):
        if column in seen:
            raise QcontrolInputError(f"{law}diagnostic {item.name!r} gives a second column named {column!r}; "
                                     "give each diagnostic its own name")
        seen.add(column)
    return tuple(declared)


def declared_diagnostics(laws: Sequence[object], kind: str) -> tuple[Diagnostic, ...]:
    """The diagnostics of a batch of :class:`~.user.Law` copies in the engine's column form (none
    for a law without :class:`LawDiagnostics`). Every copy must declare the same names, widths
    and reductions; each is evaluated with its own copy's declaration."""
    law = f"controller kind {kind!r}"
    declared = [checked_declarations(copy.diagnostics, law) if conforms(copy, LawDiagnostics) else ()
                for copy in laws]
    shapes = {tuple((d.name, d.width, d.reduce) for d in copy) for copy in declared}
    if len(shapes) != 1:
        raise QcontrolInputError(f"{law}: the copies of the law declare different diagnostics "
                                 f"({' / '.join(sorted(str([s[0] for s in shape]) for shape in shapes))}); "
                                 "declare the same ones in every copy")
    return tuple(replace(first, evaluate=PerCopy(tuple(copy[i] for copy in declared), law))
                 for i, first in enumerate(declared[0]))


def checked_class_diagnostics(diagnostics: object, kind: str) -> tuple[Diagnostic, ...]:
    """A law class's declared diagnostics (checked), each of its results checked at every
    evaluation (:class:`CheckedColumns`)."""
    declared = checked_declarations(diagnostics, "")  # the kind's parse names the law
    law = f"controller kind {kind!r}"
    return tuple(replace(d, evaluate=CheckedColumns(d.evaluate, d, law)) for d in declared)


def _refuse(law: str, d: Diagnostic, problem: str) -> QcontrolInputError:
    return QcontrolInputError(f"{law}: diagnostic {d.name!r}: evaluate(x_q, yd, state) {problem}; "
                              "fix the law")


def _numbers(values: object, law: str, d: Diagnostic) -> np.ndarray:
    """``values`` as an array of floats, if it is an array (or list) of real numbers."""
    array = np.asarray(values) if isinstance(values, np.ndarray | np.number | list | tuple | float | int) \
        else None
    if array is None or array.dtype.kind not in "biuf":
        raise _refuse(law, d, f"must return an array of real numbers, got {type(values).__name__}")
    return array.astype(float)


@dataclass(frozen=True)
class PerCopy:
    """A :class:`~.user.Law` diagnostic in the engine's column form: each copy's declaration
    (``copies``; one for every copy of a batch, or one shared by all) evaluated on that copy's
    rows, its ``(rows,)`` or ``(rows, width)`` result checked and put in the copy's column."""

    copies: tuple[Diagnostic, ...]
    law: str

    def __call__(self, x_q: Columns, yd: Columns, state: Columns) -> np.ndarray:
        rows, batch = np.shape(x_q[0])
        width = self.copies[0].width
        out = np.empty((rows, batch, width))
        if rows == 0:
            return out if width > 1 else out[..., 0]
        readings = np.stack(x_q, axis=-1)
        references = np.broadcast_to(np.stack(yd, axis=-1), (rows, batch, len(yd)))
        states = np.stack(state, axis=-1) if state else np.empty((rows, batch, 0))
        for b in range(batch):
            d = self.copies[b if len(self.copies) > 1 else 0]
            values = _numbers(d.evaluate(readings[:, b].copy(), references[:, b].copy(), states[:, b].copy()),
                              self.law, d)
            allowed = {(rows, width), (rows,)} if width == 1 else {(rows, width)}
            if values.shape not in allowed:
                wanted = f"({rows},) or ({rows}, 1)" if width == 1 else f"({rows}, {width})"
                raise _refuse(self.law, d, f"must return shape {wanted} for {rows} rows (width {width}), got "
                                           f"shape {values.shape}")
            out[:, b] = values.reshape(rows, width)
        return out if width > 1 else out[..., 0]


@dataclass(frozen=True)
class CheckedColumns:
    """A law class's diagnostic, its result checked: real numbers of the shape ``(rows, batch)``
    (a width of 1) or ``(rows, batch, width)`` the engine takes, or one that broadcasts to it."""

    evaluate: Evaluate
    declared: Diagnostic
    law: str

    def __call__(self, x_q: Columns, yd: Columns, state: Columns) -> np.ndarray:
        d = self.declared
        values = _numbers(self.evaluate(x_q, yd, state), self.law, d)
        wanted = np.shape(x_q[0]) + ((d.width,) if d.width > 1 else ())
        try:
            fits = np.broadcast_shapes(values.shape, wanted) == wanted
        except ValueError:
            fits = False
        if not fits:
            axes = "rows, batch, width" if d.width > 1 else "rows, batch"
            raise _refuse(self.law, d, f"must return shape {wanted} ({axes}), got shape {values.shape}")
        return values
