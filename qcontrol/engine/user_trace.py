"""A user law traced for the compiled loop: its own Python code run once on traced inputs, and
the recorded lines checked against it.

A :class:`~qcontrol.Law` is Python called copy by copy (:class:`~qcontrol.controller.user.UserLaw`).
Here each copy's ``control`` and its update (``advance``, or the engine's RK4 of ``state_rate``)
are called once with inputs whose entries are the traced form's symbols
(:mod:`qcontrol.compiled.traced`): ``x_q``, ``yd`` and the state are object arrays of symbols,
``t`` a symbol. Whatever the law computes from them with ``+ - * /``, indexing, ``tolist()``,
``np.array([...])``, ``float()``, expressions' ``on_floats`` and the numpy and ``math`` that
:mod:`.user_numpy` records (functions of one value, products of two vectors, where numpy's float
is the compiled line's) is recorded, in order, as lines of the compiled loop
(:mod:`.compiled_user`); the sample the update holds (u, ``x_q``, ``yd``, ``t``) is kept in the
loop's ``held`` array.

A law has no compiled form (:attr:`UserLaw.compiled_form` says why) when any of these holds:

* tracing fails: the law converts an input to a float outside its own module, compares or
  branches on one, uses numpy's reductions or matrix products (``np.sum``, ``A @ x``) or a numpy
  function that rounds differently from ``math`` on this machine, whose float results no
  compiled line restates, divides by an input in its update, or returns what its method must not;
* the law changed itself while traced (an attribute, a list it keeps), or traces to other lines
  or numbers when traced again (random numbers, a clock);
* the copies of a batch trace to different code;
* the check: the recorded lines, run in Python, must give the law's own Python results bit for
  bit (u, and the state one step on through the engine's own update) at :data:`CHECKS` samples
  (zero and random readings, references and states): a law that reads a global that changes, or
  rounds differently, fails it.

Tracing calls the law's methods on copies of it (``copy.deepcopy``); the check calls the law
itself only once its copy was found to keep no state; numpy's and Python's global random streams
are restored afterwards and printed output is discarded, so a law without a compiled form
computes exactly what it computed before.
"""

from __future__ import annotations

import contextlib
import copy
import io
import math
import random
import re
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ..compiled.traced import Symbol, recording
from ..controller.user import FastCalls, UserLaw, advances_itself, sample
from .compiled_loop import CONTROL_REFUSED
from .user_numpy import TracedInputs, UserSymbol, UserTrace, fma, inputs, same_bits, traced_names

COMPILED = "compiled"  # UserLaw.compiled_form of a law that has a compiled form
CHECKS = 8  # samples at which the traced lines must equal the law's Python, bit for bit
def _real(value: Any) -> Any:
    """A traced result entry: a symbol, or a real number as a float; else TypeError."""
    if isinstance(value, Symbol):
        return value
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | float | np.integer | np.floating):
        raise TypeError(f"returned {type(value).__name__} {value!r} where a number was expected")
    return float(value)


def _state(value: Any, m: int, method: str) -> list[Any]:
    """A traced state (``advance``'s or ``state_rate``'s result) as m entries; else TypeError."""
    if isinstance(value, Symbol) or (isinstance(value, np.ndarray) and value.ndim == 0):
        value = [value.item() if isinstance(value, np.ndarray) else value]
    if isinstance(value, np.ndarray):
        if value.ndim != 1:
            raise TypeError(f"{method} returned shape {value.shape}")
        value = value.tolist()
    if not isinstance(value, list | tuple) or len(value) != m:
        raise TypeError(f"{method} returned {type(value).__name__}, not {m} numbers")
    return [_real(v) for v in value]


class Held(NamedTuple):
    """Where the sample sits in the loop's ``held`` array: u, then x_q, yd and t."""

    n: int

    @property
    def width(self) -> int:
        return 2 * self.n + 3

    def symbols(self) -> tuple[Symbol, TracedInputs, TracedInputs, Symbol]:
        n = self.n
        return (UserSymbol("held[0]"), inputs([UserSymbol(f"held[{1 + i}]") for i in range(n)]),
                inputs([UserSymbol(f"held[{1 + n + j}]") for j in range(n + 1)]),
                UserSymbol(f"held[{2 * n + 2}]"))


class CopyTrace(NamedTuple):
    """One copy's law as lines: ``control`` (from ``sq{i}``, ``yd[r, j]``, ``adaptive`` and
    ``st`` to ``held``) and ``advance`` (``held`` and ``adaptive`` to ``adaptive``), and the
    constants ``lp`` they read."""

    control: list[str]
    advance: list[str]
    constants: list[Any]


def _rk4(rate: Any, t: Any, x_q: Any, yd: Any, state: TracedInputs, h: float, m: int) -> Any:
    """:meth:`UserLaw.step_state`'s RK4 of ``state_rate``, the same operations on traced arrays."""
    half = 0.5 * h
    k1 = inputs(_state(rate(t, x_q.copy(), yd.copy(), state.copy()), m, "state_rate()"))
    k2 = inputs(_state(rate(t, x_q.copy(), yd.copy(), state + half * k1), m, "state_rate()"))
    k3 = inputs(_state(rate(t, x_q.copy(), yd.copy(), state + half * k2), m, "state_rate()"))
    k4 = inputs(_state(rate(t, x_q.copy(), yd.copy(), state + h * k3), m, "state_rate()"))
    return state + h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)


def trace_copy(law: Any, n: int, m: int, dt: float, slots: Sequence[float] = ()) -> CopyTrace:
    """``law``'s control and update as lines (see the module docstring), its locals ``w1, w2, ..``
    and its constants after ``slots`` (the quantizer's); raises TypeError (or whatever the law
    raises) where it cannot be traced. ``law`` should be a copy: it is called."""
    trace, held = UserTrace(prefix="w"), Held(n)
    trace.constants = list(slots)
    with recording(trace), traced_names(law):
        with trace.refusing(f"return {CONTROL_REFUSED}, k"):
            x_q = inputs([UserSymbol(f"sq{i}") for i in range(n)])
            yd = inputs([UserSymbol(f"yd[r, {j}]") for j in range(n + 1)])
            state = inputs([UserSymbol(f"adaptive[{i}]") for i in range(m)])
            t = UserSymbol("st")
            u = trace.text(_real(law.control(t, x_q.copy(), yd.copy(), state.copy())))
            trace.lines += [f"held[0] = {u}", *[f"held[{1 + i}] = sq{i}" for i in range(n)],
                            *[f"held[{1 + n + j}] = yd[r, {j}]" for j in range(n + 1)],
                            f"held[{2 * n + 2}] = st"]
        control = trace.taken()
        if m:
            _, hq, hyd, ht = held.symbols()
            if advances_itself(law):
                new = _state(law.advance(ht, hq, hyd, state.copy(), dt), m, "advance()")
            else:
                new = _state(_rk4(law.state_rate, ht, hq, hyd, state, dt, m), m, "state_rate()")
            temps = [trace.assign(trace.text(v)).text for v in new]  # all read before any is written
            trace.lines += [f"adaptive[{i}] = {v}" for i, v in enumerate(temps)]
        advance = trace.taken()
    if any(isinstance(c, np.ndarray) for c in trace.constants):
        raise TypeError("an array of numbers met a single traced value")
    return CopyTrace(control, advance, trace.constants)


@contextlib.contextmanager
def quietly() -> Any:
    """Printed output discarded and the global random streams restored: the law is only traced."""
    numpy_state, python_state = np.random.get_state(), random.getstate()  # noqa: NPY002 (a law may use it)
    try:
        with contextlib.redirect_stdout(io.StringIO()), np.errstate(all="ignore"):
            yield
    finally:
        np.random.set_state(numpy_state)  # noqa: NPY002
        random.setstate(python_state)


_VALUES = frozenset({str, int, bool, type(None), bytes, complex})  # no attributes; == never raises


def unchanged(a: Any, b: Any, depth: int = 0) -> bool:
    """Whether a law's attribute is unchanged (its copy before and after tracing): numbers to the
    bit, arrays, containers and plain objects entry by entry; a symbol anywhere is a change."""
    kind = type(a)
    if kind is not type(b):
        return False
    if kind in _VALUES:  # (what the last line decides, without looking for attributes first)
        return bool(a == b)
    if kind is float or isinstance(a, float | np.floating):
        return bool(a == b or (a != a and b != b)) and math.copysign(1, a) == math.copysign(1, b)  # NaN: NaN
    if isinstance(a, Symbol):
        return False
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and (
            _all_unchanged(a.ravel(), b.ravel(), depth) if a.dtype == object else a.tobytes() == b.tobytes())
    if isinstance(a, list | tuple):
        return len(a) == len(b) and _all_unchanged(a, b, depth)
    if isinstance(a, dict):
        return a.keys() == b.keys() and _all_unchanged(a.values(), [b[k] for k in a], depth)
    if isinstance(a, np.random.Generator):
        return a.bit_generator.state == b.bit_generator.state
    if depth < 4 and not isinstance(a, type):
        try:
            return unchanged(vars(a), vars(b), depth + 1)
        except TypeError:  # no attributes of its own: compared as a value below
            pass
    try:
        return bool(a == b)
    except Exception:  # an object without a plain equality: unchanged only if it is the same one
        return a is b


def _all_unchanged(a: Any, b: Any, depth: int) -> bool:
    """:func:`unchanged` for each pair of entries of ``a`` and ``b`` (of the same length)."""
    for x, y in zip(a, b):  # noqa: B905 (the same length)
        if not unchanged(x, y, depth + 1):
            return False
    return True


def check_points(n: int, m: int, state0: np.ndarray, seed: int) -> list[tuple]:
    """The samples of the check: zero readings with the initial state, then random ones."""
    rng = np.random.default_rng(seed)
    points = [(0.0, np.zeros(n), np.zeros(n + 1), state0.copy())]
    for i in range(CHECKS - 1):
        scale = 10.0 ** rng.uniform(-2, 1)
        points.append((float(rng.uniform(0, 10)) * (i > 0), rng.normal(0, scale, n),
                       rng.normal(0, scale, n + 1), state0 + rng.normal(0, scale, m)))
    return points


class QuietFunction:
    """One function of ``math`` as compiled code has it: where Python's raises (a domain error, an
    overflow), numpy's value (NaN, Inf) instead, which the traced lines then test and refuse."""

    def __init__(self, name: str) -> None:
        self.function = getattr(math, name)
        self.fallback = getattr(np, {"pow": "power"}.get(name, name))

    def __call__(self, *args: float) -> Any:
        try:
            return self.function(*args)
        except (ValueError, OverflowError):
            with np.errstate(all="ignore"):
                return float(self.fallback(*args))


class QuietMath:
    """``math`` as compiled code has it (:class:`QuietFunction`), for running traced lines in Python."""

    def __getattr__(self, name: str) -> Any:
        value = getattr(math, name)
        return QuietFunction(name) if callable(value) else value


_CHECKERS: dict[str, dict[str, Any]] = {}  # check functions by their source (copies share them)


def check_functions(trace: CopyTrace, n: int) -> dict[str, Any]:
    """The traced lines as two Python functions, ``control`` and ``advance`` (the loop's own lines,
    run by Python: numba gives Python's float operations)."""
    source = "\n".join(["def control(sq, yd, adaptive, st, lp, held):", "    r, k = 0, 0",
                        *[f"    sq{i} = sq[{i}]" for i in range(n)],
                        *[f"    {line}" for line in trace.control], "    return 0, 0", "",
                        "def advance(adaptive, lp, held):", *[f"    {line}" for line in trace.advance],
                        "    return None"])
    if source not in _CHECKERS:
        if len(_CHECKERS) > 64:
            _CHECKERS.clear()
        names = {"math": QuietMath(), "np": np, "fma": fma}
        exec(compile(source, "<traced law>", "exec"), names)  # noqa: S102 (text made by the tracer alone)
        _CHECKERS[source] = names
    return _CHECKERS[source]


def checked(trace: CopyTrace, law: Any, user: UserLaw, dt: float, points: int) -> str | None:
    """Why the traced lines do not give ``law``'s own Python results, u and the state one step on
    through the engine's update (``user``'s :meth:`~UserLaw.step_state`), bit for bit at
    ``points`` check samples (None: they do). The law is called as the engine calls it."""
    n, m = user.n, user.state_size
    functions, lp = check_functions(trace, n), np.array(trace.constants, dtype=float)
    state0 = np.asarray(law.initial_state(), dtype=float).reshape(m)
    compared = 0
    for t, x_q, yd, state in check_points(n, m, state0, seed=n * 1000 + m)[:points]:
        held, adaptive = np.zeros(Held(n).width), state.copy()
        status, _ = functions["control"](x_q, yd.reshape(1, -1), adaptive, t, lp, held)
        if status:
            continue  # the traced lines hand over to Python here: nothing to compare
        user.failures.clear()
        try:
            u = user._number(law.control(t, x_q.copy(), yd.copy(), state.copy()))
            stepped = user.step_state(law, sample((u, t, [x_q], yd)), x_q, state.copy(), dt) if m else state
        except Exception as exc:
            return f"its Python raises where its traced lines do not ({type(exc).__name__}: {exc})"
        if user.failures:
            return "its Python fails where its traced lines do not"
        functions["advance"](adaptive, lp, held)
        pairs = zip([u, *stepped.tolist()], [held[0], *adaptive.tolist()], strict=True)
        if not all(same_bits(a, b) for a, b in pairs):
            return (f"its traced lines differ from its Python at t = {t:g}, x_q = {x_q.tolist()}: u "
                    f"{held[0]!r} vs {u!r}, state {adaptive.tolist()} vs {stepped.tolist()}")
        compared += 1
    return None if compared >= (points + 1) // 2 else "too few samples where it gives a number to check it"


def why_not(exc: BaseException) -> str:
    """A traced law's failure as a reason a user can act on."""
    text = str(exc)
    if "float() argument" in text or "must be real number" in text:
        return ("it converts a value computed from its inputs to a number outside its own module "
                "(float() or math in a helper module, dtype=float, an array of numbers it fills)")
    if "for ** or pow()" in text:
        return ("it raises a value computed from its inputs to a power with ** (pow rounds its own way, "
                "not as x * x): write the product, or an expression")
    if text.startswith("numpy's"):
        return f"it uses {text}"
    if "branches on a column" in text or "not supported between" in text:
        return "it compares or branches on a value computed from its inputs"
    if "may raise where no hand-over" in text:
        return ("its state update divides by a value computed from its inputs, or calls a function "
                "that may refuse one (log, sqrt, exp)")
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def trace_one(law: Any, user: UserLaw, dt: float, slots: Sequence[float], first: bool) -> CopyTrace | str:
    """One copy's law traced on a copy of it, then its lines checked against the law itself; or
    why not. The ``first`` copy of its class is traced twice, the second time on the copy as the
    first left it (a call may fill a cache), and must have stayed as it was and record the same
    lines; it is checked at :data:`CHECKS` samples, a later copy of the same class at 3."""
    n, m = user.n, user.state_size
    try:
        with quietly():
            traced = copy.deepcopy(law)
            one = trace_copy(traced, n, m, dt, slots)
            if first:
                before = copy.deepcopy(traced)
                again = trace_copy(traced, n, m, dt, slots)
                if not unchanged(vars(before), vars(traced)):
                    return "it changes its own attributes (a state kept outside its declared state)"
                if again != one:
                    return "it computes differently at each call (random numbers, a clock, a global?)"
            why = checked(one, law, user, dt, CHECKS if first else 3)  # the law itself, keeping no state
    except Exception as exc:  # any failure of the user's code on symbols: the Python loop
        return why_not(exc)
    return one if why is None else why


def same_law(a: Any, b: Any) -> bool:
    """Whether copy ``b`` is copy ``a`` again: the same class with the same attributes
    (:func:`unchanged`: numbers to the bit), so that it traces to the same lines and constants."""
    if a is b:
        return True
    try:
        return type(a) is type(b) and unchanged(vars(a), vars(b))
    except TypeError:  # no attributes to compare (slots): traced on its own
        return False


def trace_law(law: UserLaw, n: int, dt: float, slots: Sequence[float] = ()
              ) -> tuple[list[CopyTrace], None] | tuple[None, str]:
    """Each copy's :class:`CopyTrace` (one for the one law of every copy), checked; or why not.
    A copy equal to the copy before it (:func:`same_law`) takes that copy's trace: tracing is a
    function of the law's class and attributes (the first copy of a class is traced twice and
    must stay as it was and record the same lines), so it would record the same lines again."""
    traces: list[CopyTrace] = []
    user = UserLaw(law.laws[:1], law.c, law.max_error, law.state_name, law.kind)  # the engine's calls
    user._checked.update(["control()", "advance()", "state_rate()"])  # (first-call checks: the run's)
    classes: set[type] = set()
    for i, copy_law in enumerate(law.laws):
        if traces and same_law(law.laws[i - 1], copy_law):
            traces.append(traces[-1])
            continue
        one = trace_one(copy_law, user, dt, slots, type(copy_law) not in classes)
        if isinstance(one, str):
            return None, one
        classes.add(type(copy_law))
        if traces and (one.control, one.advance) != (traces[0].control, traces[0].advance):
            return None, "its copies in this batch trace to different code"
        traces.append(one)
    return traces, None


def explain(law: UserLaw, n: int, dt: float) -> str | None:
    """None when the law has a compiled form for a step ``dt``, else why not (kept on the law)."""
    if law.compiled_form is None:
        law.compiled_form = trace_law(law, n, dt)[1] or COMPILED
    return None if law.compiled_form == COMPILED else law.compiled_form


_RENAMED = ((re.compile(r"yd\[r, (\d+)\]"), r"y\1"), (re.compile(r"adaptive\[(\d+)\]"), r"a\1"),
            (re.compile(r"held\[(\d+)\]"), r"h\1"))
_SLOT = re.compile(r"lp\[(\d+)\]")


def _renamed(line: str, constants: Literals) -> str:
    """A traced line of the loop as a line of :func:`python_calls`' functions."""
    for pattern, name in _RENAMED:
        line = pattern.sub(name, line)
    return "    " + _SLOT.sub(constants, line).replace(f"return {CONTROL_REFUSED}, k", "return None")


def python_calls(trace: CopyTrace, n: int, m: int) -> FastCalls:
    """One copy's traced lines as two plain Python functions on floats, the law's calls on the
    Python loop (:attr:`UserLaw.fast`): ``control(q.., yd.., state.., t) -> u`` and
    ``advance(q.., yd.., t, state..) -> state``, None where the compiled loop would hand over.
    The same lines the check ran, with the arrays' entries as locals and the constants as
    literals: the same operations on the same numbers. The same trace again (a law's next run,
    or another law tracing to the same lines and constants) gives the functions made before."""
    traced = (n, m, tuple(trace.control), tuple(trace.advance), repr(tuple(trace.constants)))
    if traced not in _CALLS:
        if len(_CALLS) > 64:
            _CALLS.clear()
        _CALLS[traced] = _calls_of(trace, n, m)
    return _CALLS[traced]


def _calls_of(trace: CopyTrace, n: int, m: int) -> FastCalls:
    constants = Literals(trace.constants)
    q, y, a = [f"sq{i}" for i in range(n)], [f"y{j}" for j in range(n + 1)], [f"a{i}" for i in range(m)]
    sample = [f"h{1 + i}" for i in range(n)] + [f"h{1 + n + j}" for j in range(n + 1)] + [f"h{2 * n + 2}"]
    source = "\n".join([f"def control({', '.join([*q, *y, *a, 'st'])}, lp=lp):",
                        *[_renamed(line, constants) for line in trace.control], "    return h0", "",
                        f"def advance({', '.join([*sample, *a])}, lp=lp):",
                        *[_renamed(line, constants) for line in trace.advance],
                        f"    return ({''.join(v + ', ' for v in a)})"])
    names = {"math": math, "np": np, "fma": fma, "lp": tuple(trace.constants)}
    exec(compile(source, "<traced law>", "exec"), names)  # noqa: S102 (text made by the tracer alone)
    return FastCalls(names["control"], names["advance"])


_CALLS: dict[tuple, FastCalls] = {}  # the functions of python_calls by the trace they are made from


class Literals:
    """``lp[i]`` as the literal of its number where Python reads one back exactly, else as it is."""

    def __init__(self, constants: Sequence[float]) -> None:
        self.constants = constants

    def __call__(self, match: re.Match) -> str:
        value = float(self.constants[int(match[1])])
        return f"({value!r})" if math.isfinite(value) else match[0]
