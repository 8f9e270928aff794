"""The one closed-loop engine: fixed step, zero-order hold, for any :class:`~qcontrol.plants.Plant`.

One step of the loop (DESIGN "Data flow"):

    plant state -> sensor reading -> quantizer -> controller (u, adaptive law) -> actuator -> plant

The controller is evaluated every ``control_period`` (a multiple of ``dt``); ``u`` and the
quantized reading are held in between, and the adaptive state is integrated exactly under that
hold. Every row of a :class:`Trajectory` is one instant ``t_k = k dt``: the state there, what the
controller read, and the input applied over ``[t_k, t_k + dt)``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .controller import Controller
from .error_rate import ErrorRateStream
from .errors import QcontrolInputError
from .plants.base import Plant
from .quantizer import QuantizedReading, Quantizer, float_quantizer, quantize
from .reference import Reference

ProgressCallback = Callable[[int, int], None]
# observer(start_row, stop_row, runs): rows [start_row, stop_row) of every run are final and may
# be streamed out (e.g. to a rerun recording); ``runs`` are views truncated at stop_row.
Observer = Callable[[int, int, list["Trajectory"]], None]


@dataclass(kw_only=True)
class RunRecord:
    """What every record of a run carries: the adaptive state's name, the Lemma 2 bounds ``L_z``,
    the step and horizon, and how the run ended."""

    adaptive_name: str
    L_z: np.ndarray
    dt: float
    duration: float
    diverged: bool = False
    diverged_time: float | None = None
    divergence_reason: str = ""
    wall_time_s: float = 0.0


@dataclass(kw_only=True)
class Trajectory(RunRecord):
    """Everything one closed-loop run recorded; arrays are time-major (row k is ``t[k]``).

    ``x`` is the true state, ``x_meas`` the sensor reading, ``x_q`` its quantization,
    ``yd`` holds ``[y_d .. y_d^(n)]``, ``z`` the true errors (7)-(8) from ``x``, ``zbar`` the
    quantized errors (31)-(33), ``e_z = |z(x_meas) - zbar|`` the Lemma 2 errors with bounds
    ``L_z``, ``u`` the input held over the next step and ``adaptive`` the controller's adaptive
    state (``eps_hat`` or ``theta_hat``, named by ``adaptive_name``).
    """

    t: np.ndarray  # t[k] = k dt
    x: np.ndarray
    x_meas: np.ndarray
    x_q: np.ndarray
    yd: np.ndarray
    z: np.ndarray
    zbar: np.ndarray
    e_z: np.ndarray
    u: np.ndarray
    adaptive: np.ndarray

    @property
    def lemma2_e_z(self) -> np.ndarray:
        """The Lemma 2 errors to check: every row, except the one that stopped a diverged run
        (its state is out of range, where quantization error is meaningless)."""
        return self.e_z[:-1] if self.diverged else self.e_z

    @property
    def y(self) -> np.ndarray:
        return self.x[:, 0]

    @property
    def steps(self) -> int:
        return len(self.t) - 1


@dataclass(kw_only=True)
class RunMetrics(RunRecord):
    """What ``simulate(..., record="metrics")`` keeps of one run: everything
    :func:`qcontrol.metrics.summary` reads, in memory that does not grow with the run's length.

    ``error_rate`` is Table 1's E(omega) (streamed, :mod:`qcontrol.error_rate`),
    ``max_abs_z1_last_half``, ``max_abs_u`` and ``e_z_max`` (per i) are the largest finite
    ``|z_1|`` over the last half, ``|u|`` and Lemma 2 errors (``-inf``/NaN when there is none),
    ``final_adaptive`` the last adaptive state; ``steps`` the steps taken. The same ``summary``
    gives the same numbers as from a full :class:`Trajectory`.
    """

    steps: int
    error_rate: dict[str, float]
    max_abs_z1_last_half: float
    max_abs_u: float
    e_z_max: np.ndarray
    final_adaptive: np.ndarray

    @property
    def lemma2_e_z(self) -> np.ndarray:
        """The Lemma 2 errors to check (already reduced over the rows before any divergence)."""
        return self.e_z_max[None, :]


RECORD_MODES = ("full", "metrics")
METRICS_CHUNK = 1000  # rows buffered per reduction in record="metrics" (at least; see below)
METRICS_BUFFER_ELEMENTS = 5000  # rows x copies per chunk (so a single run reduces 5000 rows at a time)
OBSERVE_EVERY = 5000  # rows per observer call: streamed chunks, few enough to keep recording cheap
# A chunk (of observed or of reduced rows) takes in the run's last rows rather than leave fewer
# than half a chunk to the end: a 10 s, 1 kHz run streams 5000 + 5001 rows, not 5000 + 5000 + 1
# (each observer call costs a recording a send per series whatever its length).
REDUCE_ELEMENTS = 100_000  # rows x copies per block when deriving z, e_z (cache-sized temporaries)
FLUSH_ROWS = 1000  # a batch of one: rows kept as Python tuples before they are written to arrays


def lemma2_errors(controller: Controller, x_meas: np.ndarray, x_q: np.ndarray,
                  yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``zbar`` (eqs. (31)-(33)) from the quantized readings and the Lemma 2 errors
    ``e_z = |z(x_meas) - zbar|`` for many instants at once (shapes as in ``controller.errors``)."""
    zbar, _ = controller.quantized_errors(x_q, yd)
    return zbar, np.abs(controller.errors(x_meas, yd) - zbar)


def step_count(duration: float, dt: float, what: str = "simulation.duration") -> int:
    """Number of ``dt`` steps in ``duration``; refuses a duration that is not a multiple of dt."""
    if not (np.isfinite(dt) and dt > 0):
        raise QcontrolInputError(f"simulation.dt must be a finite number > 0, got {dt!r}")
    if not (np.isfinite(duration) and duration > 0):
        raise QcontrolInputError(f"{what} must be a finite number > 0, got {duration!r}")
    steps = round(duration / dt)
    if steps < 1 or abs(steps * dt - duration) > 1e-9 * max(1.0, duration):
        raise QcontrolInputError(
            f"{what} = {duration!r} is not a whole number of steps dt = {dt!r}; "
            "choose a duration that is a multiple of dt"
        )
    return steps


def simulate(
    plant: Plant,
    controller: Controller,
    quantizer: Quantizer,
    reference: Reference,
    x0: np.ndarray,
    duration: float,
    dt: float,
    control_period: float | None = None,
    state_bound: float = 1e6,
    progress: ProgressCallback | None = None,
    observer: Observer | None = None,
    observe_every: int = OBSERVE_EVERY,
    record: str = "full",
) -> list[Trajectory] | list[RunMetrics]:
    """Run the closed loop for every copy in ``plant``'s batch; one :class:`Trajectory` each.

    A copy whose state turns non-finite or leaves ``|x_i| <= state_bound`` stops there: its
    trajectory ends with the offending row, ``diverged`` is set and the others run on.
    ``observer`` is called every ``observe_every`` rows (the last call takes up to half as many
    more) and at the end with the rows that became final, so a recorder can stream them to disk
    while the run goes on.

    ``record="metrics"`` (for sweeps and long runs) keeps only :class:`RunMetrics`: the signals
    are buffered (``METRICS_CHUNK`` rows, more for small batches) and reduced, so 1000 copies of
    a 10 s, 1 kHz run need about 80 MB instead of several GB, and memory does not grow with the
    run's signals. The
    closed loop itself is the same. An observer then receives each buffered chunk as short
    trajectories (``t`` starting at the chunk's first instant) with rows ``[0, len)`` new.
    """
    if record not in RECORD_MODES:
        raise ValueError(f"record must be one of {RECORD_MODES}, got {record!r}")
    metrics_only = record == "metrics"
    n, batch = plant.n, plant.batch
    copies = getattr(controller, "copies", None)
    if copies is not None and copies != batch:
        raise ValueError(f"the controller has per-copy parameters for {copies} copies, the plant {batch}")
    steps = step_count(duration, dt)
    period = dt if control_period is None else control_period
    hold = round(period / dt)
    if hold < 1 or abs(hold * dt - period) > 1e-9 * period:
        raise QcontrolInputError(
            f"simulation.control_period = {period!r} must be a whole multiple of dt = {dt!r}"
        )
    rows = steps + 1

    def t_rows(first: int, stop: int) -> np.ndarray:
        """Instants ``k dt`` of rows [first, stop) (the same floats however they are sliced)."""
        return np.arange(first, stop) * dt if t_axis is None else t_axis[first:stop]

    t_axis = None  # full record: the whole time axis; metrics: instants computed per chunk
    if not metrics_only:
        t_axis = t_rows(0, rows)

    def reference_rows(first: int, stop: int) -> np.ndarray:
        """``[y_d .. y_d^(n)]`` at rows [first, stop), shape (stop - first, n+1)."""
        return np.asarray(reference.derivatives(t_rows(first, stop), n), dtype=float)

    # full record: the whole table, known ahead; metrics: computed per chunk (memory stays flat)
    YD = None if metrics_only else reference_rows(0, rows)

    def yd_rows(first: int, stop: int) -> np.ndarray:
        return reference_rows(first, stop) if YD is None else YD[first:stop]

    chunk = max(METRICS_CHUNK, METRICS_BUFFER_ELEMENTS // batch)
    buffered = min(rows, chunk + chunk // 2) if metrics_only else rows  # rows held in X .. S

    def chunk_end(first: int, size: int) -> int:
        """The last row of the chunk of ``size`` rows that starts at row ``first``, or the run's
        last row if fewer than ``size // 2`` rows would be left after it."""
        last = first + size - 1
        return rows - 1 if rows - 1 - last < size // 2 else last
    X = np.full((buffered, batch, n), np.nan)
    XM = np.full((buffered, batch, n), np.nan)
    XQ = np.full((buffered, batch, n), np.nan)
    U = np.full((buffered, batch), np.nan)
    S = np.full((buffered, batch, controller.state_size), np.nan)
    if metrics_only:
        reduced = _Reduced(rows, batch, n, controller.state_size, steps * dt)
    else:
        Z = np.full((rows, batch, n), np.nan)
        ZB = np.full((rows, batch, n), np.nan)
        EZ = np.full((rows, batch, n), np.nan)
    alive = np.ones(batch, dtype=bool)
    kept = np.full(batch, rows)
    reasons = [""] * batch
    diverged_time: list[float | None] = [None] * batch
    derived = 0  # rows [0, derived) have z, zbar, e_z filled in
    block = max(1, REDUCE_ELEMENTS // batch)  # rows per vectorized evaluation of z, zbar, e_z

    def derive(stop: int) -> None:
        """Fill z, zbar, e_z for rows [derived, stop): the same formulas as the controller's,
        evaluated for many instants at once instead of inside the time loop."""
        nonlocal derived
        for first in range(derived, stop, block):
            rows_ = slice(first, min(stop, first + block))
            yd = YD[rows_, None, :]
            with np.errstate(all="ignore"):  # rows of a diverged copy may hold NaN/Inf
                Z[rows_] = controller.errors(X[rows_], yd)
                ZB[rows_], EZ[rows_] = lemma2_errors(controller, XM[rows_], XQ[rows_], yd)
        derived = stop

    def collect(lengths: np.ndarray, now: float) -> list[Trajectory]:
        derive(int(lengths.max()))
        return runs_of(0, lengths, Z, ZB, EZ, now)

    def chunk_runs(stop: int, now: float) -> list[Trajectory]:
        """record="metrics": the buffered rows [base, stop) as short trajectories."""
        m = stop - base
        yd = yd_rows(base, stop)[:, None, :]
        with np.errstate(all="ignore"):
            z = controller.errors(X[:m], yd)
            zbar, e_z = lemma2_errors(controller, XM[:m], XQ[:m], yd)
        return runs_of(base, np.clip(kept - base, 0, m), z, zbar, e_z, now)

    def runs_of(first: int, lengths: np.ndarray, Z: np.ndarray, ZB: np.ndarray, EZ: np.ndarray,
                now: float) -> list[Trajectory]:
        """Trajectories over rows first + [0, lengths[b]) of the held arrays (views, no copies)."""
        return [
            Trajectory(
                t=t_rows(first, first + lengths[b]),
                x=X[: lengths[b], b],
                x_meas=XM[: lengths[b], b],
                x_q=XQ[: lengths[b], b],
                yd=yd_rows(first, first + lengths[b]),
                z=Z[: lengths[b], b],
                zbar=ZB[: lengths[b], b],
                e_z=EZ[: lengths[b], b],
                u=U[: lengths[b], b],
                adaptive=S[: lengths[b], b],
                adaptive_name=controller.state_name,
                L_z=controller.L_z.copy(),
                dt=dt,
                duration=steps * dt,
                diverged=diverged_time[b] is not None,
                diverged_time=diverged_time[b],
                divergence_reason=reasons[b],
                wall_time_s=now - started,
            )
            for b in range(batch)
        ]

    def stop_diverged(first: int, stop: int) -> None:
        """Test rows [first, stop) of every copy still running: a copy whose state or adaptive
        estimate is NaN/Inf there, or whose ``|x_i|`` exceeds ``state_bound``, stops at the first
        such row (its record ends with it)."""
        held = slice(first - base, stop - base)
        x, adaptive = X[held], S[held]  # (rows, batch, n), (rows, batch, m)
        bad_state = ~np.isfinite(x).all(axis=2) | ~np.isfinite(adaptive).all(axis=2)
        bad = (bad_state | (np.abs(x) > state_bound).any(axis=2)) & alive
        for b in np.flatnonzero(bad.any(axis=0)):
            row = int(np.argmax(bad[:, b]))
            kept[b] = first + row + 1
            diverged_time[b] = (first + row) * dt
            reasons[b] = (
                "state or adaptive estimate became NaN/Inf"
                if bad_state[row, b]
                else f"state left the bound |x_i| <= {state_bound:g}"
            )
            alive[b] = False

    def reduce(stop: int) -> None:
        """record="metrics": fold the buffered rows [base, stop) into ``reduced``."""
        nonlocal base
        with np.errstate(all="ignore"):
            for first in range(0, stop - base, block):
                b_ = slice(first, min(stop - base, first + block))
                span = (base + b_.start, base + b_.stop)
                reduced.add(base + first, t_rows(*span), X[b_], XM[b_], XQ[b_], U[b_], S[b_],
                            yd_rows(*span), kept, controller)
        base = stop

    x0 = np.broadcast_to(np.asarray(x0, dtype=float), (batch, n))
    # The loop below is one code for both kinds of batch; what differs is how values are held.
    # A batch of one runs on plain floats: the plant's state and readings as lists, the quantized
    # reading and the adaptive state as tuples of floats (a numpy call on a one-element array
    # costs about a microsecond, float arithmetic tens of nanoseconds), and the rows are buffered
    # as tuples and written to the arrays in blocks. A larger batch holds (batch, n) arrays and
    # (batch,) columns. The controller's formulas are the same for both (see qcontrol.controller).
    floats = batch == 1
    if floats:
        adaptive = tuple(controller.initial_state(1)[0].tolist())
        pending: list[tuple] = []  # the rows up to the last one recorded, not yet written to X .. S
        quantize_ = float_quantizer(quantizer)
        # tested in blocks at the events below, not every step: a per-step test cost about 1 us of
        # a 25 us MuJoCo step (four builtin calls, with the interpreter's caches cold after
        # mj_step). The copy may run on for up to FLUSH_ROWS steps after it diverged; those rows
        # do not count.

        def record(j: int, x: list[float], meas: list[float], reading: QuantizedReading, u: float,
                   adaptive: tuple) -> None:
            pending.append((*x, *meas, *reading.columns, u, *adaptive))

        def flush(stop: int) -> None:
            """Write the pending rows, which end at buffer row ``stop``."""
            if not pending:
                return
            block = np.array(pending, dtype=float)
            rows_ = slice(stop - len(pending), stop)
            X[rows_, 0], XM[rows_, 0] = block[:, :n], block[:, n : 2 * n]
            XQ[rows_, 0] = block[:, 2 * n : 3 * n]
            U[rows_, 0], S[rows_, 0] = block[:, 3 * n], block[:, 3 * n + 1 :]
            pending.clear()
    else:
        adaptive = tuple(np.ascontiguousarray(controller.initial_state(batch).T))

        def quantize_(meas: np.ndarray) -> QuantizedReading:
            return quantize(quantizer, meas)

        def healthy(j: int) -> bool:
            """Buffer row ``j`` just recorded, while it is in the cache (NaN fails either test)."""
            return np.abs(X[j]).max() <= state_bound and math.isfinite(S[j].sum())

        def record(j: int, x: np.ndarray, meas: np.ndarray, reading: QuantizedReading, u: np.ndarray,
                   adaptive: tuple) -> None:
            X[j], XM[j], XQ[j], U[j] = x, meas, reading.values, u
            for i, a in enumerate(adaptive):
                S[j, :, i] = a

    report_every = max(1, rows // 100)

    def next_event(k: int) -> int:
        """The first row after ``k`` at which the loop has more to do than step: write and test
        a batch of one's pending rows (at least every ``FLUSH_ROWS``), report progress, reduce a
        full buffer, call the observer, or end."""
        upcoming = rows - 1
        if floats:
            upcoming = min(upcoming, ((k + 1) // FLUSH_ROWS + 1) * FLUSH_ROWS - 1)
        if progress is not None:
            upcoming = min(upcoming, (k // report_every + 1) * report_every)
        if metrics_only:
            upcoming = min(upcoming, chunk_end(base, chunk))
        elif observer is not None:
            upcoming = min(upcoming, chunk_end(observed, observe_every))
        return upcoming

    yd_block: list[list[float]] = []
    yd_start = yd_stop = 0
    started = time.perf_counter()
    observed = 0
    base = 0  # row held in X[0] .. S[0]
    tested = 0  # rows [0, tested) are tested for divergence
    control, advance = controller.control, controller.advancer(dt, floats)
    with plant, np.errstate(all="ignore"):
        plant.reset(x0)
        if floats and hasattr(plant, "scalar_io"):
            observe, step = plant.scalar_io(dt)
        elif floats:
            def observe() -> tuple[list[float], list[float]]:
                return plant.state()[0].tolist(), plant.read_sensors()[0].tolist()

            def step(u: float) -> None:
                plant.step(np.array([u]), dt)
        else:
            def observe() -> tuple[np.ndarray, np.ndarray]:
                return plant.state(), plant.read_sensors()

            def step(u: np.ndarray) -> None:
                plant.step(u, dt)
        event = next_event(-1)
        for k in range(rows):
            x, meas = observe()
            reading = quantize_(meas)
            if k % hold == 0:
                if k >= yd_stop:  # y_d .. y_d^(n) as floats (the same for every copy), a block at a time
                    yd_block, yd_start, yd_stop = yd_rows(k, k + FLUSH_ROWS).tolist(), k, k + FLUSH_ROWS
                out = control(reading, yd_block[k - yd_start], adaptive)
            record(k - base, x, meas, reading, out.u, adaptive)
            if not floats and not healthy(k - base):  # a batch: this row
                stop_diverged(k, k + 1)
                event = k  # see whether every copy has stopped
            if k == event:  # the rare rows: everything but the closed loop itself happens here
                if floats:  # a batch of one: its pending rows to the arrays, and tested
                    flush(k - base + 1)
                    stop_diverged(tested, k + 1)
                    tested = k + 1
                if not alive.any():  # every copy has stopped: end where the last one did (the
                    k = int(kept.max()) - 1  # same row for a batch of one as a per-step test)
                if progress is not None and (k % report_every == 0 or k == rows - 1):
                    progress(k, rows - 1)
                finished = k == rows - 1 or not alive.any()
                if metrics_only:
                    if finished or k == chunk_end(base, chunk):
                        if observer is not None:
                            observer(0, k + 1 - base, chunk_runs(k + 1, time.perf_counter()))
                        reduce(k + 1)
                elif observer is not None and (finished or k == chunk_end(observed, observe_every)):
                    observer(observed, k + 1, collect(np.minimum(kept, k + 1), time.perf_counter()))
                    observed = k + 1
                if finished:
                    break
                event = next_event(k)
            step(out.u)
            adaptive = advance(adaptive, out)
    if metrics_only:
        now = time.perf_counter()
        return [
            reduced.run(b, kept[b], controller, dt, steps * dt, diverged_time[b], reasons[b],
                        now - started)
            for b in range(batch)
        ]
    return collect(kept, time.perf_counter())


class _Reduced:
    """The running reductions of ``record="metrics"`` (see :class:`RunMetrics`)."""

    def __init__(self, rows: int, batch: int, n: int, state_size: int, duration: float) -> None:
        self.rows = rows
        self.stream = ErrorRateStream(duration, batch=batch)
        self.half = duration / 2.0
        self.z1_last_half = np.full(batch, -np.inf)
        self.max_abs_u = np.full(batch, -np.inf)
        self.e_z_max = np.full((batch, n), -np.inf)
        self.final = np.full((batch, state_size), np.nan)

    def add(self, base: int, t: np.ndarray, X: np.ndarray, XM: np.ndarray, XQ: np.ndarray, U: np.ndarray,
            S: np.ndarray, YD: np.ndarray, kept: np.ndarray, controller: Controller) -> None:
        """Rows ``base .. base + len(X)`` at instants ``t``; rows at or after a copy's ``kept`` do
        not count. The formulas are the ones :func:`simulate` uses to derive ``z`` and ``e_z`` in
        full records, and :func:`qcontrol.metrics.summary` reduces them the same way."""
        rows = np.arange(base, base + len(X))
        # every row counts (and is Lemma 2 checked) unless a copy stopped in or before the block
        everyone = kept.min() > base + len(X)
        valid = True if everyone else rows[:, None] < kept[None, :]
        yd = YD[:, None, :]
        z1 = X[..., 0] - YD[:, None, 0]  # z_1 = x_1 - y_d, eq. (7)
        self.stream.add(t, z1 if everyone else np.where(valid, z1, np.nan))
        late = valid & (t >= self.half)[:, None] & np.isfinite(z1)
        np.maximum(self.z1_last_half, np.where(late, np.abs(z1), -np.inf).max(axis=0), out=self.z1_last_half)
        _, e_z = lemma2_errors(controller, XM, XQ, yd)
        # as metrics.summary: the Lemma 2 check stops before the row that stopped a diverged copy
        checked = np.isfinite(e_z)
        if not everyone:
            checked &= (rows[:, None] < np.where(kept < self.rows, kept - 1, kept)[None, :])[..., None]
        np.maximum(self.e_z_max, np.where(checked, e_z, -np.inf).max(axis=0), out=self.e_z_max)
        abs_u = np.abs(U)
        np.maximum(self.max_abs_u, np.where(valid & np.isfinite(abs_u), abs_u, -np.inf).max(axis=0),
                   out=self.max_abs_u)
        last = kept - 1 - base
        here = (last >= 0) & (last < len(X))
        self.final[here] = S[last[here], np.flatnonzero(here)]

    def run(self, b: int, kept: int, controller: Controller, dt: float, duration: float,
            diverged_time: float | None, reason: str, wall_time_s: float) -> RunMetrics:
        z1_late = float(self.z1_last_half[b])
        return RunMetrics(
            steps=int(kept) - 1,
            error_rate=self.stream.rates(run=b),
            max_abs_z1_last_half=z1_late if math.isfinite(z1_late) else math.nan,
            max_abs_u=float(self.max_abs_u[b]),
            e_z_max=self.e_z_max[b].copy(),
            final_adaptive=self.final[b].copy(),
            adaptive_name=controller.state_name,
            L_z=controller.L_z.copy(),
            dt=dt,
            duration=duration,
            diverged=diverged_time is not None,
            diverged_time=diverged_time,
            divergence_reason=reason,
            wall_time_s=wall_time_s,
        )
