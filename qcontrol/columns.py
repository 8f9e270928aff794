"""Columns, the form the laws' and the ODE plant's formulas are written in, and the array form.

A *column* holds one value per copy of a batch: the reading's ``q_i``, an adaptive estimate, a
state ``x_i``, a per-copy parameter. The formulas of eqs. (31)-(34), (44)-(46) and the plant's
RK4 of eq. (1) are written once over columns with elementwise arithmetic (``+ - * /``), so the
same lines run on whatever a column is. What differs between kinds of column is gathered in a
:class:`ColumnForm`: how a parameter becomes a column, how expressions are evaluated on columns,
the elementwise functions the formulas call, and how columns and ``(batch, k)`` arrays turn into
each other. A part asks the form it is given (a reading's :attr:`~qcontrol.quantizer.QuantizedReading.form`,
the form a plant is stepped in) and never branches on what a column is.

:data:`ARRAYS` is the form every part serves: each column a ``(batch,)`` numpy array, the
documented array form of the plant and law protocols. The engine runs a batch in it and chooses,
in one place (:mod:`qcontrol.engine.fastpath`), the form a single run steps in.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from .expr import Expression, combine
from .expr.calculus import Program

Column = float | np.ndarray  # one value per copy: a (batch,) array in the array form
Columns = tuple  # of Column: q_1 .. q_n, or the adaptive estimates
Parameter = float | np.ndarray  # a scalar, or one value per copy of the batch (shape (batch,))
Terms = Callable[[Sequence[Column]], list[Column]]  # expressions evaluated on columns, in order


class ColumnForm(Protocol):
    """What a formula written over columns needs to know about its columns (module docstring).

    A form is used as a dictionary key by the parts that keep what they computed for it (a law's
    constants): it is compared by identity.
    """

    expm1: Callable[[Column], Column]  # exp(x) - 1, elementwise
    maximum: Callable[[Column, Column], Column]  # numpy's maximum (NaN where either is), elementwise

    def column(self, values: Parameter | list[float]) -> Column:
        """A parameter, one number for every copy or per-copy values (a ``(batch,)`` array or a
        list), as a column of this form."""

    def terms(self, expressions: Sequence[Expression]) -> Terms:
        """``f(columns) -> [e(columns) for e in expressions]``: the expressions evaluated on columns
        of this form (``columns[i]`` the values of the expressions' ``variables[i]``)."""

    def program(self, program: Program) -> Callable[[Sequence[Column]], list[Column]]:
        """``f(columns) -> [value of each tree]``: a :class:`~qcontrol.expr.calculus.Program`
        (trees sharing subtrees, each node evaluated once) on columns of this form."""

    def combination(self, expressions: Sequence[Expression], coefficients: Sequence[Parameter | None]
                    ) -> Callable[[Sequence[Column]], Column]:
        """``f(columns) -> sum of c * e(columns)``, left to right, over the expressions and their
        coefficients (parameters as for :meth:`column`; None: the expression as it is)."""

    def columns(self, rows: np.ndarray) -> list[Column]:
        """A ``(batch, k)`` array as its k columns."""

    def array(self, columns: Sequence[Column], batch: int) -> np.ndarray:
        """k columns side by side as a ``(batch, k)`` array (``(batch, 0)`` for none)."""


class ColumnTerms:
    """Expressions evaluated on ``(batch,)`` array columns with numpy (:meth:`Expression.on_columns`)."""

    def __init__(self, expressions: Sequence[Expression]) -> None:
        self.functions = tuple(e.on_columns for e in expressions)

    def __call__(self, columns: Sequence[Column]) -> list[Column]:
        return [f(columns) for f in self.functions]


class Combination:
    """A linear combination of expressions on array columns (:func:`qcontrol.expr.combine`)."""

    def __init__(self, pairs: tuple) -> None:
        self.pairs = pairs

    def __call__(self, columns: Sequence[Column]) -> Column:
        return combine(self.pairs, columns)


def stack(columns: Sequence[Column], batch: int) -> np.ndarray:
    """Columns (arrays, or a number shared by every copy) side by side: shape ``(batch,
    len(columns))``, or more rows if the columns are longer (a state of one copy advanced with a
    batch's targets)."""
    if not columns:
        return np.empty((batch, 0))
    shape = np.broadcast_shapes((batch,), *(np.shape(c) for c in columns))
    return np.stack([np.broadcast_to(c, shape) for c in columns], axis=1)


class ArrayForm:
    """The array form: every column a ``(batch,)`` numpy array (a parameter shared by every copy
    stays a number, which numpy broadcasts)."""

    expm1 = staticmethod(np.expm1)
    maximum = staticmethod(np.maximum)

    def column(self, values: Parameter | list[float]) -> Column:
        return np.array(values, dtype=float) if type(values) is list else values

    def terms(self, expressions: Sequence[Expression]) -> Terms:
        return ColumnTerms(expressions)

    def program(self, program: Program) -> Callable[[Sequence[Column]], list[Column]]:
        return program  # (numpy's functions on the columns)

    def combination(self, expressions: Sequence[Expression], coefficients: Sequence[Parameter | None]
                    ) -> Combination:
        return Combination(tuple(zip(coefficients, (e.on_columns for e in expressions), strict=True)))

    def columns(self, rows: np.ndarray) -> list[Column]:
        return list(np.ascontiguousarray(np.asarray(rows, dtype=float).T))

    def array(self, columns: Sequence[Column], batch: int) -> np.ndarray:
        try:  # the common case, k (batch,) arrays: one copy
            rows = np.array(columns, dtype=float)
        except ValueError:  # numbers beside arrays
            return stack(columns, batch)
        return rows.T if rows.shape == (len(columns), batch) else stack(columns, batch)

    def __repr__(self) -> str:
        return "ARRAYS"


ARRAYS: ColumnForm = ArrayForm()
