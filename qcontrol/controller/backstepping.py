"""Backstepping coordinates with quantized states: the mathematics every law shares.

* :func:`backstepping_coefficients`: the constant coefficients of the virtual controls,
  recursion after eq. (27): ``alpha_i = sum_k a[i][k] x_k + sum_j b[i][j] y_d^(j)``.
* :func:`lemma2_bounds` and :func:`lemma2_L`: Lemma 2 (Appendix A), ``|z_i - zbar_i| <= L_zi``.
* :class:`Backstepping`: true errors z, eqs. (7), (8), (12), (20), (27), and quantized errors
  zbar and virtual controls alphabar, eqs. (31)-(34).
* :class:`ControlOutput`: what one evaluation of a law hands the engine.

The laws' formulas are written once, over *columns* (:mod:`qcontrol.columns`): one value per
state (``q_1 .. q_n``) or per adaptive estimate, in the form the reading says
(``reading.form``). They use only elementwise arithmetic, coefficients precomputed as Python
floats and what the form supplies (parameters as columns, expressions evaluated on columns), so
the same lines step a batch of 1000 copies and a single run in whatever form the engine runs it.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from functools import partial, update_wrapper
from types import MethodType
from typing import Any, ClassVar, NamedTuple

import numpy as np

from ..columns import Column, ColumnForm, Columns, Parameter
from ..errors import QcontrolInputError
from ..quantizer import QuantizedReading


def parameter(name: str, value: float | Sequence[float] | np.ndarray) -> Parameter:
    """A controller constant as a float, or as a ``(batch,)`` array of per-copy values."""
    array = np.asarray(value, dtype=float)
    if array.ndim > 1 or array.size == 0:
        raise QcontrolInputError(f"controller {name} must be a number or a list of per-copy numbers")
    if not (np.all(np.isfinite(array)) and np.all(array > 0)):
        raise QcontrolInputError(f"controller {name} must be a finite number > 0, got {value!r}")
    return float(array) if array.ndim == 0 else array


def backstepping_coefficients(c: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of ``alpha_i`` in x and in the reference derivatives (recursion after eq. (27)).

    Returns ``A`` of shape ``(n, n)`` with ``A[i-1, k-1] = a[i][k]`` (zero for k > i) and ``B`` of
    shape ``(n, n+1)`` with ``B[i-1, j] = b[i][j]`` (coefficient of ``y_d^(j)``).
    """
    c = np.asarray(c, dtype=float)
    n = c.size
    A = np.zeros((n, n))
    B = np.zeros((n, n + 1))
    A[0, 0] = -c[0]
    B[0, 0], B[0, 1] = c[0], 1.0
    for i in range(1, n):  # row i holds alpha_{i+1}
        ci = c[i]
        A[i, 0] = ci * A[i - 1, 0]
        A[i, 1:i] = ci * A[i - 1, 1:i] + A[i - 1, 0 : i - 1]
        A[i, i] = -ci + A[i - 1, i - 1]
        B[i, 0] = ci * B[i - 1, 0]
        B[i, 1 : i + 2] = ci * B[i - 1, 1 : i + 2] + B[i - 1, 0 : i + 1]
    return A, B


def lemma2_bounds(c: Sequence[float], max_error: float | Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Lemma 2 (Appendix A) with one bound per channel: ``L_z`` and ``L_alpha`` (both shape ``(n,)``).

    ``max_error`` is the quantizer's worst-case error m_i of each channel (a number: the same m on
    every channel, ``delta / 2`` of property (4) for the paper's quantizer):
    ``L_z1 = m_1``, ``L_alpha1 = c_1 m_1``; ``L_zi = m_i + L_alpha(i-1)``,
    ``L_alphai = c_i L_zi + sum_{k<i} |a[i-1][k]| m_{k+1}``. The paper's ``L`` is ``L_z[-1]``
    (``m_2 + c_1 m_1`` for n = 2). With one m for every channel the sum is computed as
    ``m sum_k |a[i-1][k]|``, the paper's form of the same number.
    """
    c = np.asarray(c, dtype=float)
    A, _ = backstepping_coefficients(c)
    n = c.size
    same = np.ndim(max_error) == 0
    m = np.full(n, float(max_error)) if same else np.asarray(max_error, dtype=float)
    if m.shape != (n,):
        raise QcontrolInputError(f"the quantizer gives {m.size} channel bound(s) for a plant of order {n}")
    L_z = np.empty(n)
    L_alpha = np.empty(n)
    L_z[0] = m[0]
    L_alpha[0] = c[0] * m[0]
    for i in range(1, n):
        L_z[i] = m[i] + L_alpha[i - 1]
        weights = np.abs(A[i - 1, :i])
        spread = m[0] * weights.sum() if same else (weights * m[1 : i + 1]).sum()
        L_alpha[i] = c[i] * L_z[i] + spread
    return L_z, L_alpha


def lemma2_L(c: Sequence[float], delta: float) -> float:
    """The paper's ``L = L_zn`` (Lemma 2) for gains ``c`` and quantizer step ``delta``
    (``(1 + c_1) delta / 2`` for n = 2); ``kappa`` must exceed it (Theorem 1)."""
    with np.errstate(all="ignore"):
        return float(lemma2_bounds(c, delta / 2.0)[0][-1])


# (c's bytes, the bound) -> the arrays and numbers Backstepping derives from them: a batch of user
# laws builds the same coordinates once per copy (about 70 us each), which copying them replaces
_COORDINATES: dict[tuple, tuple] = {}


class Backstepping:
    """Backstepping coordinates for gains ``c`` and a quantizer with bound ``max_error`` (a number,
    or one per channel)."""

    diagnostics: tuple = ()  # a law's own signals (:class:`~.law.Diagnostic`); none by default

    def __init__(self, c: Sequence[float], max_error: float) -> None:
        c = np.asarray(c, dtype=float)
        if c.ndim != 1 or c.size < 2:
            raise QcontrolInputError(
                f"the plant order n must be >= 2 (one gain c_i per state), got {c.size} gain(s)"
            )
        if not np.all(np.isfinite(c)) or np.any(c <= 0):
            raise QcontrolInputError(f"every design gain c_i must be a finite number > 0, got {c.tolist()}")
        if not (np.all(np.isfinite(max_error)) and np.all(np.asarray(max_error) > 0)):
            raise QcontrolInputError(f"quantizer step delta must be > 0, got bound {max_error!r}")
        self.c = c
        self.n = c.size
        # one bound for every channel (a float), or one per channel (a tuple, as the quantizer's)
        self.max_error = float(max_error) if np.ndim(max_error) == 0 else tuple(float(m) for m in max_error)
        own = type(self).recursion is Backstepping.recursion and \
            type(self)._recursion_steps is Backstepping._recursion_steps
        key = (c.tobytes(), self.max_error)
        if own and key in _COORDINATES:  # the numbers another object of the same c and bound derived
            arrays, (self.L, self._steps) = _COORDINATES[key]
            self.A, self.B, self.L_z, self.L_alpha, self._Wq, self._Wy = (a.copy(order="K") for a in arrays)
            return
        self.A, self.B = backstepping_coefficients(c)
        self.L_z, self.L_alpha = lemma2_bounds(c, max_error)
        self.L = float(self.L_z[-1])
        self._steps = self._recursion_steps()
        # [zbar | alphabar] = q @ Wq + yd @ Wy (for many instants at once, when recording): the
        # recursion applied to unit vectors, as columns of a batch of n (or n + 1) copies
        n = self.n
        zbar, alphabar = self.recursion(tuple(np.eye(n)), tuple(np.zeros((n + 1, n))))
        self._Wq = np.column_stack(zbar + alphabar)
        zbar, alphabar = self.recursion(tuple(np.zeros((n, n + 1))), tuple(np.eye(n + 1)))
        self._Wy = np.column_stack(zbar + alphabar)
        if own:  # (copies kept: every object gets arrays of its own)
            if len(_COORDINATES) >= 64:
                _COORDINATES.clear()
            arrays = (self.A, self.B, self.L_z, self.L_alpha, self._Wq, self._Wy)
            _COORDINATES[key] = (tuple(a.copy(order="K") for a in arrays), (self.L, self._steps))

    @property
    def coordinates(self) -> Backstepping:
        """The coordinates the engine records z, zbar and the Lemma 2 errors in: these."""
        return self

    def _recursion_steps(self) -> tuple:
        """``alphabar_i = -c_i zbar_i + D_i``, eq. (34), with ``D_1 = y_d'`` and
        ``D_i = sum_{k<i} a[i-1][k] q_{k+1} + sum_{j<i} b[i-1][j] y_d^(j+1)``: one
        ``(-c_i, D_i's y_d terms, D_i's q terms)`` per i as Python numbers, zero terms left out."""
        n = self.n
        Dq = np.zeros((n, n))
        Dy = np.zeros((n, n + 1))
        Dy[0, 1] = 1.0
        for i in range(1, n):
            Dq[i, 1 : i + 1] = self.A[i - 1, :i]
            Dy[i, 1 : i + 2] = self.B[i - 1, : i + 1]
        return tuple(zip(
            [-ci for ci in self.c.tolist()],
            [tuple((j, b) for j, b in enumerate(row) if b != 0.0) for row in Dy.tolist()],
            [tuple((k, a) for k, a in enumerate(row) if a != 0.0) for row in Dq.tolist()],
            strict=True,
        ))

    def errors(self, x: np.ndarray, yd: np.ndarray) -> np.ndarray:
        """True errors ``z`` (eqs. (7), (8)): ``z_1 = x_1 - y_d``, ``z_i = x_i - alpha_{i-1}``.

        ``x`` has shape ``(..., n)``; ``yd`` holds ``[y_d, ..., y_d^(n)]`` in its last axis and
        broadcasts against ``x`` (e.g. ``(n+1,)`` for one instant, ``(rows, 1, n+1)`` for many).
        """
        alpha = x @ self.A.T + yd @ self.B.T
        z = np.empty(np.broadcast_shapes(x.shape, alpha.shape))
        z[..., 0] = x[..., 0] - yd[..., 0]
        z[..., 1:] = x[..., 1:] - alpha[..., :-1]
        return z

    def quantized_errors(self, q: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Quantized errors ``zbar`` and virtual controls ``alphabar``, eqs. (31)-(34).

        Shapes as in :meth:`errors`, with the quantized state ``q`` in place of ``x``. Both are
        linear in ``(q, y_d)``: one product with the coefficients :meth:`recursion` gives.
        """
        both = q @ self._Wq + yd @ self._Wy
        return both[..., : self.n], both[..., self.n :]

    def recursion(self, q: Columns, yd: Sequence[Column]) -> tuple[list[Column], list[Column]]:
        """Eqs. (31)-(34) as written, over columns: ``zbar_1 = q_1 - y_d``,
        ``alphabar_i = -c_i zbar_i + D_i``, ``zbar_{i+1} = q_{i+1} - alphabar_i``.

        ``q`` holds the columns ``q_1 .. q_n``, ``yd`` the values ``y_d .. y_d^(n)`` (floats, the
        same for every copy). Returns the lists ``zbar_1..zbar_n`` and ``alphabar_1..alphabar_n``.
        The laws call this every sample; ``__init__`` evaluates it once on unit vectors for
        :meth:`quantized_errors`.
        """
        zbar: list[Column] = []
        alphabar: list[Column] = []
        previous = yd[0]  # zbar_1 = q_1 - y_d
        for qi, (minus_c, yd_terms, q_terms) in zip(q, self._steps):  # noqa: B905 (n of each)
            z = qi - previous
            d = 0.0
            for j, b in yd_terms:
                d = d + b * yd[j]
            for k, a in q_terms:
                d = d + a * q[k]
            previous = minus_c * z + d
            zbar.append(z)
            alphabar.append(previous)
        return zbar, alphabar

    def check_reading(self, reading: object) -> None:
        """Refuse anything but a :class:`QuantizedReading` made with this controller's bound."""
        if isinstance(reading, QuantizedReading) and reading.max_error == self.max_error:
            return
        if not isinstance(reading, QuantizedReading):
            raise TypeError(
                "controllers accept only QuantizedReading (use qcontrol.quantizer.quantize); "
                f"got {type(reading).__name__}"
            )
        raise ValueError(
            f"reading quantized with bound {reading.max_error}, but the controller's Lemma 2 "
            f"bounds assume {self.max_error}"
        )


class ControlOutput(NamedTuple):
    """One evaluation of a law: input ``u``, ``zbar``, and the held quantities that drive the
    adaptive state until the next sample.

    In the form of the columns the law was given: ``u`` a column, ``zbar`` and ``target`` tuples
    of columns, ``rate`` a float or a ``(batch,)`` array.
    """

    u: Column
    zbar: tuple  # of columns, zbar_1 .. zbar_n
    target: tuple  # of columns; proposed: s r / sigma; comparison: Gamma phi zbar_n (a rate)
    rate: float | np.ndarray  # proposed: gamma sigma, a float or per copy; comparison: 0


# ControlOutput((u, zbar, target, rate)) without NamedTuple's Python-level __new__ (hot loop)
output = partial(tuple.__new__, ControlOutput)

Advance = Callable[[Columns, ControlOutput], Columns]  # (state, held output) -> state one step on


class BacksteppingLaw(Backstepping):
    """The base of a law written in column form, the form the built-in laws are written in (the
    paper's law and the comparison law derive from it): subclass it, set ``state_size`` and write
    :meth:`initial_state`, :meth:`control` (returning a :class:`ControlOutput`, ``u`` first) and
    :meth:`advancer`; register it with ``qcontrol.register_law``.

    Column form: :meth:`control` receives the reading's columns ``reading.columns`` (``q_1 ..
    q_n``) and the state as a tuple of columns, all in the reading's form (``reading.form``, a
    :class:`~qcontrol.columns.ColumnForm`: ``(batch,)`` arrays in the array form); formulas
    written with elementwise arithmetic, taking parameters and expressions through the form
    (``form.column(p)``, ``form.terms(expressions)``), serve every form, so one class serves every
    batch size and the engine may run a single run in the form it chooses. Its
    :meth:`advancer_in` is therefore its :meth:`advancer`.
    """

    state_name = "state"  # names the state in outputs (the summary's final_<state_name>)
    state_size = 0
    copies: int | None = None  # the batch size per-copy parameters fix, or None
    # the built-in class with a compiled form this class is or derives from (None: no compiled
    # form); a built-in law declares itself with ``class PaperLaw(BacksteppingLaw, compiled=True)``
    compiled_class: ClassVar[type | None] = None

    def __init_subclass__(cls, compiled: bool = False, **kwargs: Any) -> None:
        """``compiled=True`` (the built-in laws with a compiled form): the class is its objects'
        :attr:`compiled_class`, and its ``__init__`` notes, once it is done, the instance
        attributes it set (what :attr:`has_compiled_equivalent` allows an object to hold)."""
        super().__init_subclass__(**kwargs)
        if compiled:
            cls.compiled_class = cls
            cls.__init__ = _NotingInit(cls.__init__)

    @property
    def has_compiled_equivalent(self) -> bool:
        """True only when the compiled form of the built-in law (:attr:`compiled_class`) may stand
        in for this object: it is an object of that class, or of a subclass whose class body
        defines nothing but a docstring, and holds no instance attribute that the class's
        ``__init__`` did not set (:func:`unchanged_from`). A subclass that defines any method or
        attribute of its own (``robust_gain``, a helper, ``from_context`` adding an attribute),
        and every law without a compiled form, is False and runs its own Python."""
        builtin = type(self).compiled_class
        return builtin is not None and unchanged_from(self, builtin, vars(self).get(BUILT_ATTRIBUTES, ()))

    @classmethod
    def from_context(cls, context: Any) -> BacksteppingLaw:
        """The law for a scenario (``context``: a :class:`~.law.LawContext` with n, dt, the
        control period, delta, c and the kind's own keys in ``context.settings``). This default
        builds the coordinates only; a law with settings reads them here."""
        return cls(context.c, context.max_error)

    def initial_state(self, batch: int) -> np.ndarray:
        """The state at t = 0, shape ``(batch, state_size)``: zeros unless overridden."""
        return np.zeros((batch, self.state_size))

    def control(self, reading: QuantizedReading, yd: Sequence[float], state: Columns,
                t: float = 0.0) -> ControlOutput:
        """``u`` at a control sample, and what :meth:`advancer`'s update holds until the next."""
        raise NotImplementedError(f"{type(self).__name__} must define control(reading, yd, state, t)")

    def advancer(self, h: float) -> Advance:
        """``(state, output) -> state`` one step ``h`` on, the output held (column form)."""
        raise NotImplementedError(f"{type(self).__name__} must define advancer(h)")

    def advancer_in(self, form: ColumnForm, h: float) -> Advance:
        """:meth:`advancer` for a state in ``form``: the same function (its formulas serve every form)."""
        return self.advancer(h)

    def constants(self) -> dict[str, Any]:
        """The law's constants as a recording shows them: none unless overridden."""
        return {}


BUILT_ATTRIBUTES = "_built_attributes"  # the instance attributes a built-in law's __init__ set


class _NotingInit:
    """A built-in law's ``__init__``, followed by noting the instance attributes it set (what
    :attr:`~BacksteppingLaw.has_compiled_equivalent` allows): a method of the class, as the
    ``__init__`` it wraps."""

    def __init__(self, init: Callable[..., None]) -> None:
        self.init = init
        update_wrapper(self, init)

    def __get__(self, law: Any, owner: type | None = None) -> Any:
        return self if law is None else MethodType(self, law)

    def __call__(self, law: BacksteppingLaw, *args: Any, **kwargs: Any) -> None:
        self.init(law, *args, **kwargs)
        setattr(law, BUILT_ATTRIBUTES, frozenset(vars(law)) | {BUILT_ATTRIBUTES})


# What every class body holds without defining anything of a law: a docstring, and the names
# Python itself puts there (an empty ``__annotations__`` too: Python 3.10+ adds one to a class
# the first time anything reads its annotations).
CLASS_BOOKKEEPING = frozenset({"__module__", "__doc__", "__qualname__", "__firstlineno__",
                               "__static_attributes__", "__dict__", "__weakref__"})


def defines_anything(cls: type) -> bool:
    """True when the body of ``cls`` defines something beyond :data:`CLASS_BOOKKEEPING`: a method,
    a property, a class attribute, an annotation."""
    own = vars(cls)
    empty = set() if own.get("__annotations__") else {"__annotations__"}
    return bool(set(own) - CLASS_BOOKKEEPING - empty)


def unchanged_from(law: object, builtin: type, attributes: Collection[str]) -> bool:
    """True when ``law`` computes exactly what the built-in class ``builtin`` computes, so that the
    compiled form of the built-in law may stand in for it: ``law`` is a ``builtin``; no class of
    its type's method resolution order that is not one of ``builtin``'s defines anything
    (:func:`defines_anything`: whatever it defines may change the numbers, so anything counts);
    and it holds no instance attribute beyond ``attributes``, the ones ``builtin.__init__`` set."""
    if not isinstance(law, builtin):
        return False
    own = [c for c in type(law).__mro__ if c not in builtin.__mro__ and defines_anything(c)]
    return not own and set(vars(law)) <= set(attributes)
