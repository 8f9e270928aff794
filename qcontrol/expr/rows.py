"""Regressor rows of a parametric strict-feedback plant, ``x_i' = x_{i+1} + phi_i(x_1..x_i)^T
theta``: n rows of l expressions each, "0" where a term is absent (docs/math.md). The chain of
eq. (1) is the case where every row before the last is 0. Shared by the plant's terms and the
context a law is built from."""

from __future__ import annotations

from collections.abc import Sequence

from . import Expression, compile_expression

Rows = tuple[tuple[Expression, ...], ...]


def is_zero(expression: Expression) -> bool:
    """True when ``expression`` is the constant 0 (an absent regressor, written "0")."""
    return expression._tree.constant == 0.0


def first_nonzero_row(rows: Sequence[Sequence[Expression]]) -> int | None:
    """The first equation i (1-based) among ``rows`` (phi_1 .. phi_{n-1}) whose row has a term that
    is not 0, or None: the plant is then the chain of eq. (1), the paper's class."""
    for i, row in enumerate(rows):
        if any(not is_zero(e) for e in row):
            return i + 1
    return None


def regressor_rows(order: int, last: Sequence[Expression], rows: Sequence[Sequence[Expression]]) -> Rows:
    """All n rows phi_1 .. phi_n: ``rows`` (phi_1 .. phi_{n-1}) and ``last`` (phi_n); rows not
    given are the expression 0 over ``x1 .. xn`` in every entry."""
    if rows:
        return (*(tuple(row) for row in rows), tuple(last))
    zero = compile_expression("0", [f"x{i + 1}" for i in range(order)], "plant.phi")
    return (*([(zero,) * len(last)] * (order - 1)), tuple(last))
